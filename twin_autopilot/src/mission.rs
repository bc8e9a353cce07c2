//! Missions: the items the autopilot flies in AUTO.MISSION, and MAVLink's mission protocol
//! (MISSION_INT) as PX4 serves it — upload (MISSION_COUNT → MISSION_REQUEST_INT … →
//! MISSION_ITEM_INT … → MISSION_ACK), download (MISSION_REQUEST_LIST → MISSION_COUNT →
//! MISSION_REQUEST_INT → MISSION_ITEM_INT … ← MISSION_ACK), clear (MISSION_CLEAR_ALL →
//! MISSION_ACK) and set current. Time arrives as an argument (`Instant`): the transfer's
//! re-requests and time-out are decided by the caller's clock.
//!
//! Items are checked as they arrive: a command the twin does not fly, a frame it cannot place,
//! a non-finite coordinate, or a point more than [`MAX_DISTANCE_M`] from the origin ends the
//! upload with a MISSION_ACK naming the problem; the mission flown before stays.
//! Only MAV_MISSION_TYPE_MISSION is stored: a fence or rally upload is answered
//! MAV_MISSION_UNSUPPORTED, a download of them with an empty list.

#![allow(
    deprecated,
    reason = "PX4 still serves the deprecated MISSION_ITEM, MISSION_REQUEST, MISSION_SET_CURRENT, frames and commands: so does the twin"
)]

use std::time::{Duration, Instant};

use mavlink::dialects::common::{
    MISSION_ACK_DATA, MISSION_COUNT_DATA, MISSION_ITEM_DATA, MISSION_ITEM_INT_DATA,
    MISSION_REQUEST_INT_DATA, MavCmd, MavFrame, MavMessage, MavMissionResult, MavMissionType,
};
use nalgebra::Vector3;

use crate::telemetry::{self, Home};

/// A transfer's peer silent this long gets its request again.
pub const RETRY_AFTER: Duration = Duration::from_millis(250);
/// After this many requests without an answer the transfer is abandoned.
pub const MAX_RETRIES: u32 = 8;
/// Most items a mission may hold.
pub const MAX_ITEMS: u16 = 500;
/// A mission point farther than this from the world origin is refused, m.
pub const MAX_DISTANCE_M: f64 = 10_000.0;

/// What an item makes the vehicle do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// Fly to the point; accepted within `acceptance_m` (None: NAV_ACC_RAD), then hold
    /// `hold_s`.
    Waypoint {
        /// Where, world, m.
        point_m: Vector3<f64>,
        /// Acceptance radius, m.
        acceptance_m: Option<f64>,
        /// Hold time, s.
        hold_s: f64,
        /// Heading (amstack yaw), if given.
        yaw_rad: Option<f64>,
    },
    /// Climb to the altitude (world z, m) above the current point (or `xy` if given).
    Takeoff {
        /// Altitude, world z, m.
        z_m: f64,
    },
    /// Fly to `xy` (if given) and land there; disarm on the ground.
    Land {
        /// Where to land, world x and y, m.
        xy_m: Option<(f64, f64)>,
    },
    /// Return to launch.
    ReturnToLaunch,
    /// Change the horizontal speed of the following items, m/s.
    ChangeSpeed {
        /// Speed, m/s.
        speed_mps: f64,
    },
}

/// One stored item: its wire form (for downloads) and what it does.
#[derive(Debug, Clone, PartialEq)]
pub struct Item {
    /// As received (seq rewritten to its index).
    pub wire: MISSION_ITEM_INT_DATA,
    /// What it does.
    pub action: Action,
}

/// Why an item is refused.
type Refusal = (MavMissionResult, String);

