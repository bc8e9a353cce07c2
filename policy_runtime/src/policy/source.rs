//! [`PolicySource`]: a learned policy as the flight's action source, at the chunked
//! interface (see the module above).

use std::time::Instant;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use platform::{Measurement, Vehicle};
use serde::Serialize;

use super::chunk::{self, ActionLayout, ActionSemantics};
use super::state::{StateKey, StateReader, wxyz};
use super::{Policy, PolicyConfig, PolicyImage, PolicyLatency, PolicyObservation};
use crate::flight::{ActionSource, Frames, Observation, SourceError, Step};
use crate::metrics::Stats;
use crate::stack::{Action, BaseJointTarget, EeTarget, FlightStack, Interface};

/// What a policy did over one flight.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PolicyStats {
    /// Queries answered (a failed one not counted).
    pub queries: u64,
    /// Order statistics of the answered queries' wall-clock time, ms.
    pub latency_ms: Stats,
    /// Each answered query's wall-clock time, ms (for run-level statistics).
    #[serde(skip)]
    pub latency_samples_ms: Vec<f64>,
    /// Why the policy failed, if it did (the flight ended `policy_failed`).
    pub failure: Option<String>,
}

/// A learned policy flying the chunked interface.
#[derive(Debug)]
pub struct PolicySource {
    config: PolicyConfig,
    layout: ActionLayout,
    semantics: ActionSemantics,
    reader: StateReader,
    state_keys: Vec<StateKey>,
    prompt: String,
    command_to_link: UnitQuaternion<f64>,
    stride: usize,
    dt_s: f64,
    tick_limit: Option<u64>,
    policy: Option<Box<dyn Policy>>,
    start_failure: Option<String>,
    /// The current chunk, absolute, quaternions as answered.
    chunk: Vec<Vec<f64>>,
    /// Index of the next macro action of `chunk`.
    next: usize,
    /// The current macro action's setpoints, and how many were flown.
    plan: Vec<Vec<f64>>,
    flown: usize,
    /// The last setpoint sent (the interpolation's start).
    commanded: Option<Vec<f64>>,
    /// A chunk answered but not yet in effect (latency): the tick it takes effect.
    pending: Option<(u64, Vec<Vec<f64>>)>,
    stats: PolicyStats,
}

impl PolicySource {
    /// A policy flying `vehicle` through `interface` at the control rate `control_hz`;
    /// `default_prompt` when the configuration gives none. Fails on a policy rate that does
    /// not divide the control rate, or a state the vehicle does not have.
    pub fn new(
        config: &PolicyConfig,
        vehicle: &Vehicle,
        interface: Interface,
        control_hz: f64,
        default_prompt: &str,
    ) -> Result<Self, String> {
        let stride = chunk::stride(control_hz, config.policy_hz)?;
        if config.action_steps == 0 {
            return Err("action steps 0: execute at least one action per query".to_owned());
        }
        let layout = match interface {
            Interface::Ee => ActionLayout::Ee,
            Interface::BaseJoint => ActionLayout::BaseJoint {
                arm_joints: vehicle.arm_dof(),
            },
        };
        let state_keys = config.state_keys.clone().unwrap_or_else(|| match layout {
            ActionLayout::Ee => StateKey::EE_DEFAULT.to_vec(),
            ActionLayout::BaseJoint { .. } => StateKey::BASE_JOINT_DEFAULT.to_vec(),
        });
        let reader = StateReader::new(vehicle);
        if let Some(k) = state_keys.iter().find(|k| reader.len(**k) == 0) {
            return Err(format!("state key {}: {} has none", k.name(), vehicle.id));
        }
        Ok(Self {
            semantics: config.endpoint.semantics(),
            config: config.clone(),
            layout,
            reader,
            state_keys,
            prompt: config
                .prompt
                .clone()
                .unwrap_or_else(|| default_prompt.to_owned()),
            command_to_link: vehicle.command_to_link,
            stride,
            dt_s: 1.0 / control_hz,
            tick_limit: None,
            policy: None,
            start_failure: None,
            chunk: Vec::new(),
            next: 0,
            plan: Vec::new(),
            flown: 0,
            commanded: None,
            pending: None,
            stats: PolicyStats::default(),
        })
    }

