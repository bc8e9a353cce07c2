//! The messages of a link's own log channels: what a MAVLink autopilot says about itself
//! (`/autopilot/state`) and every frame on the wire (`/mavlink/raw`). A link returns them as
//! data ([`crate::Link::drain_messages`]); the flight log writes them
//! ([`crate::flight_log::FlightLog::link_messages`]). `docs/mcap-format.md` describes them.

use std::time::{Duration, Instant};

use firmware_bridge::{AutopilotState, CaptureStats, CounterSnapshot, RawFrame};
use schemars::JsonSchema;
use serde::Serialize;

use crate::record::SchemaName;

/// One message of a link's own channels.
#[derive(Debug, Clone)]
pub struct LinkMessage {
    /// Flight time the message belongs to, s.
    pub time_s: f64,
    /// The message.
    pub payload: LinkPayload,
}

/// The messages a link may log, each on its topic.
#[derive(Debug, Clone)]
pub enum LinkPayload {
    /// On [`AUTOPILOT_STATE_TOPIC`].
    AutopilotState(Box<AutopilotStateMessage>),
    /// On [`MAVLINK_RAW_TOPIC`].
    MavlinkRaw(Box<MavlinkRawFrame>),
}

impl LinkPayload {
    /// The topic the message is logged on.
    pub fn topic(&self) -> &'static str {
        match self {
            Self::AutopilotState(_) => AUTOPILOT_STATE_TOPIC,
            Self::MavlinkRaw(_) => MAVLINK_RAW_TOPIC,
        }
    }
}

fn v3_option(v: Option<&nalgebra::Vector3<f64>>) -> [Option<f64>; 3] {
    v.map_or([None; 3], |v| [Some(v.x), Some(v.y), Some(v.z)])
}

impl SchemaName for AutopilotStateMessage {
    const SCHEMA_NAME: &'static str = "amstack.AutopilotState";
}
impl SchemaName for MavlinkRawFrame {
    const SCHEMA_NAME: &'static str = "amstack.MavlinkRaw";
}

/// Topic of [`AutopilotStateMessage`].
pub const AUTOPILOT_STATE_TOPIC: &str = "/autopilot/state";
/// Topic of [`MavlinkRawFrame`].
pub const MAVLINK_RAW_TOPIC: &str = "/mavlink/raw";

/// What a MAVLink autopilot says about itself, and the bridge's view of the link, as the
/// flight side knew it when a measurement arrived (MAVLink flights; schema
/// `amstack.AutopilotState`).
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct AutopilotStateMessage {
    /// Armed (the last HEARTBEAT's base_mode has MAV_MODE_FLAG_SAFETY_ARMED).
    pub armed: bool,
    /// PX4 custom_mode of the last HEARTBEAT (`main << 16 | sub << 24`).
    pub custom_mode: u32,
    /// PX4 main mode (3 POSCTL, 4 AUTO, 6 OFFBOARD, …).
    pub main_mode: u8,
    /// PX4 sub mode (AUTO: 3 LOITER, 6 LAND).
    pub sub_mode: u8,
    /// The mode's name (`OFFBOARD`, `AUTO.LOITER`, `MODE(9.0)`).
    pub mode: String,
    /// The main mode is OFFBOARD.
    pub offboard: bool,
    /// MAV_STATE of the last HEARTBEAT (`MAV_STATE_ACTIVE`, …); null before one.
    pub system_status: Option<String>,
    /// MAV_LANDED_STATE of the last EXTENDED_SYS_STATE; null before one.
    pub landed_state: Option<String>,
    /// Battery voltage of the last SYS_STATUS, V; null when unknown.
    pub battery_voltage_v: Option<f64>,
    /// HEARTBEATs received from the autopilot so far.
    pub heartbeats: u64,
    /// Wall-clock time since the last HEARTBEAT, s; null before one.
    pub heartbeat_age_s: Option<f64>,
    /// Last HIGHRES_IMU specific force, `base` (FLU), m/s²; nulls before one.
    pub imu_accel_body_mps2: [Option<f64>; 3],
    /// Last HIGHRES_IMU angular rate, `base` (FLU), rad/s; nulls before one.
    pub imu_gyro_body_radps: [Option<f64>; 3],
    /// Telemetry values ignored as non-finite or malformed.
    pub rejected_values: u64,
    /// The bridge's counters since the link opened.
    pub link: LinkCounters,
}

