//! The chunked action interface of AMBENCH_SPEC §5.3–5.4, as pure functions of vectors:
//! action layouts, interpolation of a 20 Hz macro action into 120 Hz setpoints, relative
//! actions and the "localised" observation state, and the checks a chunk passes before
//! anything of it reaches the stack.
//!
//! An action vector (wire and file layout, wxyz):
//! - end-effector: `[x, y, z, qw, qx, qy, qz, gripper]` (8), the target in the command frame;
//! - base + joints: `[x, y, z, qw, qx, qy, qz, q1 … qn, gripper]` (8 + n).
//!
//! Interpolation from the commanded setpoint `p` to the macro action `a` over `s` setpoints:
//! fractions k/s, k = 1..s; position, joints and gripper linear; the quaternion slerped after
//! flipping `a`'s sign if q_p·q_a < 0 (normalised lerp when the dot exceeds 0.9995).
//!
//! Relative actions (anchor `s` = the measured pose at the chunk's start):
//! rel_pos = R(q_s)ᵀ(a_pos − s_pos), rel_quat = conj(q_s) ⊗ q_a (q_a sign-aligned to q_s,
//! then canonicalised to w ≥ 0), joints a − s, gripper unchanged; decoding inverts it.

use nalgebra::{Quaternion, Vector3};

/// Index of the quaternion's w in every layout.
const QUAT: usize = 3;
/// Quaternion norms are floored here before dividing (AMBENCH_SPEC §5.4).
const NORM_FLOOR: f64 = 1e-9;
/// Above this |dot| slerp becomes a normalised lerp (AMBENCH_SPEC §5.3).
const NLERP_DOT: f64 = 0.9995;
/// How far a policy's quaternion norm may be from 1 before the chunk is refused: float32
/// round-off is ~1e-7, so anything past 1e-3 is a model that does not normalise.
pub const QUAT_NORM_TOLERANCE: f64 = 1e-3;

/// Which action vector a policy produces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ActionLayout {
    /// End-effector target + gripper (8).
    Ee,
    /// Base pose + arm joints + gripper (8 + `arm_joints`).
    BaseJoint {
        /// Arm joints of the vehicle.
        arm_joints: usize,
    },
}

impl ActionLayout {
    /// Length of one action vector.
    pub fn dim(self) -> usize {
        match self {
            Self::Ee => 8,
            Self::BaseJoint { arm_joints } => 8 + arm_joints,
        }
    }

    /// Arm joints in the vector.
    pub fn arm_joints(self) -> usize {
        match self {
            Self::Ee => 0,
            Self::BaseJoint { arm_joints } => arm_joints,
        }
    }
}

/// How a policy's actions relate to the state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActionSemantics {
    /// Absolute targets (`ee_absolute`, `base_joint_absolute`).
    Absolute,
    /// Relative to the measured pose at the chunk's start (`ee_local_relative`,
    /// `base_joint_relative`); the policy sees the localised state.
    Relative,
}

/// One query's answer: `rows` actions of `dim` values, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionChunk {
    /// Actions in the chunk (H).
    pub rows: usize,
    /// Values per action.
    pub dim: usize,
    /// H × dim values, row-major.
    pub values: Vec<f64>,
}

impl ActionChunk {
    /// Action `i`.
    pub fn row(&self, i: usize) -> &[f64] {
        &self.values[i * self.dim..(i + 1) * self.dim]
    }

    /// Why this chunk may not be flown with `layout` executing `steps` actions, if it may
    /// not: a wrong shape, a non-finite value, an unnormalised quaternion.
    pub fn check(&self, layout: ActionLayout, steps: usize) -> Result<(), String> {
        if self.dim != layout.dim()
            || self.rows < steps
            || self.values.len() != self.rows * self.dim
        {
            return Err(format!(
                "wrong shape: actions ({}, {}), expected (>= {steps}, {})",
                self.rows,
                self.dim,
                layout.dim()
            ));
        }
        for i in 0..self.rows {
            let row = self.row(i);
            if let Some(j) = row.iter().position(|v| !v.is_finite()) {
                return Err(format!("non-finite value {} at actions[{i}, {j}]", row[j]));
            }
            let norm = quat_of(row).norm();
            if (norm - 1.0).abs() > QUAT_NORM_TOLERANCE {
                return Err(format!(
                    "unnormalised quaternion at actions[{i}, 3..7]: norm {norm:.6}"
                ));
            }
        }
        Ok(())
    }
}

