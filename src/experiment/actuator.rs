//! `amstack experiment actuator`: the paper's "Actuator Dynamics Identification and Vertical
//! Tracking" table. The FA-Hexa (PID, rotor limits on) flies the low- and high-frequency
//! vertical sums of sines (`track --trajectory sines-low|sines-high`) under four motor
//! models: none, the identified first-order lag (τ = 47.5 ms), the normalised-speed rate cap
//! (0.75 s⁻¹), both. Base-z RMSE and the largest rotor thrust, beside the paper's figures.

use std::path::PathBuf;

use anyhow::Result;
use comfy_table::{Table, presets};
use serde_json::json;

use super::runs::{self, Check};
use crate::cli_error::bad_input;
use crate::output::write_json;

pub(super) const AFTER_HELP: &str = "\
Flies, for each of the four motor models (no dynamics; lag tau = 47.5 ms; rate cap 0.75 1/s;
both), the FA-Hexa with its PID and rotor limits on (--disturbances saturation) on the two
vertical references of the paper: sines-low (four 1 cm sines over 0.18-0.71 Hz) and
sines-high (0.25-1.50 Hz). Eight independent flights, run on --jobs threads (the figures do
not depend on it). Errors are scored after track's 2 s settling time.

Writes into --out: actuator.json (per motor model and band the base-z RMSE, the largest
rotor thrust, the saturation rate, the paper's figure beside ours, and the paper's claims
checked: the lag raises the error, the rate cap barely changes it, no rotor reaches T_max),
the table on the terminal, logs/<model>-<band>.mcap (every flight), and
actuator-sines-low.png, actuator-sines-high.png (compare's plot: no dynamics against the lag,
base z and rotor 0's thrust).

Example:
  amstack experiment actuator --out actuator/
  amstack experiment actuator --duration 10 --jobs 2 --out quick/";

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Seed of every flight.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    jobs: Option<usize>,
    /// Length of each flight, s [default: track's, 30 s for the sines].
    #[arg(long, value_name = "S")]
    duration: Option<f64>,
    #[command(flatten)]
    physics: crate::twin_flags::PhysicsFlags,
    /// Output folder (created; an existing one must be empty).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

/// A motor model of the table, with the paper's base-z RMSEs (cm; its Table
/// "FA-Hexa vertical tracking under different actuator configurations").
struct Model {
    key: &'static str,
    label: &'static str,
    tau_s: Option<f64>,
    rate_limit_per_s: Option<f64>,
    paper_low_cm: f64,
    paper_high_cm: f64,
}

/// The identified motor time constant, s, and normalised-speed rate cap, 1/s (the paper's).
const TAU_S: f64 = 0.0475;
const RATE_LIMIT_PER_S: f64 = 0.75;

const MODELS: [Model; 4] = [
    Model {
        key: "none",
        label: "No motor dynamics",
        tau_s: None,
        rate_limit_per_s: None,
        paper_low_cm: 0.14,
        paper_high_cm: 1.96,
    },
    Model {
        key: "delay",
        label: "Motor delay (tau = 47.5 ms)",
        tau_s: Some(TAU_S),
        rate_limit_per_s: None,
        paper_low_cm: 0.58,
        paper_high_cm: 2.33,
    },
    Model {
        key: "rate-limit",
        label: "Rate limit (0.75 1/s)",
        tau_s: None,
        rate_limit_per_s: Some(RATE_LIMIT_PER_S),
        paper_low_cm: 0.14,
        paper_high_cm: 1.95,
    },
    Model {
        key: "delay-and-rate-limit",
        label: "Motor delay and rate limit",
        tau_s: Some(TAU_S),
        rate_limit_per_s: Some(RATE_LIMIT_PER_S),
        paper_low_cm: 0.58,
        paper_high_cm: 2.33,
    },
];

const BANDS: [&str; 2] = ["sines-low", "sines-high"];

/// The flights, model-major: index = model · 2 + band.
fn flags(a: &Args, model: &Model, band: &str, mcap: &std::path::Path) -> Vec<String> {
    let mut f = runs::strings(&[
        "--platform",
        "fa-hexa",
        "--trajectory",
        band,
        "--disturbances",
        "saturation",
        "--saturated-allocation",
        "clip",
    ]);
    f.extend(["--seed".to_owned(), a.seed.to_string()]);
    f.extend(a.physics.flag_line());
    if let Some(tau) = model.tau_s {
        f.extend(["--motor-tau".to_owned(), tau.to_string()]);
    }
    if let Some(rate) = model.rate_limit_per_s {
        f.extend(["--motor-rate-limit".to_owned(), rate.to_string()]);
    }
    if let Some(d) = a.duration {
        f.extend(["--duration".to_owned(), d.to_string()]);
    }
    f.extend(["--mcap".to_owned(), mcap.display().to_string()]);
    f
}

fn pct(ours: f64, base: f64) -> f64 {
    100.0 * (ours / base - 1.0)
}

pub(super) fn run(a: &Args) -> Result<()> {
    let jobs = runs::prepare(a.jobs, &a.physics, a.duration, &a.out)?;
    let logs = a.out.join("logs");
    std::fs::create_dir_all(&logs)
        .map_err(|e| bad_input(format!("--out {}: {e}", a.out.display())))?;
    let log_path = |m: &Model, band: &str| logs.join(format!("{}-{band}.mcap", m.key));
    let mut configs = Vec::new();
    let mut labels = Vec::new();
    for m in &MODELS {
        for band in BANDS {
            configs.push(runs::track_config(&flags(a, m, band, &log_path(m, band)))?);
            labels.push(format!("{band}, {}", m.label));
        }
    }
    let thrust_max_n = configs
        .first()
        .map_or(f64::NAN, |c| c.vehicle.rotors.thrust_max_n);
    let bar = runs::progress_bar(runs::seconds(&configs));
    bar.set_prefix("actuator: 4 motor models x 2 bands");
    let results = runs::fly_tracks(&configs, &labels, jobs, &bar)?;
    bar.finish_and_clear();

    let z_cm = |model: usize, band: usize| 100.0 * results[model * 2 + band].base_z_rmse_m;
    let peak = |model: usize| {
        (0..2)
            .filter_map(|b| results[model * 2 + b].max_rotor_thrust_n)
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "Actuator configuration",
        "Low-freq. RMSE (cm)",
        "paper",
        "High-freq. RMSE (cm)",
        "paper",
        "Max rotor thrust (N)",
    ]);
    let mut rows = Vec::new();
    for (i, m) in MODELS.iter().enumerate() {
        table.add_row([
            m.label.to_owned(),
            format!("{:.4}", z_cm(i, 0)),
            format!("{:.2}", m.paper_low_cm),
            format!("{:.4}", z_cm(i, 1)),
            format!("{:.2}", m.paper_high_cm),
            format!("{:.2}", peak(i)),
        ]);
        let band = |b: usize| {
            let r = &results[i * 2 + b];
            json!({
                "trajectory": BANDS[b],
                "base_z_rmse_cm": 100.0 * r.base_z_rmse_m,
                "base_z_rmse_m": r.base_z_rmse_m,
                "ee_pos_rmse_m": r.ee_pos_rmse_m,
                "tilt_use_rad": r.tilt_use_rad,
                "saturation_rate": r.saturation_rate,
                "max_rotor_thrust_n": r.max_rotor_thrust_n,
                "duration_s": r.duration_s,
                "settle_s": r.settle_s,
                "ticks": r.ticks,
                "mcap": r.mcap,
            })
        };
        rows.push(json!({
            "key": m.key,
            "configuration": m.label,
            "motor_tau_s": m.tau_s,
            "motor_rate_limit_per_s": m.rate_limit_per_s,
            "low": band(0),
            "high": band(1),
            "max_rotor_thrust_n": peak(i),
            "paper": {"low_rmse_cm": m.paper_low_cm, "high_rmse_cm": m.paper_high_cm},
        }));
    }
    println!("{table}");
    let [none, delay, rate, both] = [0, 1, 2, 3];
    let overall_peak = (0..4).map(peak).fold(f64::NEG_INFINITY, f64::max);
    let checks = vec![
        Check::new(
            "the motor delay raises the high-frequency RMSE",
            format!("{:+.1} %", pct(z_cm(delay, 1), z_cm(none, 1))),
            "+19 % (1.96 -> 2.33 cm)",
            z_cm(delay, 1) > z_cm(none, 1),
        ),
        Check::new(
            "the motor delay raises the low-frequency RMSE",
            format!("{:+.1} %", pct(z_cm(delay, 0), z_cm(none, 0))),
            "+314 % (0.14 -> 0.58 cm)",
            z_cm(delay, 0) > z_cm(none, 0),
        ),
        Check::new(
            "the rate limit barely changes the errors (within 5 %)",
            format!(
                "low {:+.1} %, high {:+.1} %; with the delay: low {:+.1} %, high {:+.1} %",
                pct(z_cm(rate, 0), z_cm(none, 0)),
                pct(z_cm(rate, 1), z_cm(none, 1)),
                pct(z_cm(both, 0), z_cm(delay, 0)),
                pct(z_cm(both, 1), z_cm(delay, 1)),
            ),
            "low 0 %, high -0.5 %; with the delay: 0 %, 0 %",
            [
                (rate, none, 0),
                (rate, none, 1),
                (both, delay, 0),
                (both, delay, 1),
            ]
            .iter()
            .all(|&(x, y, b)| pct(z_cm(x, b), z_cm(y, b)).abs() <= 5.0),
        ),
        Check::new(
            "no rotor reaches the thrust limit",
            format!("largest rotor thrust {overall_peak:.2} N of {thrust_max_n} N"),
            "no rotor reaches 23 N",
            overall_peak < thrust_max_n - allocation::SATURATION_TOLERANCE_N,
        ),
    ];
    runs::print_checks(&checks);

    let mut plots = Vec::new();
    for band in BANDS {
        let report = runs::compare(
            &log_path(&MODELS[none], band),
            &log_path(&MODELS[delay], band),
            &["/base/state.position_m[2]", "/rotors.realised_n[0]"],
            &[],
        )?;
        let png = a.out.join(format!("actuator-{band}.png"));
        runs::plot(&png, &report)?;
        plots.push(json!({
            "file": png,
            "a": MODELS[none].key,
            "b": MODELS[delay].key,
            "base_z_difference_rmse_m": runs::stats(&report, "/base/state.position_m[2]", None).and_then(|s| s.rmse),
        }));
    }
    let document = json!({
        "experiment": "actuator",
        "platform": "fa-hexa",
        "controller": configs.first().map(|c| c.controller.name()),
        "disturbances": ["saturation"],
        "seed": a.seed,
        "physics_substeps": configs.first().map(|c| c.twin.physics_substeps),
        "solver_iterations": configs.first().map(|c| c.twin.solver_iterations),
        "rapier_steps": configs.first().map(|c| c.twin.rapier_steps),
        "thrust_max_n": thrust_max_n,
        "rows": rows,
        "checks": checks,
        "plots": plots,
        "paper": {
            "table": "FA-Hexa vertical tracking under different actuator configurations (base-z RMSE, cm)",
            "high_frequency_increase_with_delay_pct": 19,
        },
    });
    let path = a.out.join("actuator.json");
    write_json(&path, &document)?;
    eprintln!(
        "wrote {}, {} plots, {} logs in {}",
        path.display(),
        plots.len(),
        configs.len(),
        logs.display()
    );
    Ok(())
}
