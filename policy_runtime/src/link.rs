//! The seam between the flight stack and the world: the floor of this crate.
//!
//! A [`Link`] takes one [`Setpoint`] per control tick and gives back the measurement at the
//! end of that tick. It knows nothing above it — no stack, no log, no task policy: what it
//! has to say besides the measurement it returns as data (its own sensor readings
//! [`VehicleSensors`], the task scene's state [`TaskSnapshot`], and the messages of its own
//! log channels [`LinkMessage`]). Its errors are categorical ([`LinkError`]): the transport's
//! detail travels as text, so nothing above needs to know which transport failed.
//!
//! Implementations: the in-process twin ([`TwinLink`], the default for benchmarks:
//! deterministic and fastest), the twin in another process over iceoryx2
//! ([`crate::IpcLink`]), a MAVLink autopilot ([`crate::MavlinkLink`]). Controllers never know
//! which one they talk to.

use estimator::{ImuSample, OdometryMeasurement};
use platform::{ActuatorCommand, AttitudeSetpoint, Measurement};
use sim_twin::{SceneVisual, TaskSnapshot, Twin, TwinError};

pub use crate::link_channels::LinkMessage;

/// What a link is asked to fly for one control period: the output of the flight stack at the
/// level the link flies at ([`SetpointLevel`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Setpoint {
    /// Rotor thrusts (and tilt angles) from amstack's allocation, and the joint targets.
    Actuators(ActuatorCommand),
    /// The base controller's attitude setpoint (desired attitude, body rates, body force),
    /// flown by the vehicle's own attitude loop and allocation; the joint targets of
    /// `command` (its rotor thrusts are not sent).
    Attitude {
        /// The stack's command of the tick (joint targets: arm, gripper).
        command: ActuatorCommand,
        /// The controller's cascade.
        attitude: AttitudeSetpoint,
    },
}

impl Setpoint {
    /// The stack's actuator command of the tick.
    pub fn command(&self) -> &ActuatorCommand {
        match self {
            Self::Actuators(c) | Self::Attitude { command: c, .. } => c,
        }
    }

    /// Whether every value that would be sent is finite (a flight loop never sends another).
    pub fn is_finite(&self) -> bool {
        let c = self.command();
        let command_finite = c
            .rotor_thrusts_n
            .iter()
            .chain(&c.joint_targets)
            .all(|x| x.is_finite())
            && c.direct_wrench_in_body.is_none_or(|w| w.is_finite());
        match self {
            Self::Actuators(_) => command_finite,
            Self::Attitude { attitude: a, .. } => {
                command_finite
                    && a.world_from_body.coords.iter().all(|x| x.is_finite())
                    && a.force_in_body_n.iter().all(|x| x.is_finite())
                    && a.body_rates_radps
                        .is_none_or(|r| r.iter().all(|x| x.is_finite()))
            }
        }
    }
}

/// Which setpoint a link flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SetpointLevel {
    /// [`Setpoint::Actuators`].
    #[default]
    Actuators,
    /// [`Setpoint::Attitude`].
    Attitude,
}

/// What can go wrong on a link, by category; the detail is the transport's own words.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinkError {
    /// The other side refused this flight or this setpoint (a configuration, a scene or a
    /// layout that does not fit; an address that cannot be opened): the user's input.
    #[error("{0}")]
    Refused(String),
    /// The other side stopped answering (timed out, its process gone).
    #[error("{0}")]
    Silent(String),
    /// The transport or the other side failed (an autopilot that left offboard, a socket
    /// error).
    #[error("{0}")]
    Failed(String),
    /// The simulation behind the link diverged: the flight cannot go on, the run can.
    #[error("{0}")]
    Diverged(String),
}

/// One tick's readings of the vehicle's own sensors, as a link reports them.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleSensors {
    /// The IMU sample of the period that just ended (specific force and rates, body FLU).
    pub imu: Option<ImuSample>,
    /// The tick's odometry: pose and world velocity at its capture time. Its standard
    /// deviations are the link's when it reports them, NaN otherwise (the settings' are used).
    pub odometry: Option<OdometryMeasurement>,
}

impl VehicleSensors {
    /// The odometry a link reports with measurement `m` (the base's pose and world velocity
    /// at its time), without noise figures (the settings' are used).
    pub fn odometry_of(m: &Measurement) -> OdometryMeasurement {
        OdometryMeasurement {
            pose: estimator::PoseMeasurement {
                time_s: m.time_s,
                position_in_world_m: m.base.position_in_world_m,
                world_from_body: m.base.world_from_body,
                position_std_m: f64::NAN,
                attitude_std_rad: f64::NAN,
            },
            velocity_in_world_mps: m.base.velocity_in_world_mps,
            velocity_std_mps: f64::NAN,
        }
    }
}

