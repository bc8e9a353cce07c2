//! How things look: the nominal colours, the light, and the visual domain randomisation.
//!
//! **Nominal look** (`VisualDr::Off`, and the vehicle always):
//! - vehicle shapes: the URDF `<material>` colour when the URDF gives one, else the vehicle
//!   file's `[colors]` entry for the link; otherwise by link role — base and everything
//!   rigidly on it but the rotors [`BASE_RGB`], rotor discs [`ROTOR_RGB`], end-effector link
//!   and gripper fingers [`GRIPPER_RGB`], other arm links [`ARM_RGB`];
//! - scene: floor a grey checker of 0.5 m squares, walls [`WALL_RGB`], other fixed parts
//!   [`FIXED_RGB`], moving objects the [`OBJECT_PALETTE`] in scene order;
//! - light: a directional light of intensity [`NOMINAL_LIGHT_INTENSITY`] from azimuth 200°,
//!   elevation 55° (behind the robot's left, so the task walls' faces toward the robot are
//!   lit), plus ambient [`NOMINAL_AMBIENT`]; sky colour [`SKY_RGB`].
//!
//! Shading is Lambert: `rgb = albedo · (ambient + intensity · max(n·l, 0))`, clamped, written
//! as 8-bit linear values (no sRGB curve: the numbers are the image).
//!
//! **Visual domain randomisation** (`VisualDr::On`), per episode from the seed's
//! [`platform::RandomStream::VisualDomain`] stream (the one registry of a run's streams), in
//! this order:
//! 1. light azimuth U(0°, 360°), elevation U(25°, 85°), intensity U(0.45, 1.05), ambient
//!    U(0.15, 0.50);
//! 2. for every scene object in scene order (floor and walls included; the vehicle is not
//!    randomised), nine draws whatever it uses: hue U(0, 1), saturation U(0.1, 0.9), value
//!    U(0.25, 0.95); texture kind uniform among plain, checker, stripes, noise; texture period
//!    U(0.02, 0.25) m; the second colour = the first × U(0.35, 0.8); stripe direction from three
//!    U(−1, 1) draws (normalised; x when degenerate).
//!
//! Textures are procedural, computed in the fragment shader from the position in the object's
//! own frame (so they move with it): checker = parity of ⌊p/period⌋ summed over x, y, z;
//! stripes = parity of ⌊p·axis/period⌋; noise = a hash of the cell ⌊p/period⌋ mixing the two
//! colours.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use sim_twin::VisualRole;

/// Visual domain randomisation on or off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum VisualDr {
    /// The nominal look, whatever the seed.
    #[default]
    Off,
    /// Colours, textures and light drawn per episode from the seed.
    On,
}

/// Base of the vehicle (and its rotor arms), linear RGB.
pub const BASE_RGB: [f32; 3] = [0.22, 0.22, 0.25];
/// Rotor discs.
pub const ROTOR_RGB: [f32; 3] = [0.08, 0.08, 0.09];
/// Arm links.
pub const ARM_RGB: [f32; 3] = [0.78, 0.78, 0.80];
/// End-effector link and gripper fingers.
pub const GRIPPER_RGB: [f32; 3] = [0.15, 0.30, 0.62];
/// Walls.
pub const WALL_RGB: [f32; 3] = [0.86, 0.84, 0.78];
/// Fixed scene parts other than walls and floor.
pub const FIXED_RGB: [f32; 3] = [0.45, 0.50, 0.58];
/// Floor checker, light and dark squares.
pub const FLOOR_RGB: [[f32; 3]; 2] = [[0.55, 0.55, 0.52], [0.43, 0.43, 0.41]];
/// Floor checker period, m.
pub const FLOOR_PERIOD_M: f32 = 0.5;
/// Moving objects, in scene order (cycled).
pub const OBJECT_PALETTE: [[f32; 3]; 6] = [
    [0.92, 0.45, 0.08],
    [0.82, 0.14, 0.14],
    [0.18, 0.65, 0.24],
    [0.95, 0.80, 0.12],
    [0.55, 0.25, 0.70],
    [0.10, 0.60, 0.65],
];
/// Background (sky).
pub const SKY_RGB: [f32; 3] = [0.70, 0.78, 0.88];
/// Nominal directional light intensity.
pub const NOMINAL_LIGHT_INTENSITY: f32 = 0.75;
/// Nominal ambient light.
pub const NOMINAL_AMBIENT: f32 = 0.35;
/// Nominal light azimuth and elevation, degrees.
pub const NOMINAL_LIGHT_AZ_EL_DEG: [f64; 2] = [200.0, 55.0];

