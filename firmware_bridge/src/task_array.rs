//! The task scene's state on the wire: a SITL extension of the contract (docs/mavlink.md).
//!
//! A real vehicle knows nothing of the manipulation task; in SITL the twin's autopilot does,
//! and sends it so that the flight side can judge a task flown over MAVLink as the benchmark
//! does in-process. It travels as one DEBUG_FLOAT_ARRAY named `task` (array_id 2) per twin
//! step, before the ODOMETRY that closes the tick, stamped with the same `time_usec`.
//!
//! Layout of `data` (f32, as MAVLink carries it):
//!
//! | index | content |
//! |---|---|
//! | 0 | task number: k for the k-th task of the benchmark's order (1-based), 0 none |
//! | 1 | env steps since reset (exact below 2²⁴) |
//! | 2 | flags: 1 success, 2 holding an object, 4 wall pose present, 8 obstacle face present, 16 held object on a prismatic joint, 32 … on a revolute joint, 64 hand contact present |
//! | 3 | number of criteria (≤ 16) |
//! | 4 | criteria bits, criterion i is bit i |
//! | 5 | world x of the obstacle face, m |
//! | 6–8 | wall position in the world, m |
//! | 9–12 | wall orientation, w x y z |
//! | 13 | number of observation values n (≤ 33) |
//! | 14 … 13+n | the observation values, in the scene's key order |
//! | 47–49 | the held object's joint axis (unit, world), flags 16 or 32 |
//! | 50–52 | a point on that axis, m (world), flag 32 |
//! | 53–55 | the hand contact's normal (unit, world, out of what the hand touches), flag 64 |
//!
//! The held joint and the hand contact are what the whole-body MPC models of the task
//! (`platform::HeldJoint`, `Twin::hand_contact`, docs/mpc-contact.md); without them an MPC
//! flown over MAVLink would not know that its hand is pinned to a slider or pressing a knob.
//!
//! Positions are in amstack's world frame (x forward, z up), not NED: the array is ours, and
//! the values are the scene's own observation keys. Names and lengths of the keys are not
//! sent: both ends build the same scene from the task and the seed.

use mavlink::dialects::common::{DEBUG_FLOAT_ARRAY_DATA, MavMessage};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use platform::HeldJoint;

/// DEBUG_FLOAT_ARRAY's array_id for the task state.
pub const TASK_ARRAY_ID: u16 = 2;
/// DEBUG_FLOAT_ARRAY's name for the task state.
pub const TASK_ARRAY_NAME: &str = "task";
/// The most criteria the array carries.
pub const MAX_CRITERIA: usize = 16;
/// Where the observation values start.
const VALUES_AT: usize = 14;
/// Where the held joint's axis starts (then its point, then the hand contact's normal).
const JOINT_AT: usize = 47;
/// Where the point on a revolute held joint's axis starts.
const POINT_AT: usize = 50;
/// Where the hand contact's normal starts.
const CONTACT_AT: usize = 53;
/// The most observation values the array carries.
pub const MAX_VALUES: usize = JOINT_AT - VALUES_AT;
/// A received unit vector whose norm is further than this from 1 is not one (f32 rounding
/// leaves ~1e-7).
const UNIT_TOLERANCE: f64 = 1e-3;

const SUCCESS: u32 = 1;
const HOLDING: u32 = 2;
const HAS_WALL: u32 = 4;
const HAS_FACE: u32 = 8;
const HELD_PRISMATIC: u32 = 16;
const HELD_REVOLUTE: u32 = 32;
const HAS_CONTACT: u32 = 64;
const ALL_FLAGS: u32 = 127;

/// One step's task state.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskArray {
    /// The simulated time it belongs to, µs (the ODOMETRY's).
    pub time_usec: u64,
    /// The task's 1-based number in the benchmark's order.
    pub task_number: u32,
    /// Env steps since reset.
    pub steps: u64,
    /// Whether the success criterion holds.
    pub success: bool,
    /// Whether the grasp holds an object.
    pub holding: bool,
    /// Each criterion now.
    pub criteria: Vec<bool>,
    /// World x of the obstacle face, m.
    pub obstacle_face_x_m: Option<f64>,
    /// The wall's pose.
    pub wall: Option<Isometry3<f64>>,
    /// The observation values, in the scene's key order.
    pub values: Vec<f64>,
    /// The joint the held object moves on (None: nothing held, or a free object).
    pub held_joint: Option<HeldJoint>,
    /// The normal of the hand's contacts with what does not give way along them.
    pub hand_contact: Option<Vector3<f64>>,
}

