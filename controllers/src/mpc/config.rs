//! Settings of the whole-body NMPC: horizon, weights, bounds, output filter, QP tolerances and
//! fallback, with the reference's numbers as defaults (AMBENCH_SPEC §2.5 `_MPC_PARAMS`).
//!
//! Plain data: every field is public and documented with its unit and default, and checked by
//! [`MpcConfig::validate`]. Loaded from TOML with unknown keys rejected.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A configuration value the MPC cannot work with.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MpcConfigError {
    /// A field is out of its range.
    #[error("mpc config: {field} = {value} {requirement}")]
    Invalid {
        /// Dotted field name (`weights.ee_position`).
        field: &'static str,
        /// The value, as written.
        value: String,
        /// What it must be.
        requirement: &'static str,
    },
    /// The TOML text does not parse into an [`MpcConfig`].
    #[error("mpc config: {0}")]
    Toml(String),
}

/// Diagonal weights of the nonlinear least-squares cost `½‖y − y_ref‖²_W` (AMBENCH_SPEC §2.5
/// `W = blkdiag(Q, R, R_Δ)`, terminal `W_e = Q`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MpcWeights {
    /// End-effector position error (world x, y, z), 1/m². Default 6000 each.
    pub ee_position: [f64; 3],
    /// End-effector roll, pitch, yaw error, 1/rad². Default 200 each.
    pub ee_orientation: [f64; 3],
    /// Base linear velocity, s²/m². Default 20 each.
    pub velocity: [f64; 3],
    /// Base Euler angles against (0, 0, target yaw), 1/rad². Default 50 each.
    pub attitude: [f64; 3],
    /// Base angular velocity, s²/rad². Default 20 each.
    pub angular_velocity: [f64; 3],
    /// Arm joints against the default posture, 1/rad². Default 10 each.
    pub arm: [f64; 4],
    /// Input effort: force (N⁻²) ×3, torque ((N·m)⁻²) ×3, arm references (rad⁻²) ×4.
    /// Default 0.02 ×3, 0.1 ×3, 1.0 ×4.
    pub input: [f64; 10],
    /// Input change from the last applied input, same units. Default 0.01 ×6, 200 ×4.
    pub input_rate: [f64; 10],
}

impl Default for MpcWeights {
    fn default() -> Self {
        Self {
            ee_position: [6000.0; 3],
            ee_orientation: [200.0; 3],
            velocity: [20.0; 3],
            attitude: [50.0; 3],
            angular_velocity: [20.0; 3],
            arm: [10.0; 4],
            input: [0.02, 0.02, 0.02, 0.1, 0.1, 0.1, 1.0, 1.0, 1.0, 1.0],
            input_rate: [
                0.01, 0.01, 0.01, 0.01, 0.01, 0.01, 200.0, 200.0, 200.0, 200.0,
            ],
        }
    }
}

/// Which QP solver an RTI step uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum QpPath {
    /// The structure-exploiting Riccati interior-point solver of this crate (fast path).
    #[default]
    Riccati,
    /// clarabel on the sparse multiple-shooting QP (reference path).
    Clarabel,
}

impl QpPath {
    /// Both paths, fast path first.
    pub const ALL: [QpPath; 2] = [QpPath::Riccati, QpPath::Clarabel];

    /// `riccati` or `clarabel`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Riccati => "riccati",
            Self::Clarabel => "clarabel",
        }
    }
}

