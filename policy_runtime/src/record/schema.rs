//! Channel schemas: the JSON Schema of a Rust type (schemars, one source of truth) under an
//! explicit MCAP schema name.

use schemars::JsonSchema;
use schemars::generate::SchemaSettings;

/// MCAP message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "json";
/// MCAP schema encoding of every schema.
pub const SCHEMA_ENCODING: &str = "jsonschema";

/// The name of the MCAP schema record of a message type.
///
/// This name is what a viewer matches on: Foxglove draws a channel whose schema is named
/// `foxglove.PoseInFrame` as a pose, whatever the schema text says. So the name is stated
/// explicitly, next to the type, instead of being derived from the Rust type name:
///
/// - Foxglove's well-known types ([`foxglove`](super::foxglove)) use Foxglove's exact names;
/// - amstack's own types use `amstack.<Type>` (e.g. `amstack.RotorThrusts`).
///
/// ```
/// use policy_runtime::record::SchemaName;
/// #[derive(serde::Serialize, schemars::JsonSchema)]
/// struct SaturationFlag { saturated: bool }
/// impl SchemaName for SaturationFlag {
///     const SCHEMA_NAME: &'static str = "amstack.SaturationFlag";
/// }
/// ```
pub trait SchemaName {
    /// The MCAP schema name.
    const SCHEMA_NAME: &'static str;
}

/// The JSON Schema (draft 2020-12) of `T`'s serialised form as compact JSON bytes: nested types
/// inlined (no `$ref`/`$defs`, like Foxglove's published schemas) and the root `title` set to
/// [`SchemaName::SCHEMA_NAME`].
pub fn json_schema_of<T: JsonSchema + SchemaName + ?Sized>() -> Result<Vec<u8>, serde_json::Error> {
    let generator = SchemaSettings::draft2020_12()
        .for_serialize()
        .with(|s| s.inline_subschemas = true)
        .into_generator();
    let mut schema = generator.into_root_schema_for::<T>();
    schema.insert("title".to_owned(), T::SCHEMA_NAME.into());
    serde_json::to_vec(&schema)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    #[derive(serde::Serialize, JsonSchema)]
    struct Inner {
        /// Thrust per rotor, N.
        thrust_n: Vec<f64>,
    }

    /// A test message.
    #[derive(serde::Serialize, JsonSchema)]
    struct Outer {
        tick: u64,
        inner: Inner,
        note: Option<String>,
    }
    impl SchemaName for Outer {
        const SCHEMA_NAME: &'static str = "amstack.test.Outer";
    }

    #[test]
    fn schema_is_self_contained_and_titled_with_the_schema_name() {
        let bytes = json_schema_of::<Outer>().unwrap();
        let schema: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        assert_eq!(schema["title"], "amstack.test.Outer");
        assert_eq!(schema["type"], "object");
        assert!(
            schema.get("$defs").is_none(),
            "nested types are inlined: {schema}"
        );
        assert!(!String::from_utf8(bytes.clone()).unwrap().contains("$ref"));
        assert_eq!(
            schema["properties"]["inner"]["properties"]["thrust_n"]["type"],
            "array"
        );
        assert_eq!(
            schema["properties"]["inner"]["properties"]["thrust_n"]["items"]["type"],
            "number"
        );
        let required: Vec<&str> = schema["required"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap())
            .collect();
        // The schema describes what is serialised: an `Option` field is always written (as
        // `null` when `None`), so it is required and may be null.
        assert_eq!(required, ["tick", "inner", "note"]);
        assert_eq!(
            schema["properties"]["note"]["type"],
            serde_json::json!(["string", "null"])
        );
        // Deterministic: the same type gives the same bytes.
        assert_eq!(bytes, json_schema_of::<Outer>().unwrap());
    }
}
