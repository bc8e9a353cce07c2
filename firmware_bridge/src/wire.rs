//! MAVLink 2 on the wire, for both ends of the link (this crate's bridge and the twin's
//! PX4-style autopilot, `twin_autopilot`): a decoder that never panics and counts
//! everything it throws away by kind, and an encoder that signs when a key is set.
//!
//! The decoder takes bytes as they arrive and yields the frames it can check. A byte stream
//! (TCP, serial: [`Decoder::push_stream`]) may split or glue frames: a frame cut short waits
//! for the next chunk. A datagram (UDP: [`Decoder::push_datagram`]) is whole: a frame still
//! incomplete at its end is truncated.
//!
//! 1. hunt for the MAVLink 2 start byte 0xFD: bytes skipped on the way are junk
//!    ([`Counters::garbage_bytes`]); a MAVLink 1 start byte 0xFE is an unsupported frame;
//! 2. read the 10-byte header, the payload, the CRC and, with the signed flag, the 13-byte
//!    signature; a datagram ending inside a frame counts it truncated (unless another start
//!    byte follows: the length byte may be corrupt and hide a good frame);
//! 3. an unknown incompatibility flag is unsupported; an id outside the `common` dialect is
//!    unknown (its CRC cannot be checked without the message's CRC_EXTRA); a bad CRC is
//!    counted. The bytes of these frames cannot be trusted (a corrupt length byte may hide a
//!    good frame): the decoder resynchronises on the byte after their start byte;
//! 4. with signing required, an unsigned frame is refused; with a key, a signed frame whose
//!    signature does not verify (or whose timestamp is replayed) is refused;
//! 5. a payload the dialect cannot parse (an enum value out of range) counts as undecodable.
//!
//! Frames refused in steps 4–5 passed their CRC: they are skipped whole. Every refused frame
//! is counted once, by kind; [`CounterSnapshot::bad_frames`] is their sum.
//!
//! MAVLink 1 is not spoken by default (the bridge). A decoder built with
//! [`Decoder::accepting_v1`] (the twin's autopilot, which answers a MAVLink 1 peer as PX4
//! does) checks MAVLink 1 frames as well — start byte 0xFE, 5-byte header, CRC with the
//! message's CRC_EXTRA; unsigned by nature, so refused when signing is required — and marks
//! them [`Frame::version`] V1; [`Encoder::encode_v1_into`] answers in kind.

use std::sync::atomic::{AtomicU64, Ordering};

use mavlink::dialects::common::MavMessage;
use mavlink::{MAVLinkV1MessageRaw, MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message};
use mavlink::{SigningConfig, SigningData};

/// MAVLink 2 start-of-frame marker.
const STX_V2: u8 = 0xFD;
/// MAVLink 1 start-of-frame marker (counted as unsupported unless the decoder accepts v1).
const STX_V1: u8 = 0xFE;
/// MAVLink 1 header bytes after the start byte: len, seq, sysid, compid, msgid.
const HEADER_LEN_V1: usize = 5;
/// Header bytes after the start byte: len, incompat, compat, seq, sysid, compid, msgid×3.
const HEADER_LEN: usize = 9;
/// CRC bytes.
const CRC_LEN: usize = 2;
/// Signature bytes: link id, 48-bit timestamp, 48-bit signature.
const SIGNATURE_LEN: usize = 13;
/// The signed-frame incompatibility flag.
const IFLAG_SIGNED: u8 = 0x01;
/// Largest frame, bytes.
pub const MAX_FRAME: usize = 1 + HEADER_LEN + 255 + CRC_LEN + SIGNATURE_LEN;

/// What one end of a link threw away, and what it kept, by kind. Atomics: the bridge shares
/// them between its I/O thread and its users (reading them never blocks the link).
#[derive(Debug, Default)]
pub struct Counters {
    /// Frames decoded and accepted.
    pub frames_ok: AtomicU64,
    /// Junk: bytes skipped while hunting for a start byte (noise, the body of a MAVLink 1
    /// frame, the rest of a frame refused before its CRC could be trusted).
    pub garbage_bytes: AtomicU64,
    /// Frames whose CRC did not match.
    pub bad_crc: AtomicU64,
    /// Frames with a message id outside the dialect.
    pub unknown_id: AtomicU64,
    /// Frames cut short (a datagram ended inside one).
    pub truncated: AtomicU64,
    /// MAVLink 1 frames, and MAVLink 2 frames with unknown incompatibility flags.
    pub unsupported: AtomicU64,
    /// Frames refused by signing: unsigned while signing is required.
    pub refused_unsigned: AtomicU64,
    /// Frames refused by signing: bad signature or replayed timestamp.
    pub refused_bad_signature: AtomicU64,
    /// Frames with a valid CRC whose payload the dialect could not parse.
    pub undecodable: AtomicU64,
    /// Accepted frames whose message the application ignored as input (the twin's autopilot:
    /// a non-finite setpoint, a quaternion of the wrong norm, a command for another system...).
    /// Not a bad frame.
    pub rejected_input: AtomicU64,
    /// Frames sent.
    pub frames_sent: AtomicU64,
}