/// The wxyz quaternion of an action or state vector.
pub fn quat_of(v: &[f64]) -> Quaternion<f64> {
    Quaternion::new(v[QUAT], v[QUAT + 1], v[QUAT + 2], v[QUAT + 3])
}

fn set_quat(v: &mut [f64], q: &Quaternion<f64>) {
    v[QUAT] = q.w;
    v[QUAT + 1] = q.i;
    v[QUAT + 2] = q.j;
    v[QUAT + 3] = q.k;
}

/// `q / max(‖q‖, 1e-9)`.
pub fn normalized(q: &Quaternion<f64>) -> Quaternion<f64> {
    q / q.norm().max(NORM_FLOOR)
}

/// `q` with the sign that makes its dot product with `reference` non-negative.
pub fn sign_aligned(q: &Quaternion<f64>, reference: &Quaternion<f64>) -> Quaternion<f64> {
    if q.dot(reference) < 0.0 { -q } else { *q }
}

fn canonical_w(q: &Quaternion<f64>) -> Quaternion<f64> {
    if q.w < 0.0 { -q } else { *q }
}

/// Spherical interpolation from `a` to `b` (both unit, `b` already sign-aligned) at `t`.
fn slerp(a: &Quaternion<f64>, b: &Quaternion<f64>, t: f64) -> Quaternion<f64> {
    let dot = a.dot(b).clamp(-1.0, 1.0);
    if dot > NLERP_DOT {
        return normalized(&(a * (1.0 - t) + b * t));
    }
    let theta = dot.acos();
    let sin = theta.sin();
    normalized(&(a * (((1.0 - t) * theta).sin() / sin) + b * ((t * theta).sin() / sin)))
}

/// `target` with its quaternion normalised and sign-aligned to `previous`'s (the macro action
/// as it is executed and remembered as the next interpolation's start).
pub fn aligned_target(previous: &[f64], target: &[f64]) -> Vec<f64> {
    let mut out = target.to_vec();
    let q = sign_aligned(&normalized(&quat_of(target)), &quat_of(previous));
    set_quat(&mut out, &q);
    out
}

/// The `stride` setpoints that take the commanded `previous` to the macro action `target`
/// (AMBENCH_SPEC §5.3): setpoint k (1-based) at fraction k/stride; the last is `target` with
/// its quaternion sign-aligned to `previous`'s.
pub fn interpolate(previous: &[f64], target: &[f64], stride: usize) -> Vec<Vec<f64>> {
    let target = aligned_target(previous, target);
    let from = normalized(&quat_of(previous));
    let to = quat_of(&target);
    (1..=stride)
        .map(|k| {
            let t = k as f64 / stride as f64;
            let mut v: Vec<f64> = previous
                .iter()
                .zip(&target)
                .map(|(p, a)| p + t * (a - p))
                .collect();
            let q = if k == stride {
                to
            } else {
                slerp(&from, &to, t)
            };
            set_quat(&mut v, &q);
            v
        })
        .collect()
}

fn position(v: &[f64]) -> Vector3<f64> {
    Vector3::new(v[0], v[1], v[2])
}

fn rotate(q: &Quaternion<f64>, v: &Vector3<f64>) -> Vector3<f64> {
    (q * Quaternion::from_imag(*v) * q.conjugate()).imag()
}

/// An absolute action relative to the anchor state `anchor` (`[pos, quat, …]`, the measured
/// pose first, then for base + joints the arm joints): AMBENCH_SPEC §5.4's encoding.
pub fn encode_relative(layout: ActionLayout, anchor: &[f64], action: &[f64]) -> Vec<f64> {
    let q_s = normalized(&quat_of(anchor));
    let mut out = action.to_vec();
    let rel = rotate(&q_s.conjugate(), &(position(action) - position(anchor)));
    out[..3].copy_from_slice(rel.as_slice());
    let q_a = sign_aligned(&normalized(&quat_of(action)), &q_s);
    set_quat(&mut out, &canonical_w(&(q_s.conjugate() * q_a)));
    for j in 0..layout.arm_joints() {
        out[7 + j] = action[7 + j] - anchor[7 + j];
    }
    out
}

