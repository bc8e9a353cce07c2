//! MAVLink 2 frames on the wire: splitting received bytes into frames (counting everything
//! that is not a good one), signature checks, and encoding outgoing messages.
//!
//! The parser is ours rather than the `mavlink` crate's reader so that every rejected byte is
//! counted by kind; the crate decodes payloads, computes CRCs and signatures.

use mavlink::dialects::common::MavMessage;
use mavlink::{
    MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message, SigningConfig, SigningData,
};

/// MAVLink 2 start byte.
const STX_V2: u8 = 0xFD;
/// MAVLink 1 start byte.
const STX_V1: u8 = 0xFE;
/// Bytes after STX up to the payload: len, incompat, compat, seq, sysid, compid, msgid[3].
const HEADER: usize = 9;
/// The signed incompatibility flag.
const IFLAG_SIGNED: u8 = 0x01;
/// Signature block: link id, 6-byte timestamp, 6-byte signature.
const SIGNATURE: usize = 13;
/// Largest frame.
pub const MAX_FRAME: usize = 1 + HEADER + 255 + 2 + SIGNATURE;

/// What the receive side saw, by kind. Every frame is counted once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LinkCounters {
    /// Frames decoded and accepted.
    pub frames_ok: u64,
    /// Frames whose checksum did not match.
    pub bad_crc: u64,
    /// Frames of a message id the common dialect does not have.
    pub unknown_id: u64,
    /// Frames cut short (a datagram ended inside one).
    pub truncated: u64,
    /// Frames whose payload did not decode (e.g. an enum value out of range).
    pub bad_payload: u64,
    /// Unsigned frames refused because signing is required.
    pub unsigned_refused: u64,
    /// Signed frames whose signature (or timestamp) was wrong.
    pub bad_signature: u64,
    /// MAVLink 1 frames, or MAVLink 2 frames with unknown incompatibility flags: ignored.
    pub unsupported: u64,
    /// Bytes skipped while looking for a start byte.
    pub junk_bytes: u64,
    /// Well-formed messages the autopilot ignores as input (a non-finite setpoint, a quaternion
    /// of the wrong norm, a command for another system...).
    pub rejected_input: u64,
}

impl LinkCounters {
    /// Frames refused for any reason (everything but `frames_ok`, `junk_bytes` and
    /// `rejected_input`).
    pub fn bad_frames(&self) -> u64 {
        self.bad_crc
            + self.unknown_id
            + self.truncated
            + self.bad_payload
            + self.unsigned_refused
            + self.bad_signature
            + self.unsupported
    }

    /// SYS_STATUS `drop_rate_comm`: bad frames per frames received, in c% (0–10000).
    pub fn drop_rate_centi_percent(&self) -> u16 {
        let bad = self.bad_frames();
        let total = bad + self.frames_ok;
        if total == 0 {
            return 0;
        }
        u16::try_from(bad * 10_000 / total).unwrap_or(10_000)
    }
}

impl std::fmt::Display for LinkCounters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "frames ok {}, bad crc {}, unknown id {}, truncated {}, bad payload {}, unsigned refused {}, bad signature {}, unsupported {}, junk bytes {}, rejected input {}",
            self.frames_ok,
            self.bad_crc,
            self.unknown_id,
            self.truncated,
            self.bad_payload,
            self.unsigned_refused,
            self.bad_signature,
            self.unsupported,
            self.junk_bytes,
            self.rejected_input
        )
    }
}

/// A decoded frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Received {
    /// Its header.
    pub header: MavHeader,
    /// Its message.
    pub message: MavMessage,
}

/// MAVLink 2 signing settings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Signing {
    /// The 32-byte secret key.
    pub key: [u8; 32],
    /// Link id written into outgoing signatures.
    pub link_id: u8,
    /// Refuse unsigned frames.
    pub require: bool,
}

