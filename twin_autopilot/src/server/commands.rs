//! COMMAND_LONG and COMMAND_INT, answered alike (as PX4): every command for this autopilot
//! gets a COMMAND_ACK; a refusal is followed by a STATUSTEXT with the reason. COMMAND_INT
//! carries a position as integers in its frame (lat/lon · 1e7 in the global frames; local
//! x/y · 1e4 m), COMMAND_LONG as floats (degrees, altitude AMSL). A NaN parameter means
//! "unchanged / the default", as in PX4; an infinite one is refused.

#![allow(
    deprecated,
    reason = "PX4 still serves the deprecated MISSION_ITEM, MISSION_REQUEST, MISSION_SET_CURRENT, frames and commands: so does the twin"
)]

use mavlink::MavHeader;
use mavlink::dialects::common::{
    COMMAND_INT_DATA, COMMAND_LONG_DATA, MavCmd, MavFrame, MavModeFlag, MavResult,
};
use nalgebra::Vector3;

use super::guidance::Guidance;
use super::{AUTOPILOT_VERSION_ID, Autopilot, AutopilotEvent, HOME_POSITION_ID, PER_STEP_IDS};
use crate::modes::{FORCE_DISARM_MAGIC, FlightMode, Refusal};
use crate::params::Param;
use crate::telemetry;

/// Where a command's position is and how it is encoded.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Position {
    /// COMMAND_LONG: param5 latitude, param6 longitude (degrees), param7 altitude AMSL.
    Long { p5: f32, p6: f32 },
    /// COMMAND_INT: x, y in `frame`, z.
    Int { frame: MavFrame, x: i32, y: i32 },
}

/// One command, from either message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Cmd {
    command: MavCmd,
    /// param1–4.
    p: [f32; 4],
    position: Position,
    /// param7 / z.
    z: f32,
}

fn denied(reason: impl Into<String>) -> Refusal {
    Refusal {
        temporary: false,
        reason: reason.into(),
    }
}

impl Cmd {
    pub(super) fn from_long(c: &COMMAND_LONG_DATA) -> Self {
        Self {
            command: c.command,
            p: [c.param1, c.param2, c.param3, c.param4],
            position: Position::Long {
                p5: c.param5,
                p6: c.param6,
            },
            z: c.param7,
        }
    }

    pub(super) fn from_int(c: &COMMAND_INT_DATA) -> Self {
        Self {
            command: c.command,
            p: [c.param1, c.param2, c.param3, c.param4],
            position: Position::Int {
                frame: c.frame,
                x: c.x,
                y: c.y,
            },
            z: c.z,
        }
    }

    /// param5/x as a float (COMMAND_INT: the integer).
    fn p5(&self) -> f32 {
        match self.position {
            Position::Long { p5, .. } => p5,
            // Integers in a float parameter slot, as PX4 reads them.
            #[allow(clippy::cast_precision_loss)]
            Position::Int { x, .. } => x as f32,
        }
    }

    /// The commanded horizontal position (world x, y), None when not given (NaN, or 0/0
    /// in a global frame). Err for a position that is not finite or not in a frame the twin
    /// places.
    fn xy_world(&self) -> Result<Option<(f64, f64)>, String> {
        let home = &telemetry::HOME;
        match self.position {
            Position::Long { p5, p6 } => {
                if p5.is_nan() || p6.is_nan() || (p5 == 0.0 && p6 == 0.0) {
                    return Ok(None);
                }
                if !(p5.is_finite() && p6.is_finite() && p5.abs() <= 90.0 && p6.abs() <= 180.0) {
                    return Err(format!("latitude/longitude {p5}, {p6} invalid"));
                }
                Ok(Some(telemetry::world_xy_of(
                    home,
                    f64::from(p5),
                    f64::from(p6),
                )))
            }
            Position::Int { frame, x, y } => match frame {
                MavFrame::MAV_FRAME_GLOBAL
                | MavFrame::MAV_FRAME_GLOBAL_INT
                | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT
                | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT => {
                    if x == 0 && y == 0 || x == i32::MAX || y == i32::MAX {
                        return Ok(None);
                    }
                    let (lat, lon) = (f64::from(x) / 1e7, f64::from(y) / 1e7);
                    if lat.abs() > 90.0 || lon.abs() > 180.0 {
                        return Err(format!("latitude/longitude {lat}, {lon} invalid"));
                    }
                    Ok(Some(telemetry::world_xy_of(home, lat, lon)))
                }
                MavFrame::MAV_FRAME_LOCAL_NED => Ok(Some((f64::from(y) / 1e4, f64::from(x) / 1e4))),
                f => Err(format!("frame {f:?} not supported")),
            },
        }
    }