fn f(x: f64) -> f32 {
    // MAVLink carries f32; the narrowing is the protocol's.
    #[allow(clippy::cast_possible_truncation)]
    let y = x as f32;
    y
}

/// Why a task array cannot be sent or was not understood.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TaskArrayError {
    /// More than the array holds.
    #[error("{what}: {count} do not fit the task array (at most {max})")]
    TooLarge {
        /// Criteria or values.
        what: &'static str,
        /// How many there are.
        count: usize,
        /// How many fit.
        max: usize,
    },
    /// A received array that is not a task state.
    #[error("task array: {0}")]
    Malformed(String),
}

impl TaskArray {
    /// The DEBUG_FLOAT_ARRAY carrying it.
    pub fn encode(&self) -> Result<MavMessage, TaskArrayError> {
        if self.criteria.len() > MAX_CRITERIA {
            return Err(TaskArrayError::TooLarge {
                what: "criteria",
                count: self.criteria.len(),
                max: MAX_CRITERIA,
            });
        }
        if self.values.len() > MAX_VALUES {
            return Err(TaskArrayError::TooLarge {
                what: "observation values",
                count: self.values.len(),
                max: MAX_VALUES,
            });
        }
        let mut flags = 0;
        let mut data = [0.0f32; 58];
        if self.success {
            flags |= SUCCESS;
        }
        if self.holding {
            flags |= HOLDING;
        }
        if let Some(w) = &self.wall {
            flags |= HAS_WALL;
            let p = w.translation.vector;
            let q = w.rotation.into_inner();
            for (d, x) in data[6..13]
                .iter_mut()
                .zip([p.x, p.y, p.z, q.w, q.i, q.j, q.k])
            {
                *d = f(x);
            }
        }
        if let Some(x) = self.obstacle_face_x_m {
            flags |= HAS_FACE;
            data[5] = f(x);
        }
        let mut put = |at: usize, v: &Vector3<f64>| {
            for (d, x) in data[at..at + 3].iter_mut().zip(v.iter()) {
                *d = f(*x);
            }
        };
        match &self.held_joint {
            Some(HeldJoint::Prismatic { axis }) => {
                flags |= HELD_PRISMATIC;
                put(JOINT_AT, axis);
            }
            Some(HeldJoint::Revolute { axis, point }) => {
                flags |= HELD_REVOLUTE;
                put(JOINT_AT, axis);
                put(POINT_AT, point);
            }
            None => {}
        }
        if let Some(n) = &self.hand_contact {
            flags |= HAS_CONTACT;
            put(CONTACT_AT, n);
        }
        let bits = self
            .criteria
            .iter()
            .enumerate()
            .filter(|(_, c)| **c)
            .fold(0u32, |b, (i, _)| b | (1 << i));
        // Small integers: exact in f32.
        data[0] = self.task_number as f32;
        data[1] = self.steps as f32;
        data[2] = flags as f32;
        data[3] = self.criteria.len() as f32;
        data[4] = bits as f32;
        data[13] = self.values.len() as f32;
        for (d, x) in data[VALUES_AT..].iter_mut().zip(&self.values) {
            *d = f(*x);
        }
        Ok(MavMessage::DEBUG_FLOAT_ARRAY(DEBUG_FLOAT_ARRAY_DATA {
            time_usec: self.time_usec,
            array_id: TASK_ARRAY_ID,
            name: TASK_ARRAY_NAME.into(),
            data,
        }))
    }

    /// Whether `d` is a task array (its id and name).
    pub fn is_task_array(d: &DEBUG_FLOAT_ARRAY_DATA) -> bool {
        d.array_id == TASK_ARRAY_ID && d.name.to_str().is_ok_and(|n| n == TASK_ARRAY_NAME)
    }