impl Signing {
    /// A key file: 32 raw bytes, or 64 hexadecimal digits (surrounding whitespace ignored).
    pub fn key_from_file_bytes(bytes: &[u8]) -> Result<[u8; 32], String> {
        let text = std::str::from_utf8(bytes).ok().map(str::trim);
        if let Some(hex) =
            text.filter(|t| t.len() == 64 && t.chars().all(|c| c.is_ascii_hexdigit()))
        {
            let mut key = [0u8; 32];
            for (i, k) in key.iter_mut().enumerate() {
                *k = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16)
                    .map_err(|e| format!("hex digit: {e}"))?;
            }
            return Ok(key);
        }
        <[u8; 32]>::try_from(bytes).map_err(|_| {
            format!(
                "{} bytes: a key is 32 raw bytes or 64 hexadecimal digits",
                bytes.len()
            )
        })
    }
}

/// Frames in and out of one link: parser state, counters, signing, sequence numbers.
pub struct Wire {
    signing: Option<SigningData>,
    require_signing: bool,
    header: MavHeader,
    /// Stream bytes not yet parsed (serial).
    pending: Vec<u8>,
    counters: LinkCounters,
}

impl std::fmt::Debug for Wire {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Wire")
            .field("signing", &self.signing.is_some())
            .field("require_signing", &self.require_signing)
            .field("header", &self.header)
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

/// How a frame at the start of a buffer looks.
enum Frame {
    /// A whole frame of this many bytes.
    Whole(usize),
    /// The buffer ends inside a frame that would be this long.
    Short,
}

fn frame_at(buf: &[u8]) -> Frame {
    if buf.len() < 1 + HEADER {
        return Frame::Short;
    }
    let len = usize::from(buf[1]);
    let signed = buf[2] & IFLAG_SIGNED != 0;
    let total = 1 + HEADER + len + 2 + if signed { SIGNATURE } else { 0 };
    if buf.len() < total {
        Frame::Short
    } else {
        Frame::Whole(total)
    }
}

impl Wire {
    /// A wire speaking as `system_id`/`component_id`, signing with `signing` if given.
    pub fn new(system_id: u8, component_id: u8, signing: Option<&Signing>) -> Self {
        Self {
            signing: signing.map(|s| {
                SigningData::from_config(SigningConfig::new(s.key, s.link_id, true, !s.require))
            }),
            require_signing: signing.is_some_and(|s| s.require),
            header: MavHeader {
                system_id: u32::from(system_id),
                component_id,
                sequence: 0,
            },
            pending: Vec::new(),
            counters: LinkCounters::default(),
        }
    }

    /// The counters so far.
    pub fn counters(&self) -> &LinkCounters {
        &self.counters
    }

    /// Counts a well-formed message the autopilot ignores.
    pub fn count_rejected_input(&mut self) {
        self.counters.rejected_input += 1;
    }

    /// Decodes one datagram (every frame in it; a frame cut short at its end is truncated).
    pub fn datagram(&mut self, bytes: &[u8], out: &mut Vec<Received>) {
        let consumed = self.parse(bytes, out, true);
        debug_assert_eq!(consumed, bytes.len());
    }

    /// Decodes stream bytes (serial): a frame cut short waits for the rest.
    pub fn stream(&mut self, bytes: &[u8], out: &mut Vec<Received>) {
        let mut buf = std::mem::take(&mut self.pending);
        buf.extend_from_slice(bytes);
        let consumed = self.parse(&buf, out, false);
        buf.drain(..consumed);
        // A stream never holds more than one frame in waiting.
        if buf.len() > MAX_FRAME {
            self.counters.junk_bytes += (buf.len() - MAX_FRAME) as u64;
            buf.drain(..buf.len() - MAX_FRAME);
        }
        self.pending = buf;
    }

