//! PX4's flight modes as MAVLink carries them (HEARTBEAT `custom_mode`, DO_SET_MODE), and the
//! autopilot's commander: arming, mode switches and the offboard-loss failsafe, as a pure state
//! machine (time arrives as arguments).

use std::fmt;

// PX4's mode numbers and their `custom_mode` encoding: the bridge's, one definition for both
// ends of the link.
use firmware_bridge::telemetry::px4_mode;
/// The flight modes the twin's autopilot flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlightMode {
    /// Position hold with the internal controller (no RC: sticks centred). The mode at start.
    Posctl,
    /// The offboard setpoints fly the vehicle.
    Offboard,
    /// Hold position with the internal controller (also the offboard-loss failsafe).
    AutoLoiter,
    /// Descend at MPC_LAND_SPEED with the internal controller, disarm on the ground.
    AutoLand,
    /// Climb at MPC_TKO_SPEED to the takeoff altitude, then AUTO.LOITER.
    AutoTakeoff,
    /// Fly the uploaded mission.
    AutoMission,
    /// Climb to RTL_RETURN_ALT, return above home, land, disarm.
    AutoRtl,
}

impl FlightMode {
    /// `custom_mode` in PX4's encoding: `main_mode << 16 | sub_mode << 24`.
    pub fn custom_mode(self) -> u32 {
        let (main, sub) = self.main_and_sub();
        px4_mode::custom_mode(main, sub)
    }

    /// (main mode, sub mode).
    pub fn main_and_sub(self) -> (u8, u8) {
        match self {
            Self::Posctl => (px4_mode::POSCTL, 0),
            Self::Offboard => (px4_mode::OFFBOARD, 0),
            Self::AutoLoiter => (px4_mode::AUTO, px4_mode::AUTO_LOITER),
            Self::AutoLand => (px4_mode::AUTO, px4_mode::AUTO_LAND),
            Self::AutoTakeoff => (px4_mode::AUTO, px4_mode::AUTO_TAKEOFF),
            Self::AutoMission => (px4_mode::AUTO, px4_mode::AUTO_MISSION),
            Self::AutoRtl => (px4_mode::AUTO, px4_mode::AUTO_RTL),
        }
    }

    /// The mode a DO_SET_MODE asks for (param2 main mode, param3 sub mode); `Err` names a mode
    /// this autopilot does not fly.
    pub fn from_main_and_sub(main: u8, sub: u8) -> Result<Self, String> {
        match (main, sub) {
            (px4_mode::POSCTL, _) => Ok(Self::Posctl),
            (px4_mode::OFFBOARD, _) => Ok(Self::Offboard),
            (px4_mode::AUTO, px4_mode::AUTO_LOITER) => Ok(Self::AutoLoiter),
            (px4_mode::AUTO, px4_mode::AUTO_LAND) => Ok(Self::AutoLand),
            (px4_mode::AUTO, px4_mode::AUTO_TAKEOFF) => Ok(Self::AutoTakeoff),
            (px4_mode::AUTO, px4_mode::AUTO_MISSION) => Ok(Self::AutoMission),
            (px4_mode::AUTO, px4_mode::AUTO_RTL) => Ok(Self::AutoRtl),
            (px4_mode::MANUAL | px4_mode::ALTCTL | px4_mode::ACRO | px4_mode::STABILIZED, _) => {
                Err(format!("mode {main} needs RC sticks (the twin has none)"))
            }
            (px4_mode::AUTO, s) => Err(format!("AUTO sub mode {s} not supported")),
            (m, _) => Err(format!("unknown main mode {m}")),
        }
    }

    /// Whether the internal controller flies this mode (not the offboard setpoints).
    pub fn is_internal(self) -> bool {
        !matches!(self, Self::Offboard)
    }
}

