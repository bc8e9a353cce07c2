//! Tests of the vehicle descriptions against hand-derived and reference values.

use nalgebra::{Matrix3, Vector3};
use proptest::prelude::*;

use crate::{
    Actuation, BUILTIN_IDS, DescriptionError, GRAVITY_MPS2, KinematicModel, Problem, Spin, Vehicle,
    VehicleFile,
};

/// Exact arithmetic on short decimal chains: only rounding remains.
const EXACT: f64 = 1e-12;
/// The spec's derived values carry five significant digits.
const SPEC_DIGITS: f64 = 5e-5;

fn vehicle(id: &str) -> Vehicle {
    match Vehicle::builtin(id) {
        Ok(v) => v,
        Err(e) => panic!("built-in vehicle {id} must load: {e}"),
    }
}

fn assert_vec_near(actual: &Vector3<f64>, expected: [f64; 3], tol: f64, what: &str) {
    let e = Vector3::from(expected);
    assert!(
        (actual - e).amax() <= tol,
        "{what}: {actual:?} != {e:?} (tol {tol})"
    );
}

#[test]
fn every_builtin_vehicle_loads() {
    let all = Vehicle::builtins().unwrap_or_else(|e| panic!("{e}"));
    let ids: Vec<&str> = all.iter().map(|v| v.id.as_str()).collect();
    assert_eq!(ids, BUILTIN_IDS);
    let classes: Vec<Actuation> = all.iter().map(|v| v.actuation).collect();
    assert_eq!(
        classes,
        [
            Actuation::UnderActuated,
            Actuation::UnderActuated,
            Actuation::FullyActuated,
            Actuation::VariableTilt,
            Actuation::FloatingEndEffector
        ]
    );
}

#[test]
fn unknown_builtin_is_refused_naming_the_known_ones() {
    let err = Vehicle::builtin("tri-copter")
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        err.contains("unknown vehicle 'tri-copter'") && err.contains("fa-hexa"),
        "{err}"
    );
}

#[test]
fn fa_hexa_end_effector_and_tool_tip_at_zero_configuration() {
    let v = vehicle("fa-hexa");
    let q = v.model.zero_configuration();
    assert_vec_near(
        &v.base_from_ee(&q).translation.vector,
        [0.227, 0.0, 0.12375],
        EXACT,
        "ee_link",
    );
    assert_vec_near(
        &v.tool_tip_in_base(&q),
        [0.407, 0.0, 0.12375],
        EXACT,
        "tool tip",
    );
}

#[test]
fn total_masses_match_the_reference() {
    // AMBENCH_SPEC §1.3, §1.5, §1.6 (URDF sums); UA-Hexa = FA-Hexa and EE-only are [U] choices.
    for (id, kg, tol) in [
        ("fa-hexa", 6.635, 1e-9),
        ("ua-hexa", 6.635, 1e-9),
        ("ua-quad", 4.407, 0.01),
        ("omni-hexa", 3.345, 1e-9),
        ("ee-only", 5.0, 1e-9),
    ] {
        let v = vehicle(id);
        let m = v.model.total_mass_kg();
        assert!((m - kg).abs() <= tol, "{id}: {m} kg != {kg} kg");
        let mp = v.mass_properties(&v.initial_configuration());
        assert!(
            (mp.mass_kg - m).abs() <= EXACT,
            "{id}: mass properties disagree"
        );
    }
    let quad = vehicle("ua-quad").model.total_mass_kg();
    assert!(
        (quad - 4.4069261).abs() < 1e-7,
        "UA-Quad link masses sum to {quad}"
    );
}

