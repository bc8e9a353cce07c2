//! Moore–Penrose pseudo-inverse of an allocation matrix, computed once per vehicle.
//!
//! For a full-row-rank A (m × n, m ≤ n), A⁺ = Aᵀ(AAᵀ)⁻¹ and x = A⁺w is the minimum-norm
//! solution of A x = w. It is computed from the SVD A = UΣVᵀ as A⁺ = VΣ⁺Uᵀ, dropping singular
//! values below [`RANK_TOLERANCE`]·σ_max, which also gives the numerical rank.

use nalgebra::DMatrix;

/// Singular values below this fraction of the largest are treated as zero. The AM-Bench
/// matrices have σ_min/σ_max ≈ 1e-2 (the yaw row is k_f-sized), far above it.
pub const RANK_TOLERANCE: f64 = 1e-9;

/// A⁺ and the numerical rank of A.
pub(crate) fn pseudo_inverse(matrix: &DMatrix<f64>) -> (DMatrix<f64>, usize) {
    let svd = matrix.clone().svd(true, true);
    let sigma_max = svd.singular_values.max();
    let threshold = RANK_TOLERANCE * sigma_max;
    let rank = svd
        .singular_values
        .iter()
        .filter(|&&s| s > threshold)
        .count();
    // Σ⁺ by hand (nalgebra's `pseudo_inverse` takes an absolute threshold).
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        // Both were requested above; an SVD without them cannot happen. Return the zero map,
        // which `rank` (0 here) makes the caller reject.
        return (DMatrix::zeros(matrix.ncols(), matrix.nrows()), 0);
    };
    let mut sigma_pinv_u_t = u.transpose();
    for (i, &s) in svd.singular_values.iter().enumerate() {
        let inv = if s > threshold { 1.0 / s } else { 0.0 };
        sigma_pinv_u_t.row_mut(i).scale_mut(inv);
    }
    (v_t.transpose() * sigma_pinv_u_t, rank)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effectiveness::{effectiveness_matrix, reduced_effectiveness_matrix};
    use crate::fixtures::{self, assert_all_close};

    /// A A⁺ = I to this, entrywise.
    const IDENTITY_TOLERANCE: f64 = 1e-12;

    #[test]
    fn pseudo_inverse_is_a_right_inverse_of_a_full_row_rank_matrix() {
        for a in [
            effectiveness_matrix(&fixtures::fa_hexa()),
            reduced_effectiveness_matrix(&fixtures::ua_hexa()),
            reduced_effectiveness_matrix(&fixtures::ua_quad()),
        ] {
            let (pinv, rank) = pseudo_inverse(&a);
            assert_eq!(rank, a.nrows());
            let identity = DMatrix::<f64>::identity(a.nrows(), a.nrows());
            assert_all_close(
                (&a * &pinv).iter(),
                identity.iter(),
                IDENTITY_TOLERANCE,
                "A A⁺",
            );
        }
    }

    #[test]
    fn rank_deficient_matrix_reports_its_rank() {
        // Six parallel axes cannot make body F_x, F_y: rank 4 of 6.
        let (_, rank) = pseudo_inverse(&effectiveness_matrix(&fixtures::ua_hexa()));
        assert_eq!(rank, 4);
    }

    #[test]
    fn zero_matrix_has_rank_zero() {
        let (pinv, rank) = pseudo_inverse(&DMatrix::zeros(4, 4));
        assert_eq!(rank, 0);
        assert!(pinv.iter().all(|x| *x == 0.0));
    }
}
