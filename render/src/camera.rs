//! Pinhole cameras: where they are mounted, their intrinsics, and the projection the
//! renderer draws with.
//!
//! Frames follow the ROS optical convention (AMBENCH_SPEC §1.8): +z forward along the optical
//! axis, +x to the image's right, +y down the image. A point `p` in the camera frame lands at
//! pixel coordinates
//!
//! ```text
//! u = fx·x/z + cx,   v = fy·y/z + cy
//! ```
//!
//! with u to the right and v down from the image's top-left corner (pixel (i, j) covers
//! u ∈ [i, i+1), v ∈ [j, j+1), its centre at (i + ½, j + ½)). Isaac's convention gives the
//! focal length and the horizontal aperture in the same unit, so
//! `fx = width · focal / aperture`; pixels are square (`fy = fx`) and the principal point is
//! the image centre (`cx = width/2`, `cy = height/2`). For the spec's cameras (384 px, 19.6 over
//! 20.955) fx = fy = 359.17 px, HFOV = 2·atan(20.955 / 39.2) ≈ 56.3°.

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Rotation3, UnitQuaternion, Vector3};
use platform::{CameraMount, LinkId};

use crate::error::RenderError;

/// Pinhole intrinsics, pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal length along the image's x (columns), px.
    pub fx: f64,
    /// Focal length along the image's y (rows), px.
    pub fy: f64,
    /// Principal point, column, px.
    pub cx: f64,
    /// Principal point, row, px.
    pub cy: f64,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
}

impl Intrinsics {
    /// Isaac's pinhole: focal length and horizontal aperture in one unit, square pixels,
    /// principal point at the image centre.
    pub fn from_aperture(
        width: u32,
        height: u32,
        focal_length: f64,
        horizontal_aperture: f64,
    ) -> Self {
        let fx = f64::from(width) * focal_length / horizontal_aperture;
        Self {
            fx,
            fy: fx,
            cx: 0.5 * f64::from(width),
            cy: 0.5 * f64::from(height),
            width,
            height,
        }
    }

    /// Horizontal field of view, rad.
    pub fn horizontal_fov_rad(&self) -> f64 {
        2.0 * (0.5 * f64::from(self.width) / self.fx).atan()
    }

    /// The 3×3 camera matrix K = [fx 0 cx; 0 fy cy; 0 0 1].
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.fx, 0.0, self.cx, //
            0.0, self.fy, self.cy, //
            0.0, 0.0, 1.0,
        )
    }

    /// Pixel coordinates (u right, v down) of a point in the camera frame; None behind the
    /// camera (z ≤ 0).
    pub fn project(&self, point_in_camera: &Vector3<f64>) -> Option<[f64; 2]> {
        let p = point_in_camera;
        (p.z > 0.0).then(|| [self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy])
    }
}

/// What a camera is attached to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraParent {
    /// A link of the vehicle: the camera moves with it.
    Link(LinkId),
    /// The world (the scene camera).
    World,
}

/// A camera the renderer draws: name, mount, intrinsics, clipping.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraSpec {
    /// Unique name (`ee_camera`, `base_camera`, `scene_camera`).
    pub name: String,
    /// What it is attached to.
    pub parent: CameraParent,
    /// The camera (ROS optical) frame in the parent frame.
    pub parent_from_camera: Isometry3<f64>,
    /// Pinhole intrinsics.
    pub intrinsics: Intrinsics,
    /// Near and far clipping distances along the optical axis, m.
    pub clip_m: [f64; 2],
}

/// The optional scene camera of the reference's recorder (AMBENCH_SPEC §1.8): position, m.
pub const SCENE_CAMERA_EYE_M: [f64; 3] = [-2.0, -2.5, 1.6];
/// The scene camera looks at this world point, m.
pub const SCENE_CAMERA_TARGET_M: [f64; 3] = [2.0, 0.0, 1.0];

impl CameraSpec {
    /// A camera declared in a vehicle file (`[[camera]]`).
    pub fn from_mount(mount: &CameraMount) -> Self {
        Self {
            name: mount.name.clone(),
            parent: CameraParent::Link(mount.link),
            parent_from_camera: mount.link_from_camera,
            intrinsics: Intrinsics::from_aperture(
                mount.width_px,
                mount.height_px,
                mount.focal_length_mm,
                mount.horizontal_aperture_mm,
            ),
            clip_m: mount.clip_m,
        }
    }

    /// The reference's scene camera: 1280×720 at (−2, −2.5, 1.6) m looking at (2, 0, 1) m,
    /// up +z, focal 24 over aperture 20.955, clipping 0.01–100 m.
    pub fn scene() -> Self {
        Self::scene_scaled(1280, 720)
    }

    /// The scene camera at another resolution (same field of view), e.g. a small preview.
    pub fn scene_scaled(width: u32, height: u32) -> Self {
        let [ex, ey, ez] = SCENE_CAMERA_EYE_M;
        let [tx, ty, tz] = SCENE_CAMERA_TARGET_M;
        Self::look_at(
            "scene_camera",
            &Point3::new(ex, ey, ez),
            &Point3::new(tx, ty, tz),
            &Vector3::z(),
            Intrinsics::from_aperture(width, height, 24.0, 20.955),
            [0.01, 100.0],
        )
    }

