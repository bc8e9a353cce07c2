//! The estimator: the EKF of [`crate::ekf`] with time — a history of states and IMU samples
//! so a delayed measurement is fused at the time it was captured and the newer samples are
//! integrated again on top of it; measurements from ahead of the IMU wait for it.

use std::collections::VecDeque;

use nalgebra::Vector3;
use platform::RigidBodyState;
use serde::Serialize;

use crate::config::{ConfigError, EstimatorConfig};
use crate::ekf::{self, BA, BG, Covariance, Nominal, P, TH, UpdateFailure, V};
use crate::sample::{ImuSample, Measurement};

/// The most states the history keeps, whatever [`EstimatorConfig::history_s`] says
/// (bounded memory at any IMU rate: 4096 samples are 4 s at 1 kHz).
pub const MAX_HISTORY_SAMPLES: usize = 4096;

/// Why an input was not used. Rejections are normal operation (a late packet, a sensor
/// glitch); the estimate is unchanged and the reason is counted in [`Diagnostics`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, thiserror::Error)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Rejection {
    /// No estimate yet: an IMU sample before the first pose or odometry.
    #[error("not initialised: an IMU sample needs a pose or odometry first")]
    NotInitialized,
    /// A field is not finite (or a noise level not positive).
    #[error("{field} is not finite (or a noise level is not positive)")]
    NonFinite {
        /// The field.
        field: &'static str,
    },
    /// Older than something already used: an IMU sample not after the latest one, or a
    /// measurement older than the latest measurement fused.
    #[error("out of order: t = {time_s} s is before t = {latest_s} s, already used")]
    OutOfOrder {
        /// The input's time, s.
        time_s: f64,
        /// The latest time already used, s.
        latest_s: f64,
    },
    /// Captured before the oldest state the history keeps.
    #[error("too old: captured at t = {time_s} s, the history starts at t = {oldest_s} s")]
    TooOld {
        /// Capture time, s.
        time_s: f64,
        /// The oldest state kept, s.
        oldest_s: f64,
    },
    /// Ahead of the IMU and the queue of waiting measurements is full.
    #[error("{pending} measurements already wait for the IMU to reach their time")]
    QueueFull {
        /// Measurements waiting.
        pending: usize,
    },
    /// Its normalised innovation squared is over the configured gate.
    #[error("innovation gate: NIS {nis:.1} > {gate}")]
    Gated {
        /// The measurement's NIS.
        nis: f64,
        /// The gate.
        gate: f64,
    },
    /// The innovation covariance was not positive definite, or the correction not finite.
    #[error("numerical failure in the update")]
    Numerical,
}

/// What became of an accepted input.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum Accepted {
    /// An IMU sample integrated; `fused` measurements waiting for it were then fused and
    /// `rejected` were not.
    Propagated {
        /// Waiting measurements fused.
        fused: usize,
        /// Waiting measurements rejected.
        rejected: usize,
    },
    /// A measurement fused at its capture time.
    Fused(Innovation),
    /// A measurement ahead of the latest IMU sample, queued until the IMU reaches it.
    Deferred,
    /// The first pose or odometry: the estimate starts from it.
    Initialized,
}

/// The innovation of a fused measurement, for logging and tuning.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Innovation {
    /// Capture time of the measurement, s.
    pub time_s: f64,
    /// How far the measurement was behind the newest IMU sample when fused, s.
    pub delay_s: f64,
    /// `pose` or `odometry`.
    pub kind: &'static str,
    /// Position residual z − p, world, m.
    pub position_m: Vector3<f64>,
    /// Attitude residual Log(q⁻¹ ⊗ q_z), body, rad.
    pub attitude_rad: Vector3<f64>,
    /// Velocity residual, world, m/s (odometry).
    pub velocity_mps: Option<Vector3<f64>>,
    /// Normalised innovation squared yᵀS⁻¹y (χ² with `dof` degrees of freedom when the
    /// filter is consistent).
    pub nis: f64,
    /// Residual dimension: 6 (pose) or 9 (odometry).
    pub dof: usize,
}

/// Counters and the latest innovation.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Diagnostics {
    /// IMU samples integrated.
    pub imu_samples: u64,
    /// IMU intervals longer than [`EstimatorConfig::max_imu_interval_s`].
    pub imu_gaps: u64,
    /// Measurements fused.
    pub fused: u64,
    /// Measurements fused that had to reach back into the history (captured before the
    /// newest IMU sample).
    pub fused_delayed: u64,
    /// Inputs rejected (IMU samples and measurements).
    pub rejected: u64,
    /// The latest innovation.
    pub last_innovation: Option<Innovation>,
    /// The latest rejection.
    pub last_rejection: Option<Rejection>,
}