impl fmt::Display for FlightMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Posctl => "POSCTL",
            Self::Offboard => "OFFBOARD",
            Self::AutoLoiter => "AUTO.LOITER",
            Self::AutoLand => "AUTO.LAND",
            Self::AutoTakeoff => "AUTO.TAKEOFF",
            Self::AutoMission => "AUTO.MISSION",
            Self::AutoRtl => "AUTO.RTL",
        })
    }
}

/// What the commander knows about the vehicle when it decides.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleFacts {
    /// Whether a setpoint arrived within the offboard timeout.
    pub setpoints_streaming: bool,
    /// Base speed, m/s.
    pub speed_mps: f64,
    /// Whether the vehicle is in the air (above its resting height while the twin runs).
    pub in_air: bool,
    /// Whether an uploaded mission exists (AUTO.MISSION needs one).
    pub has_mission: bool,
}

/// What the offboard-loss failsafe does: PX4's COM_OBL_RC_ACT values the twin flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LossAction {
    /// 0: POSCTL (sticks centred: hold), until a commanded mode.
    Position,
    /// 3: AUTO.RTL.
    Return,
    /// 4: AUTO.LAND.
    Land,
    /// 5: AUTO.LOITER for the failsafe's hold time, then AUTO.LAND (the twin's default).
    HoldThenLand,
}

impl LossAction {
    /// From COM_OBL_RC_ACT (values the twin does not fly: hold then land).
    pub fn from_param(value: f64) -> Self {
        match value.round() as i64 {
            0 => Self::Position,
            3 => Self::Return,
            4 => Self::Land,
            _ => Self::HoldThenLand,
        }
    }
}

/// A command the commander refused, with PX4-like wording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    /// Temporarily rejected (retry may work) rather than denied.
    pub temporary: bool,
    /// The reason, ≤ 50 characters (one STATUSTEXT).
    pub reason: String,
}

impl Refusal {
    fn denied(reason: impl Into<String>) -> Self {
        Self {
            temporary: false,
            reason: reason.into(),
        }
    }

    fn temporary(reason: impl Into<String>) -> Self {
        Self {
            temporary: true,
            reason: reason.into(),
        }
    }
}

/// PX4's magic param2 of MAV_CMD_COMPONENT_ARM_DISARM that forces a disarm in the air.
pub const FORCE_DISARM_MAGIC: f32 = 21196.0;

/// Faster than this, the vehicle is not at rest and arming is refused, m/s.
pub const ARMING_MAX_SPEED_MPS: f64 = 0.3;

/// Where the offboard-loss failsafe is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Failsafe {
    /// No failsafe.
    None,
    /// Holding position since this twin time, s.
    Holding {
        /// Twin time the hold started, s.
        since_s: f64,
    },
    /// Landing.
    Landing,
    /// Another action of COM_OBL_RC_ACT (position hold, return), until a commanded mode.
    Acting,
}

/// What changed, for the log (each with the twin time when it is applied).
#[derive(Debug, Clone, PartialEq)]
pub enum Transition {
    /// Armed.
    Armed,
    /// Disarmed, and why.
    Disarmed(&'static str),
    /// The mode changed, and why.
    Mode {
        /// New mode.
        mode: FlightMode,
        /// Why.
        why: &'static str,
    },
}

impl fmt::Display for Transition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Armed => f.write_str("armed"),
            Self::Disarmed(why) => write!(f, "disarmed ({why})"),
            Self::Mode { mode, why } => write!(f, "mode {mode} ({why})"),
        }
    }
}

/// Arming state, mode and failsafe of the autopilot.
#[derive(Debug, Clone, PartialEq)]
pub struct Commander {
    armed: bool,
    mode: FlightMode,
    failsafe: Failsafe,
    hold_s: f64,
}

impl Commander {
    /// Disarmed in POSCTL; the failsafe holds for `hold_s` before landing.
    pub fn new(hold_s: f64) -> Self {
        Self {
            armed: false,
            mode: FlightMode::Posctl,
            failsafe: Failsafe::None,
            hold_s,
        }
    }

    /// Whether armed.
    pub fn armed(&self) -> bool {
        self.armed
    }