/// One side of the flight stack's contact with the vehicle (simulated or real).
pub trait Link {
    /// The latest measurement (before the first setpoint: the state at start).
    fn receive(&mut self) -> Result<Measurement, LinkError>;

    /// Applies `setpoint` for one control period. The flight loop sends only finite ones
    /// at the link's [`level`](Self::level).
    fn send(&mut self, setpoint: &Setpoint) -> Result<(), LinkError>;

    /// The setpoint this link flies (default: actuators).
    fn level(&self) -> SetpointLevel {
        SetpointLevel::Actuators
    }

    /// Short name for logs (`twin`, `ipc:<service>`, `mavlink:<address>`).
    fn name(&self) -> String;

    /// The vehicle's own sensor readings of the tick last received, for a link that reports
    /// them (a MAVLink autopilot: HIGHRES_IMU and ODOMETRY). The estimator then fuses these
    /// instead of simulated sensors. `None` (the default): the link has no sensors of its own.
    fn vehicle_sensors(&self) -> Option<VehicleSensors> {
        None
    }

    /// The task scene's state after the last step (`None` without a task scene).
    fn task(&self) -> Option<TaskSnapshot> {
        None
    }

    /// Whether [`task`](Self::task) is observed (the twin: always; a vehicle that sends no
    /// task state: its scene model only, whose success is not an observation).
    fn task_observed(&self) -> bool {
        true
    }

    /// The messages of the link's own log channels since the last call, the state ones at
    /// `time_s` (the time of the measurement last received). The flight loop calls it once
    /// per measurement, and once more before it stops on a link failure. Default: none; the
    /// MAVLink link gives `/autopilot/state` and `/mavlink/raw` (`docs/mcap-format.md`).
    fn drain_messages(&mut self, time_s: f64, out: &mut Vec<LinkMessage>) {
        let _ = (time_s, out);
    }

    /// The scene's visual shapes, for a link whose cameras can be rendered (the in-process
    /// twin); `None` (the default): this link cannot render cameras.
    fn camera_scene(&self) -> Option<Vec<SceneVisual>> {
        None
    }

    /// Fills `state` with what the cameras draw now (the vehicle's pose and joints, the
    /// scene's object poses, exact); false (the default): this link cannot render cameras.
    fn camera_state(&self, state: &mut render::Snapshot) -> bool {
        let _ = state;
        false
    }
}

/// The twin in this process: `send` advances it one control period (lockstep).
#[derive(Debug)]
pub struct TwinLink {
    twin: Twin,
    latest: Measurement,
}

impl TwinLink {
    /// A link to `twin`, starting from its current state.
    pub fn new(twin: Twin) -> Self {
        let latest = twin.truth().clone();
        Self { twin, latest }
    }

    /// The twin behind the link (scenes, truth, configuration).
    pub fn twin(&self) -> &Twin {
        &self.twin
    }

    /// The twin behind the link, mutable (adding scene objects).
    pub fn twin_mut(&mut self) -> &mut Twin {
        &mut self.twin
    }
}

impl From<TwinError> for LinkError {
    fn from(e: TwinError) -> Self {
        match e {
            TwinError::Diverged(_) => Self::Diverged(e.to_string()),
            TwinError::Command(_) | TwinError::Config(_) | TwinError::Vehicle(_) => {
                Self::Refused(e.to_string())
            }
        }
    }
}

impl Link for TwinLink {
    fn receive(&mut self) -> Result<Measurement, LinkError> {
        Ok(self.latest.clone())
    }

    fn send(&mut self, setpoint: &Setpoint) -> Result<(), LinkError> {
        match setpoint {
            Setpoint::Actuators(command) => {
                self.latest = self.twin.step(command)?;
                Ok(())
            }
            Setpoint::Attitude { .. } => Err(LinkError::Refused(
                "the twin in this process flies actuator setpoints, not attitude ones".to_owned(),
            )),
        }
    }

    fn name(&self) -> String {
        "twin".to_owned()
    }

    fn task(&self) -> Option<TaskSnapshot> {
        self.twin.task_snapshot()
    }

    fn camera_scene(&self) -> Option<Vec<SceneVisual>> {
        Some(self.twin.scene_visuals())
    }

    fn camera_state(&self, state: &mut render::Snapshot) -> bool {
        state.update_from_twin(&self.twin);
        true
    }
}