/// Interior-point settings, shared by both QP paths.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct QpSettings {
    /// Most interior-point iterations per QP: the deterministic time budget of a solve (a
    /// QP not converged within it is a failed solve and starts the fallback). Default 40.
    pub max_iterations: u32,
    /// Stationarity, primal feasibility and complementarity tolerance (absolute; clarabel's
    /// gap and feasibility tolerances). Default 1e-7.
    pub tolerance: f64,
    /// Riccati path only: after convergence, solve the equality-constrained QP of the active
    /// rows to remove the interior point's residual complementarity (exact active set, as
    /// OSQP's polish). Default false (the real-time path does not need it).
    pub polish: bool,
    /// Riccati path only: a warm solve first tries the last solution's active set, shifted
    /// (one factorisation: the equality-constrained QP of those rows), and takes it when it
    /// passes the interior point's own convergence test (every row within the tolerance,
    /// multipliers of the right sign, stationarity); otherwise the interior point runs as
    /// without it. Default true.
    pub active_set_shot: bool,
    /// Riccati path only: a warm solve starts from the last factorisation's feedback on the
    /// measured state's offset from the last plan (`RiccatiIpm::warm_start_from_plan`), not
    /// from the open-loop rollout of the shifted inputs (which in contact carries a model
    /// mismatch to the horizon's end). The same QP either way; only the iterations to its
    /// solution differ. Default true; false is the start before 2026-11-29 (with the newer
    /// 1e-3 start margin of a violated soft row).
    pub plan_start: bool,
}

impl Default for QpSettings {
    fn default() -> Self {
        Self {
            max_iterations: 40,
            tolerance: 1e-7,
            polish: false,
            active_set_shot: true,
            plan_start: true,
        }
    }
}

