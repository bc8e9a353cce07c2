//! The run's metadata record: what flew, with what, from which seed, written by which version.

use std::collections::BTreeMap;

use serde::Serialize;

use super::RecordError;

/// Version of the file layout described in the [module documentation](super). Bumped when a
/// reader of older files would misread newer ones (renamed metadata key, changed time base,
/// changed meaning of a topic), not when channels are added.
///
/// 2: the camera channels (`/camera/<name>/image`, `/camera/<name>/calibration`,
/// `/camera/tf`) are the Foxglove SDK's protobuf messages, no longer JSON. Version 1 logs
/// are still read (`replay` and `compare` do not read the camera channels).
pub const LOG_FORMAT_VERSION: u32 = 2;

/// Name of the MCAP metadata record that carries a [`RunMetadata`].
pub const RUN_METADATA_NAME: &str = "amstack.run";

/// The amstack version that writes files (the workspace version of this crate).
pub const AMSTACK_VERSION: &str = env!("CARGO_PKG_VERSION");

// Keys of the `amstack.run` metadata record (all values are strings, as MCAP requires).
const KEY_VEHICLE: &str = "vehicle_id";
const KEY_CONTROLLER: &str = "controller";
const KEY_INTERFACE: &str = "interface";
const KEY_TRAJECTORY: &str = "trajectory";
const KEY_CONFIG: &str = "config";
const KEY_CONTROLLER_CONFIG: &str = "controller_config";
const KEY_SEED: &str = "seed";
const KEY_VERSION: &str = "amstack_version";
const KEY_FORMAT: &str = "log_format_version";

/// Who and what a run was; written once, as the `amstack.run` metadata record, right after the
/// file header (so it survives any crash after [`McapRecorder::create`](super::McapRecorder::create)
/// returns).
///
/// In the record every value is a string: `seed` and `log_format_version` in decimal, `config`
/// as the JSON document itself; `interface` and `trajectory` are absent when `None`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunMetadata {
    /// Vehicle name as `platform` knows it (e.g. `fa-hexa`).
    pub vehicle_id: String,
    /// Base controller (e.g. `pid`, `l1`).
    pub controller: String,
    /// Action interface of a benchmark run (e.g. `ik`, `mpc`, `base-joint`), if any.
    pub interface: Option<String>,
    /// Reference trajectory of a `track` run (e.g. `sines-low`), if any.
    pub trajectory: Option<String>,
    /// The run's complete configuration as one JSON document (`{}` when there is none).
    pub config_json: String,
    /// The controller's configuration (gains, limits) as one JSON document, if recorded
    /// (key `controller_config`; absent in files written before it was added).
    pub controller_config_json: Option<String>,
    /// Seed of every random stream of the run.
    pub seed: u64,
    /// amstack version that wrote the file; [`RunMetadata::new`] sets [`AMSTACK_VERSION`].
    pub amstack_version: String,
    /// File layout version; [`RunMetadata::new`] sets [`LOG_FORMAT_VERSION`].
    pub log_format_version: u32,
}

impl RunMetadata {
    /// Metadata of a run of this build: empty config, no interface, no trajectory.
    pub fn new(vehicle_id: impl Into<String>, controller: impl Into<String>, seed: u64) -> Self {
        Self {
            vehicle_id: vehicle_id.into(),
            controller: controller.into(),
            interface: None,
            trajectory: None,
            config_json: "{}".to_owned(),
            controller_config_json: None,
            seed,
            amstack_version: AMSTACK_VERSION.to_owned(),
            log_format_version: LOG_FORMAT_VERSION,
        }
    }

    /// Sets the action interface.
    #[must_use]
    pub fn with_interface(mut self, interface: impl Into<String>) -> Self {
        self.interface = Some(interface.into());
        self
    }

    /// Sets the reference trajectory.
    #[must_use]
    pub fn with_trajectory(mut self, trajectory: impl Into<String>) -> Self {
        self.trajectory = Some(trajectory.into());
        self
    }

    /// Sets the configuration from any serialisable config struct.
    pub fn with_config<C: Serialize + ?Sized>(mut self, config: &C) -> Result<Self, RecordError> {
        self.config_json = serde_json::to_string(config)
            .map_err(|e| RecordError::Metadata(format!("config does not serialise: {e}")))?;
        Ok(self)
    }

    /// Sets the controller's configuration from any serialisable config struct.
    pub fn with_controller_config<C: Serialize + ?Sized>(
        mut self,
        config: &C,
    ) -> Result<Self, RecordError> {
        self.controller_config_json = Some(serde_json::to_string(config).map_err(|e| {
            RecordError::Metadata(format!("controller config does not serialise: {e}"))
        })?);
        Ok(self)
    }

    /// Checks what a reader relies on: a vehicle and a controller are named and `config_json`
    /// is a JSON document.
    pub fn validate(&self) -> Result<(), RecordError> {
        if self.vehicle_id.is_empty() {
            return Err(RecordError::Metadata("vehicle_id is empty".to_owned()));
        }
        if self.controller.is_empty() {
            return Err(RecordError::Metadata("controller is empty".to_owned()));
        }
        serde_json::from_str::<serde_json::Value>(&self.config_json)
            .map_err(|e| RecordError::Metadata(format!("config_json is not JSON: {e}")))?;
        if let Some(c) = &self.controller_config_json {
            serde_json::from_str::<serde_json::Value>(c).map_err(|e| {
                RecordError::Metadata(format!("controller_config_json is not JSON: {e}"))
            })?;
        }
        Ok(())
    }

