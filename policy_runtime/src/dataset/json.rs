//! JSON whose objects keep the order they were built in (lerobot's `info.json` and
//! `stats.json` list features in frame order), written as lerobot writes it (indent 4).

use serde::ser::{Serialize, SerializeMap, Serializer};
use serde_json::Value;

/// An ordered JSON value.
#[derive(Debug, Clone, PartialEq)]
pub enum J {
    /// An object, in this order.
    Obj(Vec<(String, J)>),
    /// Any other value (its own objects sorted).
    V(Value),
}

impl Serialize for J {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::V(v) => v.serialize(serializer),
            Self::Obj(fields) => {
                let mut map = serializer.serialize_map(Some(fields.len()))?;
                for (k, v) in fields {
                    map.serialize_entry(k, v)?;
                }
                map.end()
            }
        }
    }
}

impl J {
    /// An object of `(key, value)` pairs.
    pub fn obj<K: Into<String>>(fields: impl IntoIterator<Item = (K, J)>) -> Self {
        Self::Obj(fields.into_iter().map(|(k, v)| (k.into(), v)).collect())
    }

    /// Pretty text, 4-space indent, newline-free end (as Python's `json.dump(indent=4)`).
    pub fn pretty(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let formatter = serde_json::ser::PrettyFormatter::with_indent(b"    ");
        let mut ser = serde_json::Serializer::with_formatter(&mut out, formatter);
        // Serialising our own values into memory cannot fail (no map key is non-string).
        let _ = self.serialize(&mut ser);
        out
    }
}

impl From<Value> for J {
    fn from(v: Value) -> Self {
        Self::V(v)
    }
}