/// The whole-body NMPC of the FA-Hexa (AMBENCH_SPEC §2.5).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MpcConfig {
    /// Prediction horizon, s. Default 0.8.
    pub horizon_s: f64,
    /// Shooting intervals over the horizon. Default 32 (0.025 s each).
    pub intervals: usize,
    /// First-order arm servo gain k_a of `q̇ = k_a (q_ref − q)`, 1/s. Default 66.7: the
    /// twin's FA-Hexa arm, identified (least squares of q̇ on q_ref − q over the free flight
    /// of a Push Slider rollout, every pitch joint; its drives are 1e5 N·m/rad, 1e3
    /// N·m·s/rad). The reference's k_a is 12; with it the model's arm lags the plant's 5.6×,
    /// the MPC leads its arm references to make up for a lag the arm does not have, and the
    /// hand runs ahead of its prediction (measured, 30 rollouts each, with the other
    /// defaults: Toss Ball 93.3 → 96.7 %, Rotate Valve 73.3 → 100 %, Wipe Window 96.7 →
    /// 100 %, Cabinet's tilt use 35.4° → 1.4°; `docs/mpc-contact.md` §7). On hardware, the
    /// arm's servos identified the same way.
    pub arm_gain_per_s: f64,
    /// Cost weights.
    pub weights: MpcWeights,
    /// Lowest base position (world x, y, z), m. Default (−1, −5, 0).
    pub position_min_m: [f64; 3],
    /// Highest base position, m. Default (1.2, 2, 10); a wall lowers x per tick. The
    /// reference's profile has z ≤ 4 m, which keeps its MPC from NDT's inspection height
    /// (the goal at z = 7 m; the base must climb to ~6.3 m): its QP is then infeasible for
    /// the rest of the task and, here, the IK-PID fallback flew 54 % of every NDT rollout
    /// (tilting 20° and saturating 52 % of the ticks with ideal rotors). 10 m is a ceiling
    /// above every benchmark task (docs/mpc-contact.md §13).
    pub position_max_m: [f64; 3],
    /// Base roll and pitch stay within ±this, rad. Default 0.01.
    pub roll_pitch_limit_rad: f64,
    /// Base yaw stays within ±this, rad. Default π.
    pub yaw_limit_rad: f64,
    /// Arm joints and their references stay within ±this, intersected with the URDF limits,
    /// rad. Default π (the reference's ±180°).
    pub joint_limit_rad: f64,
    /// Default arm posture (cost reference of joints and arm references), rad. Default 0.
    pub default_arm_rad: [f64; 4],
    /// End-effector height above the base, lowest, m. Default 0.1.
    pub ee_height_min_m: f64,
    /// End-effector height above the base, highest, m. Default 2.5.
    pub ee_height_max_m: f64,
    /// Output filter `u = g∘u_opt + (1−g)∘u_last` (force ×3, torque ×3, arm ×4). Default
    /// 1 ×6, 0.5 ×4.
    pub output_filter_gain: [f64; 10],
    /// A bound the measured state already violates is approached at this rate over the
    /// horizon instead of at once (keeps the QP feasible after a disturbance), s. Default 0.2.
    pub recovery_time_constant_s: f64,
    /// Weight ρ of the exact L1 penalty on the slacks of the state rows (position, attitude,
    /// joint and EE-height bounds of stages 1..N): in the QP a row `g(x) ≤ b` becomes
    /// `g(x) ≤ b + t`, `t ≥ 0`, with `ρ·t` added to the cost. The QP is then feasible from any
    /// measured state (the rotor and arm-reference rows on the inputs stay hard), and whenever
    /// the hard QP is feasible with multipliers below ρ its solution is the soft QP's (the
    /// exact-penalty property). Unit: the QP cost per m or rad of violation. Default 1e5: the
    /// hard QPs' multipliers stay below 11 on the standard scenario (`cargo test -p
    /// controllers soft_state_rows_leave`), so the default leaves four orders of magnitude.
    /// None: hard state rows, as in the reference (a contact can make the QP infeasible).
    pub state_row_penalty: Option<f64>,
    /// With soft state rows: a solution whose largest slack exceeds this (m or rad) has
    /// found the hard QP infeasible. It is reported as `infeasible` and not taken, so the
    /// controller's fallback starts as with hard rows (flying such solutions, which violate
    /// the ±0.01 rad tilt band or the wall, tips the vehicle over in contact: see
    /// `docs/speed.md`). Default 1e-3. None: the soft solution is taken whatever its slack.
    pub state_row_slack_limit: Option<f64>,
    /// QP settings.
    pub qp: QpSettings,
    /// Which QP path the controller uses. Default `riccati`.
    pub qp_path: QpPath,
    /// Share of each rotor's thrust margin around hover that the MPC's force may use: six
    /// linear input rows per stage keep the thrust the force alone allocates to each rotor
    /// within that share (`model::RotorEnvelope`); the rest is left to the torque, which stays
    /// unbounded as in the reference (the ±0.01 rad tilt bounds need all the authority there
    /// is after a disturbance, or the QP becomes infeasible). Default 0.8 (Toss Ball's swing
    /// needs the force: 0.6 → 0.8 took it 63.3 → 96.7 % at 30 rollouts with the matched arm
    /// model; with the reference's k_a of 12, 0.8 and a 0.2 s extrapolation left Rotate Valve at
    /// 73.3 %, against 96.7 % with 0.6 and 0.4 s; `docs/mpc-contact.md` §7). None: the force is
    /// unbounded too, as in the reference (limited only by its small weight: a 1 m step then
    /// asks for ~270 N and, with thrust limits, flips the vehicle).
    pub rotor_margin_for_force: Option<f64>,
    /// Share of each rotor's thrust margin that the MPC's whole wrench may use: six more
    /// input rows per stage keep the thrust that the force, the torque and the gravity
    /// compensation (of the flown posture, at the measured attitude) allocate to each rotor
    /// (pseudo-inverse) within that share of its margin around the compensation's own thrust,
    /// so the MPC plans only wrenches its rotors can deliver. With the soft state rows
    /// a tilt bound that would need more torque is violated (and paid for) instead of making
    /// the QP infeasible. None: the torque is unbounded, as in the reference.
    pub rotor_margin_for_wrench: Option<f64>,
    /// Whether a solution whose wrench would take a rotor beyond its limits hands over to the
    /// IK-PID path at once (for rotors with enforced thrust limits; with ideal, unbounded
    /// rotors there is nothing to protect). Default true.
    pub rotor_saturation_fallback: bool,
    /// Ticks the shifted previous solution is held after a failed solve before the IK-PID
    /// path takes over. Default 12 (0.1 s at 120 Hz).
    pub fallback_hold_ticks: u32,
    /// Time constant of the arm posture the IK-PID path keeps when it takes over because
    /// the MPC's solution would saturate a rotor (not after failed solves, where the MPC's
    /// posture is where its QP stopped being solvable), s: its
    /// whole-body IK resolves the arm's redundancy about the posture it was handed (its rest
    /// term moved to the measured arm joints), fading to the IK's configured rest posture as
    /// `e^(−t/τ)`, so a motion under way (Toss Ball's swing, with the arm reaching forward)
    /// continues instead of the arm swinging back to the configured rest within a few ticks.
    /// Default 1.0. 0: the configured rest from the first tick (as before this setting);
    /// `inf`: the handed posture held until the MPC flies again.
    pub fallback_posture_time_constant_s: f64,
    /// Offset-free end-effector position: the EE position reference handed to the QP is the
    /// target plus an offset `b` that integrates, after every solved tick, the EE error the
    /// MPC's own solution still predicts at the end of its horizon,
    /// `ḃ = rate · (p_target − p_ee(x_N))` (updated only while that predicted error is within
    /// `ee_offset_limit_m`, and `‖b‖ ≤ ee_offset_limit_m`). It removes the steady-state EE
    /// error the reference's arm-posture regularisation leaves (1.1–2.1 cm with the base
    /// against a wall bound and the arm extended: the peg stops short of its hole, and a
    /// knob grasped 2 cm short of its target pins that error where the MPC cannot remove
    /// it); being computed on the model's prediction, not on the measured EE, it does not
    /// wind up against a contact. Unit 1/s. Default 20 (a 0.05 s time constant). None: the
    /// reference's cost alone (the offset stays).
    pub ee_offset_rate_per_s: Option<f64>,
    /// Bound of the EE reference offset and of the predicted error it integrates, m.
    /// Default 0.05.
    pub ee_offset_limit_m: f64,
    /// Once the measured EE lies within this of the EE the solution predicts at the end of
    /// its horizon (the hand has settled where the MPC means it to stay), the EE offset
    /// integrates the measured error `p_target − p_ee(x̂)` instead of the predicted one: that
    /// also removes what the MPC's model gets wrong of the twin or the aircraft (its arm
    /// servo, the arm's reaction on the base), which its own prediction cannot see. While
    /// the hand is stopped short of its prediction (pushed against a contact, or still
    /// moving) the predicted error alone is integrated, so the offset does not wind up
    /// against a contact. Unit m. Default None (the predicted error always): measured at 30
    /// rollouts with 0.003 m, it adds nothing the twin needs (Peg-in-Hole, Rotate Valve,
    /// Toss Ball the same or one rollout apart) and costs where the hand touches without
    /// being stopped: Cabinet's tilt use 1.35° → 17.6° and saturation 2.95 → 69.6 %, Pull
    /// Lever 93.3 → 86.7 %. For a vehicle whose model error is small and steady (a sagging
    /// servo, `mpc::tests`).
    pub ee_offset_gap_m: Option<f64>,
    /// The rate at which the measured error of `ee_offset_gap_m` is integrated, 1/s. Slower
    /// than `ee_offset_rate_per_s`: the predicted error answers an offset within the same
    /// solve, the measured one only after the vehicle has moved (~0.2 s), and at 20/s that
    /// loop rings (measured on the MPC's own model with a sagging arm servo: the error
    /// wanders 0.2–0.5 mm instead of settling). Default 2 (a 0.5 s time constant).
    pub ee_offset_measured_rate_per_s: f64,
    /// Moving targets: the EE target's velocity, estimated from the targets of the last two
    /// ticks, is extrapolated over the horizon, the reference at stage k being
    /// `p_target + v · min(t_k, target_extrapolation_s)` (the reference holds the target
    /// over its horizon, so the MPC lags any target that moves, and a throw leaves late and
    /// slow). A change faster than this between two ticks is a jump of the target (a new
    /// waypoint), not a motion, and extrapolates nothing. While the hand holds an object on
    /// a joint nothing is extrapolated either: the joint, not the script, sets how fast the
    /// object moves, and a hand led ahead of a damped valve pushes it harder (measured,
    /// 30 rollouts: Rotate Valve 96.7 → 80 % with the extrapolation on through the grasp,
    /// its tilt use 13.4° → 18.3°). Unit m/s. Default 3.0 (Toss Ball's swing peaks at
    /// 2.5 m/s). None: the target held over the horizon, as in the reference.
    pub target_velocity_limit_mps: Option<f64>,
    /// How far ahead the target's velocity is extrapolated, s (see
    /// `target_velocity_limit_mps`). Default 0.2: the extrapolation knows only the velocity,
    /// so it runs past a target that is stopping, the farther the longer it looks (a 0.3 m
    /// smootherstep in 0.6 s on the model: 34 mm past the end with 0.2 s, 52 mm with 0.4 s,
    /// 4.5 mm held); Toss Ball's throw is let go as its swing decelerates (30 rollouts: 0.4 s
    /// 66.7 %, landing up to 0.36 m long; 0.2 s 96.7 %).
    pub target_extrapolation_s: f64,
    /// Grasp rows: while the hand holds an object on a joint (given per tick by
    /// `WholeBodyMpc::set_held_joint`), the EE position of every state stage is held within
    /// ±this of its measured value along the directions the joint forbids (`mpc::grasp`;
    /// soft rows like the other state rows). Unit m. Default None (off): measured in the
    /// twin, they add nothing to `grasp_reference` and cost successes (Rotate Valve 29 → 26
    /// of 30 with a 0.01 m band; with 0.002 m most contact QPs need a slack above
    /// `state_row_slack_limit`: the model's arm servo was then the reference's 12/s, slower
    /// than the twin's ~67/s, and a pinned EE turned that mismatch into base motion;
    /// `docs/mpc-contact.md` §5; not re-measured with the matched arm model).
    pub grasp_band_m: Option<f64>,
    /// Grasp model: while the hand holds an object on a joint, the EE position target handed
    /// to the QP is moved onto that joint's motion through the measured EE (the rail through
    /// it, or its circle about the axis), so the MPC does not try to close an EE error along
    /// a direction the joint blocks; the EE offset of `ee_offset_rate_per_s` integrates only
    /// the error along the joint's motion. Default true. False: the target as given.
    pub grasp_reference: bool,
    /// With `grasp_reference`, while the hand holds an object on a revolute joint (a valve's
    /// shaft, a lever's pivot), the EE orientation target handed to the QP is the measured EE
    /// orientation turned about the joint's axis by the angle from the measured EE to the
    /// position target on the joint's circle: the orientation the hand, welded to the object,
    /// has there. The script's fixed orientation is one the held object does not let the hand
    /// take; the model, which has no contact, pitched the vehicle ~50° fighting it. Default
    /// true (FA-Hexa MPC, 30 rollouts: Pull Lever 23 → 30, tilt use 52.9° → 26.0°; Rotate
    /// Valve 28 → 30; `docs/mpc-contact.md` §10). False: the target's orientation as given.
    pub grasp_orientation: bool,
    /// Contact model: while the hand touches something that does not give way along the
    /// contact's normal (given per tick by `WholeBodyMpc::set_hand_contact`: a fixed body,
    /// or an object whose joint does not move that way — the end of Push Slider's knob
    /// against the palm before the fingers close), the part of the EE position target that
    /// lies beyond the contact plane through the measured EE is dropped (the target's
    /// velocity into it too), and the EE offset does not integrate an error into it. The
    /// model has no contact: without this it planned to close the blocked error by
    /// stretching the arm, whose drives, the hand pinned, pushed the base back until the
    /// shoulder and elbow met their limits (FA-Hexa, Push Slider with the knob reaching
    /// 0.28 m: the base 0.9 m back, 0 of 10; `docs/mpc-contact.md` §11). Default true.
    pub contact_reference: bool,
    /// Wall-time budget of one RTI step, s: a step that takes longer (by the caller's clock)
    /// counts as failed and starts the fallback. Default None: the iteration budget
    /// `qp.max_iterations` alone, so a flight does not depend on the machine's speed.
    pub solve_budget_s: Option<f64>,
}

