//! Small dense linear algebra on preallocated storage (no allocation per call).
//!
//! The IK's matrices are at most a dozen rows wide: a one-sided Jacobi SVD, an orthogonal
//! complement and an in-place Cholesky factorisation are fast and accurate at that size, and
//! they reuse the buffers the solver owns. The Cholesky routines work on the top-left `k × k`
//! block of a larger buffer.

use nalgebra::DMatrix;

/// Largest number of Jacobi sweeps (Jacobi converges quadratically: a handful suffice).
const MAX_JACOBI_SWEEPS: usize = 40;
/// One-sided Jacobi stops rotating a column pair once |cos| of their angle is below this
/// (the dot product's own round-off is ~n·ε; 1e-12 keeps singular values and vectors to
/// ~1e-12 relative, ample for the steps and the nullspace threshold).
const ONE_SIDED_ORTHOGONALITY: f64 = 1e-12;
/// A Jacobi sweep whose largest rotation tangent is below this ends the iteration (the next
/// sweep would rotate by about its square, ~1e-12).
const ONE_SIDED_LAST_SWEEP_TANGENT: f64 = 1e-6;
/// Above this |cot 2φ| the Jacobi rotation tangent uses its asymptote 1/(2·cot 2φ).
const JACOBI_HUGE_COT: f64 = 1e150;
/// A candidate e_i with less than this squared norm outside the span found so far does not
/// give a complement vector (it is in the span to round-off).
const COMPLEMENT_MIN_RESIDUAL: f64 = 1e-6;

/// One-sided (Hestenes) Jacobi orthogonalisation of the first `m` columns of `w` (n rows):
/// plane rotations of column pairs until all pairs are orthogonal to round-off, applied to the
/// first `m` columns of `u` too. For `w = Jᵀ·U₀` this is the SVD of J: on return the columns of
/// `w` are σ_j·v_j (right singular vectors scaled by the singular values) and `u`'s columns the
/// left singular vectors (`u` must hold U₀ on entry: the identity, or the vectors of a nearby
/// matrix, which cuts the sweeps to one or two). Returns false on a non-finite entry or when
/// the sweeps run out.
pub(crate) fn one_sided_jacobi(w: &mut DMatrix<f64>, u: &mut DMatrix<f64>, m: usize) -> bool {
    let n = w.nrows();
    let u_rows = u.nrows();
    let w = w.as_mut_slice();
    let u = u.as_mut_slice();
    // A column this small (squared norm relative to |W|²) is zero to round-off: its direction
    // is noise, and rotating it against the others would never settle.
    let frobenius2: f64 = w[..m * n].iter().map(|x| x * x).sum();
    let zero_column = (f64::EPSILON * f64::EPSILON) * frobenius2;
    for _ in 0..MAX_JACOBI_SWEEPS {
        let mut largest_tangent: f64 = 0.0;
        for p in 0..m {
            for q in p + 1..m {
                let (alpha, beta, gamma) = {
                    let (left, right) = w.split_at(q * n);
                    let (wp, wq) = (&left[p * n..p * n + n], &right[..n]);
                    wp.iter()
                        .zip(wq)
                        .fold((0.0, 0.0, 0.0), |(a, b, g), (x, y)| {
                            (a + x * x, b + y * y, g + x * y)
                        })
                };
                if !(alpha.is_finite() && beta.is_finite() && gamma.is_finite()) {
                    return false;
                }
                if alpha.min(beta) <= zero_column
                    || gamma.abs() <= ONE_SIDED_ORTHOGONALITY * (alpha * beta).sqrt()
                {
                    continue;
                }
                let zeta = (beta - alpha) / (2.0 * gamma);
                let t = if zeta.abs() > JACOBI_HUGE_COT {
                    0.5 / zeta
                } else {
                    zeta.signum() / (zeta.abs() + (zeta * zeta + 1.0).sqrt())
                };
                largest_tangent = largest_tangent.max(t.abs());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                rotate_columns(w, n, n, p, q, c, s);
                // Rows of U at and beyond m are zero in its first m columns.
                rotate_columns(u, u_rows, m, p, q, c, s);
            }
        }
        // Convergence is quadratic: after a sweep whose rotations were all this small, the
        // next would only rotate by round-off.
        if largest_tangent < ONE_SIDED_LAST_SWEEP_TANGENT {
            return true;
        }
    }
    false
}