/// A copy of [`Counters`] at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CounterSnapshot {
    /// Frames decoded and accepted.
    pub frames_ok: u64,
    /// Junk bytes skipped while hunting for a start byte.
    pub garbage_bytes: u64,
    /// Frames whose CRC did not match.
    pub bad_crc: u64,
    /// Frames with a message id outside the dialect.
    pub unknown_id: u64,
    /// Frames cut short.
    pub truncated: u64,
    /// MAVLink 1 frames, and frames with unknown incompatibility flags.
    pub unsupported: u64,
    /// Unsigned frames refused (signing required).
    pub refused_unsigned: u64,
    /// Frames with a bad signature or a replayed timestamp, refused.
    pub refused_bad_signature: u64,
    /// Frames whose payload could not be parsed.
    pub undecodable: u64,
    /// Accepted frames the application ignored as input.
    pub rejected_input: u64,
    /// Frames sent.
    pub frames_sent: u64,
}

impl Counters {
    /// The current values.
    pub fn snapshot(&self) -> CounterSnapshot {
        let r = |a: &AtomicU64| a.load(Ordering::Relaxed);
        CounterSnapshot {
            frames_ok: r(&self.frames_ok),
            garbage_bytes: r(&self.garbage_bytes),
            bad_crc: r(&self.bad_crc),
            unknown_id: r(&self.unknown_id),
            truncated: r(&self.truncated),
            unsupported: r(&self.unsupported),
            refused_unsigned: r(&self.refused_unsigned),
            refused_bad_signature: r(&self.refused_bad_signature),
            undecodable: r(&self.undecodable),
            rejected_input: r(&self.rejected_input),
            frames_sent: r(&self.frames_sent),
        }
    }
}

impl CounterSnapshot {
    /// Frames refused for any reason (every kind but `frames_ok`, `garbage_bytes`,
    /// `rejected_input` and `frames_sent`): SYS_STATUS `errors_comm`.
    pub fn bad_frames(&self) -> u64 {
        self.bad_crc
            + self.unknown_id
            + self.truncated
            + self.unsupported
            + self.refused_unsigned
            + self.refused_bad_signature
            + self.undecodable
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

/// The receive side, one line (the twin's autopilot prints it at exit; the names are those of
/// `docs/mavlink.md`).
impl std::fmt::Display for CounterSnapshot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "frames ok {}, bad crc {}, unknown id {}, truncated {}, bad payload {}, unsigned refused {}, bad signature {}, unsupported {}, junk bytes {}, rejected input {}",
            self.frames_ok,
            self.bad_crc,
            self.unknown_id,
            self.truncated,
            self.undecodable,
            self.refused_unsigned,
            self.refused_bad_signature,
            self.unsupported,
            self.garbage_bytes,
            self.rejected_input
        )
    }
}

fn bump(a: &AtomicU64) {
    a.fetch_add(1, Ordering::Relaxed);
}

/// A 32-byte MAVLink 2 signing secret and the link id this end signs with.
#[derive(Clone)]
pub struct SigningKey {
    /// The secret.
    pub secret: [u8; 32],
    /// Link id written into every signature this end sends (0–255).
    pub link_id: u8,
}

impl std::fmt::Debug for SigningKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never print the secret.
        f.debug_struct("SigningKey")
            .field("link_id", &self.link_id)
            .finish_non_exhaustive()
    }
}

impl SigningKey {
    /// Reads a key file: either exactly 32 raw bytes, or 64 hexadecimal digits (surrounding
    /// white space allowed). Errors name the file and what was found.
    pub fn from_file(path: &std::path::Path, link_id: u8) -> Result<Self, String> {
        let bytes = std::fs::read(path)
            .map_err(|e| format!("signing key {}: cannot read: {e}", path.display()))?;
        Self::from_bytes(&bytes, link_id)
            .map_err(|e| format!("signing key {}: {e}", path.display()))
    }