/// One standard deviation of each error-state component (the covariance's diagonal).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StateStd {
    /// Position, world, m.
    pub position_m: Vector3<f64>,
    /// Velocity, world, m/s.
    pub velocity_mps: Vector3<f64>,
    /// Attitude error, body, rad.
    pub attitude_rad: Vector3<f64>,
    /// Accelerometer bias, m/s².
    pub accel_bias_mps2: Vector3<f64>,
    /// Gyroscope bias, rad/s.
    pub gyro_bias_radps: Vector3<f64>,
}

#[derive(Debug, Clone)]
struct Node {
    time_s: f64,
    x: Nominal,
    cov: Covariance,
    /// The sample that brought the state here from the previous node (None: the first).
    imu: Option<ImuSample>,
}

/// The state estimator: IMU propagation, pose/odometry correction at the measurement's
/// capture time, the estimate as a [`RigidBodyState`].
#[derive(Debug, Clone)]
pub struct Estimator {
    config: EstimatorConfig,
    /// Oldest first; empty until initialised.
    history: VecDeque<Node>,
    /// Measurements ahead of the IMU, oldest first.
    pending: Vec<Measurement>,
    last_fused_s: Option<f64>,
    diagnostics: Diagnostics,
}

fn nominal_state(x: &Nominal) -> RigidBodyState {
    RigidBodyState {
        position_in_world_m: x.position,
        world_from_body: x.attitude,
        velocity_in_world_mps: x.velocity,
        angular_velocity_in_body_radps: Vector3::zeros(),
    }
}

impl Estimator {
    /// An estimator with `config`, waiting for its first pose or odometry.
    pub fn new(config: EstimatorConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(Self {
            config,
            history: VecDeque::new(),
            pending: Vec::new(),
            last_fused_s: None,
            diagnostics: Diagnostics::default(),
        })
    }

    /// The settings.
    pub fn config(&self) -> &EstimatorConfig {
        &self.config
    }

    /// Starts (or restarts) the estimate at `state` at `time_s` with zero biases and the
    /// configured initial uncertainty. The history and the waiting measurements are dropped.
    pub fn initialize(&mut self, time_s: f64, state: &RigidBodyState) -> Result<(), Rejection> {
        let c = &self.config;
        let stds = (
            c.initial_position_std_m,
            c.initial_velocity_std_mps,
            c.initial_attitude_std_rad,
        );
        self.start(time_s, state, stds)
    }

    /// Starts the estimate at `state` with the given deviations of position (m), velocity
    /// (m/s) and attitude (rad); the biases' from the configuration.
    fn start(
        &mut self,
        time_s: f64,
        state: &RigidBodyState,
        (position_std, velocity_std, attitude_std): (f64, f64, f64),
    ) -> Result<(), Rejection> {
        if !time_s.is_finite() {
            return Err(Rejection::NonFinite { field: "time_s" });
        }
        if !state.is_finite() {
            return Err(Rejection::NonFinite { field: "state" });
        }
        let c = &self.config;
        let mut cov = Covariance::zeros();
        for (block, std) in [
            (P, position_std),
            (V, velocity_std),
            (TH, attitude_std),
            (BA, c.initial_accel_bias_std_mps2),
            (BG, c.initial_gyro_bias_std_radps),
        ] {
            for i in block..block + 3 {
                cov[(i, i)] = std * std;
            }
        }
        self.history.clear();
        self.pending.clear();
        self.history.push_back(Node {
            time_s,
            x: Nominal {
                position: state.position_in_world_m,
                velocity: state.velocity_in_world_mps,
                attitude: state.world_from_body,
                accel_bias: Vector3::zeros(),
                gyro_bias: Vector3::zeros(),
            },
            cov,
            imu: None,
        });
        self.last_fused_s = Some(time_s);
        Ok(())
    }

    /// True once a pose, odometry or [`Estimator::initialize`] started the estimate.
    pub fn is_initialized(&self) -> bool {
        !self.history.is_empty()
    }

    /// Time of the estimate (the newest IMU sample, or the initialisation), s.
    pub fn time_s(&self) -> Option<f64> {
        self.history.back().map(|n| n.time_s)
    }