    /// Flies at most `ticks` ticks (the task's episode).
    #[must_use]
    pub fn with_tick_limit(mut self, ticks: u64) -> Self {
        self.tick_limit = Some(ticks);
        self
    }

    /// Flies `policy` (whose actions are `semantics`) instead of opening the configured
    /// endpoint: a policy of the caller's own.
    #[must_use]
    pub fn with_policy(mut self, policy: Box<dyn Policy>, semantics: ActionSemantics) -> Self {
        self.policy = Some(policy);
        self.semantics = semantics;
        self
    }

    /// What the policy did so far.
    pub fn stats(&self) -> PolicyStats {
        PolicyStats {
            latency_ms: Stats::of(self.stats.latency_samples_ms.iter().copied()),
            ..self.stats.clone()
        }
    }

    /// The pose the relative actions are anchored to: the measured pose of the interface's
    /// body (the EE link, or the base), then the arm joints (base + joints), then the
    /// gripper width.
    fn anchor(&self, m: &Measurement) -> Vec<f64> {
        let keys: &[StateKey] = match self.layout {
            ActionLayout::Ee => &StateKey::EE_DEFAULT,
            ActionLayout::BaseJoint { .. } => &StateKey::BASE_JOINT_DEFAULT,
        };
        self.reader.vector(keys, m)
    }

    /// The setpoint the vehicle holds before the first chunk: the measured pose (the EE in
    /// its command frame), the measured arm joints, and the first action's gripper.
    fn initial_command(&self, m: &Measurement, first: &[f64]) -> Vec<f64> {
        let mut v = match self.layout {
            ActionLayout::Ee => {
                let mut v: Vec<f64> = m.world_from_ee.translation.vector.iter().copied().collect();
                v.extend(wxyz(
                    &(self.command_to_link.inverse() * m.world_from_ee.rotation),
                ));
                v
            }
            ActionLayout::BaseJoint { .. } => {
                let mut v: Vec<f64> = m.base.position_in_world_m.iter().copied().collect();
                v.extend(wxyz(&m.base.world_from_body));
                v.extend(self.reader.arm_joints(m));
                v
            }
        };
        v.push(first[first.len() - 1]);
        v
    }

    /// Whether the next tick queries the policy, unless a pending chunk arrives first.
    fn query_due(&self) -> bool {
        if self.start_failure.is_some() || self.pending.is_some() || self.flown < self.plan.len() {
            // An arriving chunk starts without a query; a macro action in flight goes on.
            return false;
        }
        self.commanded.is_none() || self.next >= self.config.action_steps
    }

    /// Queries the policy on `m` and the images of `frames`: the chunk's actions, absolute
    /// and checked.
    fn query(&mut self, m: &Measurement, frames: Option<&Frames>) -> Result<Vec<Vec<f64>>, String> {
        let relative = self.semantics == ActionSemantics::Relative;
        let anchor_keys: [StateKey; 2] = match self.layout {
            ActionLayout::Ee => [StateKey::EePos, StateKey::EeQuat],
            ActionLayout::BaseJoint { .. } => [StateKey::BasePos, StateKey::BaseQuat],
        };
        let state: Vec<(StateKey, Vec<f64>)> = self
            .state_keys
            .iter()
            .map(|&k| {
                let values = match k {
                    k if relative && k == anchor_keys[0] => vec![0.0; 3],
                    k if relative && k == anchor_keys[1] => vec![1.0, 0.0, 0.0, 0.0],
                    k => {
                        let mut v = Vec::with_capacity(self.reader.len(k));
                        self.reader.read(k, m, &mut v);
                        v
                    }
                };
                (k, values)
            })
            .collect();
        // The reference's adapter sends the EE camera as `ee_image`, the base camera as
        // `base_image`; a flight without cameras sends none (a state-only policy).
        let images: Vec<PolicyImage> = frames
            .into_iter()
            .flat_map(|f| {
                [("ee", "ee_image"), ("base", "base_image")]
                    .into_iter()
                    .filter_map(move |(camera, key)| f.get(camera).map(|c| (c, key)))
            })
            .map(|(c, key)| PolicyImage {
                key: key.to_owned(),
                height: c.image.height as usize,
                width: c.image.width as usize,
                rgb: c.image.rgb.clone(),
            })
            .collect();
        let observation = PolicyObservation {
            state: &state,
            prompt: &self.prompt,
            images: &images,
        };
        let policy = self
            .policy
            .as_mut()
            .ok_or_else(|| "the policy was not started".to_owned())?;
        let started = Instant::now();
        let answer = policy.query(&observation).map_err(|e| e.0)?;
        self.stats
            .latency_samples_ms
            .push(started.elapsed().as_secs_f64() * 1e3);
        self.stats.queries += 1;
        answer.check(self.layout, self.config.action_steps)?;
        let anchor = self.anchor(m);
        Ok((0..answer.rows)
            .map(|i| match self.semantics {
                ActionSemantics::Absolute => answer.row(i).to_vec(),
                ActionSemantics::Relative => {
                    chunk::decode_relative(self.layout, &anchor, answer.row(i))
                }
            })
            .collect())
    }