#[test]
fn hover_thrust_and_thrust_to_weight_match_the_spec_derivations() {
    // AMBENCH_SPEC §2.10: FA ≈ 12.5 N and 1.84, Quad ≈ 10.8 N and 2.13, Omni ≈ 5.5 N and 4.2.
    for (id, hover, tw) in [
        ("fa-hexa", 12.53, 1.836),
        ("ua-quad", 10.81, 2.128),
        ("omni-hexa", 5.469, 4.205),
        ("ua-hexa", 10.85, 2.120),
    ] {
        let v = vehicle(id);
        let h = v.hover_thrust_per_rotor_n().unwrap_or(f64::NAN);
        let r = v.thrust_to_weight().unwrap_or(f64::NAN);
        assert!((h - hover).abs() < 0.01, "{id}: hover {h}");
        assert!((r - tw).abs() < 0.001, "{id}: T/W {r}");
        // Consistency: T/W = T_max / hover thrust.
        assert!((r - v.rotors.thrust_max_n / h).abs() < EXACT);
    }
    let ee = vehicle("ee-only");
    assert_eq!(ee.hover_thrust_per_rotor_n(), None);
    assert_eq!(ee.thrust_to_weight(), None);
    assert!((GRAVITY_MPS2 - 9.81).abs() < EXACT);
}

#[test]
fn fa_hexa_rotor_axes_match_the_spec_table() {
    let v = vehicle("fa-hexa");
    let expected = [
        (
            [0.34175, 0.1585, -0.058],
            [-0.24941, 0.43335, 0.86602],
            Spin::Positive,
        ),
        (
            [-0.0335, 0.375, -0.058],
            [0.50035, 0.0, 0.86582],
            Spin::Negative,
        ),
        (
            [-0.30825, 0.2165, -0.058],
            [-0.24941, -0.43335, 0.86602],
            Spin::Positive,
        ),
        (
            [-0.30825, -0.2165, -0.058],
            [-0.24941, 0.43335, 0.86602],
            Spin::Negative,
        ),
        (
            [-0.0335, -0.375, -0.058],
            [0.50035, 0.0, 0.86582],
            Spin::Positive,
        ),
        (
            [0.34175, -0.1585, -0.058],
            [-0.24941, -0.43335, 0.86602],
            Spin::Negative,
        ),
    ];
    assert_eq!(v.rotors.len(), 6);
    for (r, (p, a, s)) in v.rotors.rotors.iter().zip(expected) {
        assert_vec_near(&r.position_in_base, p, EXACT, &r.link);
        assert_vec_near(&r.axis_in_base, a, SPEC_DIGITS, &r.link);
        assert_eq!(r.spin, s, "{}", r.link);
    }
    assert!((v.rotors.thrust_max_n - 23.0).abs() < EXACT);
    assert!((v.rotors.reaction_torque_ratio_m - 0.02).abs() < EXACT);
}

#[test]
fn omni_hexa_tilt_geometry_matches_the_spec_table() {
    // AMBENCH_SPEC §1.6: positions at α = 0, c_i = +z, hinge a_i and s_i = normalise(a_i × c_i).
    let v = vehicle("omni-hexa");
    let h = 0.8660254;
    let expected = [
        (
            [-0.153329, -0.089682, 0.03],
            [-h, -0.5, 0.0],
            [-0.5, h, 0.0],
            Spin::Positive,
        ),
        (
            [0.0, -0.178138, 0.03],
            [0.0, -1.0, 0.0],
            [-1.0, 0.0, 0.0],
            Spin::Negative,
        ),
        (
            [0.156211, -0.090192, 0.03],
            [h, -0.5, 0.0],
            [-0.5, -h, 0.0],
            Spin::Positive,
        ),
        (
            [0.154892, 0.089399, 0.03],
            [h, 0.5, 0.0],
            [0.5, -h, 0.0],
            Spin::Negative,
        ),
        (
            [0.0, 0.178796, 0.03],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            Spin::Positive,
        ),
        (
            [-0.150797, 0.087683, 0.03],
            [-h, 0.5, 0.0],
            [0.5, h, 0.0],
            Spin::Negative,
        ),
    ];
    assert!(v.rotors.is_variable_tilt());
    for (r, (p, a, s, spin)) in v.rotors.rotors.iter().zip(expected) {
        let Some(t) = &r.tilt else {
            panic!("{} must tilt", r.link)
        };
        assert_vec_near(&r.position_in_base, p, 1e-6, &r.link);
        assert_vec_near(&r.axis_in_base, [0.0, 0.0, 1.0], 1e-7, &r.link);
        assert_vec_near(&t.hinge_axis_in_base, a, 1e-6, &r.link);
        assert_vec_near(&t.sin_axis_in_base, s, 1e-6, &r.link);
        assert_eq!(r.spin, spin);
        // At +90° the thrust turns onto s_i.
        assert_vec_near(
            &r.axis_at_tilt(std::f64::consts::FRAC_PI_2),
            s,
            1e-6,
            &r.link,
        );
    }
}