    /// The estimate: position, attitude, world velocity, and the body rate of the newest
    /// IMU sample less the estimated gyro bias (zero before the first sample).
    pub fn state(&self) -> Option<RigidBodyState> {
        let node = self.history.back()?;
        let mut state = nominal_state(&node.x);
        if let Some(imu) = &node.imu {
            state.angular_velocity_in_body_radps =
                imu.angular_velocity_in_body_radps - node.x.gyro_bias;
        }
        Some(state)
    }

    /// Estimated accelerometer bias (m/s²) and gyroscope bias (rad/s), body frame.
    pub fn biases(&self) -> Option<(Vector3<f64>, Vector3<f64>)> {
        self.history.back().map(|n| (n.x.accel_bias, n.x.gyro_bias))
    }

    /// The error-state covariance (order δp, δv, δθ, δb_a, δb_g).
    pub fn covariance(&self) -> Option<&Covariance> {
        self.history.back().map(|n| &n.cov)
    }

    /// One standard deviation of each component.
    pub fn std_devs(&self) -> Option<StateStd> {
        let cov = self.covariance()?;
        let block = |b: usize| {
            Vector3::new(
                cov[(b, b)].max(0.0).sqrt(),
                cov[(b + 1, b + 1)].max(0.0).sqrt(),
                cov[(b + 2, b + 2)].max(0.0).sqrt(),
            )
        };
        Some(StateStd {
            position_m: block(P),
            velocity_mps: block(V),
            attitude_rad: block(TH),
            accel_bias_mps2: block(BA),
            gyro_bias_radps: block(BG),
        })
    }

    /// Counters and the latest innovation.
    pub fn diagnostics(&self) -> &Diagnostics {
        &self.diagnostics
    }