/// A relative action back to absolute against the anchor state (AMBENCH_SPEC §5.4).
pub fn decode_relative(layout: ActionLayout, anchor: &[f64], relative: &[f64]) -> Vec<f64> {
    let q_s = normalized(&quat_of(anchor));
    let mut out = relative.to_vec();
    let p = position(anchor) + rotate(&q_s, &position(relative));
    out[..3].copy_from_slice(p.as_slice());
    let rel = canonical_w(&normalized(&quat_of(relative)));
    set_quat(&mut out, &sign_aligned(&(q_s * rel), &q_s));
    for j in 0..layout.arm_joints() {
        out[7 + j] = anchor[7 + j] + relative[7 + j];
    }
    out
}

/// The localised state: the anchor pose prefix (position, quaternion) replaced by the
/// identity (0,0,0, 1,0,0,0), the rest unchanged (AMBENCH_SPEC §5.4).
pub fn localised(state: &[f64]) -> Vec<f64> {
    let mut out = state.to_vec();
    out[..7].copy_from_slice(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
    out
}

/// Macro-action stride: env steps per policy step (AMBENCH_SPEC §5.3 requires an integer
/// division).
pub fn stride(env_hz: f64, policy_hz: f64) -> Result<usize, String> {
    let ratio = env_hz / policy_hz;
    let rounded = ratio.round();
    if !(policy_hz.is_finite() && policy_hz > 0.0)
        || rounded < 1.0
        || (ratio - rounded).abs() > 1e-9
    {
        return Err(format!(
            "policy rate {policy_hz} Hz does not divide the control rate {env_hz} Hz"
        ));
    }
    // A small positive integer: the cast is exact.
    Ok(rounded as usize)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    /// Exact up to the round-off of one rotation.
    const EXACT: f64 = 1e-12;

    fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn stride_of_120_over_20_is_6() {
        assert_eq!(stride(120.0, 20.0).unwrap(), 6);
        assert!(stride(120.0, 50.0).unwrap_err().contains("does not divide"));
        assert!(stride(120.0, 0.0).is_err());
        assert!(stride(120.0, 240.0).is_err());
    }

    #[test]
    fn stride_3_last_setpoint_is_the_sign_flipped_target() {
        // AMBENCH_SPEC §8 (test_action_contract): prev (0,0,0,1,0,0,0,−1) → target
        // (3,0,0,−1,0,0,0,1), stride 3: last = (3,0,0), quat (1,0,0,0), gripper 1.
        let steps = interpolate(
            &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0],
            &[3.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0],
            3,
        );
        assert_eq!(steps.len(), 3);
        assert!(close(
            &steps[2],
            &[3.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            EXACT
        ));
        assert!(close(&steps[0][..3], &[1.0, 0.0, 0.0], EXACT));
        assert!((steps[0][7] - (-1.0 + 2.0 / 3.0)).abs() < EXACT);
    }

    #[test]
    fn base_joint_stride_2_reaches_the_joint_targets() {
        // §8: BaseJoint stride 2, last joints = 1.
        let prev = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let target = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0];
        let steps = interpolate(&prev, &target, 2);
        assert!(close(&steps[0][7..11], &[0.5; 4], EXACT));
        assert!(close(&steps[1][7..11], &[1.0; 4], EXACT));
    }

    #[test]
    fn slerp_halfway_is_half_the_angle() {
        // A 90° yaw in 2 setpoints: the first is the 45° yaw (slerp, not a chord).
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let steps = interpolate(
            &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            &[0.0, 0.0, 0.0, h, 0.0, 0.0, h, 0.0],
            2,
        );
        let eighth = std::f64::consts::FRAC_PI_8;
        assert!(close(
            &steps[0][3..7],
            &[eighth.cos(), 0.0, 0.0, eighth.sin()],
            EXACT
        ));
        for s in &steps {
            assert!((quat_of(s).norm() - 1.0).abs() < EXACT);
        }
    }

    #[test]
    fn ee_relative_round_trip_is_exact() {
        // §8: state (1,2,3,1,0,0,0,0.25), action (2,4,6,−1,0,0,0,−0.5): exact for position
        // and gripper, |q·q'| = 1.
        let anchor = [1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0, 0.25];
        let action = [2.0, 4.0, 6.0, -1.0, 0.0, 0.0, 0.0, -0.5];
        let rel = encode_relative(ActionLayout::Ee, &anchor, &action);
        assert!(close(
            &rel,
            &[1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0, -0.5],
            EXACT
        ));
        let back = decode_relative(ActionLayout::Ee, &anchor, &rel);
        assert!(close(&back[..3], &action[..3], EXACT));
        assert_eq!(back[7], action[7]);
        assert!((quat_of(&back).dot(&quat_of(&action)).abs() - 1.0).abs() < EXACT);
    }

    #[test]
    fn ee_relative_round_trip_with_a_rotated_anchor() {
        // A 90° yaw anchor: a target 1 m ahead in the world (+x) is 1 m to the anchor's
        // right (−y in its frame); decoding puts it back.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let anchor = [1.0, 0.0, 2.0, h, 0.0, 0.0, h, 0.04];
        let action = [2.0, 0.0, 2.0, 0.0, 0.0, 0.0, 1.0, 1.0];
        let rel = encode_relative(ActionLayout::Ee, &anchor, &action);
        assert!(close(&rel[..3], &[0.0, -1.0, 0.0], EXACT));
        assert!(rel[3] >= 0.0);
        let back = decode_relative(ActionLayout::Ee, &anchor, &rel);
        assert!(close(&back[..3], &action[..3], EXACT));
        assert!((quat_of(&back).dot(&quat_of(&action)).abs() - 1.0).abs() < EXACT);
        // The result's sign follows the anchor's.
        assert!(quat_of(&back).dot(&quat_of(&anchor)) >= 0.0);
    }

    #[test]
    fn base_joint_relative_round_trip_is_exact() {
        // §8: state (1,2,3,1,0,0,0,0.1,0.2,0.3,0.4,0.5),
        // action (2,4,6,−1,0,0,0,0.2,0.4,0.6,0.8,−0.5): exact.
        let layout = ActionLayout::BaseJoint { arm_joints: 4 };
        let anchor = [1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3, 0.4, 0.5];
        let action = [2.0, 4.0, 6.0, -1.0, 0.0, 0.0, 0.0, 0.2, 0.4, 0.6, 0.8, -0.5];
        let rel = encode_relative(layout, &anchor, &action);
        assert!(close(&rel[7..11], &[0.1, 0.2, 0.3, 0.4], EXACT));
        let back = decode_relative(layout, &anchor, &rel);
        assert!(close(&back[..3], &action[..3], EXACT));
        assert!(close(&back[7..], &action[7..], EXACT));
        assert!((quat_of(&back).dot(&quat_of(&action)).abs() - 1.0).abs() < EXACT);
    }

    #[test]
    fn localised_state_has_the_identity_pose() {
        let state = [1.0, 2.0, 3.0, 0.0, 1.0, 0.0, 0.0, 0.03];
        assert_eq!(
            localised(&state),
            vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.03]
        );
    }

    #[test]
    fn chunk_checks_name_the_fault() {
        let good = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let chunk = |rows: Vec<[f64; 8]>| ActionChunk {
            rows: rows.len(),
            dim: 8,
            values: rows.concat(),
        };
        assert_eq!(chunk(vec![good, good]).check(ActionLayout::Ee, 2), Ok(()));
        let short = chunk(vec![good]).check(ActionLayout::Ee, 2).unwrap_err();
        assert!(
            short.contains("wrong shape: actions (1, 8), expected (>= 2, 8)"),
            "{short}"
        );
        let wide = chunk(vec![good]).check(ActionLayout::BaseJoint { arm_joints: 4 }, 1);
        assert!(wide.unwrap_err().contains("expected (>= 1, 12)"));
        let mut nan = good;
        nan[1] = f64::NAN;
        let e = chunk(vec![good, nan])
            .check(ActionLayout::Ee, 1)
            .unwrap_err();
        assert!(e.contains("non-finite value NaN at actions[1, 1]"), "{e}");
        let mut long = good;
        long[3] = 1.1;
        let e = chunk(vec![long]).check(ActionLayout::Ee, 1).unwrap_err();
        assert!(
            e.contains("unnormalised quaternion at actions[0, 3..7]: norm 1.100000"),
            "{e}"
        );
    }
}
