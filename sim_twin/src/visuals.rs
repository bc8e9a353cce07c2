//! What the twin's scene looks like, for a renderer: every scene collider (floor, walls, task
//! objects, props — everything but the vehicle) as a primitive shape, its world pose and its
//! role. Read-only: nothing here changes the physics.
//!
//! Shapes are given in the renderer's conventions, the same as `platform`'s URDF shapes:
//! cylinders and capsules lie along their frame's z axis (rapier's cylinders lie along y; the
//! conversion turns them here, once). The order of [`Twin::scene_visuals`] is the order of
//! [`Twin::scene_visual_poses_into`]: collider handle order, stable within an episode (scenes
//! add colliders only when they are built at reset).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude::*;

use crate::convert::{pose_from_rapier, vector_from_rapier};
use crate::twin::Twin;
use crate::vehicle_body::ROBOT_GROUP;

/// A fixed cuboid whose largest half extent reaches this is a wall (or a wall-like slab:
/// window, cabinet side), m. The task walls are 2 m × 2 m × 0.1 m (half extents 1, 1, 0.05).
pub const WALL_MIN_HALF_EXTENT_M: f64 = 0.5;

/// A scene body's shape, in its own frame ([`SceneVisual::world_from_shape`]).
#[derive(Debug, Clone, PartialEq)]
pub enum VisualShape {
    /// A box of these half extents, m.
    Box {
        /// Half side lengths along x, y, z, m.
        half_extents_m: Vector3<f64>,
    },
    /// A sphere.
    Sphere {
        /// Radius, m.
        radius_m: f64,
    },
    /// A cylinder along z.
    Cylinder {
        /// Radius, m.
        radius_m: f64,
        /// Half length along z, m.
        half_length_m: f64,
    },
    /// A capsule along z (half length of the cylindrical part).
    Capsule {
        /// Radius, m.
        radius_m: f64,
        /// Half length of the segment along z, m.
        half_length_m: f64,
    },
    /// A convex polyhedron: vertices and triangles (indices into the vertices).
    ConvexMesh {
        /// Vertices in the shape frame, m.
        vertices_m: Vec<Vector3<f64>>,
        /// Triangles (winding not guaranteed; the polyhedron is convex).
        triangles: Vec<[u32; 3]>,
    },
    /// The ground: the plane z = 0 of its frame, solid below (normal +z).
    Plane,
}

/// What a scene body is, for its nominal look.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VisualRole {
    /// The ground plane.
    Floor,
    /// A large fixed slab (largest half extent ≥ [`WALL_MIN_HALF_EXTENT_M`]).
    Wall,
    /// Any other fixed part (frames, pegs, rails, containers).
    Fixed,
    /// A body that moves: a free object or an articulated part (button, valve, door…).
    Moving,
}

/// One scene collider as a renderer sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneVisual {
    /// The shape, in its frame.
    pub shape: VisualShape,
    /// The shape frame in the world now.
    pub world_from_shape: Isometry3<f64>,
    /// What it is.
    pub role: VisualRole,
}

/// Colliders of the scene (not the vehicle's), in handle order.
fn scene_colliders(world: &PhysicsWorld) -> impl Iterator<Item = &Collider> {
    world
        .colliders
        .iter()
        .map(|(_, c)| c)
        .filter(|c| !c.collision_groups().memberships.intersects(ROBOT_GROUP))
}

/// A half turn about x: the frame for a direction opposite to z.
fn flipped() -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
}

/// The shape frame in the collider frame (None for a shape the scenes do not use: nothing is
/// drawn for it). Cheap: no vertex is copied (per-tick pose polling).
fn collider_from_shape(shape: &dyn Shape) -> Option<Isometry3<f64>> {
    if shape.as_cuboid().is_some()
        || shape.as_ball().is_some()
        || shape.as_convex_polyhedron().is_some()
    {
        return Some(Isometry3::identity());
    }
    if shape.as_cylinder().is_some() {
        // rapier's cylinder lies along y: the shape frame's z is the collider's y.
        let turn =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -std::f64::consts::FRAC_PI_2);
        return Some(Isometry3::from_parts(Translation3::identity(), turn));
    }
    if let Some(c) = shape.as_capsule() {
        let a = vector_from_rapier(c.segment.a);
        let b = vector_from_rapier(c.segment.b);
        let turn =
            UnitQuaternion::rotation_between(&Vector3::z(), &(b - a)).unwrap_or_else(flipped);
        return Some(Isometry3::from_parts(
            Translation3::from(0.5 * (a + b)),
            turn,
        ));
    }
    if let Some(h) = shape.as_halfspace() {
        let normal = vector_from_rapier(h.normal);
        let turn = UnitQuaternion::rotation_between(&Vector3::z(), &normal).unwrap_or_else(flipped);
        return Some(Isometry3::from_parts(Translation3::identity(), turn));
    }
    None
}