    /// The current mode.
    pub fn mode(&self) -> FlightMode {
        self.mode
    }

    /// The failsafe's state.
    pub fn failsafe(&self) -> Failsafe {
        self.failsafe
    }

    /// MAV_CMD_COMPONENT_ARM_DISARM param1 = 1.
    pub fn arm(&mut self, facts: &VehicleFacts) -> Result<Option<Transition>, Refusal> {
        if self.armed {
            return Ok(None);
        }
        if self.failsafe != Failsafe::None {
            return Err(Refusal::denied("Arming denied: failsafe in progress"));
        }
        if facts.speed_mps.is_nan() || facts.speed_mps > ARMING_MAX_SPEED_MPS {
            return Err(Refusal::denied(format!(
                "Arming denied: moving at {:.2} m/s",
                facts.speed_mps
            )));
        }
        if self.mode == FlightMode::Offboard && !facts.setpoints_streaming {
            return Err(Refusal::denied("Arming denied: offboard, no setpoints"));
        }
        self.armed = true;
        Ok(Some(Transition::Armed))
    }

    /// MAV_CMD_COMPONENT_ARM_DISARM param1 = 0 (`force`: param2 = 21196). In the air a
    /// disarm stops the rotors and the vehicle falls: PX4 refuses it unless forced.
    pub fn disarm(
        &mut self,
        facts: &VehicleFacts,
        force: bool,
    ) -> Result<Option<Transition>, Refusal> {
        if !self.armed {
            return Ok(None);
        }
        if facts.in_air && !force {
            return Err(Refusal::denied(
                "Disarming denied: in the air (force 21196)",
            ));
        }
        Ok(Some(self.do_disarm(if force {
            "forced by command"
        } else {
            "by command"
        })))
    }

    fn do_disarm(&mut self, why: &'static str) -> Transition {
        self.armed = false;
        self.failsafe = Failsafe::None;
        // As PX4 after a landing: back to the default mode.
        if self.mode != FlightMode::Offboard {
            self.mode = FlightMode::Posctl;
        }
        Transition::Disarmed(why)
    }

    /// MAV_CMD_DO_SET_MODE / MAV_CMD_NAV_LAND.
    pub fn set_mode(
        &mut self,
        mode: FlightMode,
        facts: &VehicleFacts,
    ) -> Result<Option<Transition>, Refusal> {
        if mode == FlightMode::Offboard && !facts.setpoints_streaming {
            return Err(Refusal::temporary("Offboard denied: no setpoint stream"));
        }
        if mode == FlightMode::AutoMission && !facts.has_mission {
            return Err(Refusal::temporary("Mission denied: no mission uploaded"));
        }
        if matches!(
            mode,
            FlightMode::AutoTakeoff | FlightMode::AutoRtl | FlightMode::AutoLand
        ) && !self.armed
        {
            return Err(Refusal::denied(format!("{mode} denied: not armed")));
        }
        // A commanded mode ends the failsafe (the operator takes over, as in PX4).
        self.failsafe = Failsafe::None;
        if mode == self.mode {
            return Ok(None);
        }
        self.mode = mode;
        Ok(Some(Transition::Mode {
            mode,
            why: "commanded",
        }))
    }

    /// A mode change the autopilot makes itself (takeoff done → AUTO.LOITER, a mission's
    /// RTL item), armed or not; no requirement checked.
    pub fn switch(&mut self, mode: FlightMode, why: &'static str) -> Option<Transition> {
        if mode == self.mode {
            return None;
        }
        self.mode = mode;
        Some(Transition::Mode { mode, why })
    }

