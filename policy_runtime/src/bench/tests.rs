//! Benchmark runner tests.

use std::sync::atomic::AtomicBool;

use controllers::{ControllerKind, profile};
use platform::Vehicle;
use sim_twin::{TaskId, Twin, TwinConfig};

use super::*;

fn config(vehicle: &str, controller: ControllerKind, interface: Interface) -> BenchConfig {
    let vehicle = Vehicle::builtin(vehicle).unwrap_or_else(|e| panic!("{e}"));
    BenchConfig {
        controller: profile(&vehicle, controller).unwrap_or_else(|e| panic!("{e}")),
        controller_name: "test".to_owned(),
        vehicle,
        interface,
        tasks: Vec::new(),
        rollouts: 1,
        seed: 0,
        twin: TwinConfig::default(),
        jobs: 1,
        episode: EpisodeLength::Script,
        mcap_dir: None,
        link: BenchLink::InProcess,
    }
}

/// A scripted rollout at its start, as the runner sets it up (PID, EE interface, ideal
/// rotors): the twin with `task` at `seed`, the stack, the reset measurement, the policy's
/// context and the policy (its own stream of the seed).
fn scripted_start(
    task: TaskId,
    vehicle: &str,
    seed: u64,
) -> (
    Twin,
    FlightStack,
    platform::Measurement,
    PolicyContext,
    Box<dyn crate::task_policies::TaskPolicy>,
) {
    let cfg = config(vehicle, ControllerKind::Pid, Interface::Ee);
    let twin_config = TwinConfig {
        task: Some(task),
        seed,
        ..TwinConfig::default()
    };
    let mut stack = FlightStack::for_twin(cfg.vehicle.clone(), &cfg.controller, &twin_config)
        .unwrap_or_else(|e| panic!("{e}"));
    let twin = Twin::new(cfg.vehicle.clone(), twin_config).unwrap_or_else(|e| panic!("{e}"));
    let m = twin.truth().clone();
    stack.reset_at(&m.base, &m.joint_positions);
    let ctx = PolicyContext {
        init: m.world_from_ee.translation.vector,
        task: twin.task_observation().unwrap_or_default(),
        wall: twin.task_wall(),
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(2);
    let policy = scripted(task, &ctx, &mut rng).unwrap_or_else(|e| panic!("{e}"));
    (twin, stack, m, ctx, policy)
}

/// Prints a rollout's trace every `AMSTACK_TRACE_EVERY` steps (default 60):
/// `AMSTACK_TRACE=task[:vehicle[:seed]] cargo test -p policy_runtime trace -- --ignored
/// --nocapture`.
#[test]
#[ignore = "a debugging aid, not a test"]
fn trace() {
    let spec = std::env::var("AMSTACK_TRACE").unwrap_or_else(|_| "press-button".to_owned());
    let mut parts = spec.split(':');
    let task =
        TaskId::parse(parts.next().unwrap_or("press-button")).unwrap_or_else(|e| panic!("{e}"));
    let vehicle = parts.next().unwrap_or("ee-only").to_owned();
    let seed: u64 = parts.next().and_then(|s| s.parse().ok()).unwrap_or(0);
    let (mut twin, mut stack, mut m, ctx, mut policy) = scripted_start(task, &vehicle, seed);
    println!("reset observation: {:?}\nwall: {:?}", ctx.task, ctx.wall);
    let every: u64 = std::env::var("AMSTACK_TRACE_EVERY")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60)
        .max(1);
    for step in 0..task.max_steps(120.0) {
        stack.keep_in_front_of(twin.obstacle_face_x());
        let (pose, mut g) = policy.action(step);
        if let Some(o) = gripper_override(task) {
            g = o;
        }
        let ee = EeTarget {
            world_from_ee_command: pose,
            gripper: g,
        };
        let record = stack.act(&m, &Action::Ee(ee.clone()));
        m = twin.step(&record.command).unwrap_or_else(|e| panic!("{e}"));
        let status = twin.task_status().cloned().unwrap_or_default();
        if step % every == 0 || status.success {
            let p = m.world_from_ee.translation.vector;
            let t = stack.link_target(&ee).translation.vector;
            println!(
                "{step:5} ee ({:.3} {:.3} {:.3}) target ({:.3} {:.3} {:.3}) grip {g:+.2} held {} {:?} obs {:?}",
                p.x,
                p.y,
                p.z,
                t.x,
                t.y,
                t.z,
                twin.holding(),
                status,
                twin.task_observation().map(|o| o.entries)
            );
        }
        if status.success {
            break;
        }
    }
}