#[test]
fn under_actuated_rotors_push_along_body_z() {
    for id in ["ua-quad", "ua-hexa"] {
        for r in &vehicle(id).rotors.rotors {
            assert_vec_near(&r.axis_in_base, [0.0, 0.0, 1.0], EXACT, &r.link);
        }
    }
    let quad = vehicle("ua-quad");
    let d = 0.3 / 2f64.sqrt();
    for (r, (x, y)) in quad
        .rotors
        .rotors
        .iter()
        .zip([(d, d), (-d, d), (-d, -d), (d, -d)])
    {
        assert_vec_near(&r.position_in_base, [x, y, 0.05], 1e-6, &r.link);
    }
}

#[test]
fn command_frame_offsets_point_the_tool_along_world_x() {
    // AMBENCH_SPEC §1.1: with an identity command the tool points along world +x.
    let quad = vehicle("ua-quad");
    let tool_in_link = -Vector3::z(); // UA-Quad tool along ee_link −z
    assert_vec_near(
        &(quad.command_to_link * tool_in_link),
        [1.0, 0.0, 0.0],
        1e-8,
        "UA-Quad tool",
    );
    // and its ee_link x axis along world +y, y along −z.
    assert_vec_near(
        &(quad.command_to_link * Vector3::x()),
        [0.0, 1.0, 0.0],
        1e-8,
        "UA-Quad x",
    );
    assert_vec_near(
        &(quad.command_to_link * Vector3::y()),
        [0.0, 0.0, -1.0],
        1e-8,
        "UA-Quad y",
    );
    let omni = vehicle("omni-hexa");
    assert_vec_near(
        &(omni.command_to_link * Vector3::z()),
        [1.0, 0.0, 0.0],
        1e-8,
        "Omni tool",
    );
    assert_vec_near(
        &(omni.command_to_link * Vector3::x()),
        [0.0, 0.0, -1.0],
        1e-8,
        "Omni x",
    );
}

#[test]
fn grippers_map_actions_onto_their_limits() {
    let fa = vehicle("fa-hexa");
    let Some(g) = &fa.gripper else {
        panic!("FA-Hexa has a gripper")
    };
    assert_eq!(g.targets(-1.0), vec![0.001, 0.001]);
    assert_eq!(g.targets(1.0), vec![0.045, 0.045]);
    assert_eq!(
        g.targets(7.0),
        vec![0.045, 0.045],
        "actions clamp to [-1, 1]"
    );
    assert_eq!(g.targets(f64::NAN), vec![0.001, 0.001], "NaN closes");
    let mid = g.targets(0.0);
    assert!((mid[0] - 0.023).abs() < EXACT);
    let omni = vehicle("omni-hexa");
    let Some(g) = &omni.gripper else {
        panic!("Omni-Hexa has a gripper")
    };
    assert_eq!(g.targets(-1.0), vec![0.0]);
    assert_eq!(g.targets(1.0), vec![-0.5]);
}

#[test]
fn drives_and_initial_configuration_follow_the_spec() {
    let omni = vehicle("omni-hexa");
    let q = omni.initial_configuration();
    let at = |name: &str| {
        let j = omni
            .model
            .joint_id(name)
            .and_then(|j| omni.model.joints[j].dof);
        j.map_or(f64::NAN, |d| q[d])
    };
    assert!((at("servo1") + std::f64::consts::FRAC_PI_4).abs() < 1e-9);
    assert!((at("servo2") - 3.0 * std::f64::consts::FRAC_PI_4).abs() < 1e-9);
    assert!((at("servo4") + 0.5).abs() < EXACT);
    assert!(at("base_motor_arm3").abs() < EXACT);
    // Every movable joint of every vehicle is driven exactly once.
    for v in Vehicle::builtins().unwrap_or_else(|e| panic!("{e}")) {
        assert_eq!(v.drives.len(), v.model.dof(), "{}", v.id);
    }
    let ua = vehicle("ua-hexa");
    assert!(
        ua.drives
            .iter()
            .all(|d| (d.effort_limit - 20.0).abs() < EXACT)
    );
    let fa = vehicle("fa-hexa");
    let arm = fa
        .drives
        .iter()
        .find(|d| fa.model.joints[d.joint].name == "arm_link1_pitch_joint");
    let Some(arm) = arm else {
        panic!("arm joint 1 is driven")
    };
    assert!((arm.stiffness - 1e5).abs() < EXACT && (arm.damping - 1e3).abs() < EXACT);
    assert!((arm.effort_limit - 1000.0).abs() < EXACT && (arm.velocity_limit - 5.0).abs() < EXACT);
}

