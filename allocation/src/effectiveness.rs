//! Effectiveness matrices: what one newton of each rotor's thrust does to the body wrench.
//!
//! Rotor i sits at r_i (base frame, m), pushes along the unit direction d_i, and its drag
//! reaction torque is s_i·k_f per newton along d_i (s_i = ±1 the spin sign, k_f the
//! reaction-torque ratio in m). Its column, rows `[F_x, F_y, F_z, τ_x, τ_y, τ_z]`, is
//!
//! ```text
//!     a_i = [ d_i ; r_i × d_i + s_i·k_f·d_i ]
//! ```
//!
//! and the body wrench of thrusts T is w = A·T with A = [a_1 … a_N] (6×N).
//!
//! - Under-actuated vehicles command only `[F_z, τ_x, τ_y, τ_z]`: the reduced matrix is rows
//!   2..6 of A (4×N).
//! - A variable-tilt rotor points along n_i(α) = cos α·c_i + sin α·s_i (c_i its α = 0 axis,
//!   s_i its "sin axis"), its position held at the α = 0 reference. Writing its thrust vector
//!   as c·c_i + s·s_i with (c, s) = T·(cos α, sin α) makes the map linear again: 6×2N, two
//!   interleaved columns per rotor, `[a(c_i), a(s_i)]`.
//!
//! Everything here is a pure function of the geometry, so a test can build a layout by hand
//! ([`platform::Rotor::fixed`]).

use nalgebra::{DMatrix, Vector3, Vector6};
use platform::{RotorLayout, Wrench};

use crate::AllocationError;

/// Rows of the 6-vector wrench `[F_x, F_y, F_z, τ_x, τ_y, τ_z]` that a fully actuated or
/// variable-tilt allocation commands.
pub const FULL_WRENCH_ROWS: [usize; 6] = [0, 1, 2, 3, 4, 5];

/// Rows of the 6-vector wrench that an under-actuated allocation commands:
/// `[F_z, τ_x, τ_y, τ_z]` (body F_x, F_y are not commanded).
pub const REDUCED_WRENCH_ROWS: [usize; 4] = [2, 3, 4, 5];

/// The effectiveness column of one rotor: `[d ; r × d + s·k_f·d]`.
///
/// `direction_in_base` is used as given (callers pass a unit vector).
pub fn effectiveness_column(
    position_in_base: &Vector3<f64>,
    direction_in_base: &Vector3<f64>,
    spin_sign: f64,
    reaction_torque_ratio_m: f64,
) -> Vector6<f64> {
    let torque = position_in_base.cross(direction_in_base)
        + direction_in_base * (spin_sign * reaction_torque_ratio_m);
    Vector6::new(
        direction_in_base.x,
        direction_in_base.y,
        direction_in_base.z,
        torque.x,
        torque.y,
        torque.z,
    )
}

/// The 6×N effectiveness matrix A, one column per rotor in actuator order. A tilting rotor
/// contributes its α = 0 axis (`axis_in_base`).
pub fn effectiveness_matrix(layout: &RotorLayout) -> DMatrix<f64> {
    let k_f = layout.reaction_torque_ratio_m;
    DMatrix::from_fn(6, layout.len(), |row, col| {
        let rotor = &layout.rotors[col];
        effectiveness_column(
            &rotor.position_in_base,
            &rotor.axis_in_base,
            rotor.spin.sign(),
            k_f,
        )[row]
    })
}

/// The 4×N under-actuated matrix: rows `[F_z, τ_x, τ_y, τ_z]` of [`effectiveness_matrix`].
pub fn reduced_effectiveness_matrix(layout: &RotorLayout) -> DMatrix<f64> {
    select_rows(&effectiveness_matrix(layout), &REDUCED_WRENCH_ROWS)
}

/// The 6×2N variable-tilt matrix, columns `[a(c_1), a(s_1), a(c_2), a(s_2), …]`: for rotor i
/// the cos column uses its α = 0 axis c_i, the sin column its sin axis s_i, both at the α = 0
/// rotor position.
///
/// # Errors
/// [`AllocationError::MissingTilt`] if a rotor has no tilt hinge.
pub fn variable_tilt_effectiveness_matrix(
    layout: &RotorLayout,
) -> Result<DMatrix<f64>, AllocationError> {
    let k_f = layout.reaction_torque_ratio_m;
    let mut matrix = DMatrix::zeros(6, 2 * layout.len());
    for (i, rotor) in layout.rotors.iter().enumerate() {
        let tilt = rotor
            .tilt
            .as_ref()
            .ok_or(AllocationError::MissingTilt { rotor: i })?;
        let spin = rotor.spin.sign();
        let cos_column =
            effectiveness_column(&rotor.position_in_base, &rotor.axis_in_base, spin, k_f);
        let sin_column =
            effectiveness_column(&rotor.position_in_base, &tilt.sin_axis_in_base, spin, k_f);
        matrix.set_column(2 * i, &cos_column);
        matrix.set_column(2 * i + 1, &sin_column);
    }
    Ok(matrix)
}

