//! The autopilot's end of the MAVLink 2 codec, `firmware_bridge::wire` (the bridge's too):
//! frame splitting, CRC, unknown-id, truncation and signature checks, counting by kind and
//! encoding live there. This file only bundles a decoder, an encoder and the counters of the
//! autopilot's one link, and keeps the autopilot's signing settings (as its command line
//! gives them).

use std::sync::atomic::Ordering;

use firmware_bridge::wire::{Counters, Decoder, Encoder, SigningKey};
use mavlink::dialects::common::MavMessage;

/// The link's counters: what the codec threw away and kept, by kind, and the messages the
/// autopilot ignored as input (`rejected_input`). Its Display is the line printed at exit.
pub use firmware_bridge::wire::CounterSnapshot as LinkCounters;
/// A decoded, accepted frame (header with the sender's system and component ids).
pub use firmware_bridge::wire::Frame;

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
        SigningKey::from_bytes(bytes, 0).map(|k| k.secret)
    }

    /// The codec's settings.
    fn to_wire(&self) -> firmware_bridge::wire::Signing {
        firmware_bridge::wire::Signing {
            key: SigningKey {
                secret: self.key,
                link_id: self.link_id,
            },
            require: self.require,
        }
    }
}

/// Frames in and out of one link: decoder (MAVLink 2 and 1), encoders (own ids, sequence,
/// signing; MAVLink 1 for the peers that speak it), counters.
#[derive(Debug)]
pub struct Wire {
    decoder: Decoder,
    encoder: Encoder,
    encoder_v1: Encoder,
    counters: Counters,
}

impl Wire {
    /// A wire speaking as `system_id`/`component_id`, signing with `signing` if given.
    pub fn new(system_id: u8, component_id: u8, signing: Option<&Signing>) -> Self {
        let signing = signing.map(Signing::to_wire);
        Self {
            decoder: Decoder::new(signing.as_ref()).accepting_v1(true),
            encoder: Encoder::new(system_id, component_id, signing.as_ref().map(|s| &s.key)),
            encoder_v1: Encoder::new(system_id, component_id, None),
            counters: Counters::default(),
        }
    }

    /// The counters so far.
    pub fn counters(&self) -> LinkCounters {
        self.counters.snapshot()
    }

    /// Counts a well-formed message the autopilot ignores.
    pub fn count_rejected_input(&self) {
        self.counters.rejected_input.fetch_add(1, Ordering::Relaxed);
    }

    /// Decodes one datagram (every frame in it; a frame cut short at its end is truncated).
    pub fn datagram(&mut self, bytes: &[u8], out: &mut Vec<Frame>) {
        self.decoder.push_datagram(bytes, &self.counters, out);
    }

    /// Decodes stream bytes (serial): a frame cut short waits for the rest.
    pub fn stream(&mut self, bytes: &[u8], out: &mut Vec<Frame>) {
        self.decoder.push_stream(bytes, &self.counters, out);
    }

    /// Encodes `message` (signed when signing is on), appending it to `out`.
    pub fn encode(&mut self, message: &MavMessage, out: &mut Vec<u8>) {
        self.encoder.encode_into(message, out);
    }

    /// Encodes `message` as MAVLink 1 (its own sequence; extensions dropped), appending it to
    /// `out`; false (nothing appended) for a message id above 255, which PX4 does not send to
    /// a MAVLink 1 peer either.
    pub fn encode_v1(&mut self, message: &MavMessage, out: &mut Vec<u8>) -> bool {
        self.encoder_v1.encode_v1_into(message, out)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    //! The codec itself is tested in `firmware_bridge` (every case: garbage, truncated, bad
    //! CRC, unknown id, unsigned and forged frames with signing required, random bytes); here
    //! the autopilot's settings and counters reach it.
    use super::*;
    use mavlink::dialects::common::HEARTBEAT_DATA;

    fn heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA::default())
    }

    #[test]
    fn the_autopilot_signing_settings_reach_the_codec() {
        let signing = Signing {
            key: [7u8; 32],
            link_id: 3,
            require: true,
        };
        let mut rx = Wire::new(1, 1, Some(&signing));
        let mut out = Vec::new();
        let mut bytes = Vec::new();
        Wire::new(255, 190, None).encode(&heartbeat(), &mut bytes);
        rx.datagram(&bytes, &mut out);
        assert_eq!(rx.counters().refused_unsigned, 1);
        let forger = Signing {
            key: [8u8; 32],
            ..signing.clone()
        };
        bytes.clear();
        Wire::new(255, 190, Some(&forger)).encode(&heartbeat(), &mut bytes);
        rx.datagram(&bytes, &mut out);
        assert_eq!(rx.counters().refused_bad_signature, 1);
        assert!(out.is_empty());
        // Signed, with the link id first in the signature (after header, payload and CRC).
        bytes.clear();
        let mut honest = Wire::new(255, 190, Some(&signing));
        honest.encode(&heartbeat(), &mut bytes);
        let payload_len = usize::from(bytes[1]);
        assert_eq!(bytes[2] & 1, 1, "signed");
        assert_eq!(bytes[10 + payload_len + 2], 3, "link id");
        // Two frames appended to one buffer: one datagram, both decode, over a stream too.
        honest.encode(&heartbeat(), &mut bytes);
        rx.datagram(&bytes, &mut out);
        assert_eq!(out.len(), 2);
        assert_eq!(
            (out[0].header.system_id, out[0].header.component_id),
            (255, 190)
        );
        assert_eq!(out[1].header.sequence, 1);
    }

    #[test]
    fn rejected_input_is_counted_and_printed_but_not_a_bad_frame() {
        let wire = Wire::new(1, 1, None);
        wire.count_rejected_input();
        let c = wire.counters();
        assert_eq!(c.rejected_input, 1);
        assert_eq!(c.bad_frames(), 0);
        assert!(c.to_string().ends_with("rejected input 1"), "{c}");
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
