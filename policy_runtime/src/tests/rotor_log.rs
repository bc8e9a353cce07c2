//! What `/rotors` says of thrusts beyond the rotor limits, with and without them.

use platform::{Measurement, RotorReport, Vehicle};

use crate::flight_log::FlightLog;
use crate::record::{McapRecorder, Recording, RunMetadata};

/// `/rotors.saturated` of one logged outcome with realised thrusts `realised` (N).
fn logged_saturated(limits_enforced: bool, realised: &[f64]) -> bool {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rotors.mcap");
    let run = RunMetadata::new(&vehicle.id, "pid6", 0);
    let mut log = FlightLog::new(McapRecorder::create(&path, &run).unwrap(), &vehicle)
        .unwrap()
        .with_rotor_limits(limits_enforced);
    let m = Measurement {
        rotors: realised
            .iter()
            .map(|&t| RotorReport {
                commanded_n: t,
                realised_n: t,
                applied_n: t,
                ..RotorReport::default()
            })
            .collect(),
        ..Measurement::default()
    };
    log.outcome(&m).unwrap();
    log.finish().unwrap();
    let recording = Recording::from_bytes(&std::fs::read(&path).unwrap()).unwrap();
    let message = recording
        .messages
        .iter()
        .find(|m| m.topic == "/rotors")
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&message.data).unwrap();
    v["saturated"].as_bool().unwrap()
}

/// With the twin's rotor limits off (ideal rotors) a thrust of 30 N or −1 N is what the rotor
/// did, not a rotor at its limit: `/rotors.saturated` used to read true there.
#[test]
fn without_rotor_limits_no_thrust_is_saturated() {
    let beyond = [30.0, -1.0, 12.0, 12.0, 12.0, 12.0];
    assert!(!logged_saturated(false, &beyond));
    // With the limits (23 N), the same thrusts are beyond them.
    assert!(logged_saturated(true, &beyond));
    // And within them, nothing is saturated either way.
    let within = [12.0; 6];
    assert!(!logged_saturated(true, &within));
    assert!(!logged_saturated(false, &within));
}
