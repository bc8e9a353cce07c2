//! The factorisation M = Lᵀ·D·L of a kinematic tree's joint-space mass matrix in the tree's
//! own sparsity: Featherstone's LTDL (Rigid Body Dynamics Algorithms, 2008, §6.5), the
//! factorisation MuJoCo's `mj_factorM` and Pinocchio's `cholesky::decompose` use.
//!
//! In a tree, M's entry (i, k) is zero unless one of the two degrees of freedom is an
//! ancestor of the other (a joint's motion moves only its own subtree). Numbered parents
//! before children, with λ(k) < k the parent of degree of freedom k, the factor L (unit
//! lower triangular) keeps that pattern: no fill-in, so factor and solves walk each row's
//! ancestor chain instead of the whole row. For the floating base (six degrees of freedom in
//! a chain) carrying a serial arm this is M's dense lower triangle but for the siblings
//! (fingers beside each other); the speed is in the loops' plainness: one flat row-major
//! array, no generic storage, nothing allocated.

/// The sizes factored by loops compiled for the size (the built-in vehicles' 8, 12 and 16
/// degrees of freedom among them): unrolled and without bounds checks, for the same numbers
/// on a tree's M (see [`factorize_dense`]).
const DENSE: std::ops::RangeInclusive<usize> = 7..=16;

/// λ(k) of a root: no parent.
pub(crate) const NO_PARENT: usize = usize::MAX;

/// An n × n SPD matrix factored as Lᵀ·D·L in place: row k holds D(k) at (k, k) and
/// L(k, i) at the ancestors i of k; every other entry is unused. The factor's numbering is
/// the tree's (parents first); the matrix's may be another (a URDF numbers its joints in
/// file order), mapped by `order`.
#[derive(Debug, Clone, Default)]
pub(crate) struct TreeFactor {
    n: usize,
    /// The ancestors of every degree of freedom, nearest first (λ(k), λ(λ(k)), …): those
    /// of k at `ancestors[start[k]..start[k + 1]]`, factor numbering. A degree of freedom's
    /// ancestors are the tail of its descendants' lists from it on, so one list serves the
    /// factor's two loops.
    ancestors: Vec<usize>,
    start: Vec<usize>,
    /// Whether k's ancestors are all of 0…k−1 (a chain from the root: the base and a serial
    /// arm): its loops then run over contiguous rows, which the compiler vectorises.
    chain: Vec<bool>,
    /// The matrix's index of each of the factor's; None when they are the same.
    order: Option<Vec<usize>>,
    /// The factor's index of each of the matrix's (the inverse of `order`).
    position: Vec<usize>,
    /// Row-major n × n, factor numbering.
    a: Vec<f64>,
    /// Whether n is one of [`DENSE`]'s: the loops then run over every entry of L's lower
    /// triangle with the size a constant (see [`factorize_dense`]).
    dense: bool,
    /// The right-hand side in the factor's numbering.
    scratch: Vec<f64>,
}

impl TreeFactor {
    /// A factor for matrices on the tree `parent` (λ(k) < k or `NO_PARENT`), whose
    /// degree of freedom k is the matrix's row and column `order[k]`.
    ///
    /// # Panics
    /// If a parent does not come before its child, or `order` is not a permutation of
    /// 0..n (caller bugs).
    pub(crate) fn new(parent: &[usize], order: &[usize]) -> Self {
        let n = parent.len();
        for (k, &p) in parent.iter().enumerate() {
            assert!(p == NO_PARENT || p < k, "λ({k}) = {p} must precede {k}");
        }
        assert_eq!(order.len(), n, "one matrix index per degree of freedom");
        let mut position = vec![NO_PARENT; n];
        for (k, &c) in order.iter().enumerate() {
            assert!(
                c < n && position[c] == NO_PARENT,
                "order is not a permutation"
            );
            position[c] = k;
        }
        let identity = order.iter().enumerate().all(|(k, &c)| k == c);
        let (mut ancestors, mut start, mut chain) = (Vec::new(), vec![0], Vec::with_capacity(n));
        for k in 0..n {
            let first = ancestors.len();
            let mut i = parent[k];
            while i != NO_PARENT {
                ancestors.push(i);
                i = parent[i];
            }
            chain.push(ancestors[first..].iter().copied().eq((0..k).rev()));
            start.push(ancestors.len());
        }
        Self {
            n,
            ancestors,
            start,
            chain,
            order: (!identity).then(|| order.to_vec()),
            position,
            a: vec![0.0; n * n],
            dense: DENSE.contains(&n),
            scratch: vec![0.0; n],
        }
    }

