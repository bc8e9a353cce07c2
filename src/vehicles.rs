//! Loading vehicles: the built-in five, or a user's vehicle file and the URDF it names.

use std::path::Path;

use anyhow::Result;
use platform::{Vehicle, VehicleFile};

use crate::cli_error::bad_input;

/// Reads a vehicle file (TOML) and the URDF it names (relative to the vehicle file), and
/// validates both. Any problem is bad input naming the file, the field and the value.
pub fn load_vehicle_file(path: &Path) -> Result<Vehicle> {
    let label = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| bad_input(format!("cannot read vehicle file {label}: {e}")))?;
    let file = VehicleFile::parse(&label, &text).map_err(|e| bad_input(e.to_string()))?;
    let urdf_path = path.parent().unwrap_or(Path::new(".")).join(&file.urdf);
    let urdf_label = urdf_path.display().to_string();
    let urdf_text = std::fs::read_to_string(&urdf_path)
        .map_err(|e| bad_input(format!("{label}: urdf: cannot read {urdf_label}: {e}")))?;
    let vehicle = Vehicle::assemble(&label, &file, &urdf_label, &urdf_text)
        .map_err(|e| bad_input(e.to_string()))?;
    // Loadable but impossible data of a user's vehicle, one line each, said when the command
    // has run (a refused command keeps its one-line error). The built-in FA-Hexa and UA-Hexa
    // keep the reference's base inertia, which is one (`amstack platforms` lists it).
    if let Ok(mut pending) = WARNINGS.lock() {
        for warning in vehicle.model.physical_warnings() {
            let line = format!("{urdf_label}: {warning}");
            if !pending.contains(&line) {
                pending.push(line);
            }
        }
    }
    Ok(vehicle)
}

/// Warnings about the vehicle files loaded, for the end of a successful command.
static WARNINGS: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

/// The warnings gathered so far (each once), emptied.
pub fn take_warnings() -> Vec<String> {
    WARNINGS
        .lock()
        .map(|mut w| std::mem::take(&mut *w))
        .unwrap_or_default()
}

/// The built-in vehicles followed by the user's, refusing a user id that is already taken.
pub fn all_vehicles(extra: &[std::path::PathBuf]) -> Result<Vec<Vehicle>> {
    let mut vehicles = Vehicle::builtins()?;
    for path in extra {
        let v = load_vehicle_file(path)?;
        if vehicles.iter().any(|known| known.id == v.id) {
            return Err(bad_input(format!(
                "{}: id: vehicle '{}' is already defined",
                path.display(),
                v.id
            )));
        }
        vehicles.push(v);
    }
    Ok(vehicles)
}

/// The vehicle `id` among the built-in ones and the user's (`--platform`); bad input naming
/// the known ids otherwise.
pub fn find_vehicle(extra: &[std::path::PathBuf], id: &str) -> Result<Vehicle> {
    let vehicles = all_vehicles(extra)?;
    let ids: Vec<&str> = vehicles.iter().map(|v| v.id.as_str()).collect();
    let unknown = bad_input(format!(
        "--platform {id}: unknown vehicle (known: {})",
        ids.join(", ")
    ));
    vehicles.into_iter().find(|v| v.id == id).ok_or(unknown)
}
