//! Cameras in the flight loop: the images of an observation.
//!
//! A flight with a [`CameraRig`] in its [`super::FlightSpec`] renders the rig's cameras at the
//! state of observation k — the link's state after the physics step of tick k−1, the same
//! instant as the proprioception of that observation — on the ticks where someone asked for
//! them, and only then:
//!
//! - the action source, when [`super::ActionSource::wants_frames`]`(k)` is true: the images
//!   are finished before [`super::ActionSource::next`] and given in
//!   [`super::Observation::frames`];
//! - an observer, by [`super::Observer::wants_frames`]`(k)`: [`FrameUse::Decided`] gives them
//!   in [`super::Decided::frames`] (finished while the stack decides, before the setpoint is
//!   sent); [`FrameUse::Stepped`] gives them in [`super::Stepped::frames`] only, and the frame
//!   renders beside the physics step of tick k (begun before the step, read back after it).
//!
//! Whatever asked, [`super::Stepped::frames`] of tick k carries the images of observation k
//! when they were rendered (the images after the step are those of observation k+1: the next
//! tick's). Only a link that holds the twin can render ([`crate::link::Link::camera_state`]:
//! the in-process [`crate::TwinLink`]); a flight with a rig over another link fails at start
//! with [`super::FlightError::Cameras`].

use nalgebra::Isometry3;
use platform::Vehicle;
use render::{CameraSpec, Image, Intrinsics, RenderError, Renderer, Snapshot, VisualDr};

use crate::link::Link;

/// The short names of the spec's cameras on the command line and their vehicle-file names.
pub const CAMERA_ALIASES: [(&str, &str); 3] = [
    ("ee", "ee_camera"),
    ("base", "base_camera"),
    ("scene", "scene_camera"),
];

/// One camera's image of one observation.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFrame {
    /// The camera's name (`ee_camera`, `base_camera`, `scene_camera`, or a vehicle file's).
    pub name: String,
    /// The image (RGB8, `width × height`, top row first).
    pub image: Image,
    /// The camera's pinhole intrinsics (px).
    pub intrinsics: Intrinsics,
    /// The camera frame in the world at the observation's instant (ROS optical: +z forward,
    /// +x right, +y down).
    pub world_from_camera: Isometry3<f64>,
}

/// The images of one observation: every camera of the rig, in the rig's order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Frames {
    /// The observation's tick index k.
    pub k: u64,
    /// The time of the state drawn (the measurement's time of observation k), s.
    pub time_s: f64,
    /// One frame per camera, in the rig's order.
    pub cameras: Vec<CameraFrame>,
}

impl Frames {
    /// The frame of the camera named `name` (`ee_camera`, or the short `ee`, `base`, `scene`).
    pub fn get(&self, name: &str) -> Option<&CameraFrame> {
        let full = full_camera_name(name);
        self.cameras.iter().find(|c| c.name == full)
    }

    /// The frames, in the rig's order.
    pub fn iter(&self) -> std::slice::Iter<'_, CameraFrame> {
        self.cameras.iter()
    }
}

/// When an observer needs the images of observation k (ordered: a later variant asks less).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
pub enum FrameUse {
    /// In [`super::Decided::frames`] (and [`super::Stepped::frames`]): read back before the
    /// setpoint is sent.
    Decided,
    /// In [`super::Stepped::frames`] only: the frame renders beside the physics step.
    Stepped,
    /// Not at this tick.
    #[default]
    None,
}

/// The full camera name of `name`: `ee` → `ee_camera`, `base` → `base_camera`, `scene` →
/// `scene_camera`; any other name as given.
pub fn full_camera_name(name: &str) -> &str {
    CAMERA_ALIASES
        .iter()
        .find(|(short, _)| *short == name)
        .map_or(name, |(_, full)| full)
}

/// The cameras `names` of `vehicle` (short or full names of its `[[camera]]` sections, and
/// `scene` for the reference's 1280×720 scene camera), in the order given. The error is one
/// line naming the unknown camera and the known ones.
pub fn select_cameras(vehicle: &Vehicle, names: &[&str]) -> Result<Vec<CameraSpec>, String> {
    let mut specs: Vec<CameraSpec> = Vec::with_capacity(names.len());
    for &name in names {
        let full = full_camera_name(name.trim());
        let spec = if full == "scene_camera" {
            CameraSpec::scene()
        } else {
            match vehicle.cameras.iter().find(|c| c.name == full) {
                Some(mount) => CameraSpec::from_mount(mount),
                None => {
                    let mut known: Vec<&str> =
                        vehicle.cameras.iter().map(|c| c.name.as_str()).collect();
                    known.push("scene");
                    return Err(format!(
                        "camera '{name}': vehicle '{}' has no such camera (known: {})",
                        vehicle.id,
                        known.join(", ")
                    ));
                }
            }
        };
        if specs.iter().any(|s| s.name == spec.name) {
            return Err(format!("camera '{name}' is named twice"));
        }
        specs.push(spec);
    }
    if specs.is_empty() {
        return Err("no camera named".to_owned());
    }
    Ok(specs)
}

