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

Examples:
  amstack platforms
  amstack platforms --json platforms.json
  amstack platforms --vehicle my-hexa/my-hexa.toml")]
pub struct Args {
    /// Also write the figures as JSON: an object keyed by vehicle id.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Add a vehicle from its vehicle file (TOML naming a URDF); repeatable. It is validated
    /// like the built-in ones.
    #[arg(long = "vehicle", value_name = "FILE.toml")]
    vehicles: Vec<PathBuf>,
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
    Ok(())
}