/// The bridge's counters of an [`AutopilotStateMessage`], since the link opened.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct LinkCounters {
    /// Frames decoded and accepted.
    pub frames_ok: u64,
    /// Frames sent.
    pub frames_sent: u64,
    /// Bytes skipped while looking for a start byte.
    pub garbage_bytes: u64,
    /// Frames with a bad CRC.
    pub bad_crc: u64,
    /// Frames with a message id outside the `common` dialect.
    pub unknown_id: u64,
    /// Frames cut short, or with unknown incompatibility flags.
    pub truncated: u64,
    /// Unsigned frames refused (signing required).
    pub refused_unsigned: u64,
    /// Frames refused for a bad signature or a replayed timestamp.
    pub refused_bad_signature: u64,
    /// Frames whose payload the dialect could not parse.
    pub undecodable: u64,
    /// Frames captured for `/mavlink/raw` (0 without the capture).
    pub raw_frames_captured: u64,
    /// Frames the capture dropped because its queue was full (not on `/mavlink/raw`).
    pub raw_frames_dropped: u64,
}

impl AutopilotStateMessage {
    /// The message of the bridge's state and counters.
    pub fn new(
        state: &AutopilotState,
        heartbeat_age: Option<Duration>,
        rejected_values: u64,
        counters: &CounterSnapshot,
        capture: Option<CaptureStats>,
    ) -> Self {
        let (main_mode, sub_mode) = firmware_bridge::telemetry::px4_mode::split(state.custom_mode);
        let capture = capture.unwrap_or_default();
        Self {
            armed: state.armed,
            custom_mode: state.custom_mode,
            main_mode,
            sub_mode,
            mode: state.mode_name(),
            offboard: state.in_offboard(),
            system_status: state.system_status.clone(),
            landed_state: state.landed_state.clone(),
            battery_voltage_v: state.battery_voltage_v,
            heartbeats: state.heartbeats,
            heartbeat_age_s: heartbeat_age.map(|d| d.as_secs_f64()),
            imu_accel_body_mps2: v3_option(state.imu_accel_in_body_mps2.as_ref()),
            imu_gyro_body_radps: v3_option(state.imu_gyro_in_body_radps.as_ref()),
            rejected_values,
            link: LinkCounters {
                frames_ok: counters.frames_ok,
                frames_sent: counters.frames_sent,
                garbage_bytes: counters.garbage_bytes,
                bad_crc: counters.bad_crc,
                unknown_id: counters.unknown_id,
                truncated: counters.truncated,
                refused_unsigned: counters.refused_unsigned,
                refused_bad_signature: counters.refused_bad_signature,
                undecodable: counters.undecodable,
                raw_frames_captured: capture.captured,
                raw_frames_dropped: capture.dropped,
            },
        }
    }
}

/// One MAVLink frame received from or sent to the autopilot, bytes as on the wire (MAVLink
/// flights; schema `amstack.MavlinkRaw`). Log time: `flight_time_s`.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct MavlinkRawFrame {
    /// `in` (received and accepted by the bridge) or `out` (sent by the bridge).
    pub direction: String,
    /// Message id (`331` ODOMETRY, `139` SET_ACTUATOR_CONTROL_TARGET, …).
    pub message_id: u32,
    /// Message name in the `common` dialect (`ODOMETRY`).
    pub message_name: String,
    /// Sender's system id.
    pub system_id: u8,
    /// Sender's component id.
    pub component_id: u8,
    /// The frame's sequence number.
    pub sequence: u8,
    /// The frame carries a MAVLink 2 signature.
    pub signed: bool,
    /// Wall-clock time the bridge received (in) or sent (out) it, s since the link was
    /// opened (the start of `amstack fly`'s flight).
    pub wall_time_s: f64,
    /// Time of the newest measurement the bridge had then, s (for an ODOMETRY in, its own).
    pub flight_time_s: f64,
    /// The whole frame, lower-case hexadecimal: start byte 0xFD to the CRC, then the
    /// signature when signed.
    pub bytes_hex: String,
}

impl MavlinkRawFrame {
    /// The message of a captured frame; `opened` is the wall-clock origin.
    pub fn new(frame: &RawFrame, opened: Instant) -> Self {
        Self {
            direction: frame.direction.name().to_owned(),
            message_id: frame.message_id,
            message_name: frame.message_name.to_owned(),
            system_id: frame.system_id,
            component_id: frame.component_id,
            sequence: frame.sequence,
            signed: frame.signed(),
            wall_time_s: frame.at.saturating_duration_since(opened).as_secs_f64(),
            flight_time_s: frame.flight_time_s,
            bytes_hex: firmware_bridge::capture::to_hex(&frame.bytes),
        }
    }
}