#[test]
fn rollouts_do_not_depend_on_threads() {
    let mut cfg = config("ee-only", ControllerKind::Pid, Interface::Ee);
    cfg.tasks = vec![TaskId::PressButton];
    cfg.rollouts = 2;
    let stop = AtomicBool::new(false);
    let one = run_bench(&cfg, &|_| {}, &stop).unwrap_or_else(|e| panic!("{e}"));
    cfg.jobs = 2;
    let two = run_bench(&cfg, &|_| {}, &stop).unwrap_or_else(|e| panic!("{e}"));
    let key = |r: &BenchReport| {
        serde_json::to_string(&r.tasks.iter().map(|t| &t.summary).collect::<Vec<_>>())
            .unwrap_or_default()
    };
    assert_eq!(key(&one), key(&two));
    assert_eq!(one.env_steps, two.env_steps);
}

#[test]
fn action_noise_perturbs_every_element_by_its_standard_deviation() {
    // 1000 draws of σ = 1e-2: the sample std of the x offset is σ within 10 %, the
    // quaternion stays unit and the gripper moves too.
    let noise = Normal::new(0.0, 1e-2).unwrap_or_else(|e| panic!("{e}"));
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut dx = Vec::new();
    for _ in 0..1000 {
        let mut pose = Isometry3::translation(1.0, 0.0, 1.0);
        let mut gripper = -1.0;
        add_action_noise(&mut pose, &mut gripper, &mut rng, &noise);
        dx.push(pose.translation.x - 1.0);
        assert!((pose.rotation.norm() - 1.0).abs() < 1e-12);
        assert!(gripper != -1.0);
    }
    let mean = dx.iter().sum::<f64>() / dx.len() as f64;
    let std = (dx.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (dx.len() - 1) as f64).sqrt();
    assert!((std - 1e-2).abs() < 1e-3, "std {std}");
}

/// Prints where each Toss Ball throw comes down relative to the container (the aim of the
/// script in `task_policies/toss_ball.rs`), seeds 0–39 with the EE-only oracle:
/// `cargo test --release -p policy_runtime --lib bench::tests::toss_ball_landing -- --ignored
/// --nocapture`.
#[test]
#[ignore = "a measurement, not a test"]
fn toss_ball_landing() {
    const RIM_HEIGHT_M: f64 = 0.17;
    for seed in 0..40u64 {
        let (mut twin, mut stack, mut m, ctx, mut policy) =
            scripted_start(TaskId::TossBall, "ee-only", seed);
        let target = ctx
            .task
            .vec3("target_pos", 0)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut released = None;
        let mut landing_x = None;
        let mut success = false;
        for step in 0..TaskId::TossBall.max_steps(120.0) {
            let (pose, gripper) = policy.action(step);
            let ee = EeTarget {
                world_from_ee_command: pose,
                gripper,
            };
            let record = stack.act(&m, &Action::Ee(ee));
            m = twin.step(&record.command).unwrap_or_else(|e| panic!("{e}"));
            let o = twin.task_observation().unwrap_or_default();
            let ball = o.vec3("ball_pos", 0).unwrap_or_else(|e| panic!("{e}"));
            let velocity = o.vec3("ball_lin_vel", 0).unwrap_or_else(|e| panic!("{e}"));
            if released.is_none() && !twin.holding() {
                released = Some((step, velocity));
            }
            if released.is_some() && landing_x.is_none() && ball.z < RIM_HEIGHT_M {
                landing_x = Some(ball.x);
            }
            success |= twin.task_status().is_some_and(|s| s.success);
        }
        let (step, v) = released.unwrap_or_default();
        println!(
            "seed {seed:2}: container x {:.3}, comes down at {:+.3} from its centre, released at \
             step {step} at ({:.2}, {:.2}) m/s, success {success}",
            target.x,
            landing_x.map_or(f64::NAN, |x| x - target.x),
            v.x,
            v.z
        );
    }
}