/// A procedural texture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pattern {
    /// One colour.
    Plain,
    /// A 3-D checker.
    Checker,
    /// Parallel stripes.
    Stripes,
    /// Cells of random mixes of the two colours.
    Noise,
}

impl Pattern {
    fn code(self) -> f32 {
        match self {
            Self::Plain => 0.0,
            Self::Checker => 1.0,
            Self::Stripes => 2.0,
            Self::Noise => 3.0,
        }
    }
}

/// What a surface looks like.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Albedo, linear RGB in [0, 1].
    pub rgb: [f32; 3],
    /// Second colour of a texture.
    pub rgb2: [f32; 3],
    /// Texture.
    pub pattern: Pattern,
    /// Texture period, m.
    pub period_m: f32,
    /// Stripe direction in the object frame (unit).
    pub axis: [f32; 3],
}

impl Material {
    /// One plain colour.
    pub fn plain(rgb: [f32; 3]) -> Self {
        Self {
            rgb,
            rgb2: rgb,
            pattern: Pattern::Plain,
            period_m: 1.0,
            axis: [1.0, 0.0, 0.0],
        }
    }

    /// The GPU layout: rgb, rgb2, [pattern, period, 0, 0], axis (vec4 each).
    pub(crate) fn gpu(&self) -> [[f32; 4]; 4] {
        let [r, g, b] = self.rgb;
        let [r2, g2, b2] = self.rgb2;
        let [ax, ay, az] = self.axis;
        [
            [r, g, b, 1.0],
            [r2, g2, b2, 1.0],
            [self.pattern.code(), self.period_m, 0.0, 0.0],
            [ax, ay, az, 0.0],
        ]
    }

    /// The nominal look of a scene object of `role`, the `moving_index`-th moving one.
    pub fn nominal(role: VisualRole, moving_index: usize) -> Self {
        match role {
            VisualRole::Floor => Self {
                rgb: FLOOR_RGB[0],
                rgb2: FLOOR_RGB[1],
                pattern: Pattern::Checker,
                period_m: FLOOR_PERIOD_M,
                axis: [1.0, 0.0, 0.0],
            },
            VisualRole::Wall => Self::plain(WALL_RGB),
            VisualRole::Fixed => Self::plain(FIXED_RGB),
            VisualRole::Moving => Self::plain(OBJECT_PALETTE[moving_index % OBJECT_PALETTE.len()]),
        }
    }
}

/// The light of a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lighting {
    /// Unit vector from the scene toward the light, world frame.
    pub toward_light: Vector3<f64>,
    /// Directional intensity.
    pub intensity: f32,
    /// Ambient intensity.
    pub ambient: f32,
}

fn direction(azimuth_deg: f64, elevation_deg: f64) -> Vector3<f64> {
    let (sa, ca) = azimuth_deg.to_radians().sin_cos();
    let (se, ce) = elevation_deg.to_radians().sin_cos();
    Vector3::new(ce * ca, ce * sa, se)
}

impl Default for Lighting {
    fn default() -> Self {
        let [az, el] = NOMINAL_LIGHT_AZ_EL_DEG;
        Self {
            toward_light: direction(az, el),
            intensity: NOMINAL_LIGHT_INTENSITY,
            ambient: NOMINAL_AMBIENT,
        }
    }
}