    /// A key from a key file's contents (32 raw bytes or 64 hex digits).
    pub fn from_bytes(bytes: &[u8], link_id: u8) -> Result<Self, String> {
        let text = std::str::from_utf8(bytes).ok().map(str::trim);
        let mut secret = [0u8; 32];
        match text {
            Some(t) if t.len() == 64 && t.bytes().all(|b| b.is_ascii_hexdigit()) => {
                for (i, s) in secret.iter_mut().enumerate() {
                    *s = u8::from_str_radix(&t[2 * i..2 * i + 2], 16)
                        .map_err(|e| format!("bad hex digit: {e}"))?;
                }
            }
            _ if bytes.len() == 32 => secret.copy_from_slice(bytes),
            _ => {
                return Err(format!(
                    "expected 32 raw bytes or 64 hexadecimal digits, found {} bytes",
                    bytes.len()
                ));
            }
        }
        Ok(Self { secret, link_id })
    }
}

/// Signing on one link.
#[derive(Debug, Clone)]
pub struct Signing {
    /// The key.
    pub key: SigningKey,
    /// Refuse unsigned frames (true), or accept them and only check signed ones (false).
    pub require: bool,
}

/// A decoded, accepted frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Sender and sequence.
    pub header: MavHeader,
    /// The message.
    pub message: MavMessage,
    /// MAVLink 2, or MAVLink 1 (only from a decoder [`Decoder::accepting_v1`]).
    pub version: MavlinkVersion,
    /// The frame as it was on the wire (start byte to CRC, and the signature when signed)
    /// from a decoder that keeps them ([`Decoder::keeping_bytes`]); empty otherwise.
    pub bytes: Vec<u8>,
}

/// The decoder of one link: the bytes of a stream not yet parsed, and signing.
pub struct Decoder {
    /// Stream bytes not yet parsed: at most one frame cut short (less than [`MAX_FRAME`]).
    pending: Vec<u8>,
    signing: Option<SigningData>,
    require_signing: bool,
    /// Whether accepted frames keep their bytes ([`Frame::bytes`]).
    keep_bytes: bool,
    /// Whether MAVLink 1 frames are checked and accepted (else counted unsupported).
    accept_v1: bool,
}

impl std::fmt::Debug for Decoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Decoder")
            .field("pending", &self.pending.len())
            .field("signing", &self.signing.is_some())
            .field("require_signing", &self.require_signing)
            .finish()
    }
}

/// The length of the MAVLink 2 frame at the start of `b` (which starts with 0xFD), or None if
/// `b` ends inside it.
fn frame_len(b: &[u8]) -> Option<usize> {
    let header = b.get(..1 + HEADER_LEN)?;
    let signed = header[2] & IFLAG_SIGNED != 0;
    let n =
        1 + HEADER_LEN + usize::from(header[1]) + CRC_LEN + if signed { SIGNATURE_LEN } else { 0 };
    (b.len() >= n).then_some(n)
}

impl Decoder {
    /// A decoder; with `signing`, signed frames are verified (and unsigned ones refused when
    /// it is required). Without, signed frames are accepted unchecked.
    pub fn new(signing: Option<&Signing>) -> Self {
        Self {
            pending: Vec::with_capacity(2 * MAX_FRAME),
            signing: signing.map(|s| {
                let config = SigningConfig::new(s.key.secret, s.key.link_id, true, !s.require);
                SigningData::from_config(config)
            }),
            require_signing: signing.is_some_and(|s| s.require),
            keep_bytes: false,
            accept_v1: false,
        }
    }

    /// With `accept`, MAVLink 1 frames are checked (CRC, known id) and accepted, marked
    /// [`Frame::version`] V1; refused (unsigned) when signing is required. Without (the
    /// default), they are counted unsupported.
    pub fn accepting_v1(mut self, accept: bool) -> Self {
        self.accept_v1 = accept;
        self
    }

    /// With `keep`, every accepted frame carries its bytes as they were on the wire
    /// ([`Frame::bytes`]: the flight log's `/mavlink/raw`).
    pub fn keeping_bytes(mut self, keep: bool) -> Self {
        self.keep_bytes = keep;
        self
    }

    /// Feeds bytes from a stream (TCP, serial): an incomplete frame at the end waits for
    /// the next chunk.
    pub fn push_stream(&mut self, bytes: &[u8], counters: &Counters, out: &mut Vec<Frame>) {
        let mut buf = std::mem::take(&mut self.pending);
        buf.extend_from_slice(bytes);
        let consumed = self.parse(&buf, false, counters, out);
        buf.drain(..consumed);
        self.pending = buf;
    }

