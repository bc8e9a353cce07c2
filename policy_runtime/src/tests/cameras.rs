//! Cameras in the one flight loop: the images of observation k are a render of the twin's
//! state at k (after the step of tick k−1), rendered only on the ticks someone asks for, and
//! shown to the source and observers as asked.

use controllers::{ControllerKind, profile};
use platform::{Measurement, Vehicle};
use render::{CameraSpec, RenderError, Renderer, Snapshot, VisualDr};
use sim_twin::{TaskId, Twin, TwinConfig};

use crate::flight::{
    ActionSource, CameraRig, Decided, EpisodeLength, FlightEnd, FlightError, FlightSpec, Flow,
    FrameUse, Frames, Observation, Observer, ScriptedTask, SourceError, Step, Stepped,
    select_cameras,
};
use crate::link::{Link, LinkError, Setpoint, TwinLink};
use crate::stack::{FlightStack, Interface};
use crate::state_source::StateSource;

const SEED: u64 = 3;
const TASK: TaskId = TaskId::PressButton;

fn fa_hexa() -> Vehicle {
    Vehicle::builtin("fa-hexa").unwrap_or_else(|e| panic!("{e}"))
}

fn twin_config() -> TwinConfig {
    TwinConfig {
        task: Some(TASK),
        seed: SEED,
        ..TwinConfig::default()
    }
}

/// A rig of the EE and base cameras, or None on a machine without an adapter (skipped).
fn rig(vehicle: &Vehicle, dr: VisualDr) -> Option<(CameraRig, Vec<CameraSpec>)> {
    let specs = select_cameras(vehicle, &["ee", "base"]).unwrap_or_else(|e| panic!("{e}"));
    match CameraRig::new(vehicle, &specs, dr) {
        Ok(r) => Some((r, specs)),
        Err(RenderError::NoAdapter(reason)) => {
            eprintln!("SKIPPED: no graphics adapter on this machine ({reason})");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// The scripted Press Button policy for `limit` ticks, asking for images on `query` ticks and
/// keeping them with the observation's true measurement.
struct Querying {
    inner: ScriptedTask,
    limit: u64,
    query: Vec<u64>,
    seen: Vec<(Frames, Measurement)>,
    /// Ticks whose observation carried images.
    given: Vec<u64>,
}

impl Querying {
    fn new(limit: u64, query: &[u64]) -> Self {
        Self {
            inner: ScriptedTask::new(TASK, SEED, 120.0, EpisodeLength::Spec),
            limit,
            query: query.to_vec(),
            seen: Vec::new(),
            given: Vec::new(),
        }
    }
}

impl ActionSource for Querying {
    fn start(&mut self, first: &Observation<'_>) -> Result<(), SourceError> {
        assert!(first.frames.is_none(), "no images at start");
        self.inner.start(first)
    }

    fn tick_limit(&self) -> Option<u64> {
        Some(self.limit)
    }

    fn wants_frames(&self, k: u64) -> bool {
        self.query.contains(&k)
    }

    fn next(
        &mut self,
        k: u64,
        observation: &Observation<'_>,
        stack: &mut FlightStack,
    ) -> Result<Step, SourceError> {
        if let Some(frames) = observation.frames {
            self.given.push(k);
            self.seen.push((frames.clone(), observation.truth.clone()));
        }
        self.inner.next(k, observation, stack)
    }
}

/// An observer asking for images at `at` (`FrameUse::Decided` or `Stepped`), keeping what
/// `Decided` and `Stepped` carried.
struct Watching {
    at: Vec<u64>,
    how: FrameUse,
    decided: Vec<(u64, Frames)>,
    stepped: Vec<(u64, Frames)>,
}

impl Watching {
    fn new(at: &[u64], how: FrameUse) -> Self {
        Self {
            at: at.to_vec(),
            how,
            decided: Vec::new(),
            stepped: Vec::new(),
        }
    }
}

impl Observer for Watching {
    fn wants_frames(&self, k: u64) -> FrameUse {
        if self.at.contains(&k) {
            self.how
        } else {
            FrameUse::None
        }
    }

    fn decided(&mut self, tick: &Decided<'_>) -> Result<(), FlightError> {
        if let Some(f) = tick.frames {
            self.decided.push((tick.k, f.clone()));
        }
        Ok(())
    }

    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        if let Some(f) = step.frames {
            self.stepped.push((step.k, f.clone()));
        }
        Ok(Flow::Continue)
    }
}

fn spec<'a>(ticks: u64, cameras: Option<&'a mut CameraRig>) -> FlightSpec<'a> {
    FlightSpec {
        max_ticks: ticks,
        dt_s: twin_config().control_dt_s(),
        control_rate_hz: twin_config().control_rate_hz,
        seed: SEED,
        state_source: StateSource::Truth,
        score_from_s: 0.0,
        interface: Some(Interface::Ee),
        action_noise: None,
        stop: None,
        cameras,
    }
}