/// Columns p < q (first `len` rows) of the column-major matrix `m` with `rows` rows
/// ← (c·m_p − s·m_q, s·m_p + c·m_q).
fn rotate_columns(m: &mut [f64], rows: usize, len: usize, p: usize, q: usize, c: f64, s: f64) {
    let (left, right) = m.split_at_mut(q * rows);
    let column_p = &mut left[p * rows..p * rows + len];
    let column_q = &mut right[..len];
    for (x, y) in column_p.iter_mut().zip(column_q.iter_mut()) {
        let (xp, yq) = (*x, *y);
        *x = c * xp - s * yq;
        *y = s * xp + c * yq;
    }
}

/// An orthonormal basis of the complement of the orthonormal columns `range[..r]` (n rows)
/// into the first `n − r` columns of `out`: the unit vectors e_i, most outside the range
/// first, orthogonalised against the range and each other. `norms` is scratch of length n.
/// Returns the number of vectors found.
pub(crate) fn orthogonal_complement(
    range: &DMatrix<f64>,
    r: usize,
    out: &mut DMatrix<f64>,
    norms: &mut [f64],
) -> usize {
    let n = range.nrows();
    let range = range.as_slice();
    let out = out.as_mut_slice();
    // Squared norm of each e_i outside the span found so far.
    for (i, norm) in norms.iter_mut().enumerate().take(n) {
        *norm = 1.0 - (0..r).map(|j| range[i + j * n].powi(2)).sum::<f64>();
    }
    let mut found = 0;
    while found + r < n {
        let Some((best, &residual)) = norms[..n]
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
        else {
            break;
        };
        if residual < COMPLEMENT_MIN_RESIDUAL {
            break;
        }
        let (done, rest) = out.split_at_mut(found * n);
        let x = &mut rest[..n];
        x.fill(0.0);
        x[best] = 1.0;
        // x = e_best minus its projections on the range and on the vectors found, twice for
        // accuracy (classical Gram–Schmidt twice is as good as modified).
        for _ in 0..2 {
            for column in range[..r * n].chunks_exact(n).chain(done.chunks_exact(n)) {
                let d: f64 = column.iter().zip(x.iter()).map(|(a, b)| a * b).sum();
                for (xi, ci) in x.iter_mut().zip(column) {
                    *xi -= d * ci;
                }
            }
        }
        let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        for xi in x.iter_mut() {
            *xi /= norm;
        }
        for (residual, xi) in norms.iter_mut().zip(x.iter()) {
            *residual -= xi * xi;
        }
        norms[best] = f64::NEG_INFINITY;
        found += 1;
    }
    found
}

/// Cholesky factorisation in place of the symmetric positive-definite `k × k` block of `m`:
/// on return its lower triangle holds L with `M = L·Lᵀ`. Returns false if M is not
/// (numerically) positive definite.
pub(crate) fn cholesky(m: &mut DMatrix<f64>, k: usize) -> bool {
    for j in 0..k {
        let mut d = m[(j, j)];
        for p in 0..j {
            d -= m[(j, p)] * m[(j, p)];
        }
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let d = d.sqrt();
        m[(j, j)] = d;
        for i in j + 1..k {
            let mut s = m[(i, j)];
            for p in 0..j {
                s -= m[(i, p)] * m[(j, p)];
            }
            m[(i, j)] = s / d;
        }
    }
    true
}