/// The forward map: the body wrench of thrust magnitudes `thrusts_n` (N), each rotor pointing
/// along n_i(α_i) ([`platform::Rotor::axis_at_tilt`]):
///
/// ```text
///     F = Σ T_i n_i,    τ = Σ (r_i × T_i n_i + s_i k_f T_i n_i)
/// ```
///
/// `tilt_rad` is either empty (every rotor at α = 0) or one angle per rotor (ignored for a fixed
/// rotor).
///
/// # Errors
/// [`AllocationError::LengthMismatch`] if a slice does not have one entry per rotor.
pub fn wrench_from_thrusts(
    layout: &RotorLayout,
    thrusts_n: &[f64],
    tilt_rad: &[f64],
) -> Result<Wrench, AllocationError> {
    let n = layout.len();
    if thrusts_n.len() != n {
        return Err(AllocationError::LengthMismatch {
            what: "rotor thrusts",
            expected: n,
            got: thrusts_n.len(),
        });
    }
    if !tilt_rad.is_empty() && tilt_rad.len() != n {
        return Err(AllocationError::LengthMismatch {
            what: "rotor tilt angles",
            expected: n,
            got: tilt_rad.len(),
        });
    }
    let k_f = layout.reaction_torque_ratio_m;
    let mut wrench = Wrench::ZERO;
    for (i, (rotor, &thrust)) in layout.rotors.iter().zip(thrusts_n).enumerate() {
        let angle = tilt_rad.get(i).copied().unwrap_or(0.0);
        let thrust_vector = rotor.axis_at_tilt(angle) * thrust;
        wrench.force += thrust_vector;
        wrench.torque += rotor.position_in_base.cross(&thrust_vector)
            + thrust_vector * (rotor.spin.sign() * k_f);
    }
    Ok(wrench)
}

/// The rows `rows` of `matrix`, in that order.
pub(crate) fn select_rows(matrix: &DMatrix<f64>, rows: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(rows.len(), matrix.ncols(), |r, c| matrix[(rows[r], c)])
}