/// The world point of an item's x, y, z in its frame (x/y as MISSION_ITEM_INT carries them).
/// `None` in x/y means "here" (0, 0 in a global frame).
fn place(
    frame: MavFrame,
    x: i32,
    y: i32,
    z: f32,
    home: &Home,
) -> Result<(Option<(f64, f64)>, f64), Refusal> {
    if !z.is_finite() {
        return Err((
            MavMissionResult::MAV_MISSION_INVALID_PARAM7,
            "altitude not finite".into(),
        ));
    }
    let z = f64::from(z);
    let (xy, z_world) = match frame {
        MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT => {
            let xy = (x != 0 || y != 0)
                .then(|| telemetry::world_xy_of(home, f64::from(x) / 1e7, f64::from(y) / 1e7));
            (xy, z)
        }
        MavFrame::MAV_FRAME_GLOBAL | MavFrame::MAV_FRAME_GLOBAL_INT => {
            let xy = (x != 0 || y != 0)
                .then(|| telemetry::world_xy_of(home, f64::from(x) / 1e7, f64::from(y) / 1e7));
            (xy, z - home.alt_m)
        }
        MavFrame::MAV_FRAME_LOCAL_NED => {
            // MISSION_ITEM_INT: local x, y in 1e-4 m; NED → world.
            let (north, east) = (f64::from(x) / 1e4, f64::from(y) / 1e4);
            (Some((east, north)), -z)
        }
        f => {
            return Err((
                MavMissionResult::MAV_MISSION_UNSUPPORTED_FRAME,
                format!("frame {f:?} not supported"),
            ));
        }
    };
    if let Some((px, py)) = xy
        && !(px.is_finite() && py.is_finite() && px.hypot(py) <= MAX_DISTANCE_M)
    {
        return Err((
            MavMissionResult::MAV_MISSION_INVALID_PARAM5_X,
            "point too far from home".into(),
        ));
    }
    if !(z_world.is_finite() && z_world.abs() <= MAX_DISTANCE_M) {
        return Err((
            MavMissionResult::MAV_MISSION_INVALID_PARAM7,
            "altitude out of range".into(),
        ));
    }
    Ok((xy, z_world))
}

fn finite_or(v: f32, default: f64) -> f64 {
    if v.is_finite() { f64::from(v) } else { default }
}

/// What `item` does, or why it is refused.
pub fn action_of(item: &MISSION_ITEM_INT_DATA, home: &Home) -> Result<Action, Refusal> {
    match item.command {
        MavCmd::MAV_CMD_NAV_WAYPOINT => {
            let (xy, z) = place(item.frame, item.x, item.y, item.z, home)?;
            let Some((x, y)) = xy else {
                return Err((
                    MavMissionResult::MAV_MISSION_INVALID_PARAM5_X,
                    "waypoint without a position".into(),
                ));
            };
            let hold_s = finite_or(item.param1, 0.0);
            let acceptance = finite_or(item.param2, 0.0);
            if !(0.0..=3600.0).contains(&hold_s) {
                return Err((
                    MavMissionResult::MAV_MISSION_INVALID_PARAM1,
                    "hold time out of range".into(),
                ));
            }
            if !(0.0..=1000.0).contains(&acceptance) {
                return Err((
                    MavMissionResult::MAV_MISSION_INVALID_PARAM2,
                    "acceptance radius out of range".into(),
                ));
            }
            let yaw = item.param4;
            let yaw_rad = (yaw.is_finite() && yaw.abs() <= 360.0).then(|| {
                firmware_bridge::frames::world_yaw_from_ned_yaw(f64::from(yaw).to_radians())
            });
            Ok(Action::Waypoint {
                point_m: Vector3::new(x, y, z),
                acceptance_m: (acceptance > 0.0).then_some(acceptance),
                hold_s,
                yaw_rad,
            })
        }
        MavCmd::MAV_CMD_NAV_TAKEOFF => {
            let (_, z) = place(item.frame, item.x, item.y, item.z, home)?;
            Ok(Action::Takeoff { z_m: z })
        }
        MavCmd::MAV_CMD_NAV_LAND => {
            let (xy, _) = place(item.frame, item.x, item.y, 0.0, home)?;
            Ok(Action::Land { xy_m: xy })
        }
        MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH => Ok(Action::ReturnToLaunch),
        MavCmd::MAV_CMD_DO_CHANGE_SPEED => {
            let speed = item.param2;
            if !(speed.is_finite() && speed > 0.0 && speed <= 20.0) {
                return Err((
                    MavMissionResult::MAV_MISSION_INVALID_PARAM2,
                    "speed out of (0, 20] m/s".into(),
                ));
            }
            Ok(Action::ChangeSpeed {
                speed_mps: f64::from(speed),
            })
        }
        c => Err((
            MavMissionResult::MAV_MISSION_UNSUPPORTED,
            format!("{c:?} not supported"),
        )),
    }
}

