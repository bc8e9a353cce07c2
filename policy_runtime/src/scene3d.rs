//! The flight as a 3D scene, in Foxglove's well-known schemas (the Foxglove SDK's protobuf
//! types): what Foxglove's 3D panel and Rerun's MCAP importer draw.
//!
//! | topic | schema | when | content |
//! |---|---|---|---|
//! | `/scene/tf` | foxglove.FrameTransforms | t_k | world → the URDF root link (the measured base pose), then every joint's parent link → child link at the measured joint positions |
//! | `/scene/static` | foxglove.SceneUpdate | t_0, then every simulated second | the vehicle (one entity per link with visuals, frame-locked to its link frame), the floor, walls and fixed scene parts (`world`) |
//! | `/scene/dynamic` | foxglove.SceneUpdate | t_k + dt | the task's moving objects (`world`) and one arrow per rotor along its thrust axis, length ∝ realised thrust (red: at a limit) |
//! | `/scene/targets` | foxglove.SceneUpdate | t_k | the EE target (the tick's EE reference: a sphere and its axes) and the base target the controller tracked (with the `ee` interface, the IK's) |
//!
//! The static scene is sent again every simulated second so that a viewer that seeks, or a
//! live viewer that connects mid-flight, has it. Everything here is a pure function of the
//! vehicle description, the scene's shapes and the logged state: two runs of one seed give
//! the same messages.

use foxglove::schemas::{
    ArrowPrimitive, Color, CubePrimitive, CylinderPrimitive, FrameTransform, FrameTransforms,
    Point3, Pose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp,
    TriangleListPrimitive, Vector3,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3 as V3};
use platform::{Geometry, KinematicModel, Measurement, Shape, Vehicle};
use sim_twin::{SceneVisual, VisualRole, VisualShape};

/// The world frame's name.
pub const WORLD_FRAME: &str = "world";
/// `/scene/tf`.
pub const SCENE_TF_TOPIC: &str = "/scene/tf";
/// `/scene/static`.
pub const SCENE_STATIC_TOPIC: &str = "/scene/static";
/// `/scene/dynamic`.
pub const SCENE_DYNAMIC_TOPIC: &str = "/scene/dynamic";
/// `/scene/targets`.
pub const SCENE_TARGETS_TOPIC: &str = "/scene/targets";

/// The static scene is sent again at this period of the flight's time, s.
pub const STATIC_PERIOD_S: f64 = 1.0;
/// A rotor at its maximum thrust draws an arrow this long, m.
pub const ARROW_LENGTH_AT_MAX_THRUST_M: f64 = 0.4;
/// Side of the floor drawn for the ground plane, m.
pub const FLOOR_SIDE_M: f64 = 20.0;

/// Colours (linear RGBA).
const VEHICLE_GREY: [f64; 4] = [0.35, 0.37, 0.40, 1.0];
const FLOOR: [f64; 4] = [0.55, 0.58, 0.55, 1.0];
const WALL: [f64; 4] = [0.82, 0.78, 0.70, 0.85];
const FIXED: [f64; 4] = [0.55, 0.42, 0.30, 1.0];
const MOVING: [f64; 4] = [0.15, 0.45, 0.85, 1.0];
const THRUST: [f64; 4] = [0.10, 0.75, 0.25, 0.9];
const THRUST_SATURATED: [f64; 4] = [0.90, 0.10, 0.10, 0.95];
const EE_TARGET: [f64; 4] = [1.0, 0.55, 0.0, 0.8];
const BASE_TARGET: [f64; 4] = [0.6, 0.2, 0.9, 0.5];

fn color([r, g, b, a]: [f64; 4]) -> Option<Color> {
    Some(Color { r, g, b, a })
}