    /// Reads a task array; anything out of its layout is an error naming it.
    pub fn decode(d: &DEBUG_FLOAT_ARRAY_DATA) -> Result<Self, TaskArrayError> {
        let bad = |what: String| TaskArrayError::Malformed(what);
        if !Self::is_task_array(d) {
            return Err(bad(format!(
                "array {} is not '{TASK_ARRAY_NAME}'",
                d.array_id
            )));
        }
        let count = |i: usize, max: usize, what: &str| -> Result<usize, TaskArrayError> {
            let x = d.data[i];
            if x.is_finite() && x >= 0.0 && x.fract() == 0.0 && x <= max as f32 {
                Ok(x as usize)
            } else {
                Err(bad(format!("{what} {x} (expected a whole number ≤ {max})")))
            }
        };
        let task_number = count(0, 1 << 16, "task number")?;
        let steps = count(1, 1 << 24, "steps")?;
        let flags = count(2, ALL_FLAGS as usize, "flags")?;
        let criteria_count = count(3, MAX_CRITERIA, "criteria count")?;
        let bits = count(4, (1 << MAX_CRITERIA) - 1, "criteria bits")?;
        let value_count = count(13, MAX_VALUES, "value count")?;
        let real = |i: usize, what: &str| -> Result<f64, TaskArrayError> {
            let x = f64::from(d.data[i]);
            if x.is_finite() {
                Ok(x)
            } else {
                Err(bad(format!("{what} is not finite")))
            }
        };
        let wall = if flags & HAS_WALL as usize != 0 {
            let v: Vec<f64> = (6..13)
                .map(|i| real(i, "wall pose"))
                .collect::<Result<_, _>>()?;
            let q = Quaternion::new(v[3], v[4], v[5], v[6]);
            if (q.norm() - 1.0).abs() > 1e-3 {
                return Err(bad(format!("wall quaternion of norm {}", q.norm())));
            }
            Some(Isometry3::from_parts(
                Translation3::from(Vector3::new(v[0], v[1], v[2])),
                UnitQuaternion::new_normalize(q),
            ))
        } else {
            None
        };
        let obstacle_face_x_m = if flags & HAS_FACE as usize != 0 {
            Some(real(5, "obstacle face")?)
        } else {
            None
        };
        let values = (VALUES_AT..VALUES_AT + value_count)
            .map(|i| real(i, "observation value"))
            .collect::<Result<_, _>>()?;
        let vector = |at: usize, what: &str| -> Result<Vector3<f64>, TaskArrayError> {
            Ok(Vector3::new(
                real(at, what)?,
                real(at + 1, what)?,
                real(at + 2, what)?,
            ))
        };
        // A unit vector, renormalised after f32's rounding.
        let unit = |at: usize, what: &str| -> Result<Vector3<f64>, TaskArrayError> {
            let v = vector(at, what)?;
            if (v.norm() - 1.0).abs() > UNIT_TOLERANCE {
                return Err(bad(format!("{what} of norm {} (expected 1)", v.norm())));
            }
            Ok(v.normalize())
        };
        let held_joint = match (
            flags & HELD_PRISMATIC as usize != 0,
            flags & HELD_REVOLUTE as usize != 0,
        ) {
            (false, false) => None,
            (true, false) => Some(HeldJoint::Prismatic {
                axis: unit(JOINT_AT, "held joint axis")?,
            }),
            (false, true) => Some(HeldJoint::Revolute {
                axis: unit(JOINT_AT, "held joint axis")?,
                point: vector(POINT_AT, "held joint point")?,
            }),
            (true, true) => {
                return Err(bad(
                    "flags say the held joint is both prismatic and revolute".to_owned(),
                ));
            }
        };
        let hand_contact = if flags & HAS_CONTACT as usize != 0 {
            Some(unit(CONTACT_AT, "hand contact normal")?)
        } else {
            None
        };
        Ok(Self {
            time_usec: d.time_usec,
            task_number: task_number as u32,
            steps: steps as u64,
            success: flags & SUCCESS as usize != 0,
            holding: flags & HOLDING as usize != 0,
            criteria: (0..criteria_count).map(|i| bits & (1 << i) != 0).collect(),
            obstacle_face_x_m,
            wall,
            values,
            held_joint,
            hand_contact,
        })
    }
}

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: a failed set-up fails loudly"
)]
mod tests {
    use super::*;

    fn sample() -> TaskArray {
        TaskArray {
            time_usec: 1_234_567,
            task_number: 8,
            steps: 841,
            success: false,
            holding: true,
            criteria: vec![true, false, true],
            obstacle_face_x_m: Some(1.25),
            wall: Some(Isometry3::from_parts(
                Translation3::new(1.5, -0.25, 1.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5),
            )),
            values: vec![0.125, 1.0, 1.5, -0.75, 1.25],
            held_joint: Some(HeldJoint::Revolute {
                axis: Vector3::new(0.6, 0.0, 0.8),
                point: Vector3::new(1.75, 0.5, 1.25),
            }),
            hand_contact: Some(Vector3::new(-1.0, 0.0, 0.0)),
        }
    }

