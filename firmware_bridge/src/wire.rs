//! MAVLink 2 on the wire: a byte-stream decoder that never panics and counts what it
//! throws away, and an encoder that signs when a key is set.
//!
//! The decoder takes bytes as they arrive (a UDP datagram, a TCP or serial chunk: frames may
//! be split or glued together) and yields the frames it can check:
//!
//! 1. hunt for the MAVLink 2 start byte 0xFD (anything else before it is garbage);
//! 2. read the 10-byte header, the payload, the CRC and, with the signed flag, the 13-byte
//!    signature; an unknown incompatibility flag or a frame still incomplete when the
//!    datagram ends counts as truncated;
//! 3. an id outside the `common` dialect counts as unknown (its CRC cannot be checked without
//!    the message's CRC_EXTRA); a bad CRC is counted and the decoder resynchronises on the
//!    next 0xFD after the false start;
//! 4. with signing required, an unsigned frame or a signature that does not verify (or a
//!    replayed timestamp) is refused and counted;
//! 5. a payload the dialect cannot parse (an enum value out of range) counts as undecodable.
//!
//! MAVLink 1 frames (0xFE) are not spoken: they count as garbage bytes.

use std::sync::atomic::{AtomicU64, Ordering};

use mavlink::dialects::common::MavMessage;
use mavlink::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, Message};
use mavlink::{SigningConfig, SigningData};

/// MAVLink 2 start-of-frame marker.
const STX_V2: u8 = 0xFD;
/// Header bytes after the start byte: len, incompat, compat, seq, sysid, compid, msgid×3.
const HEADER_LEN: usize = 9;
/// CRC bytes.
const CRC_LEN: usize = 2;
/// Signature bytes: link id, 48-bit timestamp, 48-bit signature.
const SIGNATURE_LEN: usize = 13;
/// The signed-frame incompatibility flag.
const IFLAG_SIGNED: u8 = 0x01;
/// Largest frame, bytes.
const MAX_FRAME: usize = 1 + HEADER_LEN + 255 + CRC_LEN + SIGNATURE_LEN;

/// What the decoder threw away, and what it kept. Shared between the bridge's I/O thread and
/// its users (atomics: reading them never blocks the link).
#[derive(Debug, Default)]
pub struct Counters {
    /// Frames decoded and accepted.
    pub frames_ok: AtomicU64,
    /// Bytes skipped while hunting for a start byte (noise, MAVLink 1, the rest of a bad frame).
    pub garbage_bytes: AtomicU64,
    /// Frames whose CRC did not match.
    pub bad_crc: AtomicU64,
    /// Frames with a message id outside the dialect.
    pub unknown_id: AtomicU64,
    /// Frames cut short (datagram or stream ended inside one) or with unknown
    /// incompatibility flags.
    pub truncated: AtomicU64,
    /// Frames refused by signing: unsigned while signing is required.
    pub refused_unsigned: AtomicU64,
    /// Frames refused by signing: bad signature or replayed timestamp.
    pub refused_bad_signature: AtomicU64,
    /// Frames with a valid CRC whose payload the dialect could not parse.
    pub undecodable: AtomicU64,
    /// Frames sent.
    pub frames_sent: AtomicU64,
}

/// A copy of [`Counters`] at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CounterSnapshot {
    /// Frames decoded and accepted.
    pub frames_ok: u64,
    /// Bytes skipped while hunting for a start byte.
    pub garbage_bytes: u64,
    /// Frames whose CRC did not match.
    pub bad_crc: u64,
    /// Frames with a message id outside the dialect.
    pub unknown_id: u64,
    /// Frames cut short or with unknown incompatibility flags.
    pub truncated: u64,
    /// Unsigned frames refused (signing required).
    pub refused_unsigned: u64,
    /// Frames with a bad signature or a replayed timestamp, refused.
    pub refused_bad_signature: u64,
    /// Frames whose payload could not be parsed.
    pub undecodable: u64,
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
            refused_unsigned: r(&self.refused_unsigned),
            refused_bad_signature: r(&self.refused_bad_signature),
            undecodable: r(&self.undecodable),
            frames_sent: r(&self.frames_sent),
        }
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
}

/// The byte-stream decoder.
pub struct Decoder {
    buffer: Vec<u8>,
    signing: Option<(SigningData, bool)>,
}

impl std::fmt::Debug for Decoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Decoder")
            .field("buffered", &self.buffer.len())
            .field("signing", &self.signing.as_ref().map(|(_, r)| *r))
            .finish()
    }
}

