//! The task scene over MAVLink: the twin's autopilot sends the scene's state as the
//! contract's SITL extension (DEBUG_FLOAT_ARRAY "task"); the names and lengths of its
//! observation keys come from the scene built on the flight side from the task and the seed
//! (the *scene model*), which also checks that the autopilot serves the same scene.

use std::borrow::Cow;

use firmware_bridge::TaskArray;
use sim_twin::{TaskId, TaskObservation, TaskSnapshot, TaskStatus};

/// The most a value of the autopilot's task state at reset may differ from the scene
/// model's: f32 rounding of values of a few metres is below 1e-6; a different seed moves
/// objects by centimetres.
const SCENE_MATCH_TOLERANCE: f64 = 1e-4;

/// The scene model's snapshot with the state the autopilot sent. `None` if the array does not
/// fit the model's keys.
pub(crate) fn snapshot_from_wire(model: &TaskSnapshot, wire: &TaskArray) -> Option<TaskSnapshot> {
    let lengths: usize = model.observation.entries.iter().map(|(_, v)| v.len()).sum();
    if lengths != wire.values.len() || wire.criteria.len() != model.status.criteria.len() {
        return None;
    }
    let mut values = wire.values.iter().copied();
    let entries = model
        .observation
        .entries
        .iter()
        .map(|(name, v)| (name.clone(), values.by_ref().take(v.len()).collect()))
        .collect::<Vec<(Cow<'static, str>, Vec<f64>)>>();
    Some(TaskSnapshot {
        task: model.task,
        status: TaskStatus {
            success: wire.success,
            criteria: wire.criteria.clone(),
        },
        observation: TaskObservation { entries },
        wall: wire.wall,
        obstacle_face_x: wire.obstacle_face_x_m,
        holding: wire.holding,
        held_joint: wire.held_joint,
        hand_contact: wire.hand_contact,
        steps: wire.steps,
    })
}

/// Checks that the autopilot's task state at reset is the scene model's: the same task, the
/// same keys, the same layout (the same seed).
pub(crate) fn check_scene(model: &TaskSnapshot, wire: &TaskArray) -> Result<(), String> {
    let served = usize::try_from(wire.task_number)
        .ok()
        .and_then(|n| n.checked_sub(1))
        .and_then(|i| TaskId::ALL.get(i));
    if served != Some(&model.task) {
        return Err(format!(
            "the autopilot serves {}, the flight is {}: start it with --task {}",
            served.map_or("no task".to_owned(), |t| format!("task {}", t.name())),
            model.task.name(),
            model.task.name()
        ));
    }
    let Some(snapshot) = snapshot_from_wire(model, wire) else {
        return Err(format!(
            "the autopilot's {} state has {} observation values and {} criteria, the scene \
             model {} and {}",
            model.task.name(),
            wire.values.len(),
            wire.criteria.len(),
            model
                .observation
                .entries
                .iter()
                .map(|(_, v)| v.len())
                .sum::<usize>(),
            model.status.criteria.len()
        ));
    };
    for ((name, ours), (_, theirs)) in model
        .observation
        .entries
        .iter()
        .zip(&snapshot.observation.entries)
    {
        let d = ours
            .iter()
            .zip(theirs)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if d > SCENE_MATCH_TOLERANCE {
            return Err(format!(
                "the autopilot's {} scene differs from this rollout's: {name} is {theirs:.4?} \
                 there, {ours:.4?} here (serve it with the same --seed and settings)",
                model.task.name()
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests: a failed set-up fails loudly"
)]
mod tests {
    use mavlink::dialects::common::MavMessage;
    use platform::Vehicle;
    use sim_twin::{Twin, TwinConfig};
    use twin_autopilot::telemetry::task_array;

    use super::*;

    /// The scene of `task` at `seed` (FA-Hexa), and its state as the twin's autopilot sends it.
    fn scene(task: TaskId, seed: u64) -> (TaskSnapshot, TaskArray) {
        let vehicle = Vehicle::builtin("fa-hexa").unwrap();
        let config = TwinConfig {
            task: Some(task),
            seed,
            ..TwinConfig::default()
        };
        let twin = Twin::new(vehicle, config).unwrap();
        let snapshot = twin.task_snapshot().unwrap();
        let Some(MavMessage::DEBUG_FLOAT_ARRAY(d)) = task_array(twin.truth(), &snapshot) else {
            panic!("a task array");
        };
        (snapshot, TaskArray::decode(&d).unwrap())
    }

    #[test]
    fn the_wire_state_of_the_same_scene_is_the_model_to_f32_precision() {
        let (model, wire) = scene(TaskId::PushSlider, 3);
        check_scene(&model, &wire).unwrap();
        let got = snapshot_from_wire(&model, &wire).unwrap();
        assert_eq!(
            got.observation.entries.len(),
            model.observation.entries.len()
        );
        for ((n, a), (m, b)) in got
            .observation
            .entries
            .iter()
            .zip(&model.observation.entries)
        {
            assert_eq!(n, m);
            for (x, y) in a.iter().zip(b) {
                // f32 keeps 24 bits: ≤ 2⁻²⁴ relative.
                assert!((x - y).abs() <= y.abs() * 6e-8 + 1e-12, "{n}: {x} vs {y}");
            }
        }
        assert_eq!(got.status, model.status);
        assert_eq!(got.steps, model.steps);
    }

    #[test]
    fn another_seed_or_task_on_the_autopilot_is_refused_by_name() {
        let (model, _) = scene(TaskId::PushSlider, 3);
        let (_, other_seed) = scene(TaskId::PushSlider, 4);
        let e = check_scene(&model, &other_seed).unwrap_err();
        assert!(e.contains("slider_body_pos") && e.contains("--seed"), "{e}");
        let (_, other_task) = scene(TaskId::PressButton, 3);
        let e = check_scene(&model, &other_task).unwrap_err();
        assert!(
            e.contains("serves task press-button") && e.contains("--task push-slider"),
            "{e}"
        );
    }
}