/// MISSION_ITEM (float x/y) as MISSION_ITEM_INT.
pub fn item_int_of(item: &MISSION_ITEM_DATA) -> MISSION_ITEM_INT_DATA {
    let global = matches!(
        item.frame,
        MavFrame::MAV_FRAME_GLOBAL | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT
    );
    let scale = if global { 1e7 } else { 1e4 };
    let int = |v: f32| -> i32 {
        let v = f64::from(v) * scale;
        if v.is_finite() {
            // Saturating: an out-of-range value is refused later as too far.
            #[allow(clippy::cast_possible_truncation)]
            let i = v.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
            i
        } else {
            i32::MAX
        }
    };
    MISSION_ITEM_INT_DATA {
        param1: item.param1,
        param2: item.param2,
        param3: item.param3,
        param4: item.param4,
        x: int(item.x),
        y: int(item.y),
        z: item.z,
        seq: item.seq,
        command: item.command,
        target_system: item.target_system,
        target_component: item.target_component,
        frame: item.frame,
        current: item.current,
        autocontinue: item.autocontinue,
        mission_type: item.mission_type,
    }
}

/// The transfer in progress.
#[derive(Debug, Clone, PartialEq)]
enum Transfer {
    Idle,
    Upload {
        peer: (u8, u8),
        count: u16,
        items: Vec<Item>,
        asked: Instant,
        retries: u32,
    },
}

/// What the protocol did with a message.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// Nothing to report.
    None,
    /// A new mission is in place (uploaded or cleared).
    Replaced,
    /// An upload was refused or abandoned; why.
    Failed(String),
}

/// The stored mission and the transfer state.
#[derive(Debug, Clone, PartialEq)]
pub struct Missions {
    items: Vec<Item>,
    transfer: Transfer,
    /// Changes on every replacement (MISSION_ACK / MISSION_CURRENT opaque id).
    id: u32,
}

impl Default for Missions {
    fn default() -> Self {
        Self {
            items: Vec::new(),
            transfer: Transfer::Idle,
            id: 0,
        }
    }
}

fn ack(
    to: (u8, u8),
    result: MavMissionResult,
    mission_type: MavMissionType,
    id: u32,
) -> MavMessage {
    MavMessage::MISSION_ACK(MISSION_ACK_DATA {
        target_system: to.0,
        target_component: to.1,
        mavtype: result,
        mission_type,
        opaque_id: id,
    })
}

fn request(to: (u8, u8), seq: u16) -> MavMessage {
    MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
        seq,
        target_system: to.0,
        target_component: to.1,
        mission_type: MavMissionType::MAV_MISSION_TYPE_MISSION,
    })
}

impl Missions {
    /// The stored items.
    pub fn items(&self) -> &[Item] {
        &self.items
    }

    /// The mission's id (changes with every new mission).
    pub fn id(&self) -> u32 {
        self.id
    }

    /// Whether an upload is in progress.
    pub fn uploading(&self) -> bool {
        !matches!(self.transfer, Transfer::Idle)
    }

    /// MISSION_COUNT from `peer`: starts an upload (or answers at once for count 0 or a
    /// type the twin does not store).
    pub fn count(
        &mut self,
        peer: (u8, u8),
        c: &MISSION_COUNT_DATA,
        now: Instant,
        out: &mut Vec<MavMessage>,
    ) -> Outcome {
        if c.mission_type != MavMissionType::MAV_MISSION_TYPE_MISSION {
            out.push(ack(
                peer,
                MavMissionResult::MAV_MISSION_UNSUPPORTED,
                c.mission_type,
                self.id,
            ));
            return Outcome::Failed(format!("{:?} not supported", c.mission_type));
        }
        if c.count > MAX_ITEMS {
            out.push(ack(
                peer,
                MavMissionResult::MAV_MISSION_NO_SPACE,
                c.mission_type,
                self.id,
            ));
            return Outcome::Failed(format!("{} items: at most {MAX_ITEMS}", c.count));
        }
        if c.count == 0 {
            self.items.clear();
            self.transfer = Transfer::Idle;
            self.id = self.id.wrapping_add(1);
            out.push(ack(
                peer,
                MavMissionResult::MAV_MISSION_ACCEPTED,
                c.mission_type,
                self.id,
            ));
            return Outcome::Replaced;
        }
        self.transfer = Transfer::Upload {
            peer,
            count: c.count,
            items: Vec::with_capacity(usize::from(c.count)),
            asked: now,
            retries: 0,
        };
        out.push(request(peer, 0));
        Outcome::None
    }