fn vector(v: &V3<f64>) -> Vector3 {
    Vector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

fn pose(p: &Isometry3<f64>) -> Option<Pose> {
    let q = p.rotation;
    Some(Pose {
        position: Some(vector(&p.translation.vector)),
        orientation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    })
}

/// The run's time in nanoseconds as a Foxglove timestamp (seconds saturate in 136 years).
pub fn timestamp(time_ns: u64) -> Timestamp {
    let sec = u32::try_from(time_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (time_ns % 1_000_000_000) as u32)
}

/// The primitives of one entity.
#[derive(Default)]
struct Primitives {
    cubes: Vec<CubePrimitive>,
    spheres: Vec<SpherePrimitive>,
    cylinders: Vec<CylinderPrimitive>,
    triangles: Vec<TriangleListPrimitive>,
}

impl Primitives {
    fn is_empty(&self) -> bool {
        self.cubes.is_empty()
            && self.spheres.is_empty()
            && self.cylinders.is_empty()
            && self.triangles.is_empty()
    }

    fn cube(&mut self, at: &Isometry3<f64>, size: V3<f64>, rgba: [f64; 4]) {
        self.cubes.push(CubePrimitive {
            pose: pose(at),
            size: Some(vector(&size)),
            color: color(rgba),
        });
    }

    fn sphere(&mut self, at: &Isometry3<f64>, radius: f64, rgba: [f64; 4]) {
        self.spheres.push(SpherePrimitive {
            pose: pose(at),
            size: Some(vector(&V3::repeat(2.0 * radius))),
            color: color(rgba),
        });
    }

    /// A cylinder along the z axis of `at` (Foxglove's cylinders lie along z, like ours).
    fn cylinder(&mut self, at: &Isometry3<f64>, radius: f64, length: f64, rgba: [f64; 4]) {
        self.cylinders.push(CylinderPrimitive {
            pose: pose(at),
            size: Some(vector(&V3::new(2.0 * radius, 2.0 * radius, length))),
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: color(rgba),
        });
    }

    /// A capsule along z: a cylinder and two spheres.
    fn capsule(&mut self, at: &Isometry3<f64>, radius: f64, length: f64, rgba: [f64; 4]) {
        self.cylinder(at, radius, length, rgba);
        for end in [-0.5, 0.5] {
            let cap = at * Translation3::new(0.0, 0.0, end * length);
            self.sphere(&cap, radius, rgba);
        }
    }

    fn mesh(&mut self, at: &Isometry3<f64>, vertices: &[V3<f64>], triangles: &[[u32; 3]]) {
        self.triangles.push(TriangleListPrimitive {
            pose: pose(at),
            points: vertices
                .iter()
                .map(|v| Point3 {
                    x: v.x,
                    y: v.y,
                    z: v.z,
                })
                .collect(),
            color: color(FIXED),
            colors: Vec::new(),
            indices: triangles.iter().flatten().copied().collect(),
        });
    }

    fn geometry(&mut self, g: &Geometry) {
        let rgba = g.rgba.unwrap_or(VEHICLE_GREY);
        let at = &g.link_from_shape;
        match g.shape {
            Shape::Box { size_m } => self.cube(at, size_m, rgba),
            Shape::Sphere { radius_m } => self.sphere(at, radius_m, rgba),
            Shape::Cylinder { radius_m, length_m } => self.cylinder(at, radius_m, length_m, rgba),
            Shape::Capsule { radius_m, length_m } => self.capsule(at, radius_m, length_m, rgba),
        }
    }

    fn scene_visual(&mut self, v: &SceneVisual, at: &Isometry3<f64>) {
        let rgba = match v.role {
            VisualRole::Floor => FLOOR,
            VisualRole::Wall => WALL,
            VisualRole::Fixed => FIXED,
            VisualRole::Moving => MOVING,
        };
        match &v.shape {
            VisualShape::Box { half_extents_m } => self.cube(at, 2.0 * half_extents_m, rgba),
            VisualShape::Sphere { radius_m } => self.sphere(at, *radius_m, rgba),
            VisualShape::Cylinder {
                radius_m,
                half_length_m,
            } => self.cylinder(at, *radius_m, 2.0 * half_length_m, rgba),
            VisualShape::Capsule {
                radius_m,
                half_length_m,
            } => self.capsule(at, *radius_m, 2.0 * half_length_m, rgba),
            VisualShape::ConvexMesh {
                vertices_m,
                triangles,
            } => self.mesh(at, vertices_m, triangles),
            VisualShape::Plane => {
                // The ground: a thin slab whose top face is the plane.
                let top = at * Translation3::new(0.0, 0.0, -0.005);
                self.cube(&top, V3::new(FLOOR_SIDE_M, FLOOR_SIDE_M, 0.01), rgba);
            }
        }
    }

    fn entity(self, time_ns: u64, frame_id: &str, id: String) -> SceneEntity {
        SceneEntity {
            timestamp: Some(timestamp(time_ns)),
            frame_id: frame_id.to_owned(),
            id,
            lifetime: None,
            frame_locked: true,
            metadata: Vec::new(),
            arrows: Vec::new(),
            cubes: self.cubes,
            spheres: self.spheres,
            cylinders: self.cylinders,
            lines: Vec::new(),
            triangles: self.triangles,
            texts: Vec::new(),
            models: Vec::new(),
        }
    }
}

/// A rotor as drawn: in its own link's frame (so a tilting rotor's arrow tilts with it).
#[derive(Debug, Clone)]
struct RotorArrow {
    frame: String,
    /// The arrow's base at the rotor, +x along the thrust axis, in the rotor link frame.
    link_from_arrow: Isometry3<f64>,
}

/// The 3D scene of one vehicle's flights: its links, rotors, and (per flight) the task scene.
/// Built once per vehicle; the per-tick methods allocate only the messages.
#[derive(Debug, Clone)]
pub struct Scene3d {
    model: KinematicModel,
    /// Frame name of each link (its URDF name).
    frames: Vec<String>,
    rotors: Vec<RotorArrow>,
    thrust_max_n: f64,
    /// The task scene's shapes (from the link, at the flight's start).
    scene: Vec<SceneVisual>,
    next_static_ns: u64,
}

impl Scene3d {
    /// The scene of `vehicle` (no task scene yet: [`Self::set_scene`]).
    pub fn new(vehicle: &Vehicle) -> Self {
        let model = vehicle.model.clone();
        let frames: Vec<String> = model
            .links
            .iter()
            .map(|l| match l.name.as_str() {
                // The names the JSON `/tf` and the world use: keep the URDF's links apart.
                WORLD_FRAME | "base" | "ee" => format!("link/{}", l.name),
                name => name.to_owned(),
            })
            .collect();
        let q0 = vec![0.0; model.dof()];
        let rest = model.forward_kinematics(&q0);
        let rotors = vehicle
            .rotors
            .rotors
            .iter()
            .map(|r| {
                let link = model.link_id(&r.link).unwrap_or(model.root);
                let link_from_root = rest[link].inverse();
                let axis = link_from_root.rotation * r.axis_in_base.into_inner();
                let turn = UnitQuaternion::rotation_between(&V3::x(), &axis).unwrap_or_else(|| {
                    UnitQuaternion::from_axis_angle(&V3::z_axis(), std::f64::consts::PI)
                });
                RotorArrow {
                    frame: frames[link].clone(),
                    link_from_arrow: Isometry3::from_parts(
                        Translation3::from(
                            (link_from_root * nalgebra::Point3::from(r.position_in_base)).coords,
                        ),
                        turn,
                    ),
                }
            })
            .collect();
        Self {
            frames,
            rotors,
            thrust_max_n: vehicle.rotors.thrust_max_n,
            scene: Vec::new(),
            model,
            next_static_ns: 0,
        }
    }

    /// The task scene's shapes for the next flight (from [`crate::Link::camera_scene`]); the
    /// static scene is sent again from the next tick.
    pub fn set_scene(&mut self, scene: Vec<SceneVisual>) {
        self.scene = scene;
        self.next_static_ns = 0;
    }

    /// Whether the static scene is due at `time_ns` (t_0, then every [`STATIC_PERIOD_S`]);
    /// marks it sent.
    pub fn static_due(&mut self, time_ns: u64) -> bool {
        if time_ns < self.next_static_ns {
            return false;
        }
        let period_ns = (STATIC_PERIOD_S * 1e9) as u64;
        self.next_static_ns = (time_ns / period_ns + 1) * period_ns;
        true
    }

    /// `/scene/tf` of `m` at `time_ns`: world → root link, then every joint.
    pub fn transforms(&mut self, time_ns: u64, m: &Measurement) -> FrameTransforms {
        let stamp = timestamp(time_ns);
        let mut transforms = Vec::with_capacity(self.model.joints.len() + 1);
        let world_from_root = m.base.pose();
        transforms.push(frame_transform(
            stamp,
            WORLD_FRAME,
            &self.frames[self.model.root],
            &world_from_root,
        ));
        let complete = m.joint_positions.len() == self.model.dof();
        for joint in &self.model.joints {
            let q = match joint.dof {
                Some(d) if complete => m.joint_positions[d],
                _ => 0.0,
            };
            transforms.push(frame_transform(
                stamp,
                &self.frames[joint.parent],
                &self.frames[joint.child],
                &joint.parent_from_child(q),
            ));
        }
        FrameTransforms { transforms }
    }

    /// `/scene/static` at `time_ns`: one entity per vehicle link with visuals (frame-locked to
    /// the link), and the task scene's floor, walls and fixed parts in `world`.
    pub fn static_scene(&self, time_ns: u64) -> SceneUpdate {
        let mut entities = Vec::new();
        for (link, frame) in self.model.links.iter().zip(&self.frames) {
            let mut p = Primitives::default();
            for g in &link.visuals {
                p.geometry(g);
            }
            if !p.is_empty() {
                entities.push(p.entity(time_ns, frame, format!("vehicle/{}", link.name)));
            }
        }
        let mut fixed = Primitives::default();
        for v in self.scene.iter().filter(|v| v.role != VisualRole::Moving) {
            fixed.scene_visual(v, &v.world_from_shape);
        }
        if !fixed.is_empty() {
            entities.push(fixed.entity(time_ns, WORLD_FRAME, "scene/fixed".to_owned()));
        }
        SceneUpdate {
            deletions: Vec::new(),
            entities,
        }
    }

    /// `/scene/dynamic` at `time_ns` (t_k + dt): the moving scene objects at `scene_poses`
    /// (world poses, the order of the scene's shapes; empty: none drawn) and the rotors'
    /// realised thrusts of `m`.
    pub fn dynamic_scene(
        &self,
        time_ns: u64,
        m: &Measurement,
        scene_poses: &[Isometry3<f64>],
    ) -> SceneUpdate {
        let mut entities = Vec::new();
        if scene_poses.len() == self.scene.len() {
            let mut moving = Primitives::default();
            for (v, at) in self.scene.iter().zip(scene_poses) {
                if v.role == VisualRole::Moving {
                    moving.scene_visual(v, at);
                }
            }
            if !moving.is_empty() {
                let mut e = moving.entity(time_ns, WORLD_FRAME, "scene/objects".to_owned());
                e.frame_locked = false;
                entities.push(e);
            }
        }
        if !m.rotors.is_empty() && self.rotors.len() == m.rotors.len() {
            let scale = ARROW_LENGTH_AT_MAX_THRUST_M / self.thrust_max_n.max(f64::MIN_POSITIVE);
            for (i, (rotor, report)) in self.rotors.iter().zip(&m.rotors).enumerate() {
                let thrust = report.realised_n;
                let length = (thrust * scale).abs();
                let at = if thrust < 0.0 {
                    rotor.link_from_arrow
                        * UnitQuaternion::from_axis_angle(&V3::z_axis(), std::f64::consts::PI)
                } else {
                    rotor.link_from_arrow
                };
                let at_limit =
                    report.saturated || (self.thrust_max_n - thrust).abs() < 1e-5 || thrust <= 1e-5;
                let arrow = ArrowPrimitive {
                    pose: pose(&at),
                    shaft_length: 0.8 * length,
                    shaft_diameter: 0.02,
                    head_length: 0.2 * length,
                    head_diameter: 0.05,
                    color: color(if at_limit { THRUST_SATURATED } else { THRUST }),
                };
                let mut e = Primitives::default().entity(
                    time_ns,
                    &rotor.frame,
                    format!("rotor/{i}/thrust"),
                );
                e.arrows.push(arrow);
                entities.push(e);
            }
        }
        SceneUpdate {
            deletions: Vec::new(),
            entities,
        }
    }

    /// `/scene/targets` at `time_ns`: the EE target and the base target, in `world`.
    pub fn targets(
        &self,
        time_ns: u64,
        world_from_ee_target: &Isometry3<f64>,
        world_from_base_target: &Isometry3<f64>,
    ) -> SceneUpdate {
        let mut ee = Primitives::default();
        ee.sphere(world_from_ee_target, 0.03, EE_TARGET);
        let mut ee = ee.entity(time_ns, WORLD_FRAME, "target/ee".to_owned());
        ee.arrows = axes(world_from_ee_target, 0.12);
        ee.frame_locked = false;
        let mut base = Primitives::default();
        base.cube(world_from_base_target, V3::new(0.3, 0.3, 0.06), BASE_TARGET);
        let mut base = base.entity(time_ns, WORLD_FRAME, "target/base".to_owned());
        base.arrows = axes(world_from_base_target, 0.3);
        base.frame_locked = false;
        SceneUpdate {
            deletions: Vec::new(),
            entities: vec![ee, base],
        }
    }
}

/// x, y, z axes of `at` as red, green, blue arrows `length` long.
fn axes(at: &Isometry3<f64>, length: f64) -> Vec<ArrowPrimitive> {
    let turns = [
        (UnitQuaternion::identity(), [0.9, 0.1, 0.1, 1.0]),
        (
            UnitQuaternion::from_axis_angle(&V3::z_axis(), std::f64::consts::FRAC_PI_2),
            [0.1, 0.8, 0.1, 1.0],
        ),
        (
            UnitQuaternion::from_axis_angle(&V3::y_axis(), -std::f64::consts::FRAC_PI_2),
            [0.1, 0.3, 0.9, 1.0],
        ),
    ];
    turns
        .into_iter()
        .map(|(turn, rgba)| ArrowPrimitive {
            pose: pose(&Isometry3::from_parts(at.translation, at.rotation * turn)),
            shaft_length: 0.8 * length,
            shaft_diameter: 0.1 * length,
            head_length: 0.2 * length,
            head_diameter: 0.2 * length,
            color: color(rgba),
        })
        .collect()
}

/// The transform `parent_from_child` as a Foxglove `FrameTransform` at `timestamp`.
pub(crate) fn frame_transform(
    timestamp: Timestamp,
    parent: &str,
    child: &str,
    parent_from_child: &Isometry3<f64>,
) -> FrameTransform {
    let q = parent_from_child.rotation;
    FrameTransform {
        timestamp: Some(timestamp),
        parent_frame_id: parent.to_owned(),
        child_frame_id: child.to_owned(),
        translation: Some(vector(&parent_from_child.translation.vector)),
        rotation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use crate::record::{McapRecorder, Recording, RunMetadata};
    use foxglove::Decode;
    use platform::{RigidBodyState, RotorReport};

    fn hover(vehicle: &Vehicle, thrust_n: f64) -> Measurement {
        let mut m = Measurement {
            base: RigidBodyState::at_rest(Isometry3::translation(1.0, 2.0, 3.0)),
            joint_positions: vec![0.0; vehicle.model.dof()],
            joint_velocities: vec![0.0; vehicle.model.dof()],
            ..Default::default()
        };
        m.rotors = (0..vehicle.rotors.rotors.len())
            .map(|_| RotorReport {
                commanded_n: thrust_n,
                realised_n: thrust_n,
                applied_n: thrust_n,
                ..Default::default()
            })
            .collect();
        m
    }

    #[test]
    fn transforms_chain_every_joint_from_the_measured_base() {
        let vehicle = Vehicle::builtin("fa-hexa").unwrap();
        let mut scene = Scene3d::new(&vehicle);
        let mut m = hover(&vehicle, 0.0);
        // Turn the first arm joint by 0.5 rad.
        m.joint_positions[0] = 0.5;
        let tf = scene.transforms(8_333_333, &m);
        assert_eq!(tf.transforms.len(), vehicle.model.joints.len() + 1);
        let root = &tf.transforms[0];
        assert_eq!(
            (root.parent_frame_id.as_str(), root.child_frame_id.as_str()),
            ("world", "base_link")
        );
        let t = root.translation.as_ref().unwrap();
        assert_eq!((t.x, t.y, t.z), (1.0, 2.0, 3.0));
        assert_eq!(root.timestamp.unwrap().nsec(), 8_333_333);
        let joint = vehicle.model.dof_joint(0);
        let child = &vehicle.model.links[joint.child].name;
        let moved = tf
            .transforms
            .iter()
            .find(|t| &t.child_frame_id == child)
            .unwrap();
        let q = moved.rotation.unwrap();
        let expected = joint.parent_from_child(0.5).rotation;
        assert!((q.w - expected.w).abs() < 1e-12 && (q.x - expected.i).abs() < 1e-12);
        assert!(
            (expected.angle() - 0.5).abs() < 1e-9 || joint.kind == platform::JointKind::Prismatic
        );
    }

    #[test]
    fn rotor_arrows_are_as_long_as_their_share_of_the_maximum_thrust() {
        let vehicle = Vehicle::builtin("fa-hexa").unwrap();
        let scene = Scene3d::new(&vehicle);
        let half = 0.5 * vehicle.rotors.thrust_max_n;
        let update = scene.dynamic_scene(0, &hover(&vehicle, half), &[]);
        assert_eq!(
            update.entities.len(),
            vehicle.rotors.rotors.len(),
            "no scene objects given"
        );
        for (i, e) in update.entities.iter().enumerate() {
            assert_eq!(e.id, format!("rotor/{i}/thrust"));
            assert_eq!(e.frame_id, vehicle.rotors.rotors[i].link);
            let a = &e.arrows[0];
            let length = a.shaft_length + a.head_length;
            assert!(
                (length - 0.5 * ARROW_LENGTH_AT_MAX_THRUST_M).abs() < 1e-12,
                "{length}"
            );
            assert_eq!(a.color.unwrap().r, THRUST[0], "not at a limit: green");
        }
        // At the maximum: red.
        let full = scene.dynamic_scene(0, &hover(&vehicle, vehicle.rotors.thrust_max_n), &[]);
        assert_eq!(
            full.entities[0].arrows[0].color.unwrap().r,
            THRUST_SATURATED[0]
        );
    }

    #[test]
    fn the_static_scene_is_due_at_start_and_each_second() {
        let vehicle = Vehicle::builtin("fa-hexa").unwrap();
        let mut scene = Scene3d::new(&vehicle);
        let due: Vec<u64> = (0..250u64)
            .map(|k| k * 1_000_000_000 / 120)
            .filter(|&t| scene.static_due(t))
            .collect();
        assert_eq!(due, [0, 1_000_000_000, 2_000_000_000]);
        let update = scene.static_scene(0);
        assert!(
            update
                .entities
                .iter()
                .any(|e| e.id == "vehicle/base_link" && e.frame_locked)
        );
    }

    #[test]
    fn sdk_messages_go_through_the_recorder_and_decode_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("scene.mcap");
        let vehicle = Vehicle::builtin("fa-hexa").unwrap();
        let mut scene = Scene3d::new(&vehicle);
        let m = hover(&vehicle, 3.0);
        let tf = scene.transforms(0, &m);
        let mut rec = McapRecorder::create(&path, &RunMetadata::new("fa-hexa", "pid6", 1)).unwrap();
        let ch = rec
            .encoded_channel::<FrameTransforms>(SCENE_TF_TOPIC)
            .unwrap();
        rec.log_encoded(&ch, 0, &tf).unwrap();
        rec.finish().unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let back = Recording::from_bytes(&bytes).unwrap();
        let msg = back
            .messages
            .iter()
            .find(|m| m.topic == SCENE_TF_TOPIC)
            .unwrap();
        assert_eq!(FrameTransforms::decode(&msg.data[..]).unwrap(), tf);
    }
}
