//! The twin's RGB cameras (AMBENCH_SPEC §1.8), rendered headless with wgpu.
//!
//! Every policy of AM-Bench sees the end-effector camera (384×384 RGB) and may see the base
//! camera; this crate draws them from the twin's state: the vehicle from its URDF visual
//! shapes at the link poses of forward kinematics, `world_from_link = world_from_base ·
//! root_from_link(q)`, and every object, wall, floor and prop of the task scene at its pose
//! ([`sim_twin::Twin::scene_visuals`]). Primitives are tessellated once into light meshes; a
//! frame is one uniform write, one depth-tested, Lambert-lit pass per camera and one readback.
//!
//! Cameras are pinholes in the ROS optical convention (+z forward, +x right, +y down), mounted
//! on a link as the vehicle file's `[[camera]]` sections say, or fixed in the world (the scene
//! camera). A point p in the camera frame lands at pixel `(fx·x/z + cx, fy·y/z + cy)` with
//! `fx = fy = width · focal / aperture`; see [`camera`].
//!
//! Visual domain randomisation ([`VisualDr`]) draws the scene's colours, procedural textures
//! and the light per episode from [`platform::RandomStream::VisualDomain`] stream of the rollout seed;
//! [`appearance`] lists the nominal look and every range. The same state and seed give the same
//! pixels on the same adapter.
//!
//! This crate is apart from `sim_twin` so the physics core and its tests do not link wgpu.
//! It needs a graphics adapter at run time: any GPU, or Mesa's Vulkan software rasteriser
//! (`mesa-vulkan-drivers`, installed by `scripts/setup.sh`); without one,
//! [`Renderer::new`] returns [`RenderError::NoAdapter`] saying so.
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use render::{CameraSpec, Renderer, Snapshot, VisualDr};
//! let vehicle = platform::Vehicle::builtin("fa-hexa")?;
//! let twin = sim_twin::Twin::new(vehicle.clone(), sim_twin::TwinConfig::default())?;
//! let cameras: Vec<CameraSpec> = vehicle.cameras.iter().map(CameraSpec::from_mount).collect();
//! let mut renderer = Renderer::new(&vehicle, &cameras, VisualDr::Off)?;
//! renderer.reset_scene(&twin.scene_visuals(), 0)?; // at every episode reset
//! let image = renderer.render(&Snapshot::of_twin(&twin), 0)?; // every tick
//! std::fs::write("ee.png", image.to_png()?)?;
//! # Ok(()) }
//! ```

pub mod appearance;
pub mod camera;
mod error;
mod image;
pub mod mesh;
mod renderer;
mod snapshot;

pub use appearance::{Lighting, Material, Pattern, VisualDr};
pub use camera::{CameraParent, CameraSpec, Intrinsics};
pub use error::RenderError;
pub use image::Image;
pub use renderer::Renderer;
pub use snapshot::Snapshot;

/// The cameras a vehicle file declares, in its order (`ee_camera`, `base_camera`, …).
pub fn vehicle_cameras(vehicle: &platform::Vehicle) -> Vec<CameraSpec> {
    vehicle.cameras.iter().map(CameraSpec::from_mount).collect()
}
