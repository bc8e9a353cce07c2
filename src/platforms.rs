//! `amstack platforms`: the vehicles and the figures a flight engineer checks first.

use std::path::PathBuf;

use anyhow::Result;
use comfy_table::{Table, presets};
use platform::Vehicle;
use serde::Serialize;

use crate::output::{check_writable, write_json};
use crate::vehicles::all_vehicles;

#[derive(Debug, clap::Args)]
#[command(after_help = "\
Figures are computed from each vehicle's description (URDF + vehicle file) at the zero joint
configuration: inertia is the composite inertia about the centre of mass, in base-frame axes;
hover thrust is m·g shared equally by the rotors' vertical components (g = 9.81 m/s²);
thrust-to-weight is Σ T_max·n_z / (m·g). Max reach is the tracking-metric normaliser.
Warnings name physically impossible data: the FA-Hexa's and UA-Hexa's base inertia is the
reference's diag(0.198, 0.198, 0.460), whose Izz exceeds Ixx + Iyy (kept for comparable results).

`--dynamics FILE.json` writes each vehicle's rigid-body dynamics at seeded random states: the
joint-space mass matrix M(q) (composite-rigid-body algorithm), the bias forces b(q, ν)
(Coriolis, centrifugal, gravity; recursive Newton-Euler), with M ν̇ + b = τ, and the forward
dynamics ν̇ = M⁻¹(τ − b) at generalised forces τ drawn in ±5 (M's LᵀDL factor in the tree's
order). ν is the base
origin's velocity and the base's angular velocity in base axes (Pinocchio's free-flyer
convention), then the joint rates; joint positions are drawn within their limits, rates in
±1.5, the base attitude's roll and pitch in ±0.5 rad. `scripts/pinocchio-peer.sh` checks the
file against Pinocchio.

Examples:
  amstack platforms
  amstack platforms --json platforms.json
  amstack platforms --vehicle my-hexa/my-hexa.toml
  amstack platforms --dynamics dynamics.json --samples 20 --seed 3")]