    /// A world-fixed camera at `eye` looking at `target`, `up` pointing up the image.
    /// Degenerate input (eye on target, up along the view) yields a camera looking along
    /// world +x.
    pub fn look_at(
        name: &str,
        eye: &Point3<f64>,
        target: &Point3<f64>,
        up: &Vector3<f64>,
        intrinsics: Intrinsics,
        clip_m: [f64; 2],
    ) -> Self {
        Self {
            name: name.to_owned(),
            parent: CameraParent::World,
            parent_from_camera: Isometry3::from_parts(
                eye.coords.into(),
                optical_look_rotation(&(target - eye), up),
            ),
            intrinsics,
            clip_m,
        }
    }

    /// Checks what the renderer relies on: finite pose, positive focal lengths, a non-empty
    /// image, 0 < near < far.
    pub fn validate(&self) -> Result<(), RenderError> {
        let fail = |message: String| RenderError::Camera {
            name: self.name.clone(),
            message,
        };
        let k = &self.intrinsics;
        if k.width == 0 || k.height == 0 {
            return Err(fail(format!("image {}×{} px is empty", k.width, k.height)));
        }
        if ![k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite()) || k.fx <= 0.0 || k.fy <= 0.0 {
            return Err(fail(format!(
                "intrinsics fx {} fy {} cx {} cy {} must be finite with positive focal lengths",
                k.fx, k.fy, k.cx, k.cy
            )));
        }
        let [near, far] = self.clip_m;
        if !(near.is_finite() && far.is_finite() && 0.0 < near && near < far) {
            return Err(fail(format!(
                "clip [{near}, {far}] m must satisfy 0 < near < far"
            )));
        }
        let p = &self.parent_from_camera;
        if !(p.translation.vector.iter().all(|v| v.is_finite())
            && p.rotation.coords.iter().all(|v| v.is_finite()))
        {
            return Err(fail("mount pose is not finite".to_owned()));
        }
        Ok(())
    }

    /// Clip-space projection of camera-frame points (column vectors `[x y z 1]`), for wgpu's
    /// conventions: x_ndc, y_ndc ∈ [−1, 1] with y up, and a reversed depth (1 at the near
    /// plane, 0 at the far plane, compared with `Greater`) for f32 precision over
    /// 0.01–1000 m. Derived from the pixel coordinates above with u = (x_ndc + 1)·W/2,
    /// v = (1 − y_ndc)·H/2.
    pub fn clip_from_camera(&self) -> Matrix4<f64> {
        let k = &self.intrinsics;
        let (w, h) = (f64::from(k.width), f64::from(k.height));
        let [n, f] = self.clip_m;
        Matrix4::new(
            2.0 * k.fx / w,
            0.0,
            2.0 * k.cx / w - 1.0,
            0.0, //
            0.0,
            -2.0 * k.fy / h,
            1.0 - 2.0 * k.cy / h,
            0.0, //
            0.0,
            0.0,
            -n / (f - n),
            n * f / (f - n), //
            0.0,
            0.0,
            1.0,
            0.0,
        )
    }
}

/// The rotation of a ROS optical frame whose +z points along `forward` and whose −y (image
/// up) leans toward `up`: x = forward × up (right), y = z × x (down).
pub fn optical_look_rotation(forward: &Vector3<f64>, up: &Vector3<f64>) -> UnitQuaternion<f64> {
    let z = forward.try_normalize(1e-12).unwrap_or_else(Vector3::x);
    let x = z.cross(up).try_normalize(1e-12).unwrap_or_else(|| {
        z.cross(&Vector3::y())
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::y)
    });
    let y = z.cross(&x);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(
        &[x, y, z],
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_intrinsics_are_isaacs_pinhole() {
        let k = Intrinsics::from_aperture(384, 384, 19.6, 20.955);
        // fx = 384 · 19.6 / 20.955 = 359.17 px.
        assert!((k.fx - 359.169_649_248_389_4).abs() < 1e-9, "{}", k.fx);
        assert_eq!((k.cx, k.cy), (192.0, 192.0));
        // HFOV = 2 atan(20.955 / 39.2) = 56.255°.
        assert!((k.horizontal_fov_rad().to_degrees() - 56.2549).abs() < 1e-3);
    }

    #[test]
    fn clip_matrix_maps_pixels_and_reversed_depth() {
        let cam = CameraSpec::scene();
        let p = Vector3::new(0.3, -0.2, 2.0);
        let [u, v] = cam.intrinsics.project(&p).unwrap_or([f64::NAN; 2]);
        let c = cam.clip_from_camera() * p.push(1.0);
        let (x, y, z) = (c.x / c.w, c.y / c.w, c.z / c.w);
        assert!(((x + 1.0) * 640.0 - u).abs() < 1e-9);
        assert!(((1.0 - y) * 360.0 - v).abs() < 1e-9);
        let depth = |d: f64| {
            let c = cam.clip_from_camera() * Vector3::new(0.0, 0.0, d).push(1.0);
            c.z / c.w
        };
        assert!((depth(0.01) - 1.0).abs() < 1e-12 && depth(100.0).abs() < 1e-12);
        assert!(z > 0.0 && z < 1.0);
    }

    #[test]
    fn scene_camera_looks_at_its_target_with_world_up_up_the_image() {
        let cam = CameraSpec::scene();
        let r = cam.parent_from_camera.rotation;
        let forward = r * Vector3::z();
        let expected = (Vector3::new(2.0, 0.0, 1.0) - Vector3::new(-2.0, -2.5, 1.6)).normalize();
        assert!((forward - expected).norm() < 1e-12);
        // Image down (+y) has a negative world z component; image right (+x) is horizontal.
        assert!((r * Vector3::y()).z < 0.0);
        assert!((r * Vector3::x()).z.abs() < 1e-12);
    }
}
