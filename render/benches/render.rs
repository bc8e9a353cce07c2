//! Frames per second of the twin's cameras on this machine's adapter: one 384×384 camera, and
//! the EE + base cameras of one tick together (one submission), on the FA-Hexa in the Press
//! Button scene at reset. Criterion's `thrpt` line is frames (or ticks) per second.
//!
//! `cargo bench -p render --bench render`

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use render::{Image, RenderError, Renderer, Snapshot, VisualDr};
use sim_twin::{TaskId, Twin, TwinConfig};

fn cameras(c: &mut Criterion) {
    let vehicle = match platform::Vehicle::builtin("fa-hexa") {
        Ok(v) => v,
        Err(e) => panic!("{e}"),
    };
    let config = TwinConfig {
        task: Some(TaskId::PressButton),
        ..TwinConfig::default()
    };
    let twin = match Twin::new(vehicle.clone(), config) {
        Ok(t) => t,
        Err(e) => panic!("{e}"),
    };
    let mut renderer =
        match Renderer::new(&vehicle, &render::vehicle_cameras(&vehicle), VisualDr::On) {
            Ok(r) => r,
            Err(RenderError::NoAdapter(reason)) => {
                eprintln!("SKIPPED: no graphics adapter ({reason})");
                return;
            }
            Err(e) => panic!("{e}"),
        };
    if let Err(e) = renderer.reset_scene(&twin.scene_visuals(), 0) {
        panic!("{e}");
    }
    let adapter = renderer.adapter().clone();
    eprintln!(
        "adapter: {} ({:?}, {:?})",
        adapter.name, adapter.backend, adapter.device_type
    );
    let (Some(ee), Some(base)) = (
        renderer.camera_index("ee_camera"),
        renderer.camera_index("base_camera"),
    ) else {
        panic!("the FA-Hexa declares ee_camera and base_camera");
    };
    let mut snapshot = Snapshot::of_twin(&twin);
    let mut one = Image::default();
    let mut two = vec![Image::default(), Image::default()];

    let mut group = c.benchmark_group("render_384x384");
    group.sample_size(30);
    group.measurement_time(Duration::from_secs(8));
    group.throughput(Throughput::Elements(1));
    group.bench_function("ee_camera", |b| {
        b.iter(|| {
            if let Err(e) = renderer.render_into(black_box(&snapshot), ee, &mut one) {
                panic!("{e}");
            }
        });
    });
    group.bench_function("ee_and_base_cameras_per_tick", |b| {
        b.iter(|| {
            snapshot.update_from_twin(&twin);
            if let Err(e) = renderer.render_set_into(black_box(&snapshot), &[ee, base], &mut two) {
                panic!("{e}");
            }
        });
    });
    group.finish();

    // One control tick of the twin (hover thrust; back to reset every simulated second) with
    // and without the EE + base cameras, and with the frame drawn while the next tick steps.
    let hover = platform::ActuatorCommand {
        rotor_thrusts_n: vec![
            vehicle.hover_thrust_per_rotor_n().unwrap_or(0.0);
            vehicle.rotors.len()
        ],
        joint_targets: vehicle.initial_configuration(),
        direct_wrench_in_body: None,
    };
    let mut twin = twin;
    let step = move |twin: &mut Twin| {
        if twin.time_s() >= 1.0
            && let Err(e) = twin.reset(0)
        {
            panic!("{e}");
        }
        if let Err(e) = twin.step(&hover) {
            panic!("{e}");
        }
    };
    let mut group = c.benchmark_group("tick_fa_hexa_press_button");
    group.sample_size(30);
    group.measurement_time(Duration::from_secs(8));
    group.throughput(Throughput::Elements(1));
    group.bench_function("twin_step_only", |b| b.iter(|| step(&mut twin)));
    group.bench_function("twin_step_then_ee_and_base", |b| {
        b.iter(|| {
            step(&mut twin);
            snapshot.update_from_twin(&twin);
            if let Err(e) = renderer.render_set_into(&snapshot, &[ee, base], &mut two) {
                panic!("{e}");
            }
        });
    });
    group.bench_function("ee_and_base_drawn_while_the_next_tick_steps", |b| {
        b.iter(|| {
            snapshot.update_from_twin(&twin);
            if let Err(e) = renderer.begin_frame(&snapshot, &[ee, base]) {
                panic!("{e}");
            }
            step(&mut twin);
            if let Err(e) = renderer.finish_frame(&mut two) {
                panic!("{e}");
            }
        });
    });
    group.finish();
}

criterion_group!(benches, cameras);
criterion_main!(benches);
