//! Raw frame capture: every frame the bridge accepted from the link and every frame it sent,
//! the bytes exactly as they were on the wire, for the flight log (`/mavlink/raw`).
//!
//! The capture runs inside the bridge's I/O thread and must never hold it up: each frame goes
//! into a bounded channel with a non-blocking `try_send`; when the flight side does not drain
//! it ([`crate::Bridge::drain_raw`]) and it is full, the frame is dropped and counted
//! ([`CaptureStats::dropped`]). Off unless [`crate::BridgeConfig::capture_raw`] is set.
//!
//! Frames received are the decoder's ([`crate::wire`]), which keeps each accepted frame's bytes
//! when the capture is on ([`crate::wire::Decoder::keeping_bytes`]). Garbage and refused frames
//! (bad CRC, unknown id, unsigned or forged) are not captured; the link's counters say how
//! many there were.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::time::Instant;

use mavlink::Message;
use mavlink::dialects::common::MavMessage;

use crate::wire::Frame;

/// Start byte and header: STX, len, incompat, compat, seq, sysid, compid, msgid×3.
const HEADER_LEN: usize = 10;
/// The signed-frame incompatibility flag.
const IFLAG_SIGNED: u8 = 0x01;

/// Which way a frame went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Received from the link (accepted by the decoder).
    In,
    /// Sent by the bridge.
    Out,
}

impl Direction {
    /// `in` or `out`.
    pub fn name(self) -> &'static str {
        match self {
            Self::In => "in",
            Self::Out => "out",
        }
    }
}

/// One frame as it was on the wire.
#[derive(Debug, Clone, PartialEq)]
pub struct RawFrame {
    /// Received or sent.
    pub direction: Direction,
    /// When the I/O thread decoded it (in) or sent it (out).
    pub at: Instant,
    /// The time of the newest measurement the bridge had assembled then, s (the autopilot's
    /// time of the last ODOMETRY, this frame included; 0 before the first).
    pub flight_time_s: f64,
    /// Sender's system id (byte 5 of the frame).
    pub system_id: u8,
    /// Sender's component id (byte 6).
    pub component_id: u8,
    /// Sequence number (byte 4).
    pub sequence: u8,
    /// Message id (bytes 7–9, little endian).
    pub message_id: u32,
    /// The message's name in the `common` dialect (`ODOMETRY`).
    pub message_name: &'static str,
    /// The frame: start byte 0xFD to the CRC, and the 13-byte signature when signed.
    pub bytes: Vec<u8>,
}

impl RawFrame {
    /// The frame carries a MAVLink 2 signature.
    pub fn signed(&self) -> bool {
        self.bytes.get(2).is_some_and(|f| f & IFLAG_SIGNED != 0)
    }
}

/// What the capture did so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CaptureStats {
    /// Frames handed to the flight side's queue.
    pub captured: u64,
    /// Frames dropped because the queue was full (the flight side did not drain it).
    pub dropped: u64,
}

#[derive(Debug, Default)]
struct Counts {
    captured: AtomicU64,
    dropped: AtomicU64,
}

/// The I/O thread's end.
#[derive(Debug)]
pub(crate) struct Capture {
    queue: SyncSender<RawFrame>,
    counts: Arc<Counts>,
}

/// The flight side's end.
#[derive(Debug)]
pub(crate) struct CaptureQueue {
    queue: Receiver<RawFrame>,
    counts: Arc<Counts>,
}

/// A capture whose queue holds up to `capacity` frames.
pub(crate) fn capture(capacity: usize) -> (Capture, CaptureQueue) {
    let (tx, rx) = sync_channel(capacity.max(1));
    let counts = Arc::new(Counts::default());
    (
        Capture {
            queue: tx,
            counts: counts.clone(),
        },
        CaptureQueue { queue: rx, counts },
    )
}

impl CaptureQueue {
    /// Moves every queued frame to `out`; returns how many.
    pub(crate) fn drain(&self, out: &mut Vec<RawFrame>) -> usize {
        let before = out.len();
        out.extend(self.queue.try_iter());
        out.len() - before
    }

    pub(crate) fn stats(&self) -> CaptureStats {
        let r = |a: &AtomicU64| a.load(Ordering::Relaxed);
        CaptureStats {
            captured: r(&self.counts.captured),
            dropped: r(&self.counts.dropped),
        }
    }
}

impl Capture {
    /// A frame the decoder accepted, its bytes kept ([`Frame::bytes`]; a frame without them
    /// is not captured).
    pub(crate) fn received(&mut self, frame: &Frame, flight_time_s: f64) {
        self.push(Direction::In, &frame.message, &frame.bytes, flight_time_s);
    }

    /// A frame the bridge sent (`bytes` as written to the link).
    pub(crate) fn sent(&mut self, message: &MavMessage, bytes: &[u8], flight_time_s: f64) {
        self.push(Direction::Out, message, bytes, flight_time_s);
    }