    /// Ticks between an answer's observation and its effect.
    fn delay_ticks(&self) -> u64 {
        let seconds = match self.config.latency {
            PolicyLatency::Frozen => return 0,
            PolicyLatency::Fixed(ms) => ms / 1e3,
            PolicyLatency::Measured => {
                self.stats.latency_samples_ms.last().copied().unwrap_or(0.0) / 1e3
            }
        };
        // A latency is small and non-negative: the cast is exact.
        (seconds / self.dt_s - 1e-9).ceil().max(0.0) as u64
    }

    fn fail(&mut self, reason: String) -> Step {
        self.stats.failure = Some(reason.clone());
        Step::Failed(reason)
    }

    /// An action vector as the stack's action.
    fn action(&self, v: &[f64]) -> Action {
        let pose = Isometry3::from_parts(
            Translation3::new(v[0], v[1], v[2]),
            UnitQuaternion::from_quaternion(chunk::quat_of(v)),
        );
        let gripper = v[v.len() - 1];
        match self.layout {
            ActionLayout::Ee => Action::Ee(EeTarget {
                world_from_ee_command: pose,
                gripper,
            }),
            ActionLayout::BaseJoint { arm_joints } => Action::BaseJoint(BaseJointTarget {
                world_from_base: pose,
                arm_joints: v[7..7 + arm_joints].to_vec(),
                gripper,
            }),
        }
    }
}

impl ActionSource for PolicySource {
    fn start(&mut self, _first: &Observation<'_>) -> Result<(), SourceError> {
        // A policy that cannot be reached fails the flight at its first tick, as a policy
        // failure (the run goes on), not as an error of the run.
        if self.policy.is_none() {
            match self.config.endpoint.open() {
                Ok(p) => self.policy = Some(p),
                Err(e) => self.start_failure = Some(e.0),
            }
        }
        Ok(())
    }

    fn tick_limit(&self) -> Option<u64> {
        self.tick_limit
    }

    fn wants_frames(&self, k: u64) -> bool {
        // A chunk arriving at k starts without a query.
        self.pending.as_ref().is_none_or(|(ready, _)| k < *ready) && self.query_due()
    }