    /// MISSION_ITEM_INT (or a converted MISSION_ITEM) from `peer`.
    pub fn item(
        &mut self,
        peer: (u8, u8),
        item: &MISSION_ITEM_INT_DATA,
        home: &Home,
        now: Instant,
        out: &mut Vec<MavMessage>,
    ) -> Outcome {
        let Transfer::Upload {
            peer: p,
            count,
            items,
            asked,
            retries,
        } = &mut self.transfer
        else {
            // PX4 ignores items outside an upload.
            return Outcome::None;
        };
        if *p != peer || item.mission_type != MavMissionType::MAV_MISSION_TYPE_MISSION {
            return Outcome::None;
        }
        let expected = u16::try_from(items.len()).unwrap_or(u16::MAX);
        if item.seq != expected {
            // A repeat or a jump: ask again for the one expected.
            out.push(request(peer, expected));
            *asked = now;
            return Outcome::None;
        }
        match action_of(item, home) {
            Ok(action) => {
                let mut wire = item.clone();
                wire.seq = expected;
                items.push(Item { wire, action });
                *retries = 0;
                *asked = now;
                if items.len() == usize::from(*count) {
                    self.items = std::mem::take(items);
                    self.transfer = Transfer::Idle;
                    self.id = self.id.wrapping_add(1);
                    out.push(ack(
                        peer,
                        MavMissionResult::MAV_MISSION_ACCEPTED,
                        MavMissionType::MAV_MISSION_TYPE_MISSION,
                        self.id,
                    ));
                    Outcome::Replaced
                } else {
                    out.push(request(peer, expected + 1));
                    Outcome::None
                }
            }
            Err((result, why)) => {
                self.transfer = Transfer::Idle;
                out.push(ack(
                    peer,
                    result,
                    MavMissionType::MAV_MISSION_TYPE_MISSION,
                    self.id,
                ));
                Outcome::Failed(format!("item {}: {why}", item.seq))
            }
        }
    }

    /// Re-requests a silent peer's next item; abandons the upload after [`MAX_RETRIES`].
    pub fn poll(&mut self, now: Instant, out: &mut Vec<MavMessage>) -> Outcome {
        let Transfer::Upload {
            peer,
            items,
            asked,
            retries,
            ..
        } = &mut self.transfer
        else {
            return Outcome::None;
        };
        if now.duration_since(*asked) < RETRY_AFTER {
            return Outcome::None;
        }
        if *retries >= MAX_RETRIES {
            let peer = *peer;
            self.transfer = Transfer::Idle;
            out.push(ack(
                peer,
                MavMissionResult::MAV_MISSION_OPERATION_CANCELLED,
                MavMissionType::MAV_MISSION_TYPE_MISSION,
                self.id,
            ));
            return Outcome::Failed("upload timed out".into());
        }
        *retries += 1;
        *asked = now;
        out.push(request(
            *peer,
            u16::try_from(items.len()).unwrap_or(u16::MAX),
        ));
        Outcome::None
    }

