//! The five vehicles of AM-Bench, compiled into the binary from `platform/vehicles/`.

use crate::error::{DescriptionError, Problem};
use crate::vehicle::Vehicle;
use crate::vehicle_file::VehicleFile;

macro_rules! vehicle_files {
    ($($id:literal),* $(,)?) => {
        [$((
            $id,
            concat!($id, ".toml"),
            include_str!(concat!("../vehicles/", $id, ".toml")),
            include_str!(concat!("../vehicles/", $id, ".urdf")),
        )),*]
    };
}

/// (id, vehicle file name, vehicle file text, URDF text).
const BUILTIN: [(&str, &str, &str, &str); 5] =
    vehicle_files!["ua-quad", "ua-hexa", "fa-hexa", "omni-hexa", "ee-only"];

/// Ids of the built-in vehicles, in the order the paper lists them.
pub const BUILTIN_IDS: [&str; 5] = ["ua-quad", "ua-hexa", "fa-hexa", "omni-hexa", "ee-only"];

impl Vehicle {
    /// A built-in vehicle by id (`ua-quad`, `ua-hexa`, `fa-hexa`, `omni-hexa`, `ee-only`).
    pub fn builtin(id: &str) -> Result<Self, DescriptionError> {
        let Some((_, file_name, text, urdf_text)) = BUILTIN.iter().find(|b| b.0 == id) else {
            return Err(DescriptionError::new(
                "built-in vehicles",
                "id",
                Problem::Invalid(format!(
                    "unknown vehicle '{id}' (known: {})",
                    BUILTIN_IDS.join(", ")
                )),
            ));
        };
        let file = VehicleFile::parse(file_name, text)?;
        let urdf_name = format!("vehicles/{}", file.urdf);
        Self::assemble(file_name, &file, &urdf_name, urdf_text)
    }

    /// All built-in vehicles, in [`BUILTIN_IDS`] order.
    pub fn builtins() -> Result<Vec<Self>, DescriptionError> {
        BUILTIN_IDS.iter().map(|id| Self::builtin(id)).collect()
    }
}