    /// The commanded altitude as world z (height above the origin's ground), None for NaN.
    /// COMMAND_LONG: AMSL; COMMAND_INT: by its frame.
    fn z_world(&self) -> Result<Option<f64>, String> {
        let z = self.z;
        if z.is_nan() {
            return Ok(None);
        }
        if !z.is_finite() {
            return Err(format!("altitude {z} not finite"));
        }
        let z = f64::from(z);
        let amsl = telemetry::HOME.alt_m;
        let world = match self.position {
            Position::Long { .. } => z - amsl,
            Position::Int { frame, .. } => match frame {
                MavFrame::MAV_FRAME_GLOBAL | MavFrame::MAV_FRAME_GLOBAL_INT => z - amsl,
                MavFrame::MAV_FRAME_LOCAL_NED => -z,
                _ => z,
            },
        };
        Ok(Some(world))
    }
}

/// Positions beyond this from the origin are refused, m.
const MAX_GOAL_M: f64 = 10_000.0;

impl Autopilot {
    /// A COMMAND_LONG or COMMAND_INT for this autopilot: every one gets a COMMAND_ACK.
    pub(super) fn command(
        &mut self,
        from: &MavHeader,
        c: &Cmd,
        on_event: &mut impl FnMut(&AutopilotEvent),
    ) {
        let facts = self.facts();
        let [p1, p2, p3, p4] = c.p;
        match c.command {
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => {
                let outcome = if p1 == 1.0 {
                    self.commander.arm(&facts)
                } else if p1 == 0.0 {
                    self.commander.disarm(&facts, p2 == FORCE_DISARM_MAGIC)
                } else {
                    Err(denied(format!("Arm/disarm: param1 {p1} not 0 or 1")))
                };
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_DO_SET_MODE => {
                let custom = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits();
                let outcome = if !(p1.is_finite() && (p1 as u32) & u32::from(custom) != 0) {
                    Err(denied("Set mode: param1 lacks CUSTOM_MODE_ENABLED"))
                } else if !(p2.is_finite() && p3.is_finite()) {
                    Err(denied("Set mode: mode not finite"))
                } else {
                    match FlightMode::from_main_and_sub(p2 as u8, p3 as u8) {
                        Ok(mode) => self.commander.set_mode(mode, &facts),
                        Err(reason) => Err(denied(format!("Set mode: {reason}"))),
                    }
                };
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_NAV_LAND => {
                let outcome = self.commander.set_mode(FlightMode::AutoLand, &facts);
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH => {
                let outcome = self.commander.set_mode(FlightMode::AutoRtl, &facts);
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_NAV_TAKEOFF => {
                let z = match c.z_world() {
                    Ok(z) => {
                        z.unwrap_or_else(|| self.home_m.z + self.params.get(Param::MisTakeoffAlt))
                    }
                    Err(why) => {
                        self.refuse(
                            from,
                            c.command,
                            &denied(format!("Takeoff: {why}")),
                            on_event,
                        );
                        return;
                    }
                };
                if !(z.is_finite() && z.abs() <= MAX_GOAL_M) {
                    self.refuse(
                        from,
                        c.command,
                        &denied("Takeoff: altitude out of range"),
                        on_event,
                    );
                    return;
                }
                let outcome = self.commander.set_mode(FlightMode::AutoTakeoff, &facts);
                let ok = outcome.is_ok();
                self.outcome(from, c.command, outcome, on_event);
                if ok {
                    let now_z = self.truth().base.position_in_world_m.z;
                    self.guidance = Guidance::Takeoff { z_m: z.max(now_z) };
                }
            }
            MavCmd::MAV_CMD_DO_REPOSITION => {
                if !self.commander.armed() {
                    self.refuse(
                        from,
                        c.command,
                        &denied("Reposition denied: not armed"),
                        on_event,
                    );
                    return;
                }
                let goal = match (c.xy_world(), c.z_world()) {
                    (Ok(xy), Ok(z)) => {
                        let p = self.truth().base.position_in_world_m;
                        let (x, y) = xy.unwrap_or((p.x, p.y));
                        Vector3::new(x, y, z.unwrap_or(p.z))
                    }
                    (Err(why), _) | (_, Err(why)) => {
                        self.refuse(
                            from,
                            c.command,
                            &denied(format!("Reposition: {why}")),
                            on_event,
                        );
                        return;
                    }
                };
                if !(goal.norm().is_finite() && goal.norm() <= MAX_GOAL_M) {
                    self.refuse(
                        from,
                        c.command,
                        &denied("Reposition: too far from home"),
                        on_event,
                    );
                    return;
                }
                if p1.is_finite() && p1 > 0.0 {
                    self.cruise_override_mps = Some(f64::from(p1).min(20.0));
                }
                let yaw_rad = (p4.is_finite() && p4.abs() <= 360.0).then(|| {
                    firmware_bridge::frames::world_yaw_from_ned_yaw(f64::from(p4).to_radians())
                });
                let outcome = self.commander.set_mode(FlightMode::AutoLoiter, &facts);
                let ok = outcome.is_ok();
                self.outcome(from, c.command, outcome, on_event);
                if ok {
                    self.guidance = Guidance::Goto {
                        goal_m: goal,
                        yaw_rad,
                    };
                }
            }
            MavCmd::MAV_CMD_DO_CHANGE_SPEED => {
                if p2.is_finite() && p2 > 0.0 && p2 <= 20.0 {
                    self.cruise_override_mps = Some(f64::from(p2));
                    self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED);
                } else if p2 == -1.0 || p2.is_nan() {
                    self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED);
                } else {
                    self.refuse(
                        from,
                        c.command,
                        &denied(format!("Change speed: {p2} m/s invalid")),
                        on_event,
                    );
                }
            }
            MavCmd::MAV_CMD_MISSION_START => {
                if p1.is_finite() && p1 >= 0.0 {
                    let seq = if p1 <= f32::from(u16::MAX) {
                        p1 as u16
                    } else {
                        u16::MAX
                    };
                    if let Err(why) = self.set_mission_current(seq) {
                        self.refuse(from, c.command, &denied(why), on_event);
                        return;
                    }
                } else if usize::from(self.mission_seq) >= self.missions.items().len() {
                    self.mission_seq = 0;
                }
                let outcome = self.commander.set_mode(FlightMode::AutoMission, &facts);
                self.outcome(from, c.command, outcome, on_event);
            }
            MavCmd::MAV_CMD_DO_SET_MISSION_CURRENT => {
                let seq = if p1.is_finite() && p1 >= 0.0 && p1 <= f32::from(u16::MAX) {
                    p1 as u16
                } else {
                    u16::MAX
                };
                match self.set_mission_current(seq) {
                    Ok(()) => self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED),
                    Err(why) => self.refuse(from, c.command, &denied(why), on_event),
                }
            }
            MavCmd::MAV_CMD_REQUEST_MESSAGE => {
                let id = p1;
                let msg = (id.is_finite() && id >= 0.0)
                    .then(|| self.message(id as u32))
                    .flatten();
                match msg {
                    Some(msg) => {
                        self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED);
                        self.send(&[msg]);
                    }
                    None => self.refuse(
                        from,
                        c.command,
                        &denied(format!("Request: message {id} not available")),
                        on_event,
                    ),
                }
            }
            MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES | MavCmd::MAV_CMD_GET_HOME_POSITION => {
                let id = if c.command == MavCmd::MAV_CMD_GET_HOME_POSITION {
                    HOME_POSITION_ID
                } else {
                    AUTOPILOT_VERSION_ID
                };
                self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED);
                if let Some(msg) = self.message(id) {
                    self.send(&[msg]);
                }
            }
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => match self.set_interval(p1, p2) {
                Ok(()) => self.ack(from, c.command, MavResult::MAV_RESULT_ACCEPTED),
                Err(reason) => self.refuse(from, c.command, &denied(reason), on_event),
            },
            other => {
                let _ = (p3, c.p5());
                self.ack(from, other, MavResult::MAV_RESULT_UNSUPPORTED);
            }
        }
    }

    /// MISSION_SET_CURRENT / DO_SET_MISSION_CURRENT: the next item to fly.
    pub(super) fn set_mission_current(&mut self, seq: u16) -> Result<(), String> {
        if usize::from(seq) >= self.missions.items().len() {
            return Err(format!("Mission: no item {seq}"));
        }
        self.mission_seq = seq;
        if self.commander.mode() == FlightMode::AutoMission {
            self.enter(FlightMode::AutoMission);
        }
        let msg = self.mission_current();
        self.send(&[msg]);
        Ok(())
    }

    /// MAV_CMD_SET_MESSAGE_INTERVAL: param1 message id, param2 interval µs (−1 off, 0 default).
    pub(super) fn set_interval(&mut self, id: f32, interval_us: f32) -> Result<(), String> {
        if !(id.is_finite() && interval_us.is_finite()) {
            return Err("Interval: parameters not finite".to_owned());
        }
        let id = id as u32;
        if PER_STEP_IDS.contains(&id) {
            return Err(format!("Interval: message {id} is sent every step"));
        }
        let Some(stream) = self.streams.iter_mut().find(|s| s.id == id) else {
            return Err(format!("Interval: message {id} not streamed"));
        };
        stream.interval = if interval_us < 0.0 {
            None
        } else if interval_us == 0.0 {
            Some(stream.default)
        } else {
            // At most 1 kHz.
            Some(std::time::Duration::from_micros(
                interval_us.max(1000.0) as u64
            ))
        };
        stream.next = std::time::Instant::now();
        Ok(())
    }
}
