//! Which rotors reach a thrust limit in a flight log, when, and for how long.
//!
//! Read from the log's `/rotors.realised_n` (the thrust the motors produced, logged one
//! control period after the tick) and `/control/wrench` (the wrench the allocator could not
//! deliver). A rotor is at a limit where [`allocation::RotorSaturation::of`] says so: within
//! [`allocation::SATURATION_TOLERANCE_N`] of T_max (tested first) or of T_min — the
//! classification the flight's own saturation indicator uses.
//! `scripts/rotor_saturation.py` computes the same summary with the PyPI `mcap` reader and
//! is the independent check of this one.

use allocation::RotorSaturation;
use serde::Serialize;

use super::FlightLogFile;
use super::signals::{self, SignalError};

/// A wrench component above this magnitude is "unallocated" (N or N·m; the allocator's
/// round-off is ~1e-12).
pub const UNALLOCATED_TOLERANCE: f64 = 1e-9;

/// One rotor against its thrust limits over a flight.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RotorLimitUse {
    /// Rotor index (the vehicle's rotor order, from 0).
    pub rotor: usize,
    /// First time the realised thrust is at T_max, s (log time; null: never).
    pub first_at_max_s: Option<f64>,
    /// First time it is at T_min, s (null: never).
    pub first_at_min_s: Option<f64>,
    /// Logged ticks at T_max.
    pub ticks_at_max: usize,
    /// Logged ticks at T_min.
    pub ticks_at_min: usize,
    /// Share of the logged ticks at either limit, 0–1.
    pub share_at_limit: f64,
    /// Longest unbroken stretch at a limit (either, possibly switching), s: from its first
    /// tick to one log period after its last.
    pub longest_at_limit_s: f64,
    /// Largest realised thrust, N.
    pub max_thrust_n: f64,
}

/// Every rotor of one flight log against its thrust limits.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SaturationSummary {
    /// T_min, N.
    pub thrust_min_n: f64,
    /// T_max, N.
    pub thrust_max_n: f64,
    /// `/rotors` messages read.
    pub ticks: usize,
    /// Per rotor, in rotor order.
    pub rotors: Vec<RotorLimitUse>,
    /// First time the allocator reported an unallocated force or torque, s (null: never).
    pub first_unallocated_s: Option<f64>,
}

impl SaturationSummary {
    /// The rotors that reached a limit at least once.
    pub fn saturated_rotors(&self) -> Vec<usize> {
        self.rotors
            .iter()
            .filter(|r| r.ticks_at_max + r.ticks_at_min > 0)
            .map(|r| r.rotor)
            .collect()
    }
}

/// Summarises `log`'s rotors against `[thrust_min_n, thrust_max_n]`. A log without `/rotors`
/// or `/control/wrench` is a [`SignalError`] naming the file and what is missing.
pub fn rotor_saturation(
    log: &FlightLogFile,
    thrust_min_n: f64,
    thrust_max_n: f64,
) -> Result<SaturationSummary, SignalError> {
    let file = log.path.display().to_string();
    let recording = &log.recording;
    let rotor_paths = signals::resolve(recording, &file, "/rotors.realised_n")?;
    let mut rotors = Vec::with_capacity(rotor_paths.len());
    let mut ticks = 0;
    for (rotor, path) in rotor_paths.iter().enumerate() {
        let series = signals::extract(recording, &file, path)?;
        ticks = series.values.len();
        // The log period: the flight's control period (uniform ticks).
        let period_s = match (series.times_s.first(), series.times_s.last()) {
            (Some(a), Some(b)) if ticks > 1 => (b - a) / (ticks - 1) as f64,
            _ => 0.0,
        };
        let mut use_ = RotorLimitUse {
            rotor,
            first_at_max_s: None,
            first_at_min_s: None,
            ticks_at_max: 0,
            ticks_at_min: 0,
            share_at_limit: 0.0,
            longest_at_limit_s: 0.0,
            max_thrust_n: f64::NEG_INFINITY,
        };
        let mut run_start: Option<f64> = None;
        for (&t, &thrust) in series.times_s.iter().zip(&series.values) {
            use_.max_thrust_n = use_.max_thrust_n.max(thrust);
            let state = RotorSaturation::of(thrust, thrust_min_n, thrust_max_n);
            match state {
                RotorSaturation::Upper => {
                    use_.first_at_max_s.get_or_insert(t);
                    use_.ticks_at_max += 1;
                }
                RotorSaturation::Lower => {
                    use_.first_at_min_s.get_or_insert(t);
                    use_.ticks_at_min += 1;
                }
                RotorSaturation::None => {}
            }
            if state.is_saturated() {
                let start = *run_start.get_or_insert(t);
                use_.longest_at_limit_s = use_.longest_at_limit_s.max(t - start + period_s);
            } else {
                run_start = None;
            }
        }
        if ticks > 0 {
            use_.share_at_limit = (use_.ticks_at_max + use_.ticks_at_min) as f64 / ticks as f64;
        }
        rotors.push(use_);
    }
    let mut first_unallocated_s: Option<f64> = None;
    for field in [
        "/control/wrench.unallocated_force_n",
        "/control/wrench.unallocated_torque_nm",
    ] {
        for path in signals::resolve(recording, &file, field)? {
            let series = signals::extract(recording, &file, &path)?;
            let first = series
                .times_s
                .iter()
                .zip(&series.values)
                .find(|(_, v)| v.abs() > UNALLOCATED_TOLERANCE)
                .map(|(t, _)| *t);
            if let Some(t) = first {
                first_unallocated_s = Some(first_unallocated_s.map_or(t, |f| f.min(t)));
            }
        }
    }
    Ok(SaturationSummary {
        thrust_min_n,
        thrust_max_n,
        ticks,
        rotors,
        first_unallocated_s,
    })
}
