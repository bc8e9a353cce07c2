//! `amstack experiment ground-effect`: the paper's ground-effect comparison (appendix
//! "Ground-Effect Comparison"), re-flown in the twin. A twin flight with strong ground effect
//! stands in for the physical flight: the FA-Hexa flies the paper's EE path
//! z_ref = 0.8 + 0.2 cos(2πt/30) m (EE interface, IK-PID) with the paper's evaluation
//! disturbances and ground-effect intensity ρ = 3.4. It is replayed (reference mode: its
//! logged EE targets through IK-PID) with and without the ground-effect model, rotor limits
//! on, and each replay is compared with it over z_ref ≤ 0.7 m and z_ref ≥ 0.9 m.

use std::path::PathBuf;

use anyhow::Result;
use comfy_table::{Table, presets};
use policy_runtime::validation::CompareReport;
use serde_json::json;

use super::runs::{self, Check};
use crate::output::{significant, write_json};

pub(super) const AFTER_HELP: &str = "\
Flies the stand-in for the paper's physical flight: the FA-Hexa on the ground sweep (EE z =
0.8 + 0.2 cos(2 pi t / 30) m, EE interface, IK-PID, 60 s) with the paper's evaluation
disturbances (--disturbances reference) and ground effect of intensity k (the paper's rho,
3.4; r_p = 0.152 m, the vehicle's propeller radius). Then replays it twice (amstack replay,
reference mode, on --jobs threads): with the ground-effect model (disturbances ground,
saturation) and without (saturation), and compares each replay with the stand-in over the
paper's two shaded intervals, z_ref <= 0.7 m and z_ref >= 0.9 m (amstack compare).