pub struct Args {
    /// Also write the figures as JSON: an object keyed by vehicle id.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable. It is validated
    /// like the built-in ones.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
    /// Also write each vehicle's mass matrix and bias forces at `--samples` random states
    /// (see below).
    #[arg(long, value_name = "FILE.json")]
    dynamics: Option<PathBuf>,
    /// States per vehicle in `--dynamics`.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    samples: u32,
    /// Seed of the `--dynamics` states.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

/// One state of `--dynamics`.
#[derive(Debug, Serialize)]
struct DynamicsSample {
    /// Joint positions, configuration order.
    q: Vec<f64>,
    /// Generalised velocity [v_B, ω_B, q̇].
    nu: Vec<f64>,
    /// World-from-base attitude, w x y z.
    attitude_wxyz: [f64; 4],
    /// Mass matrix, row by row.
    mass_matrix: Vec<Vec<f64>>,
    /// Bias forces b(q, ν), gravity included.
    bias: Vec<f64>,
    /// Generalised forces τ (base force and torque in base axes, then joint efforts).
    tau: Vec<f64>,
    /// Forward dynamics ν̇ at τ.
    acceleration: Vec<f64>,
}

/// One vehicle's `--dynamics` entry.
#[derive(Debug, Serialize)]
struct VehicleDynamics {
    /// The movable joints' URDF names, configuration order.
    joints: Vec<String>,
    /// Rigid bodies (links joined by fixed joints count once).
    bodies: usize,
    samples: Vec<DynamicsSample>,
}

fn dynamics(v: &Vehicle, samples: u32, seed: u64) -> VehicleDynamics {
    use nalgebra::{DMatrix, DVector};
    use rand::SeedableRng;
    let tree = platform::ArticulatedBody::new(&v.model);
    let mut ws = tree.workspace();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    // τ from a stream of its own, so that the states stay those of earlier files.
    let mut tau_rng = platform::RandomStream::DynamicsForces.rng(seed);
    let joints = (0..v.model.dof())
        .map(|d| v.model.dof_joint(d).name.clone())
        .collect();
    let samples = (0..samples)
        .map(|_| {
            let s = tree.sample_state(&v.model, &mut rng);
            let attitude = s.world_from_base.rotation;
            let mut m = DMatrix::zeros(tree.nv(), tree.nv());
            tree.mass_matrix(&s.q, &mut ws, &mut m);
            let mut b = DVector::zeros(tree.nv());
            tree.bias(&attitude, &s.q, &s.nu, &mut ws, &mut b);
            let tau = DVector::from_fn(tree.nv(), |_, _| {
                rand::Rng::random_range(&mut tau_rng, -5.0..5.0)
            });
            let mut acceleration = DVector::from_element(tree.nv(), f64::NAN);
            // M is positive definite for every built-in vehicle; a failed factor leaves NaN,
            // written as null, which the CLI test and the peer check report.
            let _ = tree.forward_dynamics(
                &attitude,
                &s.q,
                &s.nu,
                &tau,
                &[],
                &mut ws,
                &mut acceleration,
            );
            let w = attitude.quaternion();
            DynamicsSample {
                nu: s.nu.iter().copied().collect(),
                q: s.q,
                attitude_wxyz: [w.w, w.i, w.j, w.k],
                mass_matrix: m.row_iter().map(|r| r.iter().copied().collect()).collect(),
                bias: b.iter().copied().collect(),
                tau: tau.iter().copied().collect(),
                acceleration: acceleration.iter().copied().collect(),
            }
        })
        .collect();
    VehicleDynamics {
        joints,
        bodies: tree.body_count(),
        samples,
    }
}

/// One vehicle's figures, named with their units.
#[derive(Debug, Serialize)]
struct Figures {
    name: String,
    actuation: &'static str,
    mass_kg: f64,
    inertia_diag_kgm2: [f64; 3],
    rotors: usize,
    arm_dof: usize,
    max_reach_m: Option<f64>,
    max_thrust_per_rotor_n: Option<f64>,
    hover_thrust_per_rotor_n: Option<f64>,
    thrust_to_weight: Option<f64>,
    /// Physically impossible data in the description (one line each).
    warnings: Vec<String>,
}

fn figures(v: &Vehicle) -> Figures {
    let mp = v.mass_properties(&v.model.zero_configuration());
    let j = mp.inertia_about_com_kgm2;
    Figures {
        name: v.name.clone(),
        actuation: v.actuation.as_str(),
        mass_kg: mp.mass_kg,
        inertia_diag_kgm2: [j[(0, 0)], j[(1, 1)], j[(2, 2)]],
        rotors: v.rotors.len(),
        arm_dof: v.arm_dof(),
        max_reach_m: v.max_arm_reach_m,
        max_thrust_per_rotor_n: (!v.rotors.is_empty()).then_some(v.rotors.thrust_max_n),
        hover_thrust_per_rotor_n: v.hover_thrust_per_rotor_n(),
        thrust_to_weight: v.thrust_to_weight(),
        warnings: v.model.physical_warnings(),
    }
}

/// Four significant digits, fixed-point where that stays short.
fn significant(x: f64) -> String {
    if x != 0.0 && x.abs() < 1e-2 {
        format!("{x:.3e}")
    } else {
        format!("{x:.4}")
    }
}

fn or_dash(value: Option<f64>, decimals: usize) -> String {
    value.map_or_else(|| "—".to_owned(), |x| format!("{x:.decimals$}"))
}

pub fn run(args: &Args) -> Result<()> {
    if let Some(path) = &args.json {
        check_writable("--json", path)?;
    }
    if let Some(path) = &args.dynamics {
        check_writable("--dynamics", path)?;
    }
    let vehicles = all_vehicles(&args.vehicles)?;
    let rows: Vec<(String, Figures)> = vehicles
        .iter()
        .map(|v| (v.id.clone(), figures(v)))
        .collect();

    let mut table = Table::new();
    table.load_style(presets::ASCII_MARKDOWN).set_header([
        "vehicle",
        "actuation",
        "mass kg",
        "inertia diag kg·m²",
        "rotors",
        "arm DoF",
        "max reach m",
        "max thrust/rotor N",
        "hover thrust/rotor N",
        "thrust/weight",
    ]);
    for (id, f) in &rows {
        let [jx, jy, jz] = f.inertia_diag_kgm2;
        table.add_row([
            format!("{} ({id})", f.name),
            f.actuation.to_owned(),
            format!("{:.3}", f.mass_kg),
            format!(
                "{}, {}, {}",
                significant(jx),
                significant(jy),
                significant(jz)
            ),
            f.rotors.to_string(),
            f.arm_dof.to_string(),
            or_dash(f.max_reach_m, 2),
            or_dash(f.max_thrust_per_rotor_n, 1),
            or_dash(f.hover_thrust_per_rotor_n, 2),
            or_dash(f.thrust_to_weight, 2),
        ]);
    }
    println!("{table}");
    for (id, f) in &rows {
        for warning in &f.warnings {
            println!("warning: {id}: {warning}");
        }
    }

    if let Some(path) = &args.json {
        let object: serde_json::Map<String, serde_json::Value> = rows
            .into_iter()
            .map(|(id, f)| Ok((id, serde_json::to_value(f)?)))
            .collect::<Result<_>>()?;
        write_json(path, &serde_json::Value::Object(object))?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = &args.dynamics {
        let object: serde_json::Map<String, serde_json::Value> = vehicles
            .iter()
            .map(|v| {
                Ok((
                    v.id.clone(),
                    serde_json::to_value(dynamics(v, args.samples, args.seed))?,
                ))
            })
            .collect::<Result<_>>()?;
        write_json(path, &serde_json::Value::Object(object))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