fn stack(vehicle: &Vehicle) -> FlightStack {
    let controller = profile(vehicle, ControllerKind::Pid).unwrap_or_else(|e| panic!("{e}"));
    FlightStack::for_twin(vehicle.clone(), &controller, &twin_config())
        .unwrap_or_else(|e| panic!("{e}"))
}

fn twin_link(vehicle: &Vehicle) -> TwinLink {
    TwinLink::new(Twin::new(vehicle.clone(), twin_config()).unwrap_or_else(|e| panic!("{e}")))
}

/// Flies `ticks` ticks of the scripted Press Button (no cameras unless `rig`).
fn fly(
    vehicle: &Vehicle,
    link: &mut dyn Link,
    source: &mut dyn ActionSource,
    observers: &mut [&mut dyn Observer],
    ticks: u64,
    rig: Option<&mut CameraRig>,
) -> Result<FlightEnd, FlightError> {
    crate::flight::run(
        link,
        &mut stack(vehicle),
        source,
        observers,
        spec(ticks, rig),
    )
}

/// A standalone render of the cameras at the state of `twin` (a renderer of its own).
fn render_standalone(vehicle: &Vehicle, specs: &[CameraSpec], twin: &Twin) -> Frames {
    let mut renderer =
        Renderer::new(vehicle, specs, VisualDr::Off).unwrap_or_else(|e| panic!("{e}"));
    renderer
        .reset_scene(&twin.scene_visuals(), SEED)
        .unwrap_or_else(|e| panic!("{e}"));
    let state = Snapshot::of_twin(twin);
    Frames {
        k: 0,
        time_s: twin.time_s(),
        cameras: specs
            .iter()
            .enumerate()
            .map(|(i, s)| crate::flight::CameraFrame {
                name: s.name.clone(),
                image: renderer.render(&state, i).unwrap_or_else(|e| panic!("{e}")),
                intrinsics: s.intrinsics,
                world_from_camera: renderer
                    .world_from_camera(&state, i)
                    .unwrap_or_else(|e| panic!("{e}")),
            })
            .collect(),
    }
}

fn assert_same_images(observed: &Frames, standalone: &Frames, what: &str) {
    assert_eq!(observed.cameras.len(), standalone.cameras.len(), "{what}");
    for (o, s) in observed.cameras.iter().zip(&standalone.cameras) {
        assert_eq!(o.name, s.name, "{what}");
        assert_eq!(
            (o.image.width, o.image.height),
            (384, 384),
            "{what}: {}",
            o.name
        );
        assert!(
            o.image.rgb == s.image.rgb,
            "{what}: {} differs from the standalone render",
            o.name
        );
        assert_eq!(
            o.world_from_camera, s.world_from_camera,
            "{what}: {}",
            o.name
        );
        assert_eq!(o.intrinsics, s.intrinsics, "{what}: {}", o.name);
    }
}

