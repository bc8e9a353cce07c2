//! The renderer's contracts, on the machine's adapter: pinhole geometry to the pixel, the
//! spec's camera mounts, and deterministic visual randomisation.
//!
//! A test that needs an adapter skips with a printed reason only when the machine has none
//! (`RenderError::NoAdapter`); CI installs Mesa's Vulkan rasteriser through scripts/setup.sh.

#![allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use platform::Vehicle;
use render::{CameraSpec, Image, Intrinsics, RenderError, Renderer, Snapshot, VisualDr};
use sim_twin::{SceneVisual, TaskId, Twin, TwinConfig, VisualRole, VisualShape};

/// Largest distance between a marker's centroid and its pinhole projection, px.
const CENTROID_TOLERANCE_PX: f64 = 1.0;

fn vehicle(id: &str) -> Vehicle {
    Vehicle::builtin(id).unwrap_or_else(|e| panic!("{e}"))
}

/// A renderer, or None (with the reason printed) when the machine has no adapter.
fn renderer(vehicle: &Vehicle, cameras: &[CameraSpec], dr: VisualDr) -> Option<Renderer> {
    match Renderer::new(vehicle, cameras, dr) {
        Ok(r) => Some(r),
        Err(RenderError::NoAdapter(reason)) => {
            eprintln!("SKIPPED: no graphics adapter on this machine ({reason})");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

fn marker(position: Vector3<f64>, radius_m: f64) -> SceneVisual {
    SceneVisual {
        shape: VisualShape::Sphere { radius_m },
        world_from_shape: Isometry3::translation(position.x, position.y, position.z),
        role: VisualRole::Moving,
    }
}

/// Centre (u, v) of the pixels where two images differ, pixel centres at i + ½, and how many.
fn centroid_of_difference(with: &Image, without: &Image) -> (f64, f64, usize) {
    let (mut su, mut sv, mut n) = (0.0, 0.0, 0usize);
    for y in 0..with.height {
        for x in 0..with.width {
            if with.pixel(x, y) != without.pixel(x, y) {
                su += f64::from(x) + 0.5;
                sv += f64::from(y) + 0.5;
                n += 1;
            }
        }
    }
    let count = n.max(1) as f64;
    (su / count, sv / count, n)
}

/// Renders `state` with and without a marker sphere at `point` (world) and returns the
/// marker's centroid in camera `camera`'s image.
fn marker_centroid(
    r: &mut Renderer,
    state: &Snapshot,
    camera: usize,
    point: Vector3<f64>,
    radius_m: f64,
) -> (f64, f64, usize) {
    let mut state = state.clone();
    r.reset_scene(&[], 0).unwrap();
    state.scene_poses.clear();
    let without = r.render(&state, camera).unwrap();
    let m = marker(point, radius_m);
    state.scene_poses.push(m.world_from_shape);
    r.reset_scene(&[m], 0).unwrap();
    let with = r.render(&state, camera).unwrap();
    centroid_of_difference(&with, &without)
}

fn spec_camera_at(eye: Point3<f64>, target: Point3<f64>) -> CameraSpec {
    CameraSpec::look_at(
        "test",
        &eye,
        &target,
        &Vector3::z(),
        Intrinsics::from_aperture(384, 384, 19.6, 20.955),
        [0.01, 1000.0],
    )
}

/// The vehicle far behind a world camera, out of its view.
fn vehicle_out_of_view(v: &Vehicle) -> Snapshot {
    Snapshot {
        world_from_base: Isometry3::translation(-50.0, 0.0, 1.0),
        joint_positions: v.initial_configuration(),
        scene_poses: Vec::new(),
    }
}

#[test]
fn markers_land_on_their_pinhole_projection() {
    let v = vehicle("fa-hexa");
    let cam = spec_camera_at(Point3::new(0.0, 0.0, 1.5), Point3::new(5.0, 0.3, 1.2));
    let Some(mut r) = renderer(&v, std::slice::from_ref(&cam), VisualDr::Off) else {
        return;
    };
    let k = cam.intrinsics;
    // Hand-derived: fx = fy = 384·19.6/20.955 = 359.1696 px, c = (192, 192); the point
    // (0.3, −0.2, 1.5) of the camera frame projects to (192 + 359.1696·0.2,
    // 192 − 359.1696·0.1333) = (263.834, 144.111).
    let [u, v0] = k.project(&Vector3::new(0.3, -0.2, 1.5)).unwrap();
    assert!(
        (u - 263.834).abs() < 1e-3 && (v0 - 144.111).abs() < 1e-3,
        "{u} {v0}"
    );
    let state = vehicle_out_of_view(&v);
    let points_in_camera = [
        Vector3::new(0.0, 0.0, 1.0),
        Vector3::new(0.3, -0.2, 1.5),
        Vector3::new(-0.4, 0.35, 1.2),
        Vector3::new(0.9, 0.6, 2.5),
        Vector3::new(-1.0, -0.9, 3.0),
        Vector3::new(0.05, 0.4, 0.8),
    ];
    for p in points_in_camera {
        let world = cam.parent_from_camera * Point3::from(p);
        // Radius proportional to depth: ~3.6 px on the image wherever it is.
        let (cu, cv, n) = marker_centroid(&mut r, &state, 0, world.coords, 0.01 * p.z);
        let [eu, ev] = k.project(&p).unwrap();
        assert!(n > 20, "marker at {p:?} covers {n} px");
        let error = ((cu - eu).powi(2) + (cv - ev).powi(2)).sqrt();
        assert!(
            error < CENTROID_TOLERANCE_PX,
            "marker at {p:?}: centroid ({cu:.2}, {cv:.2}) vs projection ({eu:.2}, {ev:.2}), {error:.2} px"
        );
    }
}

#[test]
fn nearer_objects_hide_farther_ones() {
    let v = vehicle("fa-hexa");
    let cam = spec_camera_at(Point3::new(0.0, 0.0, 1.0), Point3::new(1.0, 0.0, 1.0));
    let Some(mut r) = renderer(&v, std::slice::from_ref(&cam), VisualDr::Off) else {
        return;
    };
    // A red (palette 1) sphere in front of an orange (palette 0) one on the optical axis.
    let far = marker(Vector3::new(2.0, 0.0, 1.0), 0.2);
    let near = marker(Vector3::new(1.0, 0.0, 1.0), 0.05);
    let mut state = vehicle_out_of_view(&v);
    state.scene_poses = vec![far.world_from_shape, near.world_from_shape];
    r.reset_scene(&[far, near], 0).unwrap();
    let img = r.render(&state, 0).unwrap();
    let [cr, cg, _] = img.pixel(192, 192).unwrap();
    // The near one is drawn last and first: depth decides, not order. Palette: orange has
    // g/r ≈ 0.49, red g/r ≈ 0.17.
    let ratio = f64::from(cg) / f64::from(cr.max(1));
    assert!(
        ratio < 0.3,
        "centre pixel {cr}, {cg}: the far orange sphere shows"
    );
    // Swap the order: the near sphere still wins.
    let far = marker(Vector3::new(2.0, 0.0, 1.0), 0.2);
    let near = marker(Vector3::new(1.0, 0.0, 1.0), 0.05);
    state.scene_poses = vec![near.world_from_shape, far.world_from_shape];
    r.reset_scene(&[near, far], 0).unwrap();
    let img = r.render(&state, 0).unwrap();
    let [cr, cg, _] = img.pixel(192, 192).unwrap();
    // Now the near one is palette 0 (orange), the far one red.
    let ratio = f64::from(cg) / f64::from(cr.max(1));
    assert!(
        ratio > 0.35,
        "centre pixel {cr}, {cg}: the far red sphere shows"
    );
}

/// The FA-Hexa at its reset pose and joints, 1 m up, no scene.
fn fa_hexa_at_reset(v: &Vehicle) -> Snapshot {
    Snapshot {
        world_from_base: Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        ),
        joint_positions: v.initial_configuration(),
        scene_poses: Vec::new(),
    }
}

#[test]
fn ee_camera_looks_along_the_end_effector_x_with_its_minus_y_to_the_right() {
    let v = vehicle("fa-hexa");
    let cameras = render::vehicle_cameras(&v);
    let Some(mut r) = renderer(&v, &cameras, VisualDr::Off) else {
        return;
    };
    let ee = r.camera_index("ee_camera").unwrap();
    let state = fa_hexa_at_reset(&v);
    let world_from_ee =
        state.world_from_base * v.model.root_from_link(&state.joint_positions, v.ee_link);
    let cam = r.world_from_camera(&state, ee).unwrap();
    // AMBENCH_SPEC §1.8: optical axis +x of ee_link, image right −y, image down −z.
    let axes = [
        (Vector3::z(), Vector3::x(), "optical axis"),
        (Vector3::x(), -Vector3::y(), "image right"),
        (Vector3::y(), -Vector3::z(), "image down"),
    ];
    for (in_camera, in_ee, what) in axes {
        let error = (cam.rotation * in_camera - world_from_ee.rotation * in_ee).norm();
        assert!(error < 1e-9, "{what}: {error}");
    }
    // Mounted 0.08 m ahead and 0.04 m above the ee_link origin (along ee +x, +z).
    let offset = world_from_ee.inverse() * Point3::from(cam.translation.vector);
    assert!((offset.coords - Vector3::new(0.08, 0.0, 0.04)).norm() < 1e-9);
    // A marker 1 m along ee +x from the camera and 0.15 m toward ee −y lands right of the
    // image centre: u = 192 + 359.17·0.15 = 245.88, v = 192.
    let point = cam.translation.vector + world_from_ee.rotation * Vector3::new(1.0, -0.15, 0.0);
    let (cu, cv, n) = marker_centroid(&mut r, &state, ee, point, 0.02);
    assert!(n > 20, "marker covers {n} px");
    assert!(
        (cu - 245.88).abs() < CENTROID_TOLERANCE_PX && (cv - 192.0).abs() < CENTROID_TOLERANCE_PX,
        "centroid ({cu:.2}, {cv:.2})"
    );
}

#[test]
fn base_camera_looks_forward_with_world_up_up_the_image() {
    let v = vehicle("fa-hexa");
    let cameras = render::vehicle_cameras(&v);
    let Some(mut r) = renderer(&v, &cameras, VisualDr::Off) else {
        return;
    };
    let base = r.camera_index("base_camera").unwrap();
    let state = fa_hexa_at_reset(&v);
    let cam = r.world_from_camera(&state, base).unwrap();
    let forward = state.world_from_base.rotation * Vector3::x();
    assert!((cam.rotation * Vector3::z() - forward).norm() < 1e-9);
    let offset = state.world_from_base.inverse() * Point3::from(cam.translation.vector);
    assert!((offset.coords - Vector3::new(0.1, 0.0, 0.06)).norm() < 1e-9);
    // 2 m ahead and 0.2 m up (world z; the base is level): v = 192 − 359.17·0.1 = 156.08.
    let point = cam.translation.vector + 2.0 * forward + Vector3::new(0.0, 0.0, 0.2);
    let (cu, cv, n) = marker_centroid(&mut r, &state, base, point, 0.03);
    assert!(n > 20, "marker covers {n} px");
    assert!(
        (cu - 192.0).abs() < CENTROID_TOLERANCE_PX && (cv - 156.08).abs() < CENTROID_TOLERANCE_PX,
        "centroid ({cu:.2}, {cv:.2})"
    );
}

fn press_button_twin(seed: u64) -> (Vehicle, Twin) {
    let v = vehicle("fa-hexa");
    let config = TwinConfig {
        task: Some(TaskId::PressButton),
        seed,
        ..TwinConfig::default()
    };
    let twin = Twin::new(v.clone(), config).unwrap();
    (v, twin)
}

fn differing_pixels(a: &Image, b: &Image) -> usize {
    a.rgb
        .chunks_exact(3)
        .zip(b.rgb.chunks_exact(3))
        .filter(|(p, q)| p != q)
        .count()
}

#[test]
fn same_seed_same_pixels_and_visual_dr_follows_the_seed() {
    let (v, twin) = press_button_twin(3);
    let cameras = [
        render::vehicle_cameras(&v),
        vec![CameraSpec::scene_scaled(320, 180)],
    ]
    .concat();
    let scene = twin.scene_visuals();
    let state = Snapshot::of_twin(&twin);
    let scene_cam = cameras.len() - 1;
    let Some(mut on) = renderer(&v, &cameras, VisualDr::On) else {
        return;
    };
    on.reset_scene(&scene, 3).unwrap();
    let a = on.render(&state, scene_cam).unwrap();
    let b = on.render(&state, scene_cam).unwrap();
    assert_eq!(a, b, "same state, same seed");
    on.reset_scene(&scene, 3).unwrap();
    assert_eq!(
        on.render(&state, scene_cam).unwrap(),
        a,
        "same seed after a reset"
    );
    on.reset_scene(&scene, 4).unwrap();
    let c = on.render(&state, scene_cam).unwrap();
    let changed = differing_pixels(&a, &c);
    // The floor and the wall fill most of the view: a new draw recolours most pixels.
    assert!(
        changed > 320 * 180 / 4,
        "only {changed} pixels changed with the seed"
    );

    let Some(mut off) = renderer(&v, &cameras, VisualDr::Off) else {
        return;
    };
    off.reset_scene(&scene, 3).unwrap();
    let d = off.render(&state, scene_cam).unwrap();
    off.reset_scene(&scene, 4).unwrap();
    assert_eq!(
        off.render(&state, scene_cam).unwrap(),
        d,
        "DR off ignores the seed"
    );
    assert!(
        differing_pixels(&a, &d) > 320 * 180 / 4,
        "DR on changes the nominal look"
    );
    // Rendering several cameras in one submission gives each its own image.
    let mut images = vec![Image::default(), Image::default()];
    off.render_set_into(&state, &[0, 1], &mut images).unwrap();
    assert_eq!(images[0], off.render(&state, 0).unwrap());
    assert_eq!(images[1], off.render(&state, 1).unwrap());
    assert_ne!(images[0], images[1]);
}

#[test]
fn a_state_that_does_not_match_is_refused() {
    let (v, twin) = press_button_twin(0);
    let Some(mut r) = renderer(&v, &render::vehicle_cameras(&v), VisualDr::Off) else {
        return;
    };
    let mut state = Snapshot::of_twin(&twin);
    // The scene was not given yet: its poses do not match.
    let err = r.render(&state, 0).unwrap_err().to_string();
    assert!(err.contains("scene poses"), "{err}");
    r.reset_scene(&twin.scene_visuals(), 0).unwrap();
    assert!(r.render(&state, 0).is_ok());
    assert!(matches!(
        r.render(&state, 7),
        Err(RenderError::NoCamera { index: 7, count: 2 })
    ));
    state.joint_positions.pop();
    assert!(matches!(r.render(&state, 0), Err(RenderError::State(_))));
}

#[test]
fn no_adapter_error_says_how_to_install_one() {
    let msg = RenderError::NoAdapter("no suitable adapter found".to_owned()).to_string();
    assert!(
        msg.contains("mesa-vulkan-drivers") && msg.contains("bash scripts/setup.sh"),
        "{msg}"
    );
}

#[test]
fn a_renderer_can_move_to_a_render_thread() {
    // Compile-time: the flight loop may own the renderer on a worker thread and send it
    // snapshots (wgpu's Device and Queue are Send + Sync).
    fn send<T: Send + 'static>() {}
    send::<Renderer>();
    send::<Snapshot>();
    send::<Image>();
}

#[test]
fn a_frame_begun_and_finished_later_is_the_frame_rendered_at_once() {
    let (v, mut twin) = press_button_twin(1);
    let Some(mut r) = renderer(&v, &render::vehicle_cameras(&v), VisualDr::On) else {
        return;
    };
    r.reset_scene(&twin.scene_visuals(), 1).unwrap();
    let state = Snapshot::of_twin(&twin);
    let mut at_once = vec![Image::default(), Image::default()];
    r.render_set_into(&state, &[1, 0], &mut at_once).unwrap();
    r.begin_frame(&state, &[1, 0]).unwrap();
    // One frame at a time.
    assert!(matches!(
        r.begin_frame(&state, &[0]),
        Err(RenderError::State(_))
    ));
    // The physics steps while the frame is drawn: the images are those of the state begun.
    let hover = platform::ActuatorCommand {
        rotor_thrusts_n: vec![12.5; v.rotors.len()],
        joint_targets: v.initial_configuration(),
        direct_wrench_in_body: None,
    };
    twin.step(&hover).unwrap();
    let mut later = vec![Image::default()];
    assert!(matches!(
        r.finish_frame(&mut later),
        Err(RenderError::State(_))
    ));
    later.push(Image::default());
    r.finish_frame(&mut later).unwrap();
    assert_eq!(later, at_once);
    // Camera 1 is the base camera, camera 0 the EE camera: different views.
    assert_ne!(later[0], later[1]);
}