    fn next(
        &mut self,
        k: u64,
        observation: &Observation<'_>,
        _stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        if let Some(reason) = self.start_failure.take() {
            return Ok(self.fail(reason));
        }
        if self.pending.as_ref().is_some_and(|(ready, _)| k >= *ready)
            && let Some((_, chunk)) = self.pending.take()
        {
            self.chunk = chunk;
            self.next = 0;
            // The new chunk starts now, from wherever the setpoint is.
            self.flown = self.plan.len();
        }
        if self.flown >= self.plan.len() {
            let first = self.commanded.is_none();
            if self.pending.is_none() && (first || self.next >= self.config.action_steps) {
                let chunk = match self.query(observation.measurement, observation.frames) {
                    Ok(c) => c,
                    Err(reason) => return Ok(self.fail(reason)),
                };
                if first {
                    // The first chunk is awaited: the vehicle has nothing to fly before it.
                    self.commanded = Some(self.initial_command(observation.measurement, &chunk[0]));
                }
                match self.delay_ticks() {
                    d if d == 0 || first => {
                        self.chunk = chunk;
                        self.next = 0;
                    }
                    d => self.pending = Some((k + d, chunk)),
                }
            }
            let Some(commanded) = self.commanded.clone() else {
                return Err(SourceError("the policy gave no first action".to_owned()));
            };
            // While a chunk is in flight the vehicle flies what is left of the previous one.
            let more = self.next < self.config.action_steps || self.pending.is_some();
            self.plan = match self.chunk.get(self.next) {
                Some(target) if more => {
                    self.next += 1;
                    chunk::interpolate(&commanded, target, self.stride)
                }
                _ => vec![commanded; self.stride],
            };
            self.flown = 0;
        }
        let setpoint = self.plan[self.flown].clone();
        self.flown += 1;
        let action = self.action(&setpoint);
        self.commanded = Some(setpoint);
        Ok(Step::Act {
            action,
            ee_reference: None,
        })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    use controllers::{ControllerKind, profile};
    use nalgebra::{Isometry3, Vector3};
    use sim_twin::TwinConfig;

    use super::*;
    use crate::policy::{ActionChunk, PolicyEndpoint, PolicyError};

    /// Answers chunk j with positions x = 10·j + 1 … 10·j + H (identity orientation,
    /// gripper +1), and records the EE position it was shown.
    #[derive(Debug)]
    struct Counting {
        horizon: usize,
        queries: usize,
        seen: Arc<Mutex<Vec<Vec<f64>>>>,
        broken_at: Option<usize>,
    }

    impl Policy for Counting {
        fn query(&mut self, o: &PolicyObservation<'_>) -> Result<ActionChunk, PolicyError> {
            self.seen.lock().unwrap().push(o.state[0].1.clone());
            let j = self.queries;
            self.queries += 1;
            let mut values = Vec::new();
            for i in 0..self.horizon {
                values.extend([(10 * j + i + 1) as f64, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
            }
            if self.broken_at == Some(j) {
                values[8] = f64::INFINITY;
            }
            Ok(ActionChunk {
                rows: self.horizon,
                dim: 8,
                values,
            })
        }
    }

    fn source(
        latency: PolicyLatency,
        broken_at: Option<usize>,
    ) -> (PolicySource, FlightStack, Arc<Mutex<Vec<Vec<f64>>>>) {
        let vehicle = Vehicle::builtin("ee-only").unwrap();
        let mut config = PolicyConfig::new(PolicyEndpoint::Remote {
            url: "ws://127.0.0.1:9".to_owned(),
            connect_timeout: Duration::from_millis(1),
            query_timeout: Duration::from_millis(1),
        });
        config.latency = latency;
        let seen = Arc::new(Mutex::new(Vec::new()));
        let policy = Counting {
            horizon: 10,
            queries: 0,
            seen: Arc::clone(&seen),
            broken_at,
        };
        let source = PolicySource::new(&config, &vehicle, Interface::Ee, 120.0, "test")
            .unwrap()
            .with_policy(Box::new(policy), ActionSemantics::Absolute);
        let stack = FlightStack::for_twin(
            vehicle.clone(),
            &profile(&vehicle, ControllerKind::Pid).unwrap(),
            &TwinConfig::default(),
        )
        .unwrap();
        (source, stack, seen)
    }

    /// Flies `ticks` ticks with the EE measured at x = 0.5, z = 1: each tick's commanded x,
    /// or the failure.
    fn fly(
        source: &mut PolicySource,
        stack: &mut FlightStack,
        ticks: u64,
    ) -> Result<Vec<f64>, String> {
        let m = Measurement {
            world_from_ee: Isometry3::translation(0.5, 0.0, 1.0),
            ..Measurement::default()
        };
        let o = Observation {
            time_s: 0.0,
            measurement: &m,
            truth: &m,
            scene: None,
            frames: None,
        };
        source.start(&o).unwrap();
        let mut xs = Vec::new();
        for k in 0..ticks {
            // The images are asked for exactly on the query ticks (every 48).
            if source.start_failure.is_none() {
                assert_eq!(source.wants_frames(k), k % 48 == 0, "tick {k}");
            }
            match source.next(k, &o, stack).unwrap() {
                Step::Act {
                    action: Action::Ee(ee),
                    ..
                } => {
                    let p: Vector3<f64> = ee.world_from_ee_command.translation.vector;
                    assert!(p.iter().all(|v| v.is_finite()));
                    xs.push(p.x);
                }
                Step::Failed(why) => return Err(why),
                other => panic!("{other:?}"),
            }
        }
        Ok(xs)
    }

    #[test]
    fn queries_every_8_macro_steps_and_reaches_each_action_on_its_6th_tick() {
        let (mut s, mut stack, seen) = source(PolicyLatency::Frozen, None);
        let xs = fly(&mut s, &mut stack, 97).unwrap();
        // Queries at ticks 0, 48, 96.
        assert_eq!(s.stats().queries, 3);
        assert_eq!(seen.lock().unwrap().len(), 3);
        // From the measured x = 0.5 to action 0 (x = 1) over 6 ticks.
        assert!((xs[0] - (0.5 + 0.5 / 6.0)).abs() < 1e-12);
        assert_eq!(xs[5], 1.0);
        // Action 7 (x = 8) reached at tick 47; the next chunk's first (x = 11) at 53.
        assert_eq!(xs[47], 8.0);
        assert!((xs[48] - (8.0 + 3.0 / 6.0)).abs() < 1e-12);
        assert_eq!(xs[53], 11.0);
        // Actions 8 and 9 of a chunk are never flown with time frozen: from x = 8 straight
        // to the next chunk's first action.
        for j in 1..=6 {
            assert!((xs[47 + j] - (8.0 + 3.0 * j as f64 / 6.0)).abs() < 1e-12);
        }
    }

    #[test]
    fn with_latency_the_rest_of_the_chunk_is_flown_until_the_answer_arrives() {
        // 100 ms = 12 ticks: the chunk queried at tick 48 takes effect at tick 60.
        let (mut s, mut stack, _) = source(PolicyLatency::Fixed(100.0), None);
        let xs = fly(&mut s, &mut stack, 72).unwrap();
        assert_eq!(xs[53], 9.0);
        assert_eq!(xs[59], 10.0);
        // From x = 10 to the new chunk's first action (x = 11) from tick 60.
        assert!((xs[60] - (10.0 + 1.0 / 6.0)).abs() < 1e-12);
        assert_eq!(xs[65], 11.0);
    }

    #[test]
    fn a_non_finite_chunk_fails_the_flight_and_is_never_flown() {
        let (mut s, mut stack, _) = source(PolicyLatency::Frozen, Some(1));
        let why = fly(&mut s, &mut stack, 96).unwrap_err();
        assert!(
            why.contains("non-finite value inf at actions[1, 0]"),
            "{why}"
        );
        assert_eq!(s.stats().failure, Some(why));
        assert_eq!(s.stats().queries, 2);
    }

    #[test]
    fn a_policy_that_cannot_be_reached_fails_at_the_first_tick() {
        let vehicle = Vehicle::builtin("ee-only").unwrap();
        // Port 9 (discard) on the loopback: nothing listens.
        let config = PolicyConfig::new(PolicyEndpoint::Remote {
            url: "ws://127.0.0.1:9".to_owned(),
            connect_timeout: Duration::from_millis(500),
            query_timeout: Duration::from_millis(500),
        });
        let mut s = PolicySource::new(&config, &vehicle, Interface::Ee, 120.0, "test").unwrap();
        let mut stack = FlightStack::for_twin(
            vehicle.clone(),
            &profile(&vehicle, ControllerKind::Pid).unwrap(),
            &TwinConfig::default(),
        )
        .unwrap();
        let why = fly(&mut s, &mut stack, 1).unwrap_err();
        assert!(why.contains("ws://127.0.0.1:9: cannot connect"), "{why}");
    }

    #[test]
    fn a_rate_that_does_not_divide_the_control_rate_is_refused() {
        let vehicle = Vehicle::builtin("ee-only").unwrap();
        let mut config = PolicyConfig::new(PolicyEndpoint::Remote {
            url: "ws://127.0.0.1:9".to_owned(),
            connect_timeout: Duration::from_millis(1),
            query_timeout: Duration::from_millis(1),
        });
        config.policy_hz = 50.0;
        let e = PolicySource::new(&config, &vehicle, Interface::Ee, 120.0, "test").unwrap_err();
        assert!(
            e.contains("50 Hz does not divide the control rate 120 Hz"),
            "{e}"
        );
    }
}