impl Default for MpcConfig {
    fn default() -> Self {
        Self {
            horizon_s: 0.8,
            intervals: 32,
            arm_gain_per_s: 66.7,
            weights: MpcWeights::default(),
            position_min_m: [-1.0, -5.0, 0.0],
            position_max_m: [1.2, 2.0, 10.0],
            roll_pitch_limit_rad: 0.01,
            yaw_limit_rad: std::f64::consts::PI,
            joint_limit_rad: std::f64::consts::PI,
            default_arm_rad: [0.0; 4],
            ee_height_min_m: 0.1,
            ee_height_max_m: 2.5,
            output_filter_gain: [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.5],
            recovery_time_constant_s: 0.2,
            state_row_penalty: Some(1e5),
            state_row_slack_limit: Some(1e-3),
            qp: QpSettings::default(),
            qp_path: QpPath::Riccati,
            rotor_margin_for_force: Some(0.8),
            rotor_margin_for_wrench: None,
            rotor_saturation_fallback: true,
            fallback_hold_ticks: 12,
            fallback_posture_time_constant_s: 1.0,
            ee_offset_rate_per_s: Some(20.0),
            ee_offset_limit_m: 0.05,
            ee_offset_gap_m: None,
            ee_offset_measured_rate_per_s: 2.0,
            target_velocity_limit_mps: Some(3.0),
            target_extrapolation_s: 0.2,
            grasp_band_m: None,
            grasp_reference: true,
            grasp_orientation: true,
            contact_reference: true,
            solve_budget_s: None,
        }
    }
}