    /// MISSION_REQUEST_LIST: the count (0 for fence and rally).
    pub fn request_list(
        &self,
        peer: (u8, u8),
        mission_type: MavMissionType,
        out: &mut Vec<MavMessage>,
    ) {
        let count = if mission_type == MavMissionType::MAV_MISSION_TYPE_MISSION {
            u16::try_from(self.items.len()).unwrap_or(u16::MAX)
        } else {
            0
        };
        out.push(MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
            count,
            target_system: peer.0,
            target_component: peer.1,
            mission_type,
            opaque_id: self.id,
        }));
    }

    /// MISSION_REQUEST_INT / MISSION_REQUEST of a download: the item, or MISSION_ACK
    /// INVALID_SEQUENCE.
    pub fn request_item(
        &self,
        peer: (u8, u8),
        seq: u16,
        mission_type: MavMissionType,
        out: &mut Vec<MavMessage>,
    ) {
        match self.items.get(usize::from(seq)) {
            Some(item) if mission_type == MavMissionType::MAV_MISSION_TYPE_MISSION => {
                let mut wire = item.wire.clone();
                wire.target_system = peer.0;
                wire.target_component = peer.1;
                wire.seq = seq;
                out.push(MavMessage::MISSION_ITEM_INT(wire));
            }
            _ => out.push(ack(
                peer,
                MavMissionResult::MAV_MISSION_INVALID_SEQUENCE,
                mission_type,
                self.id,
            )),
        }
    }

    /// MISSION_CLEAR_ALL.
    pub fn clear(
        &mut self,
        peer: (u8, u8),
        mission_type: MavMissionType,
        out: &mut Vec<MavMessage>,
    ) -> Outcome {
        let ours = matches!(
            mission_type,
            MavMissionType::MAV_MISSION_TYPE_MISSION | MavMissionType::MAV_MISSION_TYPE_ALL
        );
        if ours {
            self.items.clear();
            self.transfer = Transfer::Idle;
            self.id = self.id.wrapping_add(1);
        }
        out.push(ack(
            peer,
            MavMissionResult::MAV_MISSION_ACCEPTED,
            mission_type,
            self.id,
        ));
        if ours {
            Outcome::Replaced
        } else {
            Outcome::None
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use crate::telemetry::HOME;

    fn wp(seq: u16, north_m: f64, z: f32) -> MISSION_ITEM_INT_DATA {
        let (lat, lon) = telemetry::lat_lon_deg(&HOME, north_m, 0.0);
        #[allow(clippy::cast_possible_truncation)]
        MISSION_ITEM_INT_DATA {
            seq,
            command: MavCmd::MAV_CMD_NAV_WAYPOINT,
            frame: MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            x: (lat * 1e7).round() as i32,
            y: (lon * 1e7).round() as i32,
            z,
            ..MISSION_ITEM_INT_DATA::default()
        }
    }

    #[test]
    fn an_upload_requests_every_item_and_acks_and_a_bad_item_keeps_the_old_mission() {
        let mut m = Missions::default();
        let now = Instant::now();
        let peer = (255, 190);
        let mut out = Vec::new();
        m.count(
            peer,
            &MISSION_COUNT_DATA {
                count: 2,
                ..MISSION_COUNT_DATA::default()
            },
            now,
            &mut out,
        );
        assert!(matches!(&out[0], MavMessage::MISSION_REQUEST_INT(r) if r.seq == 0));
        out.clear();
        assert_eq!(
            m.item(peer, &wp(0, 1.0, 2.0), &HOME, now, &mut out),
            Outcome::None
        );
        assert!(matches!(&out[0], MavMessage::MISSION_REQUEST_INT(r) if r.seq == 1));
        out.clear();
        assert_eq!(
            m.item(peer, &wp(1, 2.0, 2.0), &HOME, now, &mut out),
            Outcome::Replaced
        );
        assert!(
            matches!(&out[0], MavMessage::MISSION_ACK(a) if a.mavtype == MavMissionResult::MAV_MISSION_ACCEPTED)
        );
        let Action::Waypoint { point_m, .. } = m.items()[1].action else {
            panic!()
        };
        // 2 m north is world +y; altitude 2 m above home.
        assert!(
            (point_m - Vector3::new(0.0, 2.0, 2.0)).norm() < 0.02,
            "{point_m}"
        );
        // A bad item (non-finite altitude) ends the next upload; the mission stays.
        out.clear();
        m.count(
            peer,
            &MISSION_COUNT_DATA {
                count: 1,
                ..MISSION_COUNT_DATA::default()
            },
            now,
            &mut out,
        );
        let r = m.item(peer, &wp(0, 1.0, f32::NAN), &HOME, now, &mut out);
        assert!(matches!(r, Outcome::Failed(_)), "{r:?}");
        assert_eq!(m.items().len(), 2);
        // Download.
        out.clear();
        m.request_list(peer, MavMissionType::MAV_MISSION_TYPE_MISSION, &mut out);
        m.request_item(peer, 1, MavMissionType::MAV_MISSION_TYPE_MISSION, &mut out);
        m.request_item(peer, 7, MavMissionType::MAV_MISSION_TYPE_MISSION, &mut out);
        assert!(matches!(&out[0], MavMessage::MISSION_COUNT(c) if c.count == 2));
        assert!(matches!(&out[1], MavMessage::MISSION_ITEM_INT(i) if i.seq == 1));
        assert!(
            matches!(&out[2], MavMessage::MISSION_ACK(a) if a.mavtype == MavMissionResult::MAV_MISSION_INVALID_SEQUENCE)
        );
    }

    #[test]
    fn a_silent_uploader_is_asked_again_then_given_up() {
        let mut m = Missions::default();
        let t0 = Instant::now();
        let mut out = Vec::new();
        m.count(
            (1, 2),
            &MISSION_COUNT_DATA {
                count: 3,
                ..MISSION_COUNT_DATA::default()
            },
            t0,
            &mut out,
        );
        let mut t = t0;
        let mut failed = false;
        for _ in 0..=MAX_RETRIES {
            t += RETRY_AFTER;
            failed |= matches!(m.poll(t, &mut out), Outcome::Failed(_));
        }
        assert!(failed);
        assert!(!m.uploading());
        assert_eq!(
            out.iter()
                .filter(|o| matches!(o, MavMessage::MISSION_REQUEST_INT(_)))
                .count(),
            1 + MAX_RETRIES as usize
        );
    }
}
