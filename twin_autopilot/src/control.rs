//! The autopilot's own control: the position hold and landing of the internal modes
//! (amstack's geometric PID from `controllers` on the twin's truth) and the attitude and rate
//! loops of the offboard attitude setpoints (`controllers::AttitudeLaw`, the law PID6 and
//! PID4 run inside), all through amstack's allocator (`allocation`) to rotor thrusts.

use allocation::{Allocation, AllocationMethod, Allocator};
use controllers::{AttitudeGains, AttitudeLaw, BaseController, BodyParams, ControllerKind};
use firmware_bridge::AttitudeSetpoint;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use platform::{ActuatorCommand, Measurement, Vehicle, Wrench};

/// The internal controller and the attitude loop of one vehicle.
#[derive(Debug)]
pub struct Control {
    body: BodyParams,
    controller: Box<dyn BaseController>,
    attitude_law: AttitudeLaw,
    allocator: Allocator,
    allocation: Allocation,
    tilt_dofs: Vec<usize>,
    measured_tilt: Vec<f64>,
    thrust_min_n: f64,
    dt_s: f64,
}

impl Control {
    /// For `vehicle` (with rotors), running every `dt_s` seconds, with the vehicle's
    /// reference PID profile (PID6 or the nested PID4).
    pub fn new(vehicle: &Vehicle, dt_s: f64) -> Result<Self, String> {
        let config =
            controllers::profile(vehicle, ControllerKind::Pid).map_err(|e| e.to_string())?;
        let attitude_gains = AttitudeGains::from_config(&config)
            .ok_or_else(|| format!("{}: no PID profile", vehicle.id))?;
        let body = BodyParams::from_vehicle(vehicle);
        let controller = controllers::build(&config, body).map_err(|e| e.to_string())?;
        let allocator = Allocator::new(
            &vehicle.rotors,
            vehicle.actuation,
            AllocationMethod::PseudoInverse,
        )
        .map_err(|e| format!("{}: allocation: {e}", vehicle.id))?;
        let allocation = allocator.new_allocation();
        let tilt_dofs = vehicle.tilt_dofs();
        Ok(Self {
            body,
            controller,
            attitude_law: AttitudeLaw::new(attitude_gains),
            allocator,
            allocation,
            measured_tilt: vec![0.0; tilt_dofs.len()],
            tilt_dofs,
            thrust_min_n: vehicle.rotors.thrust_min_n,
            dt_s,
        })
    }

    /// Clears the hold controller's integrators (on entering an internal mode).
    pub fn reset(&mut self, m: &Measurement) {
        self.controller.reset(&m.base);
    }

    /// One tick of the position hold toward `target` (position, heading level).
    pub fn hold(
        &mut self,
        m: &Measurement,
        target: &Isometry3<f64>,
        joint_targets: &[f64],
    ) -> ActuatorCommand {
        let wrench = self.controller.update(&m.base, target, self.dt_s);
        let command = self.allocate(m, &wrench, joint_targets);
        self.controller
            .saturation_feedback(&self.allocation.unallocated);
        command
    }

    /// One tick of the attitude loop: `controllers::AttitudeLaw` with the attitude gains of
    /// the vehicle's PID profile toward the setpoint's attitude (its body rates as
    /// feed-forward), and the setpoint's body force.
    pub fn attitude(
        &mut self,
        m: &Measurement,
        setpoint: &AttitudeSetpoint,
        joint_targets: &[f64],
    ) -> ActuatorCommand {
        let rates = setpoint.body_rates_radps.unwrap_or_else(Vector3::zeros);
        let torque = self.attitude_law.attitude(
            &self.body,
            &m.base,
            &setpoint.world_from_body,
            &rates,
            self.dt_s,
        );
        let wrench = Wrench::new(setpoint.force_in_body_n, torque);
        let command = self.allocate(m, &wrench, joint_targets);
        self.attitude_law
            .saturation_feedback(&self.allocation.unallocated, &m.base.world_from_body);
        command
    }

    /// One tick of the rate loop (attitude ignored): `controllers::AttitudeLaw::rates` toward
    /// `body_rates_radps` (FLU) with the body force `force_in_body_n`.
    pub fn rates(
        &mut self,
        m: &Measurement,
        body_rates_radps: &Vector3<f64>,
        force_in_body_n: &Vector3<f64>,
        joint_targets: &[f64],
    ) -> ActuatorCommand {
        let torque = self
            .attitude_law
            .rates(&self.body, &m.base, body_rates_radps, self.dt_s);
        let wrench = Wrench::new(*force_in_body_n, torque);
        self.allocate(m, &wrench, joint_targets)
    }

    /// Clears the attitude loop's integral (a new offboard attitude stream).
    pub fn reset_attitude(&mut self) {
        self.attitude_law.reset();
    }

    /// Body mass properties the loops use.
    pub fn body(&self) -> &BodyParams {
        &self.body
    }

    /// Rotor thrusts (and tilt angles) for a body wrench; idle thrust when the request or the
    /// allocation is unusable (never a non-finite command).
    fn allocate(
        &mut self,
        m: &Measurement,
        wrench: &Wrench,
        joint_targets: &[f64],
    ) -> ActuatorCommand {
        for (t, &dof) in self.measured_tilt.iter_mut().zip(&self.tilt_dofs) {
            *t = m.joint_positions.get(dof).copied().unwrap_or(0.0);
        }
        let mut command = ActuatorCommand {
            rotor_thrusts_n: vec![self.thrust_min_n; self.allocator.rotor_count()],
            joint_targets: joint_targets.to_vec(),
            direct_wrench_in_body: None,
        };
        let ok = self
            .allocator
            .allocate_into(wrench, &self.measured_tilt, &mut self.allocation)
            .is_ok();
        let a = &self.allocation;
        if ok && a.thrusts_n.iter().all(|t| t.is_finite()) {
            command.rotor_thrusts_n.clone_from(&a.thrusts_n);
            for (&dof, &angle) in self.tilt_dofs.iter().zip(&a.tilt_rad) {
                if let Some(q) = command.joint_targets.get_mut(dof)
                    && angle.is_finite()
                {
                    *q = angle;
                }
            }
        }
        command
    }
}

/// The hold target: the current position with the current heading, level.
pub fn hold_target(m: &Measurement) -> Isometry3<f64> {
    let p = m.base.position_in_world_m;
    let (_, _, yaw) = m.base.world_from_body.euler_angles();
    Isometry3::from_parts(
        Translation3::from(p),
        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
    )
}
