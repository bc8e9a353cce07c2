//! Where the internal controller flies, mode by mode: position hold (POSCTL, AUTO.LOITER),
//! reposition (DO_REPOSITION), takeoff, landing, RTL, missions, and the offboard position,
//! velocity and acceleration setpoints. Each step moves the position target
//! ([`Carrot`], within the MPC_* limits) and flies it with amstack's PID
//! ([`crate::control::Control::hold`]) through amstack's allocation.

use mavlink::dialects::common::{MISSION_ITEM_REACHED_DATA, MavMessage};
use nalgebra::Vector3;
use platform::ActuatorCommand;

use super::{Autopilot, LAND_STALL_M, LANDED_MARGIN_M, LANDED_SPEED_MPS};
use crate::mission::Action;
use crate::modes::{FlightMode, Transition};
use crate::navigator::{Carrot, Limits};
use crate::offboard::PositionTarget;
use crate::params::Param;

/// RTL's phases.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum RtlPhase {
    /// Up to the return altitude (world z, m).
    Climb { z_m: f64 },
    /// Over home at that altitude.
    Return,
    /// Down.
    Land,
}

/// A mission item's phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum ItemPhase {
    /// Flying to it.
    Flying,
    /// Reached; holding since (twin time, s).
    Holding { since_s: f64 },
    /// Landing (a land item).
    Landing,
}

/// What the internal controller does in the current mode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Guidance {
    /// Hold where the mode began.
    Hold,
    /// Fly to a point and hold there (DO_REPOSITION).
    Goto {
        goal_m: Vector3<f64>,
        yaw_rad: Option<f64>,
    },
    /// Climb to an altitude (world z), then AUTO.LOITER.
    Takeoff { z_m: f64 },
    /// Descend at MPC_LAND_SPEED; landed → the commander disarms.
    Land,
    /// Return to launch.
    Rtl(RtlPhase),
    /// Fly the mission item `mission_seq`.
    Mission(ItemPhase),
}

impl Guidance {
    /// Whether the vehicle is landing (EXTENDED_SYS_STATE).
    pub(super) fn landing(&self) -> bool {
        matches!(
            self,
            Self::Land | Self::Rtl(RtlPhase::Land) | Self::Mission(ItemPhase::Landing)
        )
    }

    /// Whether the vehicle is taking off.
    pub(super) fn taking_off(&self) -> bool {
        matches!(self, Self::Takeoff { .. })
    }
}

/// Something the step decided that the loop reports after it (transitions, messages).
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Deferred {
    Transition(Transition),
    Notice(String),
    Send(Box<MavMessage>),
}

impl Autopilot {
    /// The guidance of a mode entered now (the target restarts from the vehicle's pose).
    pub(super) fn enter(&mut self, mode: FlightMode) {
        self.carrot = None;
        self.landed_since_s = None;
        let z = self.truth().base.position_in_world_m.z;
        self.guidance = match mode {
            FlightMode::Posctl | FlightMode::AutoLoiter | FlightMode::Offboard => Guidance::Hold,
            FlightMode::AutoLand => Guidance::Land,
            FlightMode::AutoTakeoff => Guidance::Takeoff {
                z_m: (self.home_m.z + self.params.get(Param::MisTakeoffAlt)).max(z),
            },
            FlightMode::AutoRtl => Guidance::Rtl(RtlPhase::Climb {
                z_m: (self.home_m.z + self.params.get(Param::RtlReturnAlt)).max(z),
            }),
            FlightMode::AutoMission => {
                if usize::from(self.mission_seq) >= self.missions.items().len() {
                    self.mission_seq = 0;
                }
                Guidance::Mission(ItemPhase::Flying)
            }
        };
    }

    /// The horizontal speed of missions, reposition and RTL: the commanded speed or
    /// MPC_XY_CRUISE, at most MPC_XY_VEL_MAX.
    fn cruise_mps(&self) -> f64 {
        self.cruise_override_mps
            .unwrap_or_else(|| self.params.get(Param::MpcXyCruise))
            .min(self.params.get(Param::MpcXyVelMax))
    }

    /// The target's limits with horizontal speed `xy_speed_mps`.
    fn limits(&self, xy_speed_mps: f64) -> Limits {
        Limits {
            xy_speed_mps,
            up_speed_mps: self.params.get(Param::MpcZVelMaxUp),
            down_speed_mps: self.params.get(Param::MpcZVelMaxDn),
            xy_acc_mps2: self.params.get(Param::MpcAccHor),
            up_acc_mps2: self.params.get(Param::MpcAccUpMax),
            down_acc_mps2: self.params.get(Param::MpcAccDownMax),
        }
    }

