//! The IK's two decompositions, both nalgebra's: the SVD of the task Jacobian, split into the
//! range of J₁ᵀ and its orthogonal complement (the task nullspace), and the Cholesky factor of
//! the small symmetric positive-definite systems of the regularisation and correction steps.
//!
//! nalgebra's SVD returns min(rows, columns) right singular vectors. The nullspace needs all
//! n of them, so J₁ (6 + active hinges rows) is given zero rows up to n when it is wider than
//! tall: zero rows change neither the singular values nor the right singular vectors, and the
//! directions J₁ cannot see come out with singular value zero.

use nalgebra::{Cholesky, DMatrix, Dyn, SVD};

/// Most implicit-shift QR sweeps of one SVD per column (LAPACK allows about 6 per column;
/// a well-behaved problem needs about 2).
const SVD_SWEEPS_PER_COLUMN: usize = 30;

/// The right singular vectors of `j` (m × n with m ≥ n; pad with zero rows otherwise), split
/// by `ratio`: those whose singular value exceeds `ratio·σ_max` span the range of Jᵀ and go to
/// the first columns of `range`, their σ² to `sigma2`; the others span the nullspace of J and
/// go to the first columns of `null`. `range` and `null` are n × n, `sigma2` holds n. Returns
/// (range count, nullspace count), or None on a non-finite entry or when the SVD does not
/// converge.
pub(crate) fn split_range_and_nullspace(
    j: DMatrix<f64>,
    ratio: f64,
    range: &mut DMatrix<f64>,
    sigma2: &mut [f64],
    null: &mut DMatrix<f64>,
) -> Option<(usize, usize)> {
    let n = j.ncols();
    if n == 0 {
        return Some((0, 0));
    }
    if !j.iter().all(|v| v.is_finite()) {
        return None;
    }
    let j = if j.nrows() < n {
        j.resize_vertically(n, 0.0)
    } else {
        j
    };
    // Unordered: the split below needs no order, and sorting would panic on a NaN.
    let svd = SVD::try_new_unordered(j, false, true, f64::EPSILON, SVD_SWEEPS_PER_COLUMN * n)?;
    let v_t = svd.v_t.as_ref()?;
    let sigma = &svd.singular_values;
    let largest = sigma.amax();
    let (mut r, mut k) = (0, 0);
    for (i, &s) in sigma.iter().enumerate() {
        if largest > 0.0 && s > ratio * largest {
            range.column_mut(r).tr_copy_from(&v_t.row(i));
            sigma2[r] = s * s;
            r += 1;
        } else {
            null.column_mut(k).tr_copy_from(&v_t.row(i));
            k += 1;
        }
    }
    Some((r, k))
}

/// nalgebra's Cholesky factor of the symmetric positive-definite `m` (its lower triangle is
/// read); None if an entry is not finite or `m` is not (numerically) positive definite.
pub(crate) fn cholesky(m: DMatrix<f64>) -> Option<Cholesky<f64, Dyn>> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    Cholesky::new(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;

    /// Round-off allowed on reconstructions of well-conditioned 6 × 6 problems.
    const RECONSTRUCTION_TOLERANCE: f64 = 1e-12;
    /// The default `nullspace_singular_value_ratio`.
    const RATIO: f64 = 1e-6;

    fn test_matrix() -> DMatrix<f64> {
        // A rank-4 Gram matrix of a 4 × 6 "Jacobian".
        let j = DMatrix::from_fn(4, 6, |r, c| {
            ((r * 7 + c * 3) % 5) as f64 - 1.7 + 0.1 * c as f64
        });
        j.transpose() * j
    }

    /// A rank-4 "Jacobian" (4 of its 6 rows independent), 6 × 5.
    fn rank_deficient_jacobian() -> DMatrix<f64> {
        let base = DMatrix::from_fn(4, 5, |r, c| {
            ((r * 7 + c * 3) % 5) as f64 - 1.7 + 0.1 * c as f64
        });
        let mut j = DMatrix::zeros(6, 5);
        j.rows_mut(0, 4).copy_from(&base);
        j.set_row(4, &(base.row(0) + base.row(1) * 2.0));
        j.set_row(5, &(base.row(2) - base.row(3)));
        j
    }

    /// Splits `j` and checks the contract: range and nullspace together are an orthonormal
    /// basis, J annihilates the nullspace, and Σ σ_i² v_i v_iᵀ over the range rebuilds JᵀJ.
    fn assert_split(j: &DMatrix<f64>, expected_range: usize) {
        let n = j.ncols();
        let mut range = DMatrix::zeros(n, n);
        let mut null = DMatrix::zeros(n, n);
        let mut sigma2 = vec![0.0; n];
        let split = split_range_and_nullspace(j.clone(), RATIO, &mut range, &mut sigma2, &mut null);
        assert_eq!(split, Some((expected_range, n - expected_range)));
        let (r, k) = (expected_range, n - expected_range);
        let mut basis = DMatrix::zeros(n, n);
        basis.columns_mut(0, r).copy_from(&range.columns(0, r));
        basis.columns_mut(r, k).copy_from(&null.columns(0, k));
        assert!(
            (basis.transpose() * &basis - DMatrix::identity(n, n)).amax()
                < RECONSTRUCTION_TOLERANCE
        );
        let scale = j.amax();
        assert!((j * null.columns(0, k)).amax() < RECONSTRUCTION_TOLERANCE * scale);
        let mut gram = DMatrix::zeros(n, n);
        for (i, s2) in sigma2.iter().take(r).enumerate() {
            gram += range.column(i) * range.column(i).transpose() * *s2;
        }
        let jtj = j.transpose() * j;
        assert!((gram - &jtj).amax() < RECONSTRUCTION_TOLERANCE * jtj.amax());
    }

    #[test]
    fn svd_splits_a_rank_deficient_jacobian_into_range_and_nullspace() {
        assert_split(&rank_deficient_jacobian(), 4);
    }

    #[test]
    fn svd_of_a_wide_jacobian_gives_the_whole_nullspace() {
        // 4 independent rows of 5 columns (fewer rows than variables, as a pose Jacobian of
        // a vehicle with more than six variables): one nullspace vector from the zero rows.
        assert_split(&rank_deficient_jacobian().rows(0, 4).clone_owned(), 4);
    }

    #[test]
    fn svd_refuses_a_non_finite_jacobian() {
        let mut j = rank_deficient_jacobian();
        j[(2, 3)] = f64::NAN;
        let mut range = DMatrix::zeros(5, 5);
        let mut null = DMatrix::zeros(5, 5);
        let mut sigma2 = vec![0.0; 5];
        assert_eq!(
            split_range_and_nullspace(j, RATIO, &mut range, &mut sigma2, &mut null),
            None
        );
    }

    #[test]
    fn cholesky_solves_a_positive_definite_system() {
        let m0 = test_matrix() + DMatrix::identity(6, 6);
        let x_true = DVector::from_fn(6, |i, _| i as f64 - 2.5);
        let mut x = &m0 * &x_true;
        let Some(factor) = cholesky(m0.clone()) else {
            panic!("not factored");
        };
        factor.solve_mut(&mut x);
        let err = (x - x_true).amax();
        assert!(err < RECONSTRUCTION_TOLERANCE, "error {err}");
    }

    #[test]
    fn cholesky_refuses_a_singular_or_non_finite_matrix() {
        let m = DMatrix::from_element(3, 3, 1.0);
        assert!(cholesky(m).is_none());
        let mut m = DMatrix::identity(3, 3);
        m[(1, 1)] = f64::INFINITY;
        assert!(cholesky(m).is_none());
    }
}