    fn push(&self, direction: Direction, message: &MavMessage, bytes: &[u8], flight_time_s: f64) {
        if bytes.len() < HEADER_LEN {
            return;
        }
        let frame = RawFrame {
            direction,
            at: Instant::now(),
            flight_time_s,
            system_id: bytes[5],
            component_id: bytes[6],
            sequence: bytes[4],
            message_id: message.message_id(),
            message_name: message.message_name(),
            bytes: bytes.to_vec(),
        };
        let counter = match self.queue.try_send(frame) {
            Ok(()) => &self.counts.captured,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => &self.counts.dropped,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

/// Lower-case hexadecimal of `bytes` (two digits a byte, no separators).
pub fn to_hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(2 * bytes.len());
    for &b in bytes {
        s.push(char::from(DIGITS[usize::from(b >> 4)]));
        s.push(char::from(DIGITS[usize::from(b & 0x0F)]));
    }
    s
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use mavlink::dialects::common::{HEARTBEAT_DATA, ODOMETRY_DATA};
    use mavlink::{MavHeader, MavlinkReader, MavlinkVersion};

    use super::*;
    use crate::wire::{Counters, Decoder, Encoder, SigningKey};

    fn frame(seq: u8, m: &MavMessage) -> Vec<u8> {
        let mut bytes = Vec::new();
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: seq,
        };
        mavlink::write_v2_msg(&mut bytes, header, m).unwrap();
        bytes
    }

    fn odometry(t: u64) -> MavMessage {
        MavMessage::ODOMETRY(ODOMETRY_DATA {
            time_usec: t,
            x: 1.5,
            q: [1.0, 0.0, 0.0, 0.0],
            ..ODOMETRY_DATA::default()
        })
    }

    /// Feeds `stream` to a decoder and a capture in chunks of `chunk` bytes, as the I/O
    /// thread does; returns the captured frames.
    fn run(stream: &[u8], chunk: usize, datagram: bool) -> (Vec<RawFrame>, CaptureStats) {
        let counters = Counters::default();
        let mut decoder = Decoder::new(None).keeping_bytes(true);
        let (mut capture, queue) = capture(1000);
        let mut frames = Vec::new();
        for piece in stream.chunks(chunk) {
            if datagram {
                decoder.push_datagram(piece, &counters, &mut frames);
            } else {
                decoder.push_stream(piece, &counters, &mut frames);
            }
            for f in frames.drain(..) {
                capture.received(&f, 0.0);
            }
        }
        let mut out = Vec::new();
        queue.drain(&mut out);
        (out, queue.stats())
    }

    #[test]
    fn frames_split_and_glued_in_a_stream_come_out_byte_for_byte_without_the_garbage() {
        let good: Vec<Vec<u8>> = (0..20u8)
            .map(|i| {
                if i % 3 == 0 {
                    frame(i, &MavMessage::HEARTBEAT(HEARTBEAT_DATA::default()))
                } else {
                    frame(i, &odometry(u64::from(i) * 1000))
                }
            })
            .collect();
        let mut stream = Vec::new();
        for (i, f) in good.iter().enumerate() {
            // Junk, a start byte that begins nothing, and a corrupted copy between frames.
            stream.extend_from_slice(&[0x00, 0xFD, 0x42, 0x13]);
            if i % 4 == 1 {
                let mut bad = f.clone();
                let last = bad.len() - 1;
                bad[last] ^= 0xFF;
                stream.extend_from_slice(&bad);
            }
            stream.extend_from_slice(f);
        }
        // A false start waits for as many bytes as its length byte claims: pad the end.
        stream.extend_from_slice(&[0; crate::wire::MAX_FRAME]);
        // Byte by byte, in odd chunks, and all at once.
        for chunk in [1, 7, 64, stream.len()] {
            let (out, stats) = run(&stream, chunk, false);
            let bytes: Vec<Vec<u8>> = out.iter().map(|f| f.bytes.clone()).collect();
            assert_eq!(bytes, good, "chunks of {chunk}");
            assert_eq!((stats.captured, stats.dropped), (20, 0));
            for (f, seq) in out.iter().zip(0..) {
                assert_eq!((f.sequence, f.system_id, f.component_id), (seq, 1, 1));
                assert_eq!(f.direction, Direction::In);
                let (_, m) = MavlinkReader::new(&f.bytes[..])
                    .read_message::<MavMessage>(MavlinkVersion::V2)
                    .unwrap();
                assert_eq!(m.message_id(), f.message_id);
                assert_eq!(m.message_name(), f.message_name);
            }
        }
    }

    #[test]
    fn several_frames_in_one_datagram_and_signed_frames_are_found() {
        let key = SigningKey {
            secret: [7; 32],
            link_id: 3,
        };
        let mut encoder = Encoder::new(1, 1, Some(&key));
        let a = encoder.encode(&odometry(1));
        let b = encoder.encode(&MavMessage::HEARTBEAT(HEARTBEAT_DATA::default()));
        let datagram = [&a[..], &[0xAA, 0xBB][..], &b[..]].concat();
        let (out, stats) = run(&datagram, datagram.len(), true);
        assert_eq!(stats.captured, 2);
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].bytes, a);
        assert_eq!(out[1].bytes, b);
        assert!(out[0].signed() && out[1].signed());
        assert_eq!(out[0].message_name, "ODOMETRY");
    }

    #[test]
    fn a_full_queue_drops_and_counts_without_blocking() {
        let (mut capture, queue) = capture(2);
        let bytes = frame(0, &odometry(5));
        for _ in 0..5 {
            capture.sent(&odometry(5), &bytes, 1.0);
        }
        let mut out = Vec::new();
        assert_eq!(queue.drain(&mut out), 2);
        assert_eq!(
            queue.stats(),
            CaptureStats {
                captured: 2,
                dropped: 3,
            }
        );
        assert_eq!(out[0].direction, Direction::Out);
        assert_eq!(out[0].flight_time_s, 1.0);
        // Drained, it takes frames again.
        capture.sent(&odometry(5), &bytes, 2.0);
        assert_eq!(queue.drain(&mut out), 1);
    }

    #[test]
    fn hex_is_two_lower_case_digits_a_byte() {
        assert_eq!(to_hex(&[0xFD, 0x00, 0x0A, 0x7F]), "fd000a7f");
        assert_eq!(to_hex(&[]), "");
    }
}