fn invalid(
    field: &'static str,
    value: impl std::fmt::Debug,
    requirement: &'static str,
) -> MpcConfigError {
    MpcConfigError::Invalid {
        field,
        value: format!("{value:?}"),
        requirement,
    }
}

fn non_negative(field: &'static str, values: &[f64]) -> Result<(), MpcConfigError> {
    if values.iter().all(|v| v.is_finite() && *v >= 0.0) {
        Ok(())
    } else {
        Err(invalid(field, values, "must be finite and not negative"))
    }
}

fn positive(field: &'static str, v: f64) -> Result<(), MpcConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(field, v, "must be finite and positive"))
    }
}

impl MpcConfig {
    /// The reference's FA-Hexa profile (`_MPC_PARAMS`), the default.
    pub fn fa_hexa() -> Self {
        Self::default()
    }

    /// The defaults with the reference's arm servo model (k_a 12/s), the 0.6 force share
    /// and the 0.4 s extrapolation they were tuned with before the arm model was matched to
    /// the twin: the settings the solver's and several mechanisms' test figures were
    /// measured on (the QPs, not the tuning, are what those tests are about).
    #[cfg(test)]
    pub(crate) fn reference_arm_model() -> Self {
        Self {
            arm_gain_per_s: 12.0,
            rotor_margin_for_force: Some(0.6),
            target_extrapolation_s: 0.4,
            ..Self::default()
        }
    }

