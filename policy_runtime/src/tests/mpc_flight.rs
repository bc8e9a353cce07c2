//! The `mpc` controller through `amstack track`'s flight: its log, and its clock.

use controllers::{ControllerConfig, ControllerKind, profile};
use platform::Vehicle;
use sim_twin::TwinConfig;

use crate::record::Recording;
use crate::stack::{Clock, WallClock};
use crate::track::{Interface, TrackConfig, TrackResult, run_track};
use crate::trajectory::Trajectory;

fn mpc_hover(
    mcap: Option<std::path::PathBuf>,
    budget_s: Option<f64>,
    clock: Option<Clock>,
) -> TrackConfig {
    let vehicle = Vehicle::builtin("fa-hexa").unwrap();
    let mut controller = profile(&vehicle, ControllerKind::Mpc).unwrap();
    if let ControllerConfig::Mpc(c) = &mut controller {
        c.solve_budget_s = budget_s;
    }
    TrackConfig {
        live: None,
        cameras: None,
        controller,
        vehicle,
        trajectory: Trajectory::Hover,
        interface: Interface::Ee,
        duration_s: 0.5,
        settle_s: 0.0,
        twin: TwinConfig::default(),
        mcap,
        state_source: crate::StateSource::Truth,
        clock,
    }
}

fn fly(config: &TrackConfig) -> TrackResult {
    run_track(config, |_| std::ops::ControlFlow::Continue(())).unwrap()
}

/// The `/mpc/status` messages of a log, parsed.
fn statuses(path: &std::path::Path) -> Vec<serde_json::Value> {
    let bytes = std::fs::read(path).unwrap();
    let recording = Recording::from_bytes(&bytes).unwrap();
    recording
        .messages
        .iter()
        .filter(|m| m.topic == "/mpc/status")
        .map(|m| serde_json::from_slice(&m.data).unwrap())
        .collect()
}

#[test]
fn an_mpc_flight_logs_the_mpc_status_every_tick() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mpc.mcap");
    let result = fly(&mpc_hover(Some(path.clone()), None, None));
    assert_eq!(result.controller, "mpc");
    let all = statuses(&path);
    assert_eq!(all.len() as u64, result.ticks);
    assert_eq!(all[0]["mode"], "mpc");
    assert_eq!(all[0]["qp_status"], "solved");
    // In the twin the stack has no clock: no wall-clock reading enters the log.
    assert!(all.iter().all(|s| s["solve_time_ms"].is_null()));
    // A flight given the wall clock (as on hardware) times its solves.
    let timed = dir.path().join("timed.mcap");
    fly(&mpc_hover(
        Some(timed.clone()),
        None,
        Some(std::sync::Arc::new(WallClock::new())),
    ));
    assert!(
        statuses(&timed)
            .iter()
            .all(|s| s["solve_time_ms"].as_f64().is_some_and(|t| t > 0.0))
    );
}

/// The stack used to time the MPC with the wall clock whatever the link: a twin run with a
/// solve budget then depended on the machine's speed. The clock is injected now: without one
/// a 1 ns budget is never exceeded and two runs are identical bit for bit; with the wall clock
/// every solve exceeds it and the MPC hands over to its fallback.
#[test]
fn a_solve_budget_in_the_twin_does_not_read_the_wall_clock() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        dir.path().join("a.mcap"),
        dir.path().join("b.mcap"),
        dir.path().join("c.mcap"),
    );
    let ra = fly(&mpc_hover(Some(a.clone()), Some(1e-9), None));
    let rb = fly(&mpc_hover(Some(b.clone()), Some(1e-9), None));
    assert_eq!(ra.ee_pos_rmse_m.to_bits(), rb.ee_pos_rmse_m.to_bits());
    assert_eq!(ra.base_pos_rmse_m.to_bits(), rb.base_pos_rmse_m.to_bits());
    let (sa, sb) = (statuses(&a), statuses(&b));
    assert_eq!(sa, sb);
    assert!(
        sa.iter().all(|s| s["failure"].is_null()),
        "no over-budget failure without a clock"
    );
    fly(&mpc_hover(
        Some(c.clone()),
        Some(1e-9),
        Some(std::sync::Arc::new(WallClock::new())),
    ));
    assert!(
        statuses(&c).iter().any(|s| s["failure"] == "over_budget"),
        "with the wall clock a 1 ns budget is exceeded"
    );
}