#[test]
fn images_of_observation_k_are_a_render_of_the_state_at_k_shown_as_asked() {
    let vehicle = fa_hexa();
    let Some((mut rig, specs)) = rig(&vehicle, VisualDr::Off) else {
        return;
    };
    const LAST: u64 = 25;
    let mut source = Querying::new(LAST + 1, &[0, LAST]);
    let mut at_decided = Watching::new(&[10], FrameUse::Decided);
    let mut at_stepped = Watching::new(&[5, 10], FrameUse::Stepped);
    let mut link = twin_link(&vehicle);
    let end = fly(
        &vehicle,
        &mut link,
        &mut source,
        &mut [&mut at_decided, &mut at_stepped],
        LAST + 1,
        Some(&mut rig),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(end.ticks, LAST + 1);
    // Rendered on the asked ticks only: 0 and 25 (source), 5 (stepped), 10 (both observers).
    assert_eq!(end.frames_rendered, 4);
    assert_eq!(source.given, vec![0, LAST]);
    let ks = |v: &[(u64, Frames)]| v.iter().map(|(k, f)| (*k, f.k)).collect::<Vec<_>>();
    // Decided carries them where the source or a Decided observer asked; Stepped wherever
    // they were rendered; always the images of that tick's observation.
    assert_eq!(
        ks(&at_decided.decided),
        vec![(0, 0), (10, 10), (LAST, LAST)]
    );
    assert_eq!(
        ks(&at_stepped.stepped),
        vec![(0, 0), (5, 5), (10, 10), (LAST, LAST)]
    );
    assert_eq!(at_stepped.decided.len(), at_decided.decided.len());
    let (frames_25, truth_25) = &source.seen[1];
    assert_eq!(frames_25.k, LAST);
    assert_eq!(frames_25.time_s.to_bits(), truth_25.time_s.to_bits());
    assert!(frames_25.get("ee").is_some() && frames_25.get("base_camera").is_some());
    assert_eq!(&at_decided.decided[2].1, frames_25);
    assert_eq!(&at_stepped.stepped[3].1, frames_25);

    // The state at k = 25 flown again without cameras (25 steps), rendered on its own: the same
    // pixels and camera poses, and the same flight (rendering changes nothing).
    let mut plain = Querying::new(LAST, &[]);
    let mut again = twin_link(&vehicle);
    let end = fly(&vehicle, &mut again, &mut plain, &mut [], LAST, None)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(end.frames_rendered, 0);
    let truth = again.twin().truth();
    assert_eq!(truth.time_s.to_bits(), truth_25.time_s.to_bits());
    assert_eq!(
        truth.base.position_in_world_m,
        truth_25.base.position_in_world_m
    );
    assert_eq!(truth.joint_positions, truth_25.joint_positions);
    assert_same_images(
        frames_25,
        &render_standalone(&vehicle, &specs, again.twin()),
        "k = 25",
    );
    // k = 0: the state at reset.
    assert_same_images(
        &source.seen[0].0,
        &render_standalone(&vehicle, &specs, twin_link(&vehicle).twin()),
        "k = 0",
    );
    // The EE camera moved between the two observations (the policy flew).
    assert_ne!(
        source.seen[0].0.cameras[0].world_from_camera,
        frames_25.cameras[0].world_from_camera
    );
}

#[test]
fn a_rig_is_reused_and_the_same_seed_gives_the_same_pixels() {
    let vehicle = fa_hexa();
    let Some((mut rig, _)) = rig(&vehicle, VisualDr::On) else {
        return;
    };
    let mut flights = Vec::new();
    for _ in 0..2 {
        let mut source = Querying::new(13, &[12]);
        fly(
            &vehicle,
            &mut twin_link(&vehicle),
            &mut source,
            &mut [],
            13,
            Some(&mut rig),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        flights.push(source.seen.remove(0).0);
    }
    assert_eq!(flights[0], flights[1]);
    assert_eq!(rig.rendered(), 2);
}

/// The in-process twin behind a link that does not offer its state to cameras (as the links
/// to another process or an autopilot).
struct Remote(TwinLink);

impl Link for Remote {
    fn receive(&mut self) -> Result<Measurement, LinkError> {
        self.0.receive()
    }
    fn send(&mut self, setpoint: &Setpoint) -> Result<(), LinkError> {
        self.0.send(setpoint)
    }
    fn name(&self) -> String {
        "remote".to_owned()
    }
}

#[test]
fn cameras_over_a_link_that_cannot_render_are_refused_at_start() {
    let vehicle = fa_hexa();
    let Some((mut rig, _)) = rig(&vehicle, VisualDr::Off) else {
        return;
    };
    let mut source = Querying::new(5, &[0]);
    let mut link = Remote(twin_link(&vehicle));
    match fly(&vehicle, &mut link, &mut source, &mut [], 5, Some(&mut rig)) {
        Err(e @ FlightError::CamerasNeedTwin(_)) => {
            let text = e.to_string();
            assert!(
                text.contains("remote") && text.contains("--link twin"),
                "{text}"
            );
        }
        other => panic!("expected CamerasNeedTwin, got {other:?}"),
    }
    assert_eq!(link.0.twin().time_s(), 0.0, "nothing flown");
}
