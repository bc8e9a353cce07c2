//! The seam between the flight stack and the world.
//!
//! A [`Link`] takes one actuator command per control tick and gives back the measurement
//! at the end of that tick. Its implementations: the in-process twin ([`TwinLink`], the
//! default for benchmarks: deterministic and fastest), the twin in another process over
//! iceoryx2, a MAVLink autopilot. Controllers never know which one they talk to.

use platform::{ActuatorCommand, Measurement};
use sim_twin::{Twin, TwinError};

use crate::flight_log::FlightLog;
use crate::record::RecordError;
use crate::stack::TickRecord;
use crate::state_source::VehicleSensors;

/// What can go wrong on a link.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinkError {
    /// The in-process twin refused a command or could not be built.
    #[error(transparent)]
    Twin(#[from] TwinError),
    /// The twin in another process (iceoryx2) refused, failed or stopped answering.
    #[error(transparent)]
    Ipc(crate::ipc_link::IpcLinkError),
    /// The MAVLink autopilot refused, failed or stopped answering.
    #[error(transparent)]
    Mavlink(crate::mavlink_link::MavlinkLinkError),
}

/// One side of the flight stack's contact with the vehicle (simulated or real).
pub trait Link {
    /// The latest measurement (before the first command: the state at start).
    fn receive(&mut self) -> Result<Measurement, LinkError>;

    /// Applies `command` for one control period.
    fn send(&mut self, command: &ActuatorCommand) -> Result<(), LinkError>;

    /// Applies one tick's decision for one control period. The default sends
    /// `record.command`; a link that flies at a higher level (a MAVLink autopilot at the
    /// attitude level) reads the controller's wrench and attitude from the record.
    fn send_tick(&mut self, record: &TickRecord) -> Result<(), LinkError> {
        self.send(&record.command)
    }

    /// Short name for logs (`twin`, `ipc:<service>`, `mavlink:<address>`).
    fn name(&self) -> String;

    /// The vehicle's own sensor readings of the tick last received, for a link that reports
    /// them (a MAVLink autopilot: HIGHRES_IMU and ODOMETRY). The estimator then fuses these
    /// instead of simulated sensors. `None` (the default): the link has no sensors of its own.
    fn vehicle_sensors(&self) -> Option<VehicleSensors> {
        None
    }

    /// Adds the link's own channels to the flight log (through
    /// [`FlightLog::link_message`]). The flight loop calls it once per measurement it got from
    /// [`Self::receive`] — the one at the start, then one per tick after that tick's
    /// `/rotors` — with that measurement's time `time_s`, and once more with the last
    /// measurement's time before closing the log after a link failure. The default logs
    /// nothing. The MAVLink link logs `/autopilot/state` and `/mavlink/raw`
    /// (`docs/mcap-format.md`).
    fn log_tick(&mut self, log: &mut FlightLog, time_s: f64) -> Result<(), RecordError> {
        let _ = (log, time_s);
        Ok(())
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

impl Link for TwinLink {
    fn receive(&mut self) -> Result<Measurement, LinkError> {
        Ok(self.latest.clone())
    }

    fn send(&mut self, command: &ActuatorCommand) -> Result<(), LinkError> {
        self.latest = self.twin.step(command)?;
        Ok(())
    }

    fn name(&self) -> String {
        "twin".to_owned()
    }
}