    /// Length of one shooting interval, s.
    pub fn interval_s(&self) -> f64 {
        self.horizon_s / self.intervals as f64
    }

    /// Parses and validates a TOML config; unknown keys are refused.
    pub fn from_toml_str(text: &str) -> Result<Self, MpcConfigError> {
        let config: Self =
            toml::from_str(text).map_err(|e| MpcConfigError::Toml(e.message().to_owned()))?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every field.
    pub fn validate(&self) -> Result<(), MpcConfigError> {
        positive("horizon_s", self.horizon_s)?;
        if !(1..=1000).contains(&self.intervals) {
            return Err(invalid(
                "intervals",
                self.intervals,
                "must be within 1..=1000",
            ));
        }
        positive("arm_gain_per_s", self.arm_gain_per_s)?;
        let w = &self.weights;
        non_negative("weights.ee_position", &w.ee_position)?;
        non_negative("weights.ee_orientation", &w.ee_orientation)?;
        non_negative("weights.velocity", &w.velocity)?;
        non_negative("weights.attitude", &w.attitude)?;
        non_negative("weights.angular_velocity", &w.angular_velocity)?;
        non_negative("weights.arm", &w.arm)?;
        non_negative("weights.input_rate", &w.input_rate)?;
        // The input Hessian must be positive definite for a unique QP solution.
        if !w
            .input
            .iter()
            .zip(&w.input_rate)
            .all(|(a, b)| a.is_finite() && *a >= 0.0 && a + b > 0.0)
        {
            return Err(invalid(
                "weights.input",
                w.input,
                "must be finite, not negative, and input + input_rate > 0 for every input",
            ));
        }
        for k in 0..3 {
            let (lo, hi) = (self.position_min_m[k], self.position_max_m[k]);
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(invalid(
                    "position_min_m/position_max_m",
                    (self.position_min_m, self.position_max_m),
                    "must be finite with min < max on every axis",
                ));
            }
        }
        positive("roll_pitch_limit_rad", self.roll_pitch_limit_rad)?;
        positive("yaw_limit_rad", self.yaw_limit_rad)?;
        positive("joint_limit_rad", self.joint_limit_rad)?;
        if !self.default_arm_rad.iter().all(|v| v.is_finite()) {
            return Err(invalid(
                "default_arm_rad",
                self.default_arm_rad,
                "must be finite",
            ));
        }
        if !(self.ee_height_min_m.is_finite()
            && self.ee_height_max_m.is_finite()
            && self.ee_height_min_m < self.ee_height_max_m)
        {
            return Err(invalid(
                "ee_height_min_m/ee_height_max_m",
                (self.ee_height_min_m, self.ee_height_max_m),
                "must be finite with min < max",
            ));
        }
        if !self
            .output_filter_gain
            .iter()
            .all(|g| g.is_finite() && *g > 0.0 && *g <= 1.0)
        {
            return Err(invalid(
                "output_filter_gain",
                self.output_filter_gain,
                "must be within (0, 1]",
            ));
        }
        positive("recovery_time_constant_s", self.recovery_time_constant_s)?;
        if self.qp.max_iterations == 0 {
            return Err(invalid(
                "qp.max_iterations",
                self.qp.max_iterations,
                "must be at least 1",
            ));
        }
        positive("qp.tolerance", self.qp.tolerance)?;
        if let Some(f) = self.rotor_margin_for_force
            && !(f.is_finite() && f > 0.0 && f <= 1.0)
        {
            return Err(invalid(
                "rotor_margin_for_force",
                f,
                "must be within (0, 1]",
            ));
        }
        if let Some(f) = self.rotor_margin_for_wrench
            && !(f.is_finite() && f > 0.0 && f <= 1.0)
        {
            return Err(invalid(
                "rotor_margin_for_wrench",
                f,
                "must be within (0, 1]",
            ));
        }
        if self.fallback_posture_time_constant_s.is_nan()
            || self.fallback_posture_time_constant_s < 0.0
        {
            return Err(invalid(
                "fallback_posture_time_constant_s",
                self.fallback_posture_time_constant_s,
                "must be at least 0 (inf holds the handed posture)",
            ));
        }
        if let Some(rho) = self.state_row_penalty {
            positive("state_row_penalty", rho)?;
        }
        if let Some(limit) = self.state_row_slack_limit {
            positive("state_row_slack_limit", limit)?;
        }
        if let Some(rate) = self.ee_offset_rate_per_s {
            positive("ee_offset_rate_per_s", rate)?;
        }
        positive("ee_offset_limit_m", self.ee_offset_limit_m)?;
        if let Some(gap) = self.ee_offset_gap_m {
            positive("ee_offset_gap_m", gap)?;
        }
        positive(
            "ee_offset_measured_rate_per_s",
            self.ee_offset_measured_rate_per_s,
        )?;
        if let Some(limit) = self.target_velocity_limit_mps {
            positive("target_velocity_limit_mps", limit)?;
        }
        if !(self.target_extrapolation_s.is_finite() && self.target_extrapolation_s >= 0.0) {
            return Err(invalid(
                "target_extrapolation_s",
                self.target_extrapolation_s,
                "must be finite and at least 0",
            ));
        }
        if let Some(band) = self.grasp_band_m {
            positive("grasp_band_m", band)?;
        }
        if let Some(b) = self.solve_budget_s {
            positive("solve_budget_s", b)?;
        }
        Ok(())
    }
}