    /// The same factor with the tree's loops or the size's (tests compare the two).
    #[cfg(test)]
    fn with_dense(mut self, dense: bool) -> Self {
        self.dense = dense;
        self
    }

    /// Loads the symmetric `m` (n × n, column-major: a symmetric matrix's column-major
    /// storage is its row-major one) for [`Self::factorize`]. The tree's loops read only the
    /// tree's pattern; the size's read the whole lower triangle, which is zero outside the
    /// pattern in a tree's mass matrix (the CRBA writes nothing there).
    ///
    /// # Panics
    /// If `m` is not n × n long.
    pub(crate) fn load(&mut self, m: &[f64]) {
        let n = self.n;
        assert_eq!(m.len(), n * n, "matrix size");
        match &self.order {
            None => self.a.copy_from_slice(m),
            Some(order) => {
                for (r, &mr) in order.iter().enumerate() {
                    for (c, &mc) in order.iter().enumerate() {
                        self.a[r * n + c] = m[mc * n + mr];
                    }
                }
            }
        }
    }

    /// Adds `v` to the loaded matrix's diagonal entry (k, k) (the matrix's numbering).
    pub(crate) fn add_diagonal(&mut self, k: usize, v: f64) {
        let f = self.position[k];
        self.a[f * self.n + f] += v;
    }

    /// Factors the loaded matrix in place. False if a pivot is not positive and finite (the
    /// matrix is not positive definite, or not finite); the factor is then unusable until
    /// the next load.
    pub(crate) fn factorize(&mut self) -> bool {
        let n = self.n;
        if self.dense {
            return match n {
                7 => factorize_dense::<7>(&mut self.a),
                8 => factorize_dense::<8>(&mut self.a),
                9 => factorize_dense::<9>(&mut self.a),
                10 => factorize_dense::<10>(&mut self.a),
                11 => factorize_dense::<11>(&mut self.a),
                12 => factorize_dense::<12>(&mut self.a),
                13 => factorize_dense::<13>(&mut self.a),
                14 => factorize_dense::<14>(&mut self.a),
                15 => factorize_dense::<15>(&mut self.a),
                16 => factorize_dense::<16>(&mut self.a),
                _ => unreachable!("dense only for {DENSE:?}"),
            };
        }
        for k in (0..n).rev() {
            let (above, from_k) = self.a.split_at_mut(k * n);
            let row_k = &mut from_k[..n];
            let dk = row_k[k];
            if !(dk > 0.0 && dk.is_finite()) {
                return false;
            }
            // Each ancestor i of k (nearest first): row i at i and its ancestors less
            // L(k, i) times row k there (row k's entries still M's: scaled after use).
            let ancestors = &self.ancestors[self.start[k]..self.start[k + 1]];
            let inverse = 1.0 / dk;
            for (p, &i) in ancestors.iter().enumerate() {
                let l = row_k[i] * inverse;
                let row_i = &mut above[i * n..(i + 1) * n];
                if self.chain[k] {
                    for (x, y) in row_i[..=i].iter_mut().zip(&row_k[..=i]) {
                        *x -= l * y;
                    }
                } else {
                    for &j in &ancestors[p..] {
                        row_i[j] -= l * row_k[j];
                    }
                }
                row_k[i] = l;
            }
        }
        true
    }