    /// Parses whole frames from `buf`; returns the bytes consumed (the rest is a frame cut
    /// short, or nothing). In a datagram nothing more will come: a frame cut short is
    /// truncated unless another start byte follows (its length byte may be corrupt and hide
    /// a good frame: resync).
    fn parse(&mut self, buf: &[u8], out: &mut Vec<Received>, datagram: bool) -> usize {
        let mut at = 0;
        while at < buf.len() {
            let rest = &buf[at..];
            match rest[0] {
                STX_V2 => match frame_at(rest) {
                    Frame::Short if datagram && rest[1..].contains(&STX_V2) => {
                        self.counters.junk_bytes += 1;
                        at += 1;
                    }
                    Frame::Short if datagram => {
                        self.counters.truncated += 1;
                        return buf.len();
                    }
                    Frame::Short => return at,
                    Frame::Whole(n) => {
                        if self.frame(&rest[..n], out) {
                            at += n;
                        } else {
                            // A bad frame may hide a good one after its start byte: resync.
                            at += 1;
                        }
                    }
                },
                STX_V1 if rest.len() >= 8 => {
                    // MAVLink 1: len + 6 header bytes + payload + CRC; skipped whole.
                    self.counters.unsupported += 1;
                    at += (8 + usize::from(rest[1])).min(rest.len());
                }
                STX_V1 if datagram => {
                    self.counters.unsupported += 1;
                    return buf.len();
                }
                STX_V1 => return at,
                _ => {
                    self.counters.junk_bytes += 1;
                    at += 1;
                }
            }
        }
        at
    }

    /// Checks and decodes one whole frame; false if it was refused (counted).
    fn frame(&mut self, bytes: &[u8], out: &mut Vec<Received>) -> bool {
        let incompat = bytes[2];
        if incompat & !IFLAG_SIGNED != 0 {
            self.counters.unsupported += 1;
            return false;
        }
        let id = u32::from(bytes[7]) | (u32::from(bytes[8]) << 8) | (u32::from(bytes[9]) << 16);
        if MavMessage::default_message_from_id(id).is_none() {
            self.counters.unknown_id += 1;
            return false;
        }
        let mut raw = MAVLinkV2MessageRaw::new();
        let Some(slot) = raw.as_mut_slice().get_mut(..bytes.len()) else {
            self.counters.truncated += 1;
            return false;
        };
        slot.copy_from_slice(bytes);
        if !raw.has_valid_crc::<MavMessage>() {
            self.counters.bad_crc += 1;
            return false;
        }
        let signed = incompat & IFLAG_SIGNED != 0;
        match (&self.signing, signed) {
            (Some(s), true) if !s.verify_signature(&raw) => {
                self.counters.bad_signature += 1;
                return false;
            }
            (_, false) if self.require_signing => {
                self.counters.unsigned_refused += 1;
                return false;
            }
            _ => {}
        }
        match MavMessage::parse(MavlinkVersion::V2, id, raw.payload()) {
            Ok(message) => {
                self.counters.frames_ok += 1;
                out.push(Received {
                    header: MavHeader {
                        system_id: u32::from(bytes[5]),
                        component_id: bytes[6],
                        sequence: bytes[4],
                    },
                    message,
                });
                true
            }
            Err(_) => {
                self.counters.bad_payload += 1;
                false
            }
        }
    }