#[test]
fn cameras_have_the_reference_field_of_view() {
    let fa = vehicle("fa-hexa");
    let names: Vec<&str> = fa.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["ee_camera", "base_camera"]);
    let hfov = fa.cameras[0].horizontal_fov_rad().to_degrees();
    assert!((hfov - 56.3).abs() < 0.05, "HFOV {hfov}°");
    // AMBENCH_SPEC §1.8: DEFAULT_EE_CAMERA looks along ee_link +x.
    assert_vec_near(
        &fa.cameras[0].optical_axis_in_link(),
        [1.0, 0.0, 0.0],
        1e-9,
        "ee camera axis",
    );
    let quad = vehicle("ua-quad");
    assert_vec_near(
        &quad.cameras[0].optical_axis_in_link(),
        [0.0, 0.0, -1.0],
        1e-9,
        "quad ee camera",
    );
}

/// Two links of 1 kg: A at the origin, B at x = 1 with inertia diag(1, 2, 3) turned 90° about z.
const TWO_BODIES: &str = r#"<robot name="two">
  <link name="a"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="b"><inertial><origin xyz="0 0 0" rpy="0 0 1.5707963267948966"/><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="2" iyz="0" izz="3"/></inertial></link>
  <joint name="slide" type="prismatic"><parent link="a"/><child link="b"/><origin xyz="1 0 0"/><axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"#;

#[test]
fn composite_inertia_is_the_hand_derived_one() {
    let m = KinematicModel::from_urdf("two.urdf", TWO_BODIES).unwrap_or_else(|e| panic!("{e}"));
    let mp = m.mass_properties(&[0.0]);
    assert!((mp.mass_kg - 2.0).abs() < EXACT);
    assert_vec_near(&mp.com_in_root_m, [0.5, 0.0, 0.0], EXACT, "com");
    // A: 0.1·1 + 1·(0.25·1 − diag(0.25,0,0)); B: diag(2,1,3) + the same parallel-axis term.
    let expected = Matrix3::from_diagonal(&Vector3::new(
        0.1 + 2.0,
        0.1 + 0.25 + 1.0 + 0.25,
        0.1 + 0.25 + 3.0 + 0.25,
    ));
    assert!(
        (mp.inertia_about_com_kgm2 - expected).amax() < 1e-12,
        "{}",
        mp.inertia_about_com_kgm2
    );
    // Sliding B out by 0.5 m moves the centre of mass by 0.25 m.
    let moved = m.mass_properties(&[0.5]);
    assert_vec_near(
        &moved.com_in_root_m,
        [0.75, 0.0, 0.0],
        EXACT,
        "com after slide",
    );
}

#[test]
fn inertia_is_symmetric_and_positive_definite_for_every_vehicle() {
    for v in Vehicle::builtins().unwrap_or_else(|e| panic!("{e}")) {
        let j = v
            .mass_properties(&v.initial_configuration())
            .inertia_about_com_kgm2;
        assert!((j - j.transpose()).amax() < 1e-15, "{}", v.id);
        assert!(j.symmetric_eigenvalues().min() > 0.0, "{}", v.id);
    }
}