    /// x ← M⁻¹·x with the factor of M (x in the matrix's numbering).
    ///
    /// # Panics
    /// If `x` is not n long.
    pub(crate) fn solve_mut(&mut self, x: &mut [f64]) {
        assert_eq!(x.len(), self.n, "right-hand side length");
        match self.order.as_deref() {
            None => self.solve_in_place(x),
            Some(order) => {
                for (y, &c) in self.scratch.iter_mut().zip(order) {
                    *y = x[c];
                }
                let mut y = std::mem::take(&mut self.scratch);
                self.solve_in_place(&mut y);
                self.scratch = y;
                for (y, &c) in self.scratch.iter().zip(order) {
                    x[c] = *y;
                }
            }
        }
    }

    /// x ← (Lᵀ·D·L)⁻¹·x, the factor's numbering.
    fn solve_in_place(&self, x: &mut [f64]) {
        let n = self.n;
        if self.dense {
            match n {
                7 => solve_dense::<7>(&self.a, x),
                8 => solve_dense::<8>(&self.a, x),
                9 => solve_dense::<9>(&self.a, x),
                10 => solve_dense::<10>(&self.a, x),
                11 => solve_dense::<11>(&self.a, x),
                12 => solve_dense::<12>(&self.a, x),
                13 => solve_dense::<13>(&self.a, x),
                14 => solve_dense::<14>(&self.a, x),
                15 => solve_dense::<15>(&self.a, x),
                16 => solve_dense::<16>(&self.a, x),
                _ => unreachable!("dense only for {DENSE:?}"),
            }
            return;
        }
        let ancestors = |k: usize| &self.ancestors[self.start[k]..self.start[k + 1]];
        // Lᵀ·y = x, from the leaves up.
        for k in (0..n).rev() {
            let (below, from_k) = x.split_at_mut(k);
            let (xk, row_k) = (from_k[0], &self.a[k * n..k * n + k]);
            if self.chain[k] {
                for (xi, l) in below.iter_mut().zip(row_k) {
                    *xi -= l * xk;
                }
            } else {
                for &i in ancestors(k) {
                    below[i] -= row_k[i] * xk;
                }
            }
        }
        for (k, xk) in x.iter_mut().enumerate() {
            *xk /= self.a[k * n + k];
        }
        // L·x = D⁻¹·y, from the root down.
        for k in 0..n {
            let row_k = &self.a[k * n..k * n + k];
            let s: f64 = if self.chain[k] {
                row_k.iter().zip(&x[..k]).map(|(l, xi)| l * xi).sum()
            } else {
                // Root first, as the dense loop sums.
                ancestors(k).iter().rev().map(|&i| row_k[i] * x[i]).sum()
            };
            x[k] -= s;
        }
    }
}

/// [`TreeFactor::factorize`] over the whole lower triangle, N a constant. The same numbers as
/// the tree's loops, to the bit: an entry (k, i) outside the tree's pattern is zero in M
/// and stays zero (it is updated only from a common descendant of k and i, which has none),
/// so the entries the tree's loops skip add exact zeros here.
fn factorize_dense<const N: usize>(a: &mut [f64]) -> bool {
    assert_eq!(a.len(), N * N, "an N × N factor");
    for k in (0..N).rev() {
        let (above, from_k) = a.split_at_mut(k * N);
        let row_k = &mut from_k[..N];
        let dk = row_k[k];
        if !(dk > 0.0 && dk.is_finite()) {
            return false;
        }
        let inverse = 1.0 / dk;
        for i in (0..k).rev() {
            let l = row_k[i] * inverse;
            let row_i = &mut above[i * N..(i + 1) * N];
            for (x, y) in row_i[..i + 1].iter_mut().zip(&row_k[..i + 1]) {
                *x -= l * y;
            }
            row_k[i] = l;
        }
    }
    true
}