    /// Feeds one datagram (UDP): a frame cannot span datagrams, so an incomplete one at the
    /// end is truncated. (Independent of the bytes a stream left waiting.)
    pub fn push_datagram(&mut self, bytes: &[u8], counters: &Counters, out: &mut Vec<Frame>) {
        let consumed = self.parse(bytes, true, counters, out);
        debug_assert_eq!(consumed, bytes.len());
    }

    /// Parses the frames in `buf`; returns the bytes consumed (the rest is a frame cut short
    /// that a stream will complete, or nothing).
    fn parse(
        &self,
        buf: &[u8],
        datagram: bool,
        counters: &Counters,
        out: &mut Vec<Frame>,
    ) -> usize {
        let mut at = 0;
        while let Some(rest) = buf.get(at..).filter(|r| !r.is_empty()) {
            match rest[0] {
                STX_V2 => match frame_len(rest) {
                    Some(n) => at += self.accept(&rest[..n], counters, out),
                    // A false start (its length byte may be corrupt): the rest may hold a
                    // good frame.
                    None if datagram && rest[1..].contains(&STX_V2) => {
                        bump(&counters.garbage_bytes);
                        at += 1;
                    }
                    None if datagram => {
                        bump(&counters.truncated);
                        return buf.len();
                    }
                    None => return at,
                },
                STX_V1 if self.accept_v1 => match frame_len_v1(rest) {
                    Some(n) => at += self.accept_v1_frame(&rest[..n], counters, out),
                    None if datagram && rest[1..].iter().any(|&b| b == STX_V2 || b == STX_V1) => {
                        bump(&counters.garbage_bytes);
                        at += 1;
                    }
                    None if datagram => {
                        bump(&counters.truncated);
                        return buf.len();
                    }
                    None => return at,
                },
                STX_V1 => {
                    // MAVLink 1: not spoken. Its body (not checked: its length byte cannot be
                    // trusted) is hunted through as junk.
                    bump(&counters.unsupported);
                    at += 1;
                }
                _ => {
                    let n = rest
                        .iter()
                        .position(|&b| b == STX_V2 || b == STX_V1)
                        .unwrap_or(rest.len());
                    counters
                        .garbage_bytes
                        .fetch_add(n as u64, Ordering::Relaxed);
                    at += n;
                }
            }
        }
        at
    }

    /// Checks the whole frame `b`; returns how many bytes to consume: the frame, or one byte
    /// when its bytes cannot be trusted (the decoder resynchronises after its start byte).
    fn accept(&self, b: &[u8], counters: &Counters, out: &mut Vec<Frame>) -> usize {
        let incompat = b[2];
        if incompat & !IFLAG_SIGNED != 0 {
            // Unknown incompatibility flag (or the non-standard 32-bit system id): not ours.
            bump(&counters.unsupported);
            return 1;
        }
        let msgid = u32::from_le_bytes([b[7], b[8], b[9], 0]);
        if MavMessage::default_message_from_id(msgid).is_none() {
            // Without CRC_EXTRA the CRC cannot be checked: a corrupted byte could look like an
            // unknown id.
            bump(&counters.unknown_id);
            return 1;
        }
        let mut raw = MAVLinkV2MessageRaw::new();
        let Some(slot) = raw.as_mut_slice().get_mut(..b.len()) else {
            // Cannot happen (a frame is at most MAX_FRAME bytes); never panic.
            bump(&counters.truncated);
            return 1;
        };
        slot.copy_from_slice(b);
        if !raw.has_valid_crc::<MavMessage>() {
            bump(&counters.bad_crc);
            return 1;
        }
        let signed = incompat & IFLAG_SIGNED != 0;
        match &self.signing {
            Some(data) if signed && !data.verify_signature(&raw) => {
                bump(&counters.refused_bad_signature);
                return b.len();
            }
            _ if !signed && self.require_signing => {
                bump(&counters.refused_unsigned);
                return b.len();
            }
            _ => {}
        }
        match MavMessage::parse(MavlinkVersion::V2, msgid, raw.payload()) {
            Ok(message) => {
                bump(&counters.frames_ok);
                out.push(Frame {
                    header: MavHeader {
                        system_id: raw.system_id(),
                        component_id: raw.component_id(),
                        sequence: raw.sequence(),
                    },
                    message,
                    version: MavlinkVersion::V2,
                    bytes: if self.keep_bytes {
                        b.to_vec()
                    } else {
                        Vec::new()
                    },
                });
            }
            Err(_) => bump(&counters.undecodable),
        }
        b.len()
    }
}