    /// The key/value map of the `amstack.run` metadata record.
    pub fn to_record_map(&self) -> BTreeMap<String, String> {
        let mut map = BTreeMap::new();
        let mut put = |k: &str, v: String| map.insert(k.to_owned(), v);
        put(KEY_VEHICLE, self.vehicle_id.clone());
        put(KEY_CONTROLLER, self.controller.clone());
        if let Some(interface) = &self.interface {
            put(KEY_INTERFACE, interface.clone());
        }
        if let Some(trajectory) = &self.trajectory {
            put(KEY_TRAJECTORY, trajectory.clone());
        }
        put(KEY_CONFIG, self.config_json.clone());
        if let Some(c) = &self.controller_config_json {
            put(KEY_CONTROLLER_CONFIG, c.clone());
        }
        put(KEY_SEED, self.seed.to_string());
        put(KEY_VERSION, self.amstack_version.clone());
        put(KEY_FORMAT, self.log_format_version.to_string());
        map
    }

    /// Parses the map of an `amstack.run` metadata record (the inverse of
    /// [`RunMetadata::to_record_map`]). Unknown keys are ignored, so newer writers may add some.
    pub fn from_record_map(map: &BTreeMap<String, String>) -> Result<Self, RecordError> {
        let get = |k: &str| {
            map.get(k)
                .cloned()
                .ok_or_else(|| RecordError::Metadata(format!("key `{k}` missing")))
        };
        let parse_err = |k: &str, v: &str| {
            RecordError::Metadata(format!("key `{k}` = `{v}` is not an unsigned integer"))
        };
        let seed = get(KEY_SEED)?;
        let format = get(KEY_FORMAT)?;
        Ok(Self {
            vehicle_id: get(KEY_VEHICLE)?,
            controller: get(KEY_CONTROLLER)?,
            interface: map.get(KEY_INTERFACE).cloned(),
            trajectory: map.get(KEY_TRAJECTORY).cloned(),
            config_json: get(KEY_CONFIG)?,
            controller_config_json: map.get(KEY_CONTROLLER_CONFIG).cloned(),
            seed: seed.parse().map_err(|_| parse_err(KEY_SEED, &seed))?,
            amstack_version: get(KEY_VERSION)?,
            log_format_version: format.parse().map_err(|_| parse_err(KEY_FORMAT, &format))?,
        })
    }

    /// The MCAP metadata record.
    pub(crate) fn to_record(&self) -> mcap::records::Metadata {
        mcap::records::Metadata {
            name: RUN_METADATA_NAME.to_owned(),
            metadata: self.to_record_map(),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    #[test]
    fn record_map_round_trips_with_and_without_optional_fields() {
        let bare = RunMetadata::new("fa-hexa", "pid", 7);
        assert_eq!(
            RunMetadata::from_record_map(&bare.to_record_map()).unwrap(),
            bare
        );
        assert!(!bare.to_record_map().contains_key(KEY_INTERFACE));

        #[derive(Serialize)]
        struct Config {
            rate_hz: f64,
            substeps: u32,
        }
        let full = RunMetadata::new("omni-hexa", "l1", u64::MAX)
            .with_interface("ik")
            .with_trajectory("sines-high")
            .with_config(&Config {
                rate_hz: 120.0,
                substeps: 4,
            })
            .unwrap()
            .with_controller_config(&Config {
                rate_hz: 1.0,
                substeps: 2,
            })
            .unwrap();
        let map = full.to_record_map();
        assert_eq!(map[KEY_SEED], "18446744073709551615");
        assert_eq!(map[KEY_CONFIG], r#"{"rate_hz":120.0,"substeps":4}"#);
        assert_eq!(map[KEY_FORMAT], LOG_FORMAT_VERSION.to_string());
        assert_eq!(RunMetadata::from_record_map(&map).unwrap(), full);
    }

    #[test]
    fn validate_rejects_what_a_reader_could_not_use() {
        assert!(RunMetadata::new("fa-hexa", "pid", 0).validate().is_ok());
        assert!(RunMetadata::new("", "pid", 0).validate().is_err());
        assert!(RunMetadata::new("fa-hexa", "", 0).validate().is_err());
        let mut bad = RunMetadata::new("fa-hexa", "pid", 0);
        bad.config_json = "{not json".to_owned();
        assert!(
            matches!(bad.validate(), Err(RecordError::Metadata(m)) if m.contains("config_json"))
        );
    }

    #[test]
    fn missing_or_malformed_keys_are_named() {
        let mut map = RunMetadata::new("fa-hexa", "pid", 1).to_record_map();
        map.insert(KEY_SEED.to_owned(), "-3".to_owned());
        let err = RunMetadata::from_record_map(&map).unwrap_err().to_string();
        assert!(err.contains("seed") && err.contains("-3"), "{err}");
        map.remove(KEY_CONTROLLER);
        let err = RunMetadata::from_record_map(&map).unwrap_err().to_string();
        assert!(err.contains("controller"), "{err}");
    }
}