/// The cameras of a run (`--cameras`, `--visual-dr`, `--camera-log-every`): what each of its
/// flights builds its [`CameraRig`] from.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraConfig {
    /// The cameras, in order ([`select_cameras`]).
    pub cameras: Vec<CameraSpec>,
    /// Visual domain randomisation (drawn per flight from its seed).
    pub visual_dr: VisualDr,
    /// The flight log holds the images of every this many-th observation (0: none).
    pub log_every: u64,
}

impl CameraConfig {
    /// A rig of these cameras on `vehicle`.
    pub fn rig(&self, vehicle: &Vehicle) -> Result<CameraRig, RenderError> {
        CameraRig::new(vehicle, &self.cameras, self.visual_dr)
    }
}

/// The cameras of a flight: a renderer of the vehicle's cameras, reused from flight to flight
/// (build it once per worker: opening the adapter is the slow part), and the images of the
/// last observation rendered.
#[derive(Debug)]
pub struct CameraRig {
    renderer: Renderer,
    all: Vec<usize>,
    state: Snapshot,
    scratch: Vec<Image>,
    frames: Frames,
    in_flight: bool,
    rendered: u64,
}

impl CameraRig {
    /// A rig of `cameras` (see [`select_cameras`]) on `vehicle`; `dr` sets visual domain
    /// randomisation (drawn per flight from the flight's seed). Fails without a graphics
    /// adapter ([`RenderError::NoAdapter`]).
    pub fn new(
        vehicle: &Vehicle,
        cameras: &[CameraSpec],
        dr: VisualDr,
    ) -> Result<Self, RenderError> {
        let renderer = Renderer::new(vehicle, cameras, dr)?;
        let frames = Frames {
            k: 0,
            time_s: 0.0,
            cameras: cameras
                .iter()
                .map(|c| CameraFrame {
                    name: c.name.clone(),
                    image: Image::default(),
                    intrinsics: c.intrinsics,
                    world_from_camera: Isometry3::identity(),
                })
                .collect(),
        };
        Ok(Self {
            renderer,
            all: (0..cameras.len()).collect(),
            state: Snapshot::default(),
            scratch: vec![Image::default(); cameras.len()],
            frames,
            in_flight: false,
            rendered: 0,
        })
    }

    /// The renderer (adapter, cameras, lighting).
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    /// The camera names, in the rig's order.
    pub fn camera_names(&self) -> impl ExactSizeIterator<Item = &str> {
        self.frames.cameras.iter().map(|c| c.name.as_str())
    }

    /// The images last rendered.
    pub fn frames(&self) -> &Frames {
        &self.frames
    }

    /// Observations rendered since the rig was built.
    pub fn rendered(&self) -> u64 {
        self.rendered
    }

    /// A new flight on `link`: its scene's shapes, and the look drawn from `seed` (visual
    /// DR on). Errors: the link cannot render (`Err(None)`), or the renderer's.
    pub(crate) fn start(&mut self, link: &dyn Link, seed: u64) -> Result<(), Option<RenderError>> {
        let scene = link.camera_scene().ok_or(None)?;
        self.finish().map_err(Some)?;
        self.renderer.reset_scene(&scene, seed).map_err(Some)
    }

    /// Begins rendering observation `k` at `time_s`: the link's state now.
    pub(crate) fn begin(
        &mut self,
        link: &dyn Link,
        k: u64,
        time_s: f64,
    ) -> Result<(), RenderError> {
        if !link.camera_state(&mut self.state) {
            return Err(RenderError::State(format!(
                "link '{}' gave no state to render",
                link.name()
            )));
        }
        for (i, frame) in self.frames.cameras.iter_mut().enumerate() {
            frame.world_from_camera = self.renderer.world_from_camera(&self.state, i)?;
        }
        self.frames.k = k;
        self.frames.time_s = time_s;
        self.renderer.begin_frame(&self.state, &self.all)?;
        self.in_flight = true;
        Ok(())
    }

    /// Waits for the frame begun (if any) and makes it [`Self::frames`].
    pub(crate) fn finish(&mut self) -> Result<(), RenderError> {
        if !self.in_flight {
            return Ok(());
        }
        self.in_flight = false;
        self.renderer.finish_frame(&mut self.scratch)?;
        for (frame, image) in self.frames.cameras.iter_mut().zip(&mut self.scratch) {
            std::mem::swap(&mut frame.image, image);
        }
        self.rendered += 1;
        Ok(())
    }
}