    /// The current target, or one at the vehicle's pose (clearing the controller).
    fn carrot_now(&mut self) -> Carrot {
        match self.carrot {
            Some(c) => c,
            None => {
                let m = self.twin.truth().clone();
                self.control.reset(&m);
                let (_, _, yaw) = m.base.world_from_body.euler_angles();
                Carrot::at(m.base.position_in_world_m, yaw)
            }
        }
    }

    /// One step of the landing descent: the target goes down at MPC_LAND_SPEED to the resting
    /// height (never into the ground: a controller pushing into the ground winds up and tips
    /// an under-actuated vehicle over); landed = on the ground (at the resting height, or held
    /// up by an arm or an object while the target is well below), slow. True on the step the
    /// vehicle is first found landed.
    fn land_step(&mut self, carrot: &mut Carrot) -> bool {
        let m = self.twin.truth();
        let speed = self.params.get(Param::MpcLandSpeed);
        carrot.position_m.z = (carrot.position_m.z - speed * self.dt_s).max(self.rest_z_m);
        carrot.velocity_mps = Vector3::zeros();
        let z = m.base.position_in_world_m.z;
        let still = m.base.velocity_in_world_mps.norm() < LANDED_SPEED_MPS;
        let held_up = carrot.position_m.z < z - LAND_STALL_M;
        if (z < self.rest_z_m + LANDED_MARGIN_M || held_up) && still {
            let first = self.landed_since_s.is_none();
            self.landed_since_s.get_or_insert(m.time_s);
            first
        } else {
            self.landed_since_s = None;
            false
        }
    }

    /// Whether the vehicle is within `radius_m` of `point_m`.
    fn within(&self, point_m: &Vector3<f64>, radius_m: f64) -> bool {
        (self.truth().base.position_in_world_m - point_m).norm() <= radius_m
    }

    /// The command of one step of an internal mode.
    pub(super) fn internal_command(&mut self) -> ActuatorCommand {
        let mut carrot = self.carrot_now();
        let dt = self.dt_s;
        let acceptance = self.params.get(Param::NavAccRad);
        match self.guidance {
            Guidance::Hold => {}
            Guidance::Goto { goal_m, yaw_rad } => {
                if let Some(y) = yaw_rad {
                    carrot.yaw_rad = y;
                }
                carrot.toward(&goal_m, &self.limits(self.cruise_mps()), dt);
            }
            Guidance::Takeoff { z_m } => {
                let goal = Vector3::new(carrot.position_m.x, carrot.position_m.y, z_m);
                let mut limits = self.limits(self.cruise_mps());
                limits.up_speed_mps = self.params.get(Param::MpcTkoSpeed);
                let arrived = carrot.toward(&goal, &limits, dt);
                if arrived
                    && self.within(&goal, acceptance)
                    && let Some(t) = self
                        .commander
                        .switch(FlightMode::AutoLoiter, "takeoff done")
                {
                    self.deferred.push(Deferred::Transition(t));
                }
            }
            Guidance::Land => {
                self.land_step(&mut carrot);
            }
            Guidance::Rtl(phase) => match phase {
                RtlPhase::Climb { z_m } => {
                    let goal = Vector3::new(carrot.position_m.x, carrot.position_m.y, z_m);
                    if carrot.toward(&goal, &self.limits(self.cruise_mps()), dt) {
                        self.guidance = Guidance::Rtl(RtlPhase::Return);
                    }
                }
                RtlPhase::Return => {
                    let goal = Vector3::new(self.home_m.x, self.home_m.y, carrot.position_m.z);
                    let arrived = carrot.toward(&goal, &self.limits(self.cruise_mps()), dt);
                    if arrived && self.within(&goal, acceptance) {
                        self.guidance = Guidance::Rtl(RtlPhase::Land);
                        self.deferred
                            .push(Deferred::Notice("RTL: over home, landing".to_owned()));
                    }
                }
                RtlPhase::Land => {
                    self.land_step(&mut carrot);
                }
            },
            Guidance::Mission(phase) => self.mission_step(&mut carrot, phase, acceptance),
        }
        self.carrot = Some(carrot);
        let m = self.twin.truth().clone();
        self.control.hold(&m, &carrot.pose(), &self.joint_targets)
    }

    fn reached(&mut self, seq: u16) {
        self.deferred
            .push(Deferred::Send(Box::new(MavMessage::MISSION_ITEM_REACHED(
                MISSION_ITEM_REACHED_DATA { seq },
            ))));
        self.deferred
            .push(Deferred::Notice(format!("mission item {seq} reached")));
    }