/// Twist of `point_in_link` by central differences of forward kinematics.
fn finite_difference_jacobian(v: &Vehicle, q: &[f64]) -> nalgebra::Matrix6xX<f64> {
    const H: f64 = 1e-6;
    let mut jac = nalgebra::Matrix6xX::zeros(q.len());
    for i in 0..q.len() {
        let (mut plus, mut minus) = (q.to_vec(), q.to_vec());
        plus[i] += H;
        minus[i] -= H;
        let (tp, tm) = (v.base_from_ee(&plus), v.base_from_ee(&minus));
        let linear = (v.tool_tip_in_base(&plus) - v.tool_tip_in_base(&minus)) / (2.0 * H);
        let angular = (tp.rotation * tm.rotation.inverse()).scaled_axis() / (2.0 * H);
        jac.fixed_view_mut::<3, 1>(0, i).copy_from(&linear);
        jac.fixed_view_mut::<3, 1>(3, i).copy_from(&angular);
    }
    jac
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn jacobian_equals_finite_differences_of_forward_kinematics(
        which in 0usize..5,
        unit in proptest::collection::vec(0.0f64..1.0, 16),
    ) {
        let v = vehicle(BUILTIN_IDS[which]);
        // A configuration inside every joint's limits (±π for continuous ones).
        let q: Vec<f64> = (0..v.model.dof())
            .map(|d| {
                let (lo, hi) = v.model.dof_joint(d).limits.map_or((-3.0, 3.0), |l| (l.lower, l.upper));
                lo + unit[d] * (hi - lo)
            })
            .collect();
        let analytic = v.tool_tip_jacobian(&q);
        let numeric = finite_difference_jacobian(&v, &q);
        let err = (analytic - numeric).amax();
        prop_assert!(err < 1e-7, "{}: |J − J_fd| = {err:e}", v.id);
    }
}

#[test]
fn jacobian_has_no_column_for_joints_off_the_chain() {
    let fa = vehicle("fa-hexa");
    let q = fa.model.zero_configuration();
    let jac = fa.tool_tip_jacobian(&q);
    for d in 0..fa.model.dof() {
        let name = &fa.model.dof_joint(d).name;
        let on_chain = fa.arm_joints.contains(&fa.model.dofs[d]);
        assert_eq!(jac.column(d).amax() > 0.0, on_chain, "{name}");
    }
    // Joint 1 (pitch about +y at (0.088, 0, 0.06475)): v = ŷ × (tip − o).
    let lever = Vector3::new(0.407 - 0.088, 0.0, 0.12375 - 0.06475);
    let v1 = Vector3::y().cross(&lever);
    assert_vec_near(
        &jac.fixed_view::<3, 1>(0, fa.arm_dofs()[0]).into_owned(),
        [v1.x, v1.y, v1.z],
        EXACT,
        "J col 1",
    );
}

// ---- Bad input: each refusal names the file, the field and the value. ----

fn fa_files() -> (&'static str, &'static str) {
    (
        include_str!("../vehicles/fa-hexa.toml"),
        include_str!("../vehicles/fa-hexa.urdf"),
    )
}

fn load(toml: &str, urdf: &str) -> Result<Vehicle, DescriptionError> {
    let file = VehicleFile::parse("my.toml", toml)?;
    Vehicle::assemble("my.toml", &file, "my.urdf", urdf)
}

fn refusal(toml: &str, urdf: &str) -> DescriptionError {
    match load(toml, urdf) {
        Ok(v) => panic!("{} must be refused", v.id),
        Err(e) => {
            assert!(!e.to_string().contains('\n'), "one line: {e}");
            e
        }
    }
}

fn edited(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "fixture must contain {from:?}");
    text.replacen(from, to, 1)
}

#[test]
fn malformed_urdf_is_refused_on_one_line() {
    let (toml, urdf) = fa_files();
    let e = refusal(toml, &urdf.replace("</robot>", ""));
    assert!(matches!(e.problem, Problem::Syntax(_)), "{e}");
    assert!(e.to_string().starts_with("my.urdf: cannot parse"), "{e}");
}

#[test]
fn unknown_link_in_a_joint_is_refused() {
    let (toml, urdf) = fa_files();
    let bad = edited(
        urdf,
        r#"<parent link="arm_link2_pitch_link"/>"#,
        r#"<parent link="arm_link9"/>"#,
    );
    let e = refusal(toml, &bad);
    assert_eq!(e.problem, Problem::UnknownLink("arm_link9".into()));
    assert_eq!(
        e.to_string(),
        "my.urdf: joint 'arm_link3_pitch_joint' parent: unknown link 'arm_link9'"
    );
}

