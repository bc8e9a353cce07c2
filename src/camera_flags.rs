//! `--cameras`, `--visual-dr`, `--camera-log-every`: the twin's cameras in a flight (`bench`,
//! `track`, `fly --link twin`).

use std::path::Path;

use anyhow::Result;
use policy_runtime::flight::{CameraConfig, full_camera_name, select_cameras};
use policy_runtime::video::{VideoConfig, ffmpeg_program};
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

/// A video frame every this many env steps: 30 fps from 120 Hz, as the reference's videos.
const VIDEO_EVERY: u64 = 4;

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
    /// With --cameras and an MCAP log (or --live): log the images (PNG in the Foxglove
    /// SDK's foxglove.CompressedImage + CameraCalibration, protobuf) of every N-th
    /// observation (0: none).
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

    /// The cameras' configuration for `vehicle` (None without --cameras and --video). With
    /// `video` (`--video`: its path), the scene camera is added and a video of it — with the EE
    /// camera beside it when --cameras names it — is made of every 4th observation. Bad input:
    /// an unknown camera; no graphics adapter on this machine; no ffmpeg (checked here, before
    /// anything runs).
    pub fn config(
        &self,
        vehicle: &platform::Vehicle,
        video: Option<&Path>,
    ) -> Result<Option<CameraConfig>> {
        let list = match (&self.cameras, video) {
            (None, None) => return Ok(None),
            (Some(list), _) => list.clone(),
            (None, Some(_)) => String::new(),
        };
        let mut names: Vec<&str> = list
            .split(',')
            .map(str::trim)
            .filter(|n| !n.is_empty())
            .collect();
        if video.is_some() && !names.iter().any(|n| full_camera_name(n) == "scene_camera") {
            names.push("scene");
        }
        let cameras = select_cameras(vehicle, &names)
            .map_err(|e| bad_input(format!("--cameras {list}: {e}")))?;
        let video = match video {
            None => None,
            Some(path) => {
                let program = ffmpeg_program().map_err(|e| bad_input(format!("--video: {e}")))?;
                let mut shown = vec!["scene_camera".to_owned()];
                if names.iter().any(|n| full_camera_name(n) == "ee_camera") {
                    shown.push("ee_camera".to_owned());
                }
                Some(VideoConfig {
                    program,
                    path: path.to_owned(),
                    cameras: shown,
                    every: VIDEO_EVERY,
                })
            }
        };
        let config = CameraConfig {
            cameras,
            visual_dr: self.visual_dr.into(),
            log_every: self.camera_log_every,
            video,
        };
        // Open the adapter once now: a machine that cannot render is told before the run.
        config.rig(vehicle).map_err(|e| match e {
            RenderError::NoAdapter(_) => bad_input(format!("--cameras: {e}")),
            other => anyhow::Error::new(other),
        })?;
        Ok(Some(config))
    }
}
