//! `--cameras`, `--visual-dr`, `--camera-log-every`: the twin's cameras in a flight (`bench`,
//! `track`, `fly --link twin`).

use anyhow::Result;
use policy_runtime::flight::{CameraConfig, select_cameras};
use render::{RenderError, VisualDr};

use crate::cli_error::bad_input;

/// On or off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub(crate) enum OnOff {
    On,
    #[default]
    Off,
}

impl From<OnOff> for VisualDr {
    fn from(v: OnOff) -> Self {
        match v {
            OnOff::On => Self::On,
            OnOff::Off => Self::Off,
        }
    }
}

/// The cameras of a flight.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct CameraFlags {
    /// Render these cameras in the loop, comma-separated: ee, base (the vehicle file's
    /// ee_camera, base_camera, or any [[camera]] name), scene (1280x720). Each observation's
    /// images are of the state after the physics step that led to it. The in-process twin
    /// only (--link twin); it needs a graphics adapter (mesa-vulkan-drivers).
    #[arg(long, value_name = "LIST")]
    pub cameras: Option<String>,
    /// Visual domain randomisation of the cameras' scene (colours, textures, light from the
    /// rollout seed).
    #[arg(long, value_name = "on|off", default_value = "off")]
    pub visual_dr: OnOff,
    /// With --cameras and an MCAP log: log the images (PNG, foxglove.CompressedImage +
    /// CameraCalibration) of every N-th observation (0: none).
    #[arg(long, value_name = "N", default_value_t = 4)]
    pub camera_log_every: u64,
}

impl CameraFlags {
    /// The cameras asked for, as given (`ee`, `base_camera`, …).
    pub fn names(&self) -> Vec<String> {
        self.cameras
            .iter()
            .flat_map(|l| l.split(','))
            .map(|n| n.trim().to_owned())
            .collect()
    }

    /// Whether cameras were asked for.
    pub fn any(&self) -> bool {
        self.cameras.is_some()
    }

    /// The cameras' configuration for `vehicle` (None without --cameras). Bad input: an unknown
    /// camera; no graphics adapter on this machine (checked here, before anything runs).
    pub fn config(&self, vehicle: &platform::Vehicle) -> Result<Option<CameraConfig>> {
        let Some(list) = &self.cameras else {
            return Ok(None);
        };
        let names: Vec<&str> = list.split(',').map(str::trim).collect();
        let cameras = select_cameras(vehicle, &names)
            .map_err(|e| bad_input(format!("--cameras {list}: {e}")))?;
        let config = CameraConfig {
            cameras,
            visual_dr: self.visual_dr.into(),
            log_every: self.camera_log_every,
        };
        // Open the adapter once now: a machine that cannot render is told before the run.
        config.rig(vehicle).map_err(|e| match e {
            RenderError::NoAdapter(_) => bad_input(format!("--cameras: {e}")),
            other => anyhow::Error::new(other),
        })?;
        Ok(Some(config))
    }
}