    fn advance(&mut self) {
        self.mission_seq = self.mission_seq.saturating_add(1);
        self.guidance = Guidance::Mission(ItemPhase::Flying);
        let msg = self.mission_current();
        self.deferred.push(Deferred::Send(Box::new(msg)));
        if usize::from(self.mission_seq) >= self.missions.items().len() {
            self.deferred.push(Deferred::Notice(
                "mission complete: holding at the last point".to_owned(),
            ));
        }
    }

    fn mission_step(&mut self, carrot: &mut Carrot, phase: ItemPhase, acceptance: f64) {
        let seq = self.mission_seq;
        let Some(item) = self.missions.items().get(usize::from(seq)) else {
            // Done: hold.
            return;
        };
        let dt = self.dt_s;
        let now_s = self.twin.time_s();
        match item.action {
            Action::Waypoint {
                point_m,
                acceptance_m,
                hold_s,
                yaw_rad,
            } => match phase {
                ItemPhase::Flying => {
                    if let Some(y) = yaw_rad {
                        carrot.yaw_rad = y;
                    }
                    let arrived = carrot.toward(&point_m, &self.limits(self.cruise_mps()), dt);
                    if arrived && self.within(&point_m, acceptance_m.unwrap_or(acceptance)) {
                        self.reached(seq);
                        self.guidance = Guidance::Mission(ItemPhase::Holding { since_s: now_s });
                    }
                }
                ItemPhase::Holding { since_s } => {
                    if now_s - since_s >= hold_s {
                        self.advance();
                    }
                }
                ItemPhase::Landing => self.advance(),
            },
            Action::Takeoff { z_m } => {
                let goal = Vector3::new(
                    carrot.position_m.x,
                    carrot.position_m.y,
                    z_m.max(self.rest_z_m),
                );
                let mut limits = self.limits(self.cruise_mps());
                limits.up_speed_mps = self.params.get(Param::MpcTkoSpeed);
                let arrived = carrot.toward(&goal, &limits, dt);
                if arrived && self.within(&goal, acceptance) {
                    self.reached(seq);
                    self.advance();
                }
            }
            Action::Land { xy_m } => match phase {
                ItemPhase::Flying | ItemPhase::Holding { .. } => match xy_m {
                    Some((x, y)) => {
                        let goal = Vector3::new(x, y, carrot.position_m.z);
                        let arrived = carrot.toward(&goal, &self.limits(self.cruise_mps()), dt);
                        if arrived && self.within(&goal, acceptance) {
                            self.guidance = Guidance::Mission(ItemPhase::Landing);
                        }
                    }
                    None => self.guidance = Guidance::Mission(ItemPhase::Landing),
                },
                ItemPhase::Landing => {
                    if self.land_step(carrot) {
                        self.reached(seq);
                    }
                }
            },
            Action::ReturnToLaunch => {
                self.reached(seq);
                self.mission_seq = self.mission_seq.saturating_add(1);
                if let Some(t) = self
                    .commander
                    .switch(FlightMode::AutoRtl, "mission: RTL item")
                {
                    self.deferred.push(Deferred::Transition(t));
                }
            }
            Action::ChangeSpeed { speed_mps } => {
                self.cruise_override_mps = Some(speed_mps);
                self.reached(seq);
                self.advance();
            }
        }
    }

    /// The command of one offboard position/velocity/acceleration step (PX4's type-mask
    /// semantics, see [`crate::offboard`]) within MPC_XY_VEL_MAX and MPC_Z_VEL_MAX_*.
    pub(super) fn offboard_position_command(&mut self, target: &PositionTarget) -> ActuatorCommand {
        let mut carrot = self.carrot_now();
        let dt = self.dt_s;
        let limits = self.limits(self.params.get(Param::MpcXyVelMax));
        if target.has_position() {
            let mut goal = carrot.position_m;
            for (g, p) in goal.iter_mut().zip(target.position_m) {
                if let Some(p) = p {
                    *g = p;
                }
            }
            carrot.toward(&goal, &limits, dt);
        } else if let Some(v) = target.velocity_mps {
            carrot.with_velocity(&v, &limits, dt);
        } else if let Some(a) = target.acceleration_mps2 {
            let v = carrot.velocity_mps + a * dt;
            carrot.with_velocity(&v, &limits, dt);
        }
        if let Some(yaw) = target.yaw_rad {
            carrot.yaw_rad = yaw;
        } else if let Some(rate) = target.yaw_rate_radps {
            let max = self.params.get(Param::McYawrateMax).to_radians();
            carrot.yaw_rad += rate.clamp(-max, max) * dt;
        }
        self.carrot = Some(carrot);
        let m = self.twin.truth().clone();
        self.control.hold(&m, &carrot.pose(), &self.joint_targets)
    }
}