/// Solves `L·Lᵀ·x = b` in place (`b` becomes x) with the factor left by [`cholesky`].
pub(crate) fn cholesky_solve(l: &DMatrix<f64>, b: &mut [f64]) {
    let k = b.len();
    for i in 0..k {
        let mut s = b[i];
        for p in 0..i {
            s -= l[(i, p)] * b[p];
        }
        b[i] = s / l[(i, i)];
    }
    for i in (0..k).rev() {
        let mut s = b[i];
        for p in i + 1..k {
            s -= l[(p, i)] * b[p];
        }
        b[i] = s / l[(i, i)];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;

    /// Round-off allowed on reconstructions of well-conditioned 6 × 6 problems.
    const RECONSTRUCTION_TOLERANCE: f64 = 1e-12;

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

    #[test]
    fn one_sided_jacobi_gives_the_svd_of_a_rank_deficient_jacobian() {
        let j = rank_deficient_jacobian();
        let mut w = j.transpose(); // 5 × 6
        let mut u = DMatrix::identity(6, 6);
        assert!(one_sided_jacobi(&mut w, &mut u, 6));
        // W = JᵀU with orthogonal columns, U orthogonal.
        assert!((j.transpose() * &u - &w).amax() < RECONSTRUCTION_TOLERANCE);
        assert!((u.transpose() * &u - DMatrix::identity(6, 6)).amax() < RECONSTRUCTION_TOLERANCE);
        let gram = w.transpose() * &w;
        let off = gram.clone() - DMatrix::from_diagonal(&gram.diagonal());
        assert!(off.amax() < RECONSTRUCTION_TOLERANCE * gram.amax());
        // Four non-zero singular values, two zero to round-off.
        let largest = gram.diagonal().amax().sqrt();
        let zero = gram
            .diagonal()
            .iter()
            .filter(|d| d.sqrt() < 1e-12 * largest)
            .count();
        assert_eq!(zero, 2);
    }

    #[test]
    fn one_sided_jacobi_warm_started_from_nearby_vectors_converges() {
        let j = rank_deficient_jacobian();
        let mut w = j.transpose();
        let mut u = DMatrix::identity(6, 6);
        assert!(one_sided_jacobi(&mut w, &mut u, 6));
        let nearby = &j + DMatrix::from_fn(6, 5, |r, c| 1e-3 * ((r + c) as f64));
        let mut w2 = nearby.transpose() * &u;
        assert!(one_sided_jacobi(&mut w2, &mut u, 6));
        assert!((nearby.transpose() * &u - &w2).amax() < RECONSTRUCTION_TOLERANCE);
        let gram = w2.transpose() * &w2;
        let off = gram.clone() - DMatrix::from_diagonal(&gram.diagonal());
        assert!(off.amax() < RECONSTRUCTION_TOLERANCE * gram.amax());
    }

    #[test]
    fn orthogonal_complement_completes_an_orthonormal_basis() {
        // Range: two orthonormal vectors in R⁵.
        let mut range = DMatrix::zeros(5, 5);
        let a = DVector::from_vec(vec![1.0, 2.0, 0.0, -1.0, 0.5]).normalize();
        let b0 = DVector::from_vec(vec![0.0, 1.0, 1.0, 0.0, 0.0]);
        let b = (&b0 - &a * a.dot(&b0)).normalize();
        range.set_column(0, &a);
        range.set_column(1, &b);
        let mut null = DMatrix::zeros(5, 5);
        let mut norms = vec![0.0; 5];
        assert_eq!(orthogonal_complement(&range, 2, &mut null, &mut norms), 3);
        let mut basis = range.columns(0, 2).clone_owned();
        basis = basis.insert_columns(2, 3, 0.0);
        basis.columns_mut(2, 3).copy_from(&null.columns(0, 3));
        assert!(
            (basis.transpose() * &basis - DMatrix::identity(5, 5)).amax()
                < RECONSTRUCTION_TOLERANCE
        );
    }

    #[test]
    fn cholesky_solves_a_positive_definite_system() {
        let m0 = test_matrix() + DMatrix::identity(6, 6);
        let x_true = DVector::from_fn(6, |i, _| i as f64 - 2.5);
        let b = &m0 * &x_true;
        let mut m = m0.clone();
        assert!(cholesky(&mut m, 6));
        let mut x = b.as_slice().to_vec();
        cholesky_solve(&m, &mut x);
        let err = (DVector::from_vec(x) - x_true).amax();
        assert!(err < RECONSTRUCTION_TOLERANCE, "error {err}");
    }

    #[test]
    fn cholesky_refuses_a_singular_matrix() {
        let mut m = DMatrix::from_element(3, 3, 1.0);
        assert!(!cholesky(&mut m, 3));
    }
}