/// Checks the figures an allocator relies on: at least one rotor, finite geometry, unit axes,
/// 0 ≤ T_min < T_max finite, k_f finite.
pub(crate) fn validate_layout(layout: &RotorLayout) -> Result<(), AllocationError> {
    /// How far from 1 a thrust axis norm may be (the platform normalises them).
    const UNIT_AXIS_TOLERANCE: f64 = 1e-9;
    /// Largest |c_i · s_i| accepted for a tilting rotor.
    const ORTHOGONALITY_TOLERANCE: f64 = 1e-6;
    if layout.is_empty() {
        return Err(AllocationError::NoRotors);
    }
    let (t_min, t_max) = (layout.thrust_min_n, layout.thrust_max_n);
    if !(t_min.is_finite() && t_max.is_finite() && t_min >= 0.0 && t_max > t_min) {
        return Err(AllocationError::InvalidLayout(format!(
            "thrust limits must be finite with 0 ≤ min < max, got ({t_min}, {t_max}) N"
        )));
    }
    if !layout.reaction_torque_ratio_m.is_finite() {
        return Err(AllocationError::InvalidLayout(format!(
            "reaction torque ratio must be finite, got {} m",
            layout.reaction_torque_ratio_m
        )));
    }
    let unit = |v: &Vector3<f64>| (v.norm() - 1.0).abs() <= UNIT_AXIS_TOLERANCE;
    for (i, rotor) in layout.rotors.iter().enumerate() {
        if !rotor.position_in_base.iter().all(|x| x.is_finite()) {
            return Err(AllocationError::InvalidLayout(format!(
                "rotor {i}: position must be finite, got {:?}",
                rotor.position_in_base.as_slice()
            )));
        }
        if !unit(&rotor.axis_in_base) {
            return Err(AllocationError::InvalidLayout(format!(
                "rotor {i}: thrust axes must be unit vectors, got {:?}",
                rotor.axis_in_base.as_slice()
            )));
        }
        if let Some(tilt) = &rotor.tilt {
            let sin_axis = tilt.sin_axis_in_base.into_inner();
            if !unit(&sin_axis) {
                return Err(AllocationError::InvalidLayout(format!(
                    "rotor {i}: sin axes must be unit vectors, got {:?}",
                    sin_axis.as_slice()
                )));
            }
            if sin_axis.dot(&rotor.axis_in_base).abs() > ORTHOGONALITY_TOLERANCE {
                return Err(AllocationError::InvalidLayout(format!(
                    "rotor {i}: cos and sin axes must be orthogonal"
                )));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
#[expect(clippy::unwrap_used, reason = "a test fails loudly")]
mod tests {
    use super::*;
    use crate::fixtures::{self, assert_all_close};
    use nalgebra::DVector;
    use platform::{Rotor, Spin};

    /// Entries computed by hand, or the same sum in another order.
    const HAND_TOLERANCE: f64 = 1e-12;
    /// Smallest singular value a matrix must keep to count as full rank.
    const RANK_FLOOR: f64 = 1e-3;
    /// The spec prints FA-Hexa axes to five decimals.
    const SPEC_AXIS_TOLERANCE: f64 = 1e-4;

    #[test]
    fn ua_quad_reduced_matrix_matches_hand_derivation() {
        // +z rotors: column = [1, y_i, −x_i, s_i·k_f] (r × ẑ = (y, −x, 0)); the z offset of
        // 0.05 m does not enter.
        let layout = fixtures::ua_quad();
        let a = reduced_effectiveness_matrix(&layout);
        let d = 0.3 / 2f64.sqrt();
        let k_f = 0.02;
        #[rustfmt::skip]
        let expected = DMatrix::from_row_slice(4, 4, &[
            1.0,   1.0,  1.0,   1.0,
            d,     d,   -d,    -d,
           -d,     d,    d,    -d,
           -k_f,   k_f, -k_f,   k_f,
        ]);
        assert_all_close(
            a.iter(),
            expected.iter(),
            HAND_TOLERANCE,
            "UA-Quad reduced matrix",
        );
        // The full matrix has zero body F_x, F_y rows.
        let full = effectiveness_matrix(&layout);
        assert!(full.rows(0, 2).iter().all(|&x| x == 0.0));
    }

    #[test]
    fn fa_hexa_matrix_has_full_rank() {
        let a = effectiveness_matrix(&fixtures::fa_hexa());
        let singular = a.singular_values();
        assert_eq!(singular.len(), 6);
        assert!(
            singular.min() > RANK_FLOOR,
            "singular values {singular:?}: FA-Hexa should span all six wrench axes"
        );
        // The spec's derived axis of rotor 1 is (0.50035, 0, 0.86582).
        assert_all_close(
            a.column(1).rows(0, 3).iter(),
            [0.50035, 0.0, 0.86582].iter(),
            SPEC_AXIS_TOLERANCE,
            "FA-Hexa rotor 1 axis",
        );
    }

    #[test]
    fn ua_hexa_full_matrix_is_rank_four() {
        let a = effectiveness_matrix(&fixtures::ua_hexa());
        let rank = a
            .singular_values()
            .iter()
            .filter(|&&s| s > RANK_FLOOR)
            .count();
        assert_eq!(rank, 4, "parallel axes cannot produce body F_x, F_y");
        let reduced = reduced_effectiveness_matrix(&fixtures::ua_hexa());
        assert!(reduced.singular_values().min() > RANK_FLOOR);
    }

    #[test]
    fn variable_tilt_columns_interleave_cos_and_sin_axes() {
        let layout = fixtures::omni_hexa();
        let a = variable_tilt_effectiveness_matrix(&layout).unwrap();
        assert_eq!(a.shape(), (6, 12));
        for (i, rotor) in layout.rotors.iter().enumerate() {
            let tilt = rotor.tilt.as_ref().unwrap();
            let spin = rotor.spin.sign();
            let c = effectiveness_column(&rotor.position_in_base, &rotor.axis_in_base, spin, 0.02);
            let s =
                effectiveness_column(&rotor.position_in_base, &tilt.sin_axis_in_base, spin, 0.02);
            assert_eq!(a.column(2 * i).into_owned(), c);
            assert_eq!(a.column(2 * i + 1).into_owned(), s);
        }
        assert!(
            a.singular_values().min() > RANK_FLOOR,
            "Omni-Hexa spans all six axes"
        );
    }

    #[test]
    fn variable_tilt_matrix_requires_a_hinge_on_every_rotor() {
        assert_eq!(
            variable_tilt_effectiveness_matrix(&fixtures::ua_quad()),
            Err(AllocationError::MissingTilt { rotor: 0 })
        );
    }

    #[test]
    fn forward_map_equals_matrix_product() {
        let layout = fixtures::fa_hexa();
        let thrusts = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let w = wrench_from_thrusts(&layout, &thrusts, &[]).unwrap();
        let expected = effectiveness_matrix(&layout) * DVector::from_row_slice(&thrusts);
        assert_all_close(
            w.to_vector().iter(),
            expected.iter(),
            HAND_TOLERANCE,
            "wrench",
        );
    }

    #[test]
    fn forward_map_of_tilted_rotors_matches_interleaved_matrix() {
        let layout = fixtures::omni_hexa();
        let thrusts = [3.0, 4.0, 5.0, 6.0, 7.0, 8.0];
        let angles = [0.1, -0.5, 1.0, 2.5, -3.0, 0.0];
        let w = wrench_from_thrusts(&layout, &thrusts, &angles).unwrap();
        let x = DVector::from_fn(12, |j, _| {
            let (t, a) = (thrusts[j / 2], angles[j / 2]);
            if j % 2 == 0 { t * a.cos() } else { t * a.sin() }
        });
        let expected = variable_tilt_effectiveness_matrix(&layout).unwrap() * x;
        assert_all_close(
            w.to_vector().iter(),
            expected.iter(),
            HAND_TOLERANCE,
            "wrench",
        );
    }

    #[test]
    fn single_rotor_reaction_torque_follows_spin() {
        let rotor = Rotor::fixed(Vector3::zeros(), Vector3::z(), Spin::Negative);
        let layout = fixtures::layout(vec![rotor], 0.0, 100.0, 0.1);
        let w = wrench_from_thrusts(&layout, &[10.0], &[]).unwrap();
        assert_eq!(w.force, Vector3::new(0.0, 0.0, 10.0));
        assert_eq!(w.torque, Vector3::new(0.0, 0.0, -1.0));
    }

    #[test]
    fn forward_map_rejects_wrong_lengths() {
        let layout = fixtures::ua_quad();
        assert!(matches!(
            wrench_from_thrusts(&layout, &[1.0; 3], &[]),
            Err(AllocationError::LengthMismatch {
                expected: 4,
                got: 3,
                ..
            })
        ));
        assert!(matches!(
            wrench_from_thrusts(&layout, &[1.0; 4], &[0.0; 2]),
            Err(AllocationError::LengthMismatch {
                expected: 4,
                got: 2,
                ..
            })
        ));
    }

    #[test]
    fn zero_thrusts_give_zero_wrench() {
        for layout in [
            fixtures::fa_hexa(),
            fixtures::ua_hexa(),
            fixtures::ua_quad(),
            fixtures::omni_hexa(),
        ] {
            let zeros = vec![0.0; layout.len()];
            assert_eq!(
                wrench_from_thrusts(&layout, &zeros, &zeros).unwrap(),
                Wrench::ZERO
            );
        }
    }

    #[test]
    fn layout_validation_rejects_bad_figures() {
        let mut layout = fixtures::ua_quad();
        assert_eq!(validate_layout(&layout), Ok(()));
        layout.thrust_max_n = f64::NAN;
        assert!(validate_layout(&layout).is_err());
        let mut layout = fixtures::ua_quad();
        layout.thrust_min_n = 30.0;
        assert!(validate_layout(&layout).is_err(), "min above max");
        let mut layout = fixtures::ua_quad();
        layout.rotors[2].position_in_base.x = f64::NAN;
        let message = validate_layout(&layout).unwrap_err().to_string();
        assert!(message.contains("finite"), "{message}");
        let mut layout = fixtures::ua_quad();
        layout.rotors[1].axis_in_base = nalgebra::Unit::new_unchecked(Vector3::new(0.0, 0.0, 2.0));
        let message = validate_layout(&layout).unwrap_err().to_string();
        assert!(message.contains("unit vectors"), "{message}");
        let mut layout = fixtures::omni_hexa();
        let cos_axis = layout.rotors[0].axis_in_base;
        if let Some(tilt) = layout.rotors[0].tilt.as_mut() {
            tilt.sin_axis_in_base = cos_axis;
        }
        let message = validate_layout(&layout).unwrap_err().to_string();
        assert!(message.contains("orthogonal"), "{message}");
        let mut layout = fixtures::ua_quad();
        layout.rotors.clear();
        assert_eq!(validate_layout(&layout), Err(AllocationError::NoRotors));
    }
}
