//! `amstack experiment wrench-limit`: the paper's wrench-limit step responses (appendix
//! "Wrench-Limit Step Response"), in the twin. The FA-Hexa (PID, rotor limits on) steps 1 m
//! along x at t = 1 s under two wrench-space limits of its PID, I: |F| ≤ 80 N and
//! II: |F| ≤ 100 N (hover needs 65 N). The two responses are compared, the step's arrival and
//! the altitude it costs measured, and which rotors reach a thrust limit, when and for how
//! long is read from each flight's log ([`policy_runtime::validation::rotor_saturation`]).

use std::path::{Path, PathBuf};

use anyhow::Result;
use comfy_table::{Table, presets};
use policy_runtime::validation::{SaturationSummary, rotor_saturation, signals};
use serde::Serialize;
use serde_json::json;

use super::runs::{self, Check};
use crate::cli_error::bad_input;
use crate::output::write_json;

pub(super) const AFTER_HELP: &str = "\
Flies the FA-Hexa (PID, rotor limits on: --disturbances saturation) through track's step (1 m
along world x at t = 1 s, 6 s) twice, on --jobs threads: with the PID's force norm bounded
at 80 N (limit I) and at 100 N (limit II). Compares the two (amstack compare: base x and z,
force x and z, rotors 1 and 0 over t = 1..3 s), measures when x first reaches 90 % of the
step and how low the base sinks, and reads from each log which rotors sit at a thrust limit
(0 or 23 N), first when, for how long, and when the allocator first falls short.