/// HSV (all in [0, 1]) to linear RGB.
fn hsv(h: f64, s: f64, v: f64) -> [f32; 3] {
    let h6 = h.rem_euclid(1.0) * 6.0;
    let c = v * s;
    let x = c * (1.0 - ((h6 % 2.0) - 1.0).abs());
    let (r, g, b) = match h6 {
        h if h < 1.0 => (c, x, 0.0),
        h if h < 2.0 => (x, c, 0.0),
        h if h < 3.0 => (0.0, c, x),
        h if h < 4.0 => (0.0, x, c),
        h if h < 5.0 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    #[allow(clippy::cast_possible_truncation)]
    [(r + m) as f32, (g + m) as f32, (b + m) as f32]
}

/// The looks of one episode: the light and every scene object's material.
#[derive(Debug, Clone, PartialEq)]
pub struct Appearance {
    /// The light.
    pub lighting: Lighting,
    /// One material per scene object, scene order.
    pub materials: Vec<Material>,
}

impl Appearance {
    /// The nominal look (`dr` off) or the draws of `seed` (`dr` on) for scene objects of
    /// these roles.
    pub fn draw(dr: VisualDr, seed: u64, roles: &[VisualRole]) -> Self {
        let mut moving = 0;
        let nominal: Vec<Material> = roles
            .iter()
            .map(|&r| {
                let m = Material::nominal(r, moving);
                moving += usize::from(r == VisualRole::Moving);
                m
            })
            .collect();
        match dr {
            VisualDr::Off => Self {
                lighting: Lighting::default(),
                materials: nominal,
            },
            VisualDr::On => {
                let mut rng = platform::RandomStream::VisualDomain.rng(seed);
                let az = rng.random_range(0.0..360.0);
                let el = rng.random_range(25.0..85.0);
                let intensity: f32 = rng.random_range(0.45..1.05);
                let ambient: f32 = rng.random_range(0.15..0.50);
                let lighting = Lighting {
                    toward_light: direction(az, el),
                    intensity,
                    ambient,
                };
                let materials = roles
                    .iter()
                    .map(|_| Self::random_material(&mut rng))
                    .collect();
                Self {
                    lighting,
                    materials,
                }
            }
        }
    }

    fn random_material(rng: &mut ChaCha8Rng) -> Material {
        let h = rng.random_range(0.0..1.0);
        let s = rng.random_range(0.1..0.9);
        let v = rng.random_range(0.25..0.95);
        let pattern = match rng.random_range(0..4u32) {
            0 => Pattern::Plain,
            1 => Pattern::Checker,
            2 => Pattern::Stripes,
            _ => Pattern::Noise,
        };
        let period_m: f32 = rng.random_range(0.02..0.25);
        let dark: f32 = rng.random_range(0.35..0.8);
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        )
        .try_normalize(1e-6)
        .unwrap_or_else(Vector3::x);
        let rgb = hsv(h, s, v);
        #[allow(clippy::cast_possible_truncation)]
        Material {
            rgb,
            rgb2: rgb.map(|c| c * dark),
            pattern,
            period_m,
            axis: [axis.x as f32, axis.y as f32, axis.z as f32],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hsv_primaries() {
        assert_eq!(hsv(0.0, 1.0, 1.0), [1.0, 0.0, 0.0]);
        assert_eq!(hsv(1.0 / 3.0, 1.0, 1.0), [0.0, 1.0, 0.0]);
        assert_eq!(hsv(0.5, 0.0, 0.5), [0.5, 0.5, 0.5]);
    }

    #[test]
    fn nominal_light_comes_from_behind_the_robot_and_above() {
        let l = Lighting::default();
        // Walls face −x toward the robot: the light must have a −x component to light them.
        assert!(l.toward_light.x < -0.5 && l.toward_light.z > 0.8 * 0.9);
        assert!((l.toward_light.norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn draws_are_the_seeds_and_stay_in_their_ranges() {
        let roles = [VisualRole::Floor, VisualRole::Wall, VisualRole::Moving];
        let a = Appearance::draw(VisualDr::On, 7, &roles);
        assert_eq!(a, Appearance::draw(VisualDr::On, 7, &roles));
        assert_ne!(a, Appearance::draw(VisualDr::On, 8, &roles));
        assert_eq!(
            Appearance::draw(VisualDr::Off, 7, &roles),
            Appearance::draw(VisualDr::Off, 8, &roles)
        );
        for seed in 0..50 {
            let a = Appearance::draw(VisualDr::On, seed, &roles);
            let el = a.lighting.toward_light.z.asin().to_degrees();
            assert!((25.0..=85.0).contains(&el), "elevation {el}");
            assert!((0.45..=1.05).contains(&a.lighting.intensity));
            for m in &a.materials {
                let max = m.rgb.iter().copied().fold(0.0, f32::max);
                assert!((0.25..=0.95).contains(&max), "value {max}");
                assert!((0.02..=0.25).contains(&m.period_m));
            }
        }
    }
}