#[test]
fn non_unit_axis_is_refused_with_its_value() {
    let (toml, urdf) = fa_files();
    let bad = edited(urdf, r#"<axis xyz="0 1 0"/>"#, r#"<axis xyz="0 2 0"/>"#);
    let e = refusal(toml, &bad);
    assert_eq!(
        e.to_string(),
        "my.urdf: joint 'arm_link1_pitch_joint' axis: (0, 2, 0) is not a unit vector (norm 2)"
    );
}

#[test]
fn negative_mass_is_refused() {
    let (toml, urdf) = fa_files();
    let e = refusal(
        toml,
        &edited(
            urdf,
            r#"<mass value="5.615"/>"#,
            r#"<mass value="-5.615"/>"#,
        ),
    );
    assert_eq!(e.problem, Problem::NegativeMass(-5.615));
    assert_eq!(
        e.to_string(),
        "my.urdf: link 'base_link' inertial: negative mass -5.615 kg"
    );
}

#[test]
fn duplicate_joint_and_link_names_are_refused() {
    let (toml, urdf) = fa_files();
    let e = refusal(
        toml,
        &edited(
            urdf,
            r#"name="arm_link2_pitch_joint""#,
            r#"name="arm_link1_pitch_joint""#,
        ),
    );
    assert_eq!(
        e.problem,
        Problem::DuplicateJoint("arm_link1_pitch_joint".into())
    );
    let e = refusal(
        toml,
        &edited(urdf, r#"<link name="rotor_5">"#, r#"<link name="rotor_4">"#),
    );
    assert_eq!(e.problem, Problem::DuplicateLink("rotor_4".into()));
}

#[test]
fn rotor_count_mismatch_is_refused() {
    let (toml, urdf) = fa_files();
    let e = refusal(&edited(toml, "count = 6", "count = 5"), urdf);
    assert_eq!(
        e.problem,
        Problem::RotorCountMismatch {
            declared: 5,
            listed: 6
        }
    );
    assert_eq!(
        e.to_string(),
        "my.toml: rotors.count: rotors.count = 5 but 6 rotors are listed"
    );
}

#[test]
fn rotor_on_an_unknown_or_moving_link_is_refused() {
    let (toml, urdf) = fa_files();
    let e = refusal(
        &edited(toml, r#"link = "rotor_3""#, r#"link = "rotor_33""#),
        urdf,
    );
    assert_eq!(
        e.to_string(),
        "my.toml: rotors.rotor[3].link: unknown link 'rotor_33'"
    );
    let e = refusal(
        &edited(toml, r#"link = "rotor_3""#, r#"link = "ee_link""#),
        urdf,
    );
    assert!(
        e.to_string()
            .contains("moves with joint 'arm_link1_pitch_joint'"),
        "{e}"
    );
    let e = refusal(&edited(toml, "spin = -1 }", "spin = 2 }"), urdf);
    assert_eq!(
        e.to_string(),
        "my.toml: rotors.rotor[1].spin: 2 must be 1 or -1"
    );
}

#[test]
fn vehicle_file_typos_and_wrong_types_are_refused_with_their_line() {
    let (toml, urdf) = fa_files();
    let e = refusal(
        &edited(toml, "thrust_max_n = 23.0", "thrust_mx_n = 23.0"),
        urdf,
    );
    assert!(matches!(e.problem, Problem::Syntax(_)), "{e}");
    assert!(
        e.to_string().contains("thrust_mx_n") && e.field.starts_with("line "),
        "{e}"
    );
    let e = refusal(
        &edited(toml, "thrust_max_n = 23.0", "thrust_max_n = \"lots\""),
        urdf,
    );
    assert!(e.field.starts_with("line "), "{e}");
    let e = refusal(&edited(toml, "schema = 1", "schema = 7"), urdf);
    assert_eq!(
        e.to_string(),
        "my.toml: schema: version 7 is not supported (this amstack reads version 1)"
    );
}

#[test]
fn inconsistent_vehicle_files_are_refused() {
    let (toml, urdf) = fa_files();
    // FA-Hexa rotors are tilted: not an under-actuated vehicle.
    let e = refusal(
        &edited(
            toml,
            r#"actuation = "fully-actuated""#,
            r#"actuation = "under-actuated""#,
        ),
        urdf,
    );
    assert!(e.to_string().contains("is not body +z"), "{e}");
    let e = refusal(
        &edited(
            toml,
            r#"base_link = "base_link""#,
            r#"base_link = "ee_link""#,
        ),
        urdf,
    );
    assert_eq!(
        e.to_string(),
        "my.toml: base_link: 'ee_link' is not the URDF root link 'base_link'"
    );
    let e = refusal(
        &edited(toml, r#""arm_link4_roll_joint"]"#, r#""arm_base_fixed"]"#),
        urdf,
    );
    assert_eq!(
        e.to_string(),
        "my.toml: arm_joints[3]: joint 'arm_base_fixed' is fixed"
    );
    let e = refusal(&edited(toml, "initial = 0.001", "initial = 0.5"), urdf);
    assert!(
        e.to_string()
            .contains("0.5 is outside joint 'arm_lfinger_joint' limits [0.001, 0.045]"),
        "{e}"
    );
    let e = refusal(
        &edited(toml, "[0.5, -0.5, 0.5, -0.5]", "[0.5, -0.5, 0.5, 0.5, 1.0]"),
        urdf,
    );
    assert_eq!(
        e.to_string(),
        "my.toml: camera[0].orientation_wxyz: [0.5, -0.5, 0.5, 0.5, 1.0] has 5 values, needs 4"
    );
    let e = refusal(
        &edited(toml, "[0.5, -0.5, 0.5, -0.5]", "[0.5, -0.5, 0.5, -0.6]"),
        urdf,
    );
    assert!(e.to_string().starts_with("my.toml: camera[0].orientation_wxyz: [0.5, -0.5, 0.5, -0.6] is not a unit quaternion (norm 1.05"), "{e}");
    let e = refusal(
        &edited(toml, "thrust_min_n = 0.0", "thrust_min_n = 30.0"),
        urdf,
    );
    assert_eq!(
        e.to_string(),
        "my.toml: rotors.thrust_max_n: 23 must be finite and above thrust_min_n 30"
    );
}

#[test]
fn urdf_structure_errors_are_refused() {
    let (toml, urdf) = fa_files();
    let e = refusal(
        toml,
        &edited(
            urdf,
            r#"<joint name="arm_base_fixed" type="fixed">
    <parent link="base_link"/><child link="arm_base_link"/>"#,
            r#"<joint name="arm_base_fixed" type="fixed">
    <parent link="arm_base_link"/><child link="arm_base_link"/>"#,
        ),
    );
    assert!(
        e.to_string()
            .contains("parent and child are both 'arm_base_link'"),
        "{e}"
    );
    let e = refusal(
        toml,
        &edited(
            urdf,
            r#"lower="0" upper="2.268928""#,
            r#"lower="3" upper="2.268928""#,
        ),
    );
    assert!(
        e.to_string()
            .contains("lower 3 must be below upper 2.268928"),
        "{e}"
    );
    let e = refusal(
        toml,
        &edited(
            urdf,
            r#"<box size="0.4475 0.03 0.03"/>"#,
            r#"<mesh filename="link2.stl"/>"#,
        ),
    );
    assert!(
        e.to_string().contains("mesh 'link2.stl' is not supported"),
        "{e}"
    );
    let e = refusal(
        toml,
        &edited(
            urdf,
            r#"<parent link="base_link"/><child link="rotor_0"/>"#,
            r#"<parent link="rotor_0"/><child link="base_link"/>"#,
        ),
    );
    assert!(
        e.to_string().contains("already has parent joint") || e.to_string().contains("root"),
        "{e}"
    );
    let e = refusal(toml, &edited(urdf, r#"ixx="0.198""#, r#"ixx="-0.198""#));
    assert!(
        e.to_string().contains("is not positive semi-definite"),
        "{e}"
    );
}

mod thrust_curve {
    use crate::ThrustCurve;

    const CURVE: ThrustCurve = ThrustCurve {
        model_factor: 0.3,
        thrust_min_n: 0.0,
        thrust_max_n: 23.0,
    };

    #[test]
    fn half_command_gives_the_px4_relative_thrust() {
        // t(0.5) = 0.3·0.25 + 0.7·0.5 = 0.425 → 0.425 · 23 N.
        assert!((CURVE.thrust_n(0.5) - 0.425 * 23.0).abs() < 1e-12);
        assert_eq!(CURVE.thrust_n(0.0), 0.0);
        assert!((CURVE.thrust_n(1.0) - 23.0).abs() < 1e-12);
    }

    #[test]
    fn command_inverts_thrust_and_clamps() {
        for u in [0.0, 0.1, 0.37, 0.5, 0.99, 1.0] {
            assert!((CURVE.command(CURVE.thrust_n(u)) - u).abs() < 1e-12, "{u}");
        }
        assert_eq!(CURVE.command(-5.0), 0.0);
        assert_eq!(CURVE.command(100.0), 1.0);
        assert_eq!(CURVE.command(f64::NAN), 0.0);
        assert_eq!(CURVE.thrust_n(f64::NAN), 0.0);
        let linear = ThrustCurve {
            model_factor: 0.0,
            ..CURVE
        };
        assert!((linear.command(11.5) - 0.5).abs() < 1e-12);
    }
}

#[test]
fn urdf_visual_colours_come_from_inline_or_named_materials() {
    let urdf = r#"<robot name="painted">
  <material name="red"><color rgba="1 0 0 1"/></material>
  <link name="a">
    <visual><geometry><box size="1 1 1"/></geometry><material name="red"/></visual>
    <visual><geometry><sphere radius="0.1"/></geometry><material name="x"><color rgba="0 0.5 1 1"/></material></visual>
    <visual><geometry><sphere radius="0.1"/></geometry></visual>
  </link>
</robot>"#;
    let m = KinematicModel::from_urdf("painted.urdf", urdf).unwrap_or_else(|e| panic!("{e}"));
    let colours: Vec<_> = m.links[0].visuals.iter().map(|v| v.rgba).collect();
    assert_eq!(
        colours,
        [Some([1.0, 0.0, 0.0, 1.0]), Some([0.0, 0.5, 1.0, 1.0]), None]
    );
    let bad = urdf.replace("1 0 0 1", "2 0 0 1");
    let err = KinematicModel::from_urdf("painted.urdf", &bad)
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        err.contains("material 'red'") && err.contains("[0, 1]"),
        "{err}"
    );
}

#[test]
fn vehicle_file_colours_are_checked_and_indexed_by_link() {
    let (toml, urdf) = fa_files();
    let painted = format!("{toml}\n[colors]\nbase_link = [0.1, 0.2, 0.3]\n");
    let v = load(&painted, urdf).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(v.link_colors.len(), v.model.links.len());
    assert_eq!(v.link_colors[v.base_link], Some([0.1, 0.2, 0.3]));
    assert_eq!(v.link_colors.iter().flatten().count(), 1);
    let unpainted = load(toml, urdf).unwrap_or_else(|e| panic!("{e}"));
    assert!(unpainted.link_colors.iter().all(Option::is_none));
    let e = refusal(
        &format!("{toml}\n[colors]\nbase_link = [0.1, 2.0, 0.3]\n"),
        urdf,
    );
    assert_eq!(
        e.to_string(),
        "my.toml: colors.base_link: [0.1, 2.0, 0.3] must lie in [0, 1]"
    );
    let e = refusal(&format!("{toml}\n[colors]\nwing = [0.1, 0.2, 0.3]\n"), urdf);
    assert!(e.to_string().contains("colors.wing"), "{e}");
}

#[test]
fn the_reference_hexa_base_inertia_breaks_the_triangle_inequality_and_is_reported() {
    // diag(0.198, 0.198, 0.460): 0.460 > 0.198 + 0.198 (AMBENCH_SPEC §1.2; issue 16).
    for id in ["fa-hexa", "ua-hexa"] {
        let warnings = vehicle(id).model.physical_warnings();
        assert_eq!(warnings.len(), 1, "{id}: {warnings:?}");
        assert!(
            warnings[0].contains("'base_link'") && warnings[0].contains("0.4600 > 0.1980 + 0.1980"),
            "{id}: {}",
            warnings[0]
        );
    }
    for id in ["ua-quad", "omni-hexa", "ee-only"] {
        assert_eq!(
            vehicle(id).model.physical_warnings(),
            Vec::<String>::new(),
            "{id}"
        );
    }
}
