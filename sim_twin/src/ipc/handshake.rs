//! What the two sides must agree on before they fly, and the refusal that names both values.
//!
//! Hashes are FNV-1a (64 bit) of JSON: the vehicle description as `platform` serialises it
//! (any change of a mass, a rotor position or a joint limit changes it) and the twin
//! configuration ([`TwinConfig`], seed included).

use platform::Vehicle;
use serde_json::Value;

use super::messages::{
    Hello, MAX_CONFIG_BYTES, MAX_JOINTS, MAX_ROTORS, MESSAGE_VERSION, TooLarge, get_str, put_str,
};
use crate::TwinConfig;

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Hash of the vehicle description.
pub fn vehicle_hash(vehicle: &Vehicle) -> u64 {
    fnv1a(
        serde_json::to_string(vehicle)
            .unwrap_or_default()
            .as_bytes(),
    )
}

/// The twin configuration as the handshake carries it (JSON).
pub fn config_json(config: &TwinConfig) -> String {
    serde_json::to_string(config).unwrap_or_default()
}

/// Hash of the twin configuration.
pub fn config_hash(config: &TwinConfig) -> u64 {
    fnv1a(config_json(config).as_bytes())
}

/// One side's terms: what it flies or serves.
#[derive(Debug, Clone, PartialEq)]
pub struct Offer {
    /// Vehicle id.
    pub vehicle_id: String,
    /// [`vehicle_hash`].
    pub vehicle_hash: u64,
    /// Control rate, Hz.
    pub control_rate_hz: f64,
    /// [`config_json`].
    pub config_json: String,
    /// [`config_hash`].
    pub config_hash: u64,
    /// Rotors.
    pub rotor_count: usize,
    /// Movable joints.
    pub joint_count: usize,
}

impl Offer {
    /// The terms of flying `vehicle` in a twin configured by `config`.
    pub fn new(vehicle: &Vehicle, config: &TwinConfig) -> Result<Self, TooLarge> {
        let offer = Self {
            vehicle_id: vehicle.id.clone(),
            vehicle_hash: vehicle_hash(vehicle),
            control_rate_hz: config.control_rate_hz,
            config_json: config_json(config),
            config_hash: config_hash(config),
            rotor_count: vehicle.rotors.len(),
            joint_count: vehicle.model.dof(),
        };
        if offer.rotor_count > MAX_ROTORS {
            return Err(TooLarge {
                what: "rotors",
                count: offer.rotor_count,
                max: MAX_ROTORS,
            });
        }
        if offer.joint_count > MAX_JOINTS {
            return Err(TooLarge {
                what: "movable joints",
                count: offer.joint_count,
                max: MAX_JOINTS,
            });
        }
        if offer.config_json.len() > MAX_CONFIG_BYTES {
            return Err(TooLarge {
                what: "twin configuration bytes",
                count: offer.config_json.len(),
                max: MAX_CONFIG_BYTES,
            });
        }
        Ok(offer)
    }

    /// The flight's [`Hello`] with these terms.
    pub fn hello(&self, pid: u32, node_id: [u64; 2]) -> Hello {
        let mut hello = Hello {
            pid,
            node_id,
            control_rate_hz: self.control_rate_hz,
            vehicle_hash: self.vehicle_hash,
            config_hash: self.config_hash,
            ..Hello::default()
        };
        hello.id_len = put_str(&mut hello.vehicle_id, &self.vehicle_id);
        hello.config_len = put_str(&mut hello.config_json, &self.config_json);
        hello
    }
}

/// The fields of the twin configuration a flight process may choose per session when the
/// twin lets it choose the episode.
const EPISODE_FIELDS: [&str; 2] = ["seed", "task"];

/// Checks a flight's [`Hello`] against the twin's terms; the refusal names both values
/// (message version, vehicle id, vehicle description, control rate, then the first field of
/// the twin configuration that differs). With `flight_chooses_episode`, the configuration's
/// `seed` and `task` are the flight's to choose.
pub fn check_hello(
    hello: &Hello,
    twin: &Offer,
    flight_chooses_episode: bool,
) -> Result<(), String> {
    if hello.version != MESSAGE_VERSION {
        return Err(format!(
            "message version mismatch: the flight process speaks v{}, the twin v{MESSAGE_VERSION}",
            hello.version
        ));
    }
    let flight_id = get_str(&hello.vehicle_id, hello.id_len);
    if flight_id != twin.vehicle_id {
        return Err(format!(
            "vehicle mismatch: the flight process flies '{flight_id}', the twin serves '{}'",
            twin.vehicle_id
        ));
    }
    if hello.vehicle_hash != twin.vehicle_hash {
        return Err(format!(
            "vehicle '{flight_id}' is described differently: description hash {:016x} in the flight process, {:016x} in the twin",
            hello.vehicle_hash, twin.vehicle_hash
        ));
    }
    if hello.control_rate_hz.to_bits() != twin.control_rate_hz.to_bits() {
        return Err(format!(
            "control rate mismatch: the flight process runs at {} Hz, the twin at {} Hz",
            hello.control_rate_hz, twin.control_rate_hz
        ));
    }
    let flight_json = get_str(&hello.config_json, hello.config_len);
    if flight_chooses_episode {
        let without_episode = |json: &str| {
            let mut value: Value = serde_json::from_str(json).ok()?;
            let object = value.as_object_mut()?;
            for field in EPISODE_FIELDS {
                object.remove(field);
            }
            Some(value)
        };
        let flight = without_episode(&flight_json)
            .ok_or_else(|| "the flight process's twin configuration is not valid".to_owned())?;
        let served = without_episode(&twin.config_json).unwrap_or(Value::Null);
        return match diff(&flight, &served, String::new()) {
            None if serde_json::from_str::<TwinConfig>(&flight_json).is_ok() => Ok(()),
            None => Err("the flight process's twin configuration is not valid".to_owned()),
            Some((path, a, b)) => Err(format!(
                "twin configuration mismatch at {path}: flight {a}, twin {b} (the episode, \
                 task and seed, is the flight's to choose)"
            )),
        };
    }
    if hello.config_hash != twin.config_hash {
        let difference = first_difference(&flight_json, &twin.config_json)
            .map(|(path, a, b)| format!(" at {path}: flight {a}, twin {b};"))
            .unwrap_or_default();
        return Err(format!(
            "twin configuration mismatch:{difference} hash {:016x} in the flight process, {:016x} in the twin",
            hello.config_hash, twin.config_hash
        ));
    }
    Ok(())
}

/// The first leaf where two JSON documents differ: its path and both values.
fn first_difference(a: &str, b: &str) -> Option<(String, String, String)> {
    let a: Value = serde_json::from_str(a).ok()?;
    let b: Value = serde_json::from_str(b).ok()?;
    diff(&a, &b, String::new())
}

fn diff(a: &Value, b: &Value, path: String) -> Option<(String, String, String)> {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter().find_map(|k| {
                let child = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                diff(
                    x.get(k).unwrap_or(&Value::Null),
                    y.get(k).unwrap_or(&Value::Null),
                    child,
                )
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (p, q))| diff(p, q, format!("{path}[{i}]"))),
        _ if a == b => None,
        _ => Some((path, a.to_string(), b.to_string())),
    }
}
