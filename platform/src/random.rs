//! The one registry of a run's random streams.
//!
//! Every random draw of a run comes from a ChaCha8 stream of the run seed named here, so
//! adding draws to one stream never shifts another, and a reader of the code finds every
//! source of randomness in one place.
//!
//! | stream | ChaCha stream | draws |
//! |---|---|---|
//! | [`RandomStream::TwinNoise`] | seed, stream 0 | the twin's observation noise and biases |
//! | [`RandomStream::Scene`] | seed, stream 1 | the task scene's randomisation (object poses, sizes) |
//! | [`RandomStream::Policy`] | seed, stream 2 | the scripted policies' offsets |
//! | [`RandomStream::ActionNoise`] | seed, stream 3 | N(0, σ²) on every action value (AMBENCH_SPEC §3.1) |
//! | [`RandomStream::Sensors`] | seed, stream 4 | the simulated IMU and pose sensor (and their biases) |
//! | [`RandomStream::Magnetometer`] | seed, stream 5 | the simulated magnetometer (bias, noise) |
//! | [`RandomStream::Barometer`] | seed, stream 6 | the simulated barometer (bias, drift, noise) |
//! | [`RandomStream::Gnss`] | seed, stream 7 | the simulated GNSS receiver |
//! | [`RandomStream::VisualDomain`] | seed, stream 8 | the cameras' visual domain randomisation |
//! | [`RandomStream::DynamicsForces`] | seed, stream 9 | `amstack platforms --dynamics`'s generalised forces τ (its states: seed, stream 0) |
//! | [`RandomStream::TrackActionNoise`] | seed XOR `"action"`, stream 0 | `amstack track`'s action noise on the reference's base + joint target |
//!
//! `TrackActionNoise` is its own seeding for a historical reason: `track` drew its action
//! noise so before the streams were named, and its results (and logs that `replay`
//! re-flies) are kept bit for bit. New draws take a new stream number here.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A named random stream of a run seed (see the module's table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RandomStream {
    /// The twin's observation noise.
    TwinNoise,
    /// The task scene's randomisation.
    Scene,
    /// The scripted policies' offsets.
    Policy,
    /// Action noise of a rollout (AMBENCH_SPEC §3.1).
    ActionNoise,
    /// The simulated sensors (IMU, pose).
    Sensors,
    /// The simulated magnetometer.
    Magnetometer,
    /// The simulated barometer.
    Barometer,
    /// The simulated GNSS receiver.
    Gnss,
    /// Visual domain randomisation of the cameras.
    VisualDomain,
    /// `amstack track`'s action noise (its historical seeding, kept for its results).
    TrackActionNoise,
    /// The generalised forces at which `amstack platforms --dynamics` writes the forward
    /// dynamics.
    DynamicsForces,
}

/// `"action"` in ASCII: the historical seed offset of [`RandomStream::TrackActionNoise`].
const TRACK_ACTION_SEED_XOR: u64 = 0x6163_7469_6f6e;

impl RandomStream {
    /// The generator of this stream for run seed `seed`, at its start.
    pub fn rng(self, seed: u64) -> ChaCha8Rng {
        let (seed, stream) = match self {
            Self::TwinNoise => (seed, 0),
            Self::Scene => (seed, 1),
            Self::Policy => (seed, 2),
            Self::ActionNoise => (seed, 3),
            Self::Sensors => (seed, 4),
            Self::Magnetometer => (seed, 5),
            Self::Barometer => (seed, 6),
            Self::Gnss => (seed, 7),
            Self::VisualDomain => (seed, 8),
            Self::TrackActionNoise => (seed ^ TRACK_ACTION_SEED_XOR, 0),
            Self::DynamicsForces => (seed, 9),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream);
        rng
    }
}

#[cfg(test)]
mod tests {
    use rand::RngCore;

    use super::*;

    /// Each stream is the ChaCha stream its table row names: stream 0 of a seed is the
    /// seed's plain generator, and no two streams of one seed start alike.
    #[test]
    fn streams_are_the_documented_chacha_streams_and_distinct() {
        let seed = 42;
        assert_eq!(
            RandomStream::TwinNoise.rng(seed).next_u64(),
            ChaCha8Rng::seed_from_u64(seed).next_u64()
        );
        let mut by_hand = ChaCha8Rng::seed_from_u64(seed);
        by_hand.set_stream(3);
        assert_eq!(
            RandomStream::ActionNoise.rng(seed).next_u64(),
            by_hand.next_u64()
        );
        assert_eq!(
            RandomStream::TrackActionNoise.rng(seed).next_u64(),
            ChaCha8Rng::seed_from_u64(seed ^ 0x6163_7469_6f6e).next_u64()
        );
        let all = [
            RandomStream::TwinNoise,
            RandomStream::Scene,
            RandomStream::Policy,
            RandomStream::ActionNoise,
            RandomStream::Sensors,
            RandomStream::Magnetometer,
            RandomStream::Barometer,
            RandomStream::Gnss,
            RandomStream::VisualDomain,
            RandomStream::TrackActionNoise,
            RandomStream::DynamicsForces,
        ];
        let firsts: Vec<u64> = all.iter().map(|s| s.rng(seed).next_u64()).collect();
        for (i, a) in firsts.iter().enumerate() {
            for b in &firsts[i + 1..] {
                assert_ne!(a, b);
            }
        }
    }
}