impl Decoder {
    /// Checks the whole MAVLink 1 frame `b` (as [`Self::accept`] for MAVLink 2).
    fn accept_v1_frame(&self, b: &[u8], counters: &Counters, out: &mut Vec<Frame>) -> usize {
        let msgid = u32::from(b[5]);
        if MavMessage::default_message_from_id(msgid).is_none() {
            bump(&counters.unknown_id);
            return 1;
        }
        let mut raw = MAVLinkV1MessageRaw::new();
        let Some(slot) = raw.as_mut_slice().get_mut(..b.len()) else {
            bump(&counters.truncated);
            return 1;
        };
        slot.copy_from_slice(b);
        if !raw.has_valid_crc::<MavMessage>() {
            bump(&counters.bad_crc);
            return 1;
        }
        if self.require_signing {
            // MAVLink 1 cannot be signed.
            bump(&counters.refused_unsigned);
            return b.len();
        }
        match MavMessage::parse(MavlinkVersion::V1, msgid, raw.payload()) {
            Ok(message) => {
                bump(&counters.frames_ok);
                out.push(Frame {
                    header: MavHeader {
                        system_id: u32::from(raw.system_id()),
                        component_id: raw.component_id(),
                        sequence: raw.sequence(),
                    },
                    message,
                    version: MavlinkVersion::V1,
                    bytes: if self.keep_bytes {
                        b.to_vec()
                    } else {
                        Vec::new()
                    },
                });
            }
            Err(_) => bump(&counters.undecodable),
        }
        b.len()
    }
}

/// The length of the MAVLink 1 frame at the start of `b` (which starts with 0xFE), or None if
/// `b` ends inside it.
fn frame_len_v1(b: &[u8]) -> Option<usize> {
    let len = usize::from(*b.get(1)?);
    let n = 1 + HEADER_LEN_V1 + len + CRC_LEN;
    (b.len() >= n).then_some(n)
}

/// The encoder: sequence numbers, own ids, optional signing.
pub struct Encoder {
    system_id: u8,
    component_id: u8,
    sequence: u8,
    signing: Option<SigningData>,
}

impl std::fmt::Debug for Encoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Encoder")
            .field("system_id", &self.system_id)
            .field("component_id", &self.component_id)
            .field("signing", &self.signing.is_some())
            .finish()
    }
}

impl Encoder {
    /// An encoder sending as `system_id`/`component_id`, signing with `key` if given.
    pub fn new(system_id: u8, component_id: u8, key: Option<&SigningKey>) -> Self {
        Self {
            system_id,
            component_id,
            sequence: 0,
            signing: key.map(|k| {
                SigningData::from_config(SigningConfig::new(k.secret, k.link_id, true, false))
            }),
        }
    }

    /// One frame of `message`.
    pub fn encode(&mut self, message: &MavMessage) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(MAX_FRAME);
        self.encode_into(message, &mut bytes);
        bytes
    }

    /// One frame of `message`, appended to `out` (several frames can go out as one datagram
    /// or write).
    pub fn encode_into(&mut self, message: &MavMessage, out: &mut Vec<u8>) {
        let header = MavHeader {
            system_id: u32::from(self.system_id),
            component_id: self.component_id,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let mut raw = MAVLinkV2MessageRaw::new();
        match &self.signing {
            Some(data) => {
                raw.serialize_message_for_signing(header, message);
                data.sign_message(&mut raw);
            }
            None => raw.serialize_message(header, message),
        }
        out.extend_from_slice(raw.raw_bytes());
    }

    /// One MAVLink 1 frame of `message` appended to `out` (unsigned: MAVLink 1 has no
    /// signature; extension fields dropped). False, and nothing written, for a message id
    /// above 255, which MAVLink 1 cannot carry.
    pub fn encode_v1_into(&mut self, message: &MavMessage, out: &mut Vec<u8>) -> bool {
        if message.message_id() > 255 {
            return false;
        }
        let header = MavHeader {
            system_id: u32::from(self.system_id),
            component_id: self.component_id,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let mut raw = MAVLinkV1MessageRaw::new();
        raw.serialize_message(header, message);
        out.extend_from_slice(raw.raw_bytes());
        true
    }
}