/// What one look at the front of the buffer found.
enum Step {
    /// Not enough bytes yet.
    NeedMore,
    /// Drop this many bytes and look again.
    Skip(usize),
    /// A frame of this many bytes is at the front.
    Frame(usize),
}

impl Decoder {
    /// A decoder; with `signing`, signed frames are verified (and unsigned ones refused when
    /// it is required).
    pub fn new(signing: Option<&Signing>) -> Self {
        Self {
            buffer: Vec::with_capacity(2 * MAX_FRAME),
            signing: signing.map(|s| {
                let config = SigningConfig::new(s.key.secret, s.key.link_id, true, !s.require);
                (SigningData::from_config(config), s.require)
            }),
        }
    }

    /// Feeds bytes from a stream (TCP, serial): an incomplete frame at the end waits for
    /// the next chunk.
    pub fn push_stream(&mut self, bytes: &[u8], counters: &Counters, out: &mut Vec<Frame>) {
        self.buffer.extend_from_slice(bytes);
        self.drain(counters, out);
    }

    /// Feeds one datagram (UDP): a frame cannot span datagrams, so an incomplete one at the
    /// end is truncated.
    pub fn push_datagram(&mut self, bytes: &[u8], counters: &Counters, out: &mut Vec<Frame>) {
        self.buffer.clear();
        self.buffer.extend_from_slice(bytes);
        self.drain(counters, out);
        if !self.buffer.is_empty() {
            bump(&counters.truncated);
            self.buffer.clear();
        }
    }

    fn drain(&mut self, counters: &Counters, out: &mut Vec<Frame>) {
        let mut start = 0;
        loop {
            match self.step(&self.buffer[start..]) {
                Step::NeedMore => break,
                Step::Skip(n) => {
                    counters
                        .garbage_bytes
                        .fetch_add(n as u64, Ordering::Relaxed);
                    start += n;
                }
                Step::Frame(n) => {
                    let consumed = self.accept(start, n, counters, out);
                    start += consumed;
                }
            }
        }
        self.buffer.drain(..start);
    }

    fn step(&self, b: &[u8]) -> Step {
        let Some(first) = b.first() else {
            return Step::NeedMore;
        };
        if *first != STX_V2 {
            let n = b.iter().position(|&x| x == STX_V2).unwrap_or(b.len());
            return Step::Skip(n);
        }
        if b.len() < 1 + HEADER_LEN {
            return Step::NeedMore;
        }
        let len = usize::from(b[1]);
        let signed = b[2] & IFLAG_SIGNED != 0;
        let n = 1 + HEADER_LEN + len + CRC_LEN + if signed { SIGNATURE_LEN } else { 0 };
        if b.len() < n {
            return Step::NeedMore;
        }
        Step::Frame(n)
    }

    /// Checks the frame of `n` bytes at `start`; returns how many bytes to consume (the frame,
    /// or one byte for a false start so the decoder resynchronises).
    fn accept(&self, start: usize, n: usize, counters: &Counters, out: &mut Vec<Frame>) -> usize {
        let b = &self.buffer[start..start + n];
        let incompat = b[2];
        if incompat & !IFLAG_SIGNED != 0 {
            // Unknown incompatibility flag (or the non-standard 32-bit system id): not ours.
            bump(&counters.truncated);
            return 1;
        }
        let msgid = u32::from_le_bytes([b[7], b[8], b[9], 0]);
        let known = MavMessage::default_message_from_id(msgid).is_some();
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.as_mut_slice()[..n].copy_from_slice(b);
        if !known {
            // Without CRC_EXTRA the CRC cannot be checked: a corrupted byte could look like an
            // unknown id; either way the frame is skipped whole.
            bump(&counters.unknown_id);
            return n;
        }
        if !raw.has_valid_crc::<MavMessage>() {
            bump(&counters.bad_crc);
            return 1;
        }
        if let Some((data, require)) = &self.signing {
            let signed = incompat & IFLAG_SIGNED != 0;
            if !signed && *require {
                bump(&counters.refused_unsigned);
                return n;
            }
            if signed && !data.verify_signature(&raw) {
                bump(&counters.refused_bad_signature);
                return n;
            }
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
                });
            }
            Err(_) => bump(&counters.undecodable),
        }
        n
    }
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
        raw.raw_bytes().to_vec()
    }
}