    /// Encodes `message` (signed when signing is on), appending it to `out`.
    pub fn encode(&mut self, message: &MavMessage, out: &mut Vec<u8>) {
        // Writing into a Vec cannot fail.
        let _ = mavlink::write_v2_msg_signed(out, self.header, message, self.signing.as_ref());
        self.header.sequence = self.header.sequence.wrapping_add(1);
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use mavlink::dialects::common::{HEARTBEAT_DATA, MavAutopilot, MavModeFlag, MavState, MavType};

    fn heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 393_216,
            mavtype: MavType::MAV_TYPE_GCS,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        })
    }

    fn frame(wire: &mut Wire) -> Vec<u8> {
        let mut bytes = Vec::new();
        wire.encode(&heartbeat(), &mut bytes);
        bytes
    }

    #[test]
    fn a_good_frame_decodes_and_bad_ones_are_counted_by_kind() {
        let mut tx = Wire::new(255, 190, None);
        let mut rx = Wire::new(1, 1, None);
        let good = frame(&mut tx);
        let mut out = Vec::new();
        rx.datagram(&good, &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].message, heartbeat());
        assert_eq!(out[0].header.system_id, 255);

        let mut bad_crc = good.clone();
        let last = bad_crc.len() - 1;
        bad_crc[last] ^= 0x55;
        rx.datagram(&bad_crc, &mut out);
        assert_eq!(rx.counters().bad_crc, 1);

        rx.datagram(&good[..good.len() - 3], &mut out);
        assert_eq!(rx.counters().truncated, 1);

        let mut unknown = good.clone();
        unknown[7] = 0xEE;
        unknown[8] = 0xEE;
        rx.datagram(&unknown, &mut out);
        assert_eq!(rx.counters().unknown_id, 1);

        // (After a refused frame the parser resyncs byte by byte: those bytes count as junk.)
        let junk = rx.counters().junk_bytes;
        rx.datagram(&[1, 2, 3], &mut out);
        assert_eq!(rx.counters().junk_bytes, junk + 3);
        assert_eq!(out.len(), 1, "nothing bad got through");
        // A good frame after garbage in the same datagram still decodes.
        let mut mixed = vec![0u8, 0xFD, 7];
        mixed.extend_from_slice(&good);
        rx.datagram(&mixed, &mut out);
        assert_eq!(out.len(), 2, "{}", rx.counters());
        assert_eq!(rx.counters().frames_ok, 2);
        assert_eq!(rx.counters().bad_crc, 1);
        assert_eq!(rx.counters().unknown_id, 1);
    }

    #[test]
    fn a_stream_waits_for_the_rest_of_a_frame() {
        let mut tx = Wire::new(255, 190, None);
        let mut rx = Wire::new(1, 1, None);
        let good = frame(&mut tx);
        let mut out = Vec::new();
        let (a, b) = good.split_at(5);
        rx.stream(a, &mut out);
        assert!(out.is_empty());
        rx.stream(b, &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(rx.counters().truncated, 0);
    }

    #[test]
    fn required_signing_refuses_unsigned_and_forged_frames() {
        let key = [7u8; 32];
        let signing = Signing {
            key,
            link_id: 3,
            require: true,
        };
        let mut rx = Wire::new(1, 1, Some(&signing));
        let mut out = Vec::new();
        let mut plain = Wire::new(255, 190, None);
        rx.datagram(&frame(&mut plain), &mut out);
        assert_eq!(rx.counters().unsigned_refused, 1);
        let forger = Signing {
            key: [8u8; 32],
            ..signing.clone()
        };
        let mut forged = Wire::new(255, 190, Some(&forger));
        rx.datagram(&frame(&mut forged), &mut out);
        assert_eq!(rx.counters().bad_signature, 1);
        assert!(out.is_empty());
        let mut honest = Wire::new(255, 190, Some(&signing));
        rx.datagram(&frame(&mut honest), &mut out);
        assert_eq!(out.len(), 1);
    }

    #[test]
    fn never_panics_on_random_bytes() {
        // A fixed xorshift stream: every length, every byte value, some start bytes.
        let mut rx = Wire::new(1, 1, None);
        let mut out = Vec::new();
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for n in 0..2000 {
            let mut buf = Vec::with_capacity(n % 300);
            for _ in 0..n % 300 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                buf.push(if x.is_multiple_of(17) {
                    0xFD
                } else {
                    (x >> 24) as u8
                });
            }
            rx.datagram(&buf, &mut out);
            rx.stream(&buf, &mut out);
        }
        assert!(rx.counters().junk_bytes > 0);
    }

    #[test]
    fn key_files_are_raw_or_hex() {
        let hex = "00".repeat(31) + "ff\n";
        let key = Signing::key_from_file_bytes(hex.as_bytes()).unwrap();
        assert_eq!(key[31], 0xFF);
        assert_eq!(Signing::key_from_file_bytes(&[9u8; 32]).unwrap(), [9u8; 32]);
        assert!(Signing::key_from_file_bytes(b"short").is_err());
    }
}