    /// Measurements waiting for the IMU to reach their time.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    fn reject<T>(&mut self, r: Rejection) -> Result<T, Rejection> {
        self.diagnostics.rejected += 1;
        self.diagnostics.last_rejection = Some(r);
        Err(r)
    }

    /// Integrates one IMU sample (it must be newer than the previous one), then fuses the
    /// waiting measurements it has reached.
    pub fn predict(&mut self, imu: &ImuSample) -> Result<Accepted, Rejection> {
        if let Some(field) = imu.non_finite_field() {
            return self.reject(Rejection::NonFinite { field });
        }
        let Some(newest) = self.history.back() else {
            return self.reject(Rejection::NotInitialized);
        };
        let dt = imu.time_s - newest.time_s;
        if dt <= 0.0 {
            let latest_s = newest.time_s;
            return self.reject(Rejection::OutOfOrder {
                time_s: imu.time_s,
                latest_s,
            });
        }
        let mut node = Node {
            time_s: imu.time_s,
            imu: Some(*imu),
            ..newest.clone()
        };
        ekf::propagate(&mut node.x, &mut node.cov, imu, dt, &self.config);
        self.history.push_back(node);
        self.diagnostics.imu_samples += 1;
        if dt > self.config.max_imu_interval_s {
            self.diagnostics.imu_gaps += 1;
        }
        self.prune();

        let (mut fused, mut rejected) = (0, 0);
        while self
            .pending
            .first()
            .is_some_and(|m| m.time_s() <= imu.time_s)
        {
            let m = self.pending.remove(0);
            match self.fuse(&m) {
                Ok(_) => fused += 1,
                Err(_) => rejected += 1,
            }
        }
        Ok(Accepted::Propagated { fused, rejected })
    }

    /// Drops the states older than the history needs: it keeps the newest state at or
    /// before `newest − history_s`, so a measurement that old can still be fused.
    fn prune(&mut self) {
        let Some(newest) = self.history.back().map(|n| n.time_s) else {
            return;
        };
        let horizon = newest - self.config.history_s;
        while self.history.len() > 1
            && (self.history.len() > MAX_HISTORY_SAMPLES
                || self.history.get(1).is_some_and(|n| n.time_s <= horizon))
        {
            self.history.pop_front();
        }
    }

    /// A pose or odometry measurement: fused at its capture time (reaching back into the
    /// history if it is older than the newest IMU sample), queued if it is ahead of the IMU,
    /// or the start of the estimate if there is none yet (with the measurement's deviations
    /// for what it measures, the configured initial ones for the rest).
    pub fn correct(&mut self, m: &Measurement) -> Result<Accepted, Rejection> {
        if let Some(field) = m.bad_field() {
            return self.reject(Rejection::NonFinite { field });
        }
        let t = m.time_s();
        let Some(newest) = self.history.back().map(|n| n.time_s) else {
            let pose = m.pose();
            let (velocity, velocity_std) = match m {
                Measurement::Odometry(o) => (o.velocity_in_world_mps, o.velocity_std_mps),
                Measurement::Pose(_) => (Vector3::zeros(), self.config.initial_velocity_std_mps),
            };
            let state = RigidBodyState {
                position_in_world_m: pose.position_in_world_m,
                world_from_body: pose.world_from_body,
                velocity_in_world_mps: velocity,
                angular_velocity_in_body_radps: Vector3::zeros(),
            };
            // Position and attitude as well known as the measurement says.
            let stds = (pose.position_std_m, velocity_std, pose.attitude_std_rad);
            self.start(t, &state, stds)?;
            return Ok(Accepted::Initialized);
        };
        let latest_used = self
            .pending
            .last()
            .map(Measurement::time_s)
            .or(self.last_fused_s);
        if let Some(latest_s) = latest_used
            && t < latest_s
        {
            return self.reject(Rejection::OutOfOrder {
                time_s: t,
                latest_s,
            });
        }
        if t > newest {
            if self.pending.len() >= self.config.max_pending {
                let pending = self.pending.len();
                return self.reject(Rejection::QueueFull { pending });
            }
            self.pending.push(*m);
            return Ok(Accepted::Deferred);
        }
        self.fuse(m).map(Accepted::Fused)
    }

    /// Fuses `m` (captured no later than the newest state) at its time and re-integrates the
    /// newer samples.
    fn fuse(&mut self, m: &Measurement) -> Result<Innovation, Rejection> {
        let t = m.time_s();
        let (Some(oldest), Some(newest)) = (self.history.front(), self.history.back()) else {
            return self.reject(Rejection::NotInitialized);
        };
        let (oldest_s, newest_s) = (oldest.time_s, newest.time_s);
        if t < oldest_s {
            return self.reject(Rejection::TooOld {
                time_s: t,
                oldest_s,
            });
        }
        // The last state at or before t.
        let k = self
            .history
            .iter()
            .rposition(|n| n.time_s <= t)
            .unwrap_or(0);
        let mut node = self.history[k].clone();
        if t > node.time_s
            && let Some(imu) = self.history.get(k + 1).and_then(|n| n.imu)
        {
            ekf::propagate(
                &mut node.x,
                &mut node.cov,
                &imu,
                t - node.time_s,
                &self.config,
            );
            node.time_s = t;
        }
        let residual = match ekf::update(
            &mut node.x,
            &mut node.cov,
            m,
            self.config.innovation_gate_nis,
        ) {
            Ok(r) => r,
            Err((UpdateFailure::Gated { nis }, _)) => {
                let gate = self.config.innovation_gate_nis.unwrap_or(f64::INFINITY);
                return self.reject(Rejection::Gated { nis, gate });
            }
            Err((UpdateFailure::Numerical, _)) => return self.reject(Rejection::Numerical),
        };
        // Re-integrate every newer sample on top of the corrected state.
        let same_time = node.time_s <= self.history[k].time_s;
        if same_time {
            self.history[k].x = node.x;
            self.history[k].cov = node.cov;
        }
        for j in k + 1..self.history.len() {
            let (time_s, imu) = (self.history[j].time_s, self.history[j].imu);
            if let Some(imu) = imu {
                ekf::propagate(
                    &mut node.x,
                    &mut node.cov,
                    &imu,
                    time_s - node.time_s,
                    &self.config,
                );
            }
            node.time_s = time_s;
            self.history[j].x = node.x;
            self.history[j].cov = node.cov;
        }
        let innovation = Innovation {
            time_s: t,
            delay_s: newest_s - t,
            kind: m.kind(),
            position_m: residual.position_m,
            attitude_rad: residual.attitude_rad,
            velocity_mps: residual.velocity_mps,
            nis: residual.nis,
            dof: residual.dof,
        };
        self.last_fused_s = Some(t);
        self.diagnostics.fused += 1;
        if t < newest_s {
            self.diagnostics.fused_delayed += 1;
        }
        self.diagnostics.last_innovation = Some(innovation);
        Ok(innovation)
    }
}