/// The shape of a collider in the renderer's conventions, and the shape frame in the
/// collider frame.
fn visual_shape(collider: &Collider) -> Option<(VisualShape, Isometry3<f64>)> {
    let shape = collider.shape();
    let pose = collider_from_shape(shape)?;
    let visual = if let Some(c) = shape.as_cuboid() {
        VisualShape::Box {
            half_extents_m: vector_from_rapier(c.half_extents),
        }
    } else if let Some(b) = shape.as_ball() {
        VisualShape::Sphere { radius_m: b.radius }
    } else if let Some(c) = shape.as_cylinder() {
        VisualShape::Cylinder {
            radius_m: c.radius,
            half_length_m: c.half_height,
        }
    } else if let Some(c) = shape.as_capsule() {
        VisualShape::Capsule {
            radius_m: c.radius,
            half_length_m: 0.5
                * (vector_from_rapier(c.segment.b) - vector_from_rapier(c.segment.a)).norm(),
        }
    } else if let Some(p) = shape.as_convex_polyhedron() {
        let (points, triangles) = p.to_trimesh();
        VisualShape::ConvexMesh {
            vertices_m: points.iter().map(|v| Vector3::new(v.x, v.y, v.z)).collect(),
            triangles,
        }
    } else {
        VisualShape::Plane
    };
    Some((visual, pose))
}

fn role(world: &PhysicsWorld, collider: &Collider, shape: &VisualShape) -> VisualRole {
    let fixed = collider
        .parent()
        .and_then(|h| world.bodies.get(h))
        .is_none_or(RigidBody::is_fixed);
    match shape {
        VisualShape::Plane => VisualRole::Floor,
        _ if !fixed => VisualRole::Moving,
        VisualShape::Box { half_extents_m } if half_extents_m.max() >= WALL_MIN_HALF_EXTENT_M => {
            VisualRole::Wall
        }
        _ => VisualRole::Fixed,
    }
}

impl Twin {
    /// Every scene collider (ground, task objects, walls, props; not the vehicle) with its
    /// shape, world pose now and role, in the order of [`Self::scene_visual_poses_into`].
    /// Shapes do not change within an episode: call this once per reset, then poll the poses.
    pub fn scene_visuals(&self) -> Vec<SceneVisual> {
        let world = self.world();
        scene_colliders(world)
            .filter_map(|c| {
                let (shape, collider_from_shape) = visual_shape(c)?;
                let role = role(world, c, &shape);
                Some(SceneVisual {
                    world_from_shape: pose_from_rapier(c.position()) * collider_from_shape,
                    shape,
                    role,
                })
            })
            .collect()
    }

    /// The world poses of the shapes of [`Self::scene_visuals`] now, same order, into
    /// `poses` (cleared first; no allocation once it has the capacity).
    pub fn scene_visual_poses_into(&self, poses: &mut Vec<Isometry3<f64>>) {
        poses.clear();
        for c in scene_colliders(self.world()) {
            if let Some(collider_from_shape) = collider_from_shape(c.shape()) {
                poses.push(pose_from_rapier(c.position()) * collider_from_shape);
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use crate::config::TwinConfig;
    use crate::tasks::TaskId;

    fn twin(task: TaskId) -> Twin {
        let vehicle = platform::Vehicle::builtin("fa-hexa").unwrap();
        let config = TwinConfig {
            task: Some(task),
            ..TwinConfig::default()
        };
        Twin::new(vehicle, config).unwrap()
    }

    #[test]
    fn press_button_scene_has_floor_wall_and_a_moving_plunger() {
        let t = twin(TaskId::PressButton);
        let v = t.scene_visuals();
        let count = |r| v.iter().filter(|s| s.role == r).count();
        assert_eq!(count(VisualRole::Floor), 1);
        assert_eq!(count(VisualRole::Wall), 1);
        assert_eq!(count(VisualRole::Moving), 1, "the plunger");
        // The wall is the 0.1 × 2 × 2 m slab centred near (2, 0, 1).
        let wall = v.iter().find(|s| s.role == VisualRole::Wall).unwrap();
        assert!(
            (wall.world_from_shape.translation.vector - Vector3::new(2.0, 0.0, 1.0)).norm() < 0.3
        );
        // The plunger is a cylinder turned onto the world x axis (it points at the robot).
        let plunger = v.iter().find(|s| s.role == VisualRole::Moving).unwrap();
        assert!(matches!(plunger.shape, VisualShape::Cylinder { .. }));
        let axis = plunger.world_from_shape.rotation * Vector3::z();
        assert!(axis.x.abs() > 0.9, "plunger axis {axis:?}");
        let mut poses = Vec::new();
        t.scene_visual_poses_into(&mut poses);
        assert_eq!(poses.len(), v.len());
        for (p, s) in poses.iter().zip(&v) {
            assert_eq!(*p, s.world_from_shape);
        }
    }

    #[test]
    fn peg_in_hole_hole_is_convex_meshes_and_the_vehicle_is_left_out() {
        let t = twin(TaskId::PegInHole);
        let v = t.scene_visuals();
        let meshes = v
            .iter()
            .filter(|s| matches!(s.shape, VisualShape::ConvexMesh { .. }))
            .count();
        assert_eq!(meshes, 4, "the hole's four bars");
        // Floor, wall, four bars, the peg: nothing of the vehicle.
        assert_eq!(v.len(), 7);
    }
}