    fn data(m: &MavMessage) -> &DEBUG_FLOAT_ARRAY_DATA {
        let MavMessage::DEBUG_FLOAT_ARRAY(d) = m else {
            panic!("a DEBUG_FLOAT_ARRAY");
        };
        d
    }

    #[test]
    fn a_task_state_survives_the_wire_to_f32_precision() {
        let a = sample();
        let m = a.encode().unwrap();
        let d = data(&m);
        // The layout of the contract, by hand.
        assert_eq!((d.array_id, d.name.to_str().unwrap()), (2, "task"));
        // Flags: holding 2, wall 4, face 8, revolute held joint 32, contact 64.
        assert_eq!(&d.data[..5], &[8.0, 841.0, 110.0, 3.0, 5.0]);
        assert_eq!(d.data[13], 5.0);
        assert_eq!(
            &d.data[47..56],
            &[0.6, 0.0, 0.8, 1.75, 0.5, 1.25, -1.0, 0.0, 0.0]
        );
        let b = TaskArray::decode(d).unwrap();
        assert_eq!(b.criteria, a.criteria);
        assert_eq!((b.steps, b.holding, b.success), (841, true, false));
        // Binary fractions survive exactly; the wall's rotation to f32's precision.
        assert_eq!(b.values, a.values);
        let (wa, wb) = (a.wall.unwrap(), b.wall.unwrap());
        assert_eq!(wb.translation, wa.translation);
        assert!(wa.rotation.angle_to(&wb.rotation) < 1e-6);
        // The held joint and the contact: unit vectors to f32's precision, renormalised.
        let Some(HeldJoint::Revolute { axis, point }) = b.held_joint else {
            panic!("a revolute held joint, got {:?}", b.held_joint);
        };
        assert!((axis - Vector3::new(0.6, 0.0, 0.8)).norm() < 1e-7);
        assert!((axis.norm() - 1.0).abs() < 1e-15);
        assert_eq!(point, Vector3::new(1.75, 0.5, 1.25));
        assert_eq!(b.hand_contact, a.hand_contact);
        // A prismatic joint sends its axis only.
        let c = TaskArray {
            held_joint: Some(HeldJoint::Prismatic {
                axis: Vector3::new(0.0, 1.0, 0.0),
            }),
            hand_contact: None,
            ..sample()
        };
        let m = c.encode().unwrap();
        assert_eq!(data(&m).data[2], 30.0);
        let d = TaskArray::decode(data(&m)).unwrap();
        assert_eq!((d.held_joint, d.hand_contact), (c.held_joint, None));
    }

    #[test]
    fn absent_parts_stay_absent() {
        let a = TaskArray {
            wall: None,
            obstacle_face_x_m: None,
            values: vec![],
            criteria: vec![],
            held_joint: None,
            hand_contact: None,
            ..sample()
        };
        let b = TaskArray::decode(data(&a.encode().unwrap())).unwrap();
        assert_eq!(b, a);
    }

    #[test]
    fn too_much_is_refused_before_sending() {
        let a = TaskArray {
            values: vec![0.0; MAX_VALUES + 1],
            ..sample()
        };
        assert!(matches!(
            a.encode(),
            Err(TaskArrayError::TooLarge { max: 33, .. })
        ));
    }

    #[test]
    fn malformed_arrays_are_errors_not_panics() {
        let good = sample().encode().unwrap();
        let mut cases = Vec::new();
        for (i, x) in [
            (13, 34.0),
            (13, 1.5),
            // Prismatic and revolute at once; an unknown flag.
            (2, 126.0),
            (2, 128.0),
            // Not unit: the held joint's axis, the contact's normal.
            (47, 0.9),
            (53, -0.5),
            (54, f32::NAN),
            (3, -1.0),
            (2, f32::NAN),
            (6, f32::INFINITY),
            (9, 3.0),
        ] {
            let mut d = data(&good).clone();
            d.data[i] = x;
            cases.push(d);
        }
        let mut wrong_id = data(&good).clone();
        wrong_id.array_id = 1;
        cases.push(wrong_id);
        for d in &cases {
            assert!(TaskArray::decode(d).is_err(), "{:?}", &d.data);
        }
    }
}