/// [`TreeFactor::solve_in_place`] over the whole lower triangle, N a constant: the same
/// numbers again (the tree's loops sum each row from the root, as this one does).
fn solve_dense<const N: usize>(a: &[f64], x: &mut [f64]) {
    assert!(a.len() == N * N && x.len() == N, "an N × N factor, N long");
    for k in (0..N).rev() {
        let xk = x[k];
        for (xi, l) in x[..k].iter_mut().zip(&a[k * N..k * N + k]) {
            *xi -= l * xk;
        }
    }
    for (k, xk) in x.iter_mut().enumerate() {
        *xk /= a[k * N + k];
    }
    for k in 0..N {
        let mut s = 0.0;
        for (l, xi) in a[k * N..k * N + k].iter().zip(&x[..k]) {
            s += l * xi;
        }
        x[k] -= s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// A branched tree: 0 → 1 → 2 → {3, 4}, 2 → 5 → 6, and a second root 7 → 8.
    fn tree() -> Vec<usize> {
        vec![NO_PARENT, 0, 1, 2, 2, 2, 5, NO_PARENT, 7]
    }

    fn ancestor_or_self(parent: &[usize], k: usize, i: usize) -> bool {
        let mut j = k;
        while j != NO_PARENT {
            if j == i {
                return true;
            }
            j = parent[j];
        }
        false
    }

    /// An SPD matrix with the tree's pattern: Jᵀ·J + I with J's rows supported on each
    /// degree of freedom's ancestor chain (as a body's Jacobian is).
    fn spd_on(parent: &[usize]) -> DMatrix<f64> {
        let n = parent.len();
        let mut m = DMatrix::identity(n, n);
        for body in 0..n {
            let row = DMatrix::from_fn(1, n, |_, i| {
                if ancestor_or_self(parent, body, i) {
                    1.0 + 0.37 * (i as f64) - 0.11 * (body as f64)
                } else {
                    0.0
                }
            });
            m += row.transpose() * &row;
        }
        m
    }

    #[test]
    fn the_factor_solves_as_a_dense_cholesky_does_and_fills_nothing_outside_the_tree() {
        let parent = tree();
        let m = spd_on(&parent);
        // The pattern: zero wherever neither is the other's ancestor.
        for k in 0..parent.len() {
            for i in 0..parent.len() {
                if !ancestor_or_self(&parent, k, i) && !ancestor_or_self(&parent, i, k) {
                    assert_eq!(m[(k, i)], 0.0, "({k}, {i})");
                }
            }
        }
        let mut f =
            TreeFactor::new(&parent, &(0..parent.len()).collect::<Vec<_>>()).with_dense(false);
        f.load(m.as_slice());
        assert!(f.factorize());
        let b: Vec<f64> = (0..parent.len()).map(|i| 1.0 - 0.3 * i as f64).collect();
        let mut x = b.clone();
        f.solve_mut(&mut x);
        let dense = m
            .clone()
            .cholesky()
            .unwrap_or_else(|| panic!("M is SPD"))
            .solve(&nalgebra::DVector::from_vec(b.clone()));
        for (xi, di) in x.iter().zip(dense.iter()) {
            assert!((xi - di).abs() < 1e-12 * di.abs().max(1.0), "{xi} vs {di}");
        }
        // M·x = b.
        let r = &m * nalgebra::DVector::from_vec(x) - nalgebra::DVector::from_vec(b);
        assert!(r.amax() < 1e-12, "residual {}", r.amax());
    }

    #[test]
    fn a_matrix_that_is_not_positive_definite_is_refused() {
        let parent = tree();
        let mut m = spd_on(&parent);
        // A joint with no inertia of its own and nothing below it (a massless leaf).
        m[(4, 4)] = 0.0;
        let mut f = TreeFactor::new(&parent, &(0..parent.len()).collect::<Vec<_>>());
        f.load(m.as_slice());
        assert!(!f.factorize());
        m[(4, 4)] = f64::NAN;
        f.load(m.as_slice());
        assert!(!f.factorize());
        // A large diagonal weight (a joint held on its bound) factors and holds the joint.
        let m = spd_on(&parent);
        f.load(m.as_slice());
        f.add_diagonal(3, 1e12);
        assert!(f.factorize());
        let mut x = vec![0.0; parent.len()];
        x[3] = 1e12 * 0.25;
        f.solve_mut(&mut x);
        assert!((x[3] - 0.25).abs() < 1e-9, "{}", x[3]);
        // Without the weight, M·x is zero but on the held row (the force that holds it).
        let r = &m * nalgebra::DVector::from_vec(x);
        for (k, rk) in r.iter().enumerate().filter(|(k, _)| *k != 3) {
            assert!(rk.abs() < 1e-9, "row {k}: {rk}");
        }
    }

    #[test]
    #[should_panic(expected = "must precede")]
    fn a_parent_after_its_child_is_a_caller_bug() {
        TreeFactor::new(&[1, NO_PARENT], &[0, 1]);
    }

    #[test]
    fn a_matrix_numbered_otherwise_than_the_tree_is_factored_through_its_order() {
        // The tree's matrix with its rows and columns shuffled (a URDF listing a child's
        // joint before its parent's): the same solution, shuffled alike.
        let parent = tree();
        let n = parent.len();
        let m = spd_on(&parent);
        let order = vec![4, 0, 8, 2, 6, 1, 7, 3, 5];
        let shuffled = DMatrix::from_fn(n, n, |r, c| {
            // The factor's index of matrix index r is where r sits in `order`.
            let at = |r: usize| order.iter().position(|&o| o == r).unwrap_or(usize::MAX);
            m[(at(r), at(c))]
        });
        let b: Vec<f64> = (0..n).map(|i| 0.5 + 0.2 * i as f64).collect();
        let mut with_weight = shuffled.clone();
        with_weight[(order[3], order[3])] += 2.0;
        // The tree's loops (which need the order) and the size's.
        for dense in [false, true] {
            let mut x = b.clone();
            let mut f = TreeFactor::new(&parent, &order).with_dense(dense);
            f.load(shuffled.as_slice());
            f.add_diagonal(order[3], 2.0);
            assert!(f.factorize());
            f.solve_mut(&mut x);
            let r = &with_weight * nalgebra::DVector::from_vec(x)
                - nalgebra::DVector::from_vec(b.clone());
            assert!(r.amax() < 1e-12, "dense {dense}: residual {}", r.amax());
        }
    }

    #[test]
    fn the_loops_compiled_for_the_size_give_the_trees_numbers_to_the_bit() {
        // The FA-Hexa's tree: the base's six in a chain, four arm joints, two fingers side
        // by side on the last.
        let parent = vec![NO_PARENT, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9];
        let n = parent.len();
        assert!(DENSE.contains(&n));
        let m = spd_on(&parent);
        let b: Vec<f64> = (0..n).map(|i| 0.7 - 0.13 * i as f64).collect();
        let solve = |dense: bool| {
            let mut f = TreeFactor::new(&parent, &(0..n).collect::<Vec<_>>()).with_dense(dense);
            f.load(m.as_slice());
            f.add_diagonal(10, 3.5);
            assert!(f.factorize());
            let mut x = b.clone();
            f.solve_mut(&mut x);
            (f, x)
        };
        let ((tree, x_tree), (dense, x_dense)) = (solve(false), solve(true));
        assert!(dense.dense && !tree.dense);
        for k in 0..n {
            let pattern = &tree.ancestors[tree.start[k]..tree.start[k + 1]];
            for &i in std::iter::once(&k).chain(pattern) {
                assert_eq!(
                    tree.a[k * n + i].to_bits(),
                    dense.a[k * n + i].to_bits(),
                    "({k}, {i})"
                );
            }
        }
        // The fingers do not couple: their entry stays zero.
        assert_eq!(dense.a[11 * n + 10], 0.0);
        assert_eq!(x_tree, x_dense);
        let mut with_weight = m.clone();
        with_weight[(10, 10)] += 3.5;
        let r = with_weight * nalgebra::DVector::from_vec(x_dense) - nalgebra::DVector::from_vec(b);
        assert!(r.amax() < 1e-12, "residual {}", r.amax());
    }
}