Writes into --out: wrench-limit.json (both responses, the rotor-saturation summaries, the
comparison, the checks), the tables on the terminal, step-I.mcap, step-II.mcap, and
wrench-limit-step.png (compare's plot of II against I). The paper prints no figures for this
experiment, only its plot (similar saturation patterns in the real and simulated responses).
scripts/rotor_saturation.py reads the same logs with the PyPI mcap package (a cross-check).

Example:
  amstack experiment wrench-limit --out wrench-limit/";

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Seed of both flights.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    jobs: Option<usize>,
    /// Length of each flight, s (the step is at 1 s).
    #[arg(long, value_name = "S", default_value_t = 6.0)]
    duration: f64,
    #[command(flatten)]
    physics: crate::twin_flags::PhysicsFlags,
    /// Output folder (created; an existing one must be empty).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

/// The two limits: (name, largest force norm, N).
const LIMITS: [(&str, f64); 2] = [("I", 80.0), ("II", 100.0)];

/// The share of the step that counts as arrived.
const ARRIVED: f64 = 0.9;

/// One step response, read from its log.
#[derive(Debug, Serialize)]
struct Response {
    limit: String,
    max_force_n: f64,
    mcap: PathBuf,
    /// When the x reference steps, s.
    step_time_s: Option<f64>,
    /// Its size, m.
    step_m: f64,
    /// Time after the step at which base x first covers 90 % of it, s (null: not within the
    /// flight).
    x_arrival_s: Option<f64>,
    /// Lowest base z after the step, m, and the reference z, m.
    min_base_z_m: f64,
    reference_z_m: f64,
    base_pos_rmse_m: f64,
    saturation_rate: Option<f64>,
    /// Which rotors sat at a thrust limit, when, how long.
    saturation: SaturationSummary,
}

fn series(log: &policy_runtime::validation::FlightLogFile, path: &str) -> Result<signals::Series> {
    let file = log.path.display().to_string();
    let resolved = signals::resolve(&log.recording, &file, path)?;
    let [one] = resolved.as_slice() else {
        return Err(anyhow::anyhow!("{path}: not one signal in {file}"));
    };
    Ok(signals::extract(&log.recording, &file, one)?)
}

fn response(
    (name, force): (&str, f64),
    mcap: &Path,
    track: &policy_runtime::TrackResult,
    limits: (f64, f64),
) -> Result<Response> {
    let log = runs::read_log(mcap)?;
    let x_ref = series(&log, "/base/reference.pose.position.x")?;
    let z_ref = series(&log, "/base/reference.pose.position.z")?;
    let x = series(&log, "/base/state.position_m[0]")?;
    let z = series(&log, "/base/state.position_m[2]")?;
    let x0 = x_ref.values.first().copied().unwrap_or(0.0);
    let x1 = x_ref.values.last().copied().unwrap_or(0.0);
    let step_time_s = x_ref
        .times_s
        .iter()
        .zip(&x_ref.values)
        .find(|(_, v)| (**v - x0).abs() > 1e-9)
        .map(|(t, _)| *t);
    let step_m = x1 - x0;
    let after = |t: f64| step_time_s.is_some_and(|s| t >= s);
    let x_arrival_s = step_time_s.and_then(|s| {
        x.times_s
            .iter()
            .zip(&x.values)
            .find(|(t, v)| after(**t) && (**v - x0) * step_m.signum() >= ARRIVED * step_m.abs())
            .map(|(t, _)| t - s)
    });
    let min_base_z_m = z
        .times_s
        .iter()
        .zip(&z.values)
        .filter(|(t, _)| after(**t))
        .map(|(_, v)| *v)
        .fold(f64::INFINITY, f64::min);
    Ok(Response {
        limit: name.to_owned(),
        max_force_n: force,
        mcap: mcap.to_path_buf(),
        step_time_s,
        step_m,
        x_arrival_s,
        min_base_z_m,
        reference_z_m: z_ref.values.last().copied().unwrap_or(f64::NAN),
        base_pos_rmse_m: track.base_pos_rmse_m,
        saturation_rate: track.saturation_rate,
        saturation: rotor_saturation(&log, limits.0, limits.1)?,
    })
}

fn time(t: Option<f64>) -> String {
    t.map_or_else(|| "never".to_owned(), |t| format!("{t:.3}"))
}

pub(super) fn run(a: &Args) -> Result<()> {
    let jobs = runs::jobs(a.jobs)?;
    a.physics.check()?;
    if !(a.duration.is_finite() && a.duration > 1.0) {
        return Err(bad_input(format!(
            "--duration {}: must be longer than 1 s (the step is at 1 s)",
            a.duration
        )));
    }
    super::prepare_out(&a.out)?;
    let log = |name: &str| a.out.join(format!("step-{name}.mcap"));
    let configs = LIMITS
        .iter()
        .map(|(name, force)| {
            let mut f = runs::strings(&[
                "--platform",
                "fa-hexa",
                "--trajectory",
                "step",
                "--settle",
                "0",
                "--disturbances",
                "saturation",
                "--saturated-allocation",
                "clip",
            ]);
            f.extend([
                "--duration".to_owned(),
                a.duration.to_string(),
                "--max-force".to_owned(),
                force.to_string(),
                "--seed".to_owned(),
                a.seed.to_string(),
                "--mcap".to_owned(),
                log(name).display().to_string(),
            ]);
            f.extend(a.physics.flag_line());
            runs::track_config(&f)
        })
        .collect::<Result<Vec<_>>>()?;
    let limits = configs.first().map_or((0.0, f64::INFINITY), |c| {
        (c.vehicle.rotors.thrust_min_n, c.vehicle.rotors.thrust_max_n)
    });
    let bar = runs::progress_bar(runs::seconds(&configs));
    bar.set_prefix("wrench limit: steps I and II");
    let labels: Vec<String> = LIMITS
        .iter()
        .map(|(name, force)| format!("step under limit {name} (|F| <= {force} N)"))
        .collect();
    let tracks = runs::fly_tracks(&configs, &labels, jobs, &bar)?;
    bar.finish_and_clear();
    let responses = LIMITS
        .iter()
        .zip(&tracks)
        .map(|(&limit, track)| response(limit, &log(limit.0), track, limits))
        .collect::<Result<Vec<_>>>()?;
    let (one, two) = (&responses[0], &responses[1]);

    let report = runs::compare(
        &log("I"),
        &log("II"),
        &[
            "/base/state.position_m[0]",
            "/base/state.position_m[2]",
            "/control/wrench.force_n[0]",
            "/control/wrench.force_n[2]",
            "/rotors.realised_n[1]",
            "/rotors.realised_n[0]",
        ],
        &["t=1..3"],
    )?;
    let png = a.out.join("wrench-limit-step.png");
    runs::plot(&png, &report)?;

    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "limit",
        "|F| max (N)",
        "x at 90 % after (s)",
        "lowest base z (m)",
        "base pos. RMSE (cm)",
        "saturation (%)",
        "first unallocated (s)",
    ]);
    for r in &responses {
        table.add_row([
            r.limit.clone(),
            format!("{:.0}", r.max_force_n),
            time(r.x_arrival_s),
            format!("{:.3}", r.min_base_z_m),
            format!("{:.1}", 100.0 * r.base_pos_rmse_m),
            r.saturation_rate
                .map_or_else(|| "N/A".to_owned(), |s| format!("{:.1}", 100.0 * s)),
            time(r.saturation.first_unallocated_s),
        ]);
    }
    println!("{table}");
    let mut rotors = Table::new();
    let (lo, hi) = limits;
    rotors.load_style(presets::ASCII_MARKDOWN).set_header([
        "rotor".to_owned(),
        format!("I: first at {hi} N (s)"),
        format!("I: first at {lo} N (s)"),
        "I: at a limit (%)".to_owned(),
        "I: longest (s)".to_owned(),
        format!("II: first at {hi} N (s)"),
        format!("II: first at {lo} N (s)"),
        "II: at a limit (%)".to_owned(),
        "II: longest (s)".to_owned(),
    ]);
    for (r1, r2) in one.saturation.rotors.iter().zip(&two.saturation.rotors) {
        let mut row = vec![r1.rotor.to_string()];
        for r in [r1, r2] {
            row.extend([
                time(r.first_at_max_s),
                time(r.first_at_min_s),
                format!("{:.1}", 100.0 * r.share_at_limit),
                format!("{:.3}", r.longest_at_limit_s),
            ]);
        }
        rotors.add_row(row);
    }
    println!("{rotors}");

    let checks = vec![
        Check::new(
            "the wider limit II costs less altitude than I (the norm bound scales the gravity compensation too)",
            format!(
                "lowest base z {:.3} m (II) vs {:.3} m (I)",
                two.min_base_z_m, one.min_base_z_m
            ),
            "no figure (the paper's plot)",
            two.min_base_z_m > one.min_base_z_m,
        ),
        Check::new(
            "the limits are reached: rotors saturate at the step in both",
            format!(
                "rotors at a limit: I {:?}, II {:?}",
                one.saturation.saturated_rotors(),
                two.saturation.saturated_rotors()
            ),
            "similar control-input saturation patterns when the limits are reached",
            !one.saturation.saturated_rotors().is_empty()
                && !two.saturation.saturated_rotors().is_empty(),
        ),
    ];
    runs::print_checks(&checks);

    let document = json!({
        "experiment": "wrench-limit",
        "platform": "fa-hexa",
        "seed": a.seed,
        "duration_s": a.duration,
        "physics_substeps": configs.first().map(|c| c.twin.physics_substeps),
        "solver_iterations": configs.first().map(|c| c.twin.solver_iterations),
        "rapier_steps": configs.first().map(|c| c.twin.rapier_steps),
        "thrust_limits_n": [lo, hi],
        "arrival_share": ARRIVED,
        "responses": responses,
        "compare": report,
        "plot": png,
        "checks": checks,
        "paper": "no figures: the paper shows the real and simulated responses in a plot (Fig. realworld_stepx)",
    });
    let path = a.out.join("wrench-limit.json");
    write_json(&path, &document)?;
    eprintln!(
        "wrote {}, {}, step-I.mcap, step-II.mcap",
        path.display(),
        png.display()
    );
    Ok(())
}