Writes into --out: ground-effect.json (the EE-z and base-z RMSE, max error and bias per
interval and replay, the paper's figures beside ours: 1.91 -> 0.99 cm near the ground,
0.75 / 0.84 cm away from it, and its claims checked), the table on the terminal,
ge-real.mcap, ge-sim-with.mcap, ge-sim-without.mcap, and ground-effect-with.png,
ground-effect-without.png (compare's plot: stand-in vs replay, the intervals shaded).

Example:
  amstack experiment ground-effect --out ground-effect/
  amstack experiment ground-effect --duration 20 --out quick/   (one pass near the ground)";

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Seed of the stand-in flight (its noise and wind draws); the replays keep it.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads for the two replays [default: all cores].
    #[arg(long)]
    jobs: Option<usize>,
    /// Length of the stand-in flight, s [default: 60, two periods of the sweep; 20 is one
    /// pass near the ground].
    #[arg(long, value_name = "S")]
    duration: Option<f64>,
    /// Ground-effect intensity k of the stand-in flight (the paper's rho).
    #[arg(long, value_name = "K", default_value_t = 3.4)]
    ground_effect_k: f64,
    #[command(flatten)]
    physics: crate::twin_flags::PhysicsFlags,
    /// Output folder (created; an existing one must be empty).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

const NEAR: &str = "z_ref<=0.7";
const HIGH: &str = "z_ref>=0.9";
const EE_Z: &str = "/ee/pose.pose.position.z";
const BASE_Z: &str = "/base/state.position_m[2]";

/// The paper's simulation-to-real EE-z RMSEs, cm: (with the model, without), near the ground
/// and away from it.
const PAPER_NEAR_CM: (f64, f64) = (0.99, 1.91);
const PAPER_HIGH_CM: (f64, f64) = (0.84, 0.75);

/// The replays: (key, label, disturbances).
const REPLAYS: [(&str, &str, &str); 2] = [
    ("with", "simulation with ground effect", "ground,saturation"),
    ("without", "simulation without ground effect", "saturation"),
];

fn cm(report: &CompareReport, signal: &str, interval: Option<&str>) -> Option<f64> {
    runs::stats(report, signal, interval)
        .and_then(|s| s.rmse)
        .map(|m| 100.0 * m)
}

fn cell(x: Option<f64>) -> String {
    x.filter(|v| v.is_finite())
        .map_or_else(|| "N/A".to_owned(), significant)
}

pub(super) fn run(a: &Args) -> Result<()> {
    let jobs = runs::prepare(a.jobs, &a.physics, a.duration, &a.out)?;
    let real = a.out.join("ge-real.mcap");
    let mut flags = runs::strings(&[
        "--platform",
        "fa-hexa",
        "--trajectory",
        "ground-sweep",
        "--interface",
        "ee",
        "--disturbances",
        "reference",
        "--saturated-allocation",
        "clip",
    ]);
    flags.extend([
        "--ground-effect-k".to_owned(),
        a.ground_effect_k.to_string(),
        "--seed".to_owned(),
        a.seed.to_string(),
        "--mcap".to_owned(),
        real.display().to_string(),
    ]);
    if let Some(d) = a.duration {
        flags.extend(["--duration".to_owned(), d.to_string()]);
    }
    // The replays fly the logged twin configuration, substeps included.
    flags.extend(a.physics.flag_line());
    let config = runs::track_config(&flags)?;
    let total = runs::seconds(std::slice::from_ref(&config));
    // The replays fly the same length again, each.
    let bar = runs::progress_bar(3 * total);
    bar.set_prefix("ground effect: the stand-in flight");
    let label = format!(
        "the stand-in flight (ground effect k = {}, disturbances reference)",
        a.ground_effect_k
    );
    let stand_in = runs::fly_tracks(std::slice::from_ref(&config), &[label], 1, &bar)?;
    let stand_in = stand_in.first().cloned();

    bar.set_prefix("ground effect: two replays");
    let sim = |key: &str| a.out.join(format!("ge-sim-{key}.mcap"));
    let prepared = REPLAYS
        .iter()
        .map(|(key, _, disturbances)| {
            let flags = vec![
                real.display().to_string(),
                "--disturbances".to_owned(),
                (*disturbances).to_owned(),
                "--out".to_owned(),
                sim(key).display().to_string(),
            ];
            let args: crate::replay::Args = crate::flag_line::parse("replay", &flags)?;
            crate::replay::prepare(&args)
        })
        .collect::<Result<Vec<_>>>()?;
    let replays = runs::in_parallel(prepared.len(), jobs, &|i| {
        let r = crate::replay::fly(&prepared[i])?;
        bar.inc(total);
        let (key, _, disturbances) = REPLAYS[i];
        bar.suspend(|| {
            eprintln!(
                "  replayed: {key} the ground-effect model (disturbances {disturbances}), {} ticks",
                r.replayed_ticks
            );
        });
        Ok(r)
    })?;
    bar.finish_and_clear();

    let mut reports = Vec::new();
    for (key, _, _) in REPLAYS {
        let report = runs::compare(&real, &sim(key), &[EE_Z, BASE_Z], &[NEAR, HIGH])?;
        runs::plot(&a.out.join(format!("ground-effect-{key}.png")), &report)?;
        reports.push(report);
    }
    let (with, without) = (&reports[0], &reports[1]);

    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "EE-z RMSE (cm)",
        "z_ref <= 0.7 m",
        "paper",
        "z_ref >= 0.9 m",
        "paper",
        "whole flight",
    ]);
    for ((_, label, _), (report, paper)) in REPLAYS.iter().zip([
        (with, (PAPER_NEAR_CM.0, PAPER_HIGH_CM.0)),
        (without, (PAPER_NEAR_CM.1, PAPER_HIGH_CM.1)),
    ]) {
        table.add_row([
            (*label).to_owned(),
            cell(cm(report, EE_Z, Some(NEAR))),
            format!("{:.2}", paper.0),
            cell(cm(report, EE_Z, Some(HIGH))),
            format!("{:.2}", paper.1),
            cell(cm(report, EE_Z, None)),
        ]);
    }
    println!("{table}");

    let near = (cm(with, EE_Z, Some(NEAR)), cm(without, EE_Z, Some(NEAR)));
    let high = (cm(with, EE_Z, Some(HIGH)), cm(without, EE_Z, Some(HIGH)));
    let reduction = match near {
        (Some(w), Some(wo)) if wo > 0.0 => Some(100.0 * (1.0 - w / wo)),
        _ => None,
    };
    let checks = vec![
        Check::new(
            "near the ground (z_ref <= 0.7 m) the model lowers the sim-to-real EE-z error",
            format!(
                "{} -> {} cm ({} % lower)",
                cell(near.1),
                cell(near.0),
                reduction.map_or_else(|| "N/A".to_owned(), |r| format!("{r:.0}"))
            ),
            "1.91 -> 0.99 cm (48 % lower)",
            matches!(near, (Some(w), Some(wo)) if w < wo),
        ),
        Check::new(
            "away from the ground (z_ref >= 0.9 m) the errors with and without the model are comparable (within 2x)",
            format!("{} cm with, {} cm without", cell(high.0), cell(high.1)),
            "0.84 cm with, 0.75 cm without",
            matches!(high, (Some(w), Some(wo)) if w.max(wo) <= 2.0 * w.min(wo)),
        ),
    ];
    runs::print_checks(&checks);

    let compared = |report: &CompareReport, key: &str| {
        json!({
            "replay": sim(key),
            "plot": a.out.join(format!("ground-effect-{key}.png")),
            "ee_z_rmse_cm": {
                "near_ground": cm(report, EE_Z, Some(NEAR)),
                "high": cm(report, EE_Z, Some(HIGH)),
                "whole": cm(report, EE_Z, None),
            },
            "compare": report,
        })
    };
    let document = json!({
        "experiment": "ground-effect",
        "platform": "fa-hexa",
        "seed": a.seed,
        "ground_effect_k": a.ground_effect_k,
        "physics_substeps": config.twin.physics_substeps,
        "solver_iterations": config.twin.solver_iterations,
        "rapier_steps": config.twin.rapier_steps,
        "intervals": {"near_ground": NEAR, "high": HIGH},
        "stand_in": {"mcap": real, "track": stand_in},
        "replays": replays,
        "with": compared(with, "with"),
        "without": compared(without, "without"),
        "near_ground_reduction_pct": reduction,
        "paper": {
            "ee_z_rmse_cm": {
                "with": {"near_ground": PAPER_NEAR_CM.0, "high": PAPER_HIGH_CM.0},
                "without": {"near_ground": PAPER_NEAR_CM.1, "high": PAPER_HIGH_CM.1},
            },
            "near_ground_reduction_pct": 48,
        },
        "checks": checks,
    });
    let path = a.out.join("ground-effect.json");
    write_json(&path, &document)?;
    eprintln!(
        "wrote {}, ground-effect-with.png, ground-effect-without.png and three logs in {}",
        path.display(),
        a.out.display()
    );
    Ok(())
}