    /// Advances the failsafe at twin time `now_s`: offboard without setpoints → `action`
    /// (hold then land: AUTO.LOITER, after the hold AUTO.LAND); `landed` (on the ground, at
    /// rest) while landing (AUTO.LAND, AUTO.RTL, a mission's land) → disarm.
    pub fn update(
        &mut self,
        now_s: f64,
        setpoints_streaming: bool,
        landed: bool,
        action: LossAction,
    ) -> Option<Transition> {
        if !self.armed {
            return None;
        }
        match (self.mode, self.failsafe) {
            (FlightMode::Offboard, _) if !setpoints_streaming => {
                let (mode, failsafe, why) = match action {
                    LossAction::HoldThenLand => (
                        FlightMode::AutoLoiter,
                        Failsafe::Holding { since_s: now_s },
                        "failsafe: offboard setpoints lost, holding",
                    ),
                    LossAction::Land => (
                        FlightMode::AutoLand,
                        Failsafe::Landing,
                        "failsafe: offboard setpoints lost, landing",
                    ),
                    LossAction::Return => (
                        FlightMode::AutoRtl,
                        Failsafe::Acting,
                        "failsafe: offboard setpoints lost, returning",
                    ),
                    LossAction::Position => (
                        FlightMode::Posctl,
                        Failsafe::Acting,
                        "failsafe: offboard setpoints lost, position hold",
                    ),
                };
                self.mode = mode;
                self.failsafe = failsafe;
                Some(Transition::Mode { mode, why })
            }
            (FlightMode::AutoLoiter, Failsafe::Holding { since_s })
                if now_s - since_s >= self.hold_s =>
            {
                self.mode = FlightMode::AutoLand;
                self.failsafe = Failsafe::Landing;
                Some(Transition::Mode {
                    mode: FlightMode::AutoLand,
                    why: "failsafe: hold over, landing",
                })
            }
            (FlightMode::AutoLand | FlightMode::AutoRtl | FlightMode::AutoMission, _) if landed => {
                Some(self.do_disarm("landed"))
            }
            _ => None,
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    fn facts(streaming: bool) -> VehicleFacts {
        VehicleFacts {
            setpoints_streaming: streaming,
            speed_mps: 0.0,
            in_air: false,
            has_mission: false,
        }
    }

    impl Commander {
        fn update_hold(&mut self, now_s: f64, streaming: bool, landed: bool) -> Option<Transition> {
            self.update(now_s, streaming, landed, LossAction::HoldThenLand)
        }
    }

    #[test]
    fn the_loss_action_follows_com_obl_rc_act_and_auto_modes_have_requirements() {
        let mut c = Commander::new(5.0);
        assert!(
            c.set_mode(FlightMode::AutoMission, &facts(false))
                .unwrap_err()
                .temporary
        );
        assert!(c.set_mode(FlightMode::AutoTakeoff, &facts(false)).is_err());
        c.set_mode(FlightMode::Offboard, &facts(true)).unwrap();
        c.arm(&facts(true)).unwrap();
        let t = c.update(1.0, false, false, LossAction::Land).unwrap();
        assert!(matches!(
            t,
            Transition::Mode {
                mode: FlightMode::AutoLand,
                ..
            }
        ));
        c.set_mode(FlightMode::Offboard, &facts(true)).unwrap();
        let t = c.update(2.0, false, false, LossAction::Return).unwrap();
        assert!(matches!(
            t,
            Transition::Mode {
                mode: FlightMode::AutoRtl,
                ..
            }
        ));
        assert_eq!(
            c.update(3.0, false, true, LossAction::Return),
            Some(Transition::Disarmed("landed"))
        );
        assert_eq!(LossAction::from_param(0.0), LossAction::Position);
        assert_eq!(LossAction::from_param(5.0), LossAction::HoldThenLand);
    }

    #[test]
    fn custom_modes_are_px4s_encoding() {
        // PX4 OFFBOARD = 6 << 16 = 393216; AUTO.LOITER = 4 << 16 | 3 << 24 = 50593792;
        // AUTO.LAND = 4 << 16 | 6 << 24 = 100925440; POSCTL = 3 << 16 = 196608.
        assert_eq!(FlightMode::Offboard.custom_mode(), 393_216);
        assert_eq!(FlightMode::AutoLoiter.custom_mode(), 50_593_792);
        assert_eq!(FlightMode::AutoLand.custom_mode(), 100_925_440);
        assert_eq!(FlightMode::Posctl.custom_mode(), 196_608);
        for m in [
            FlightMode::Posctl,
            FlightMode::Offboard,
            FlightMode::AutoLoiter,
            FlightMode::AutoLand,
            FlightMode::AutoTakeoff,
            FlightMode::AutoMission,
            FlightMode::AutoRtl,
        ] {
            let (main, sub) = m.main_and_sub();
            assert_eq!(FlightMode::from_main_and_sub(main, sub).unwrap(), m);
        }
        assert!(FlightMode::from_main_and_sub(px4_mode::MANUAL, 0).is_err());
        assert!(FlightMode::from_main_and_sub(px4_mode::AUTO, 7).is_err());
        assert!(FlightMode::from_main_and_sub(42, 0).is_err());
    }

    #[test]
    fn offboard_needs_a_setpoint_stream_and_arming_in_offboard_too() {
        let mut c = Commander::new(5.0);
        let refused = c.set_mode(FlightMode::Offboard, &facts(false)).unwrap_err();
        assert!(refused.temporary, "{refused:?}");
        assert_eq!(c.mode(), FlightMode::Posctl);
        c.set_mode(FlightMode::Offboard, &facts(true)).unwrap();
        assert_eq!(c.mode(), FlightMode::Offboard);
        let refused = c.arm(&facts(false)).unwrap_err();
        assert!(!refused.temporary && refused.reason.contains("setpoints"));
        assert!(!c.armed());
        assert_eq!(c.arm(&facts(true)).unwrap(), Some(Transition::Armed));
        assert!(c.armed());
    }

    #[test]
    fn arming_refused_while_moving() {
        let mut c = Commander::new(5.0);
        let moving = VehicleFacts {
            speed_mps: 1.0,
            ..facts(true)
        };
        assert!(c.arm(&moving).unwrap_err().reason.contains("moving"));
        let nan = VehicleFacts {
            speed_mps: f64::NAN,
            ..facts(true)
        };
        assert!(c.arm(&nan).is_err());
    }

    #[test]
    fn disarm_in_the_air_needs_force() {
        let mut c = Commander::new(5.0);
        c.arm(&facts(false)).unwrap();
        let flying = VehicleFacts {
            in_air: true,
            ..facts(false)
        };
        assert!(c.disarm(&flying, false).is_err());
        assert!(c.armed());
        c.disarm(&flying, true).unwrap();
        assert!(!c.armed());
    }

    #[test]
    fn offboard_loss_holds_then_lands_then_disarms() {
        let mut c = Commander::new(5.0);
        c.set_mode(FlightMode::Offboard, &facts(true)).unwrap();
        c.arm(&facts(true)).unwrap();
        assert_eq!(c.update_hold(1.0, true, false), None);
        let t = c.update_hold(2.0, false, false).unwrap();
        assert!(matches!(
            t,
            Transition::Mode {
                mode: FlightMode::AutoLoiter,
                ..
            }
        ));
        assert_eq!(c.failsafe(), Failsafe::Holding { since_s: 2.0 });
        // Setpoints coming back do not end the failsafe by themselves (PX4 needs a mode switch).
        assert_eq!(c.update_hold(6.99, true, false), None);
        let t = c.update_hold(7.0, false, false).unwrap();
        assert!(matches!(
            t,
            Transition::Mode {
                mode: FlightMode::AutoLand,
                ..
            }
        ));
        assert_eq!(c.update_hold(8.0, false, false), None);
        assert_eq!(
            c.update_hold(9.0, false, true),
            Some(Transition::Disarmed("landed"))
        );
        assert!(!c.armed());
        assert_eq!(c.failsafe(), Failsafe::None);
        // Arming is refused during a failsafe, allowed after.
        assert!(c.arm(&facts(false)).is_ok());
    }
}
