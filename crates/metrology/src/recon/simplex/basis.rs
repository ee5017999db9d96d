//! The anchor basis B₀ = A_S₀ and its factorizations: a dense LU (f64, or f32 for half the memory
//! traffic), and the [`Anchor`] interface the restricted simplex solves through.
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::lu::partial_pivoting::factor::{lu_in_place, lu_in_place_scratch};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_unit_lower_triangular_in_place,
    solve_unit_upper_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Col, Mat, Par};

use crate::recon::dct::Dct;

/// Scalar of a factorization: f64, or f32 for the anchor basis (half the memory traffic and
/// twice the SIMD width; its rounding is removed by refinement against the f64 transforms).
pub(super) trait Real: faer::traits::RealField + Copy {
    /// Whether the factorization is f64 (a failed certificate is then final).
    const DOUBLE: bool;
    fn from64(v: f64) -> Self;
    fn to64(self) -> f64;
    /// `lu` ← A_S, the sampled DCT columns `support`.
    fn fill_basis(dct: &Dct, idx: &[usize], support: &[usize], lu: &mut Mat<Self>);
}

impl Real for f64 {
    const DOUBLE: bool = true;
    fn fill_basis(dct: &Dct, idx: &[usize], support: &[usize], lu: &mut Mat<f64>) {
        for (c, &k) in support.iter().enumerate() {
            if let Some(col) = lu.col_mut(c).try_as_col_major_mut() {
                dct.basis_column(k, idx, col.as_slice_mut());
            }
        }
    }
    fn from64(v: f64) -> Self {
        v
    }
    fn to64(self) -> f64 {
        self
    }
}

impl Real for f32 {
    const DOUBLE: bool = false;
    fn fill_basis(dct: &Dct, idx: &[usize], support: &[usize], lu: &mut Mat<f32>) {
        let mut cols: Vec<&mut [f32]> = lu
            .col_iter_mut()
            .filter_map(|c| c.try_as_col_major_mut().map(|c| c.as_slice_mut()))
            .collect();
        dct.basis_block_f32(idx, support, &mut cols);
    }
    fn from64(v: f64) -> Self {
        v as f32
    }
    fn to64(self) -> f64 {
        self as f64
    }
}

/// A square matrix as one dense LU with partial pivoting.
///
/// The factorization and the solves run single-threaded (`Par::Seq`): the solver is specified
/// single-threaded, and on a loaded 2-core machine faer's default thread pool made each triangular
/// solve about twice as slow (measured 290 µs against 120 µs at m = 600).
pub(super) struct Basis<T: Real = f64> {
    /// L (unit lower, below the diagonal) and U (upper) of P·B in one matrix.
    lu: Mat<T>,
    /// Row i of P·B is row `perm[i]` of B.
    perm: Vec<usize>,
}

impl<T: Real> Basis<T> {
    /// LU of B = A_S, the sampled DCT columns `support`.
    pub(super) fn factor(dct: &Dct, idx: &[usize], support: &[usize]) -> Option<Self> {
        let m = idx.len();
        let mut lu = Mat::<T>::zeros(m, m);
        T::fill_basis(dct, idx, support, &mut lu);
        Self::from_matrix(lu)
    }

    /// LU of a square matrix; `None` when (nearly) singular.
    pub(super) fn from_matrix(mut lu: Mat<T>) -> Option<Self> {
        let m = lu.nrows();
        let mut perm = vec![0usize; m];
        let mut perm_inv = vec![0usize; m];
        let mut buf = MemBuffer::new(lu_in_place_scratch::<usize, T>(
            m,
            m,
            Par::Seq,
            Default::default(),
        ));
        lu_in_place(
            lu.as_mut(),
            &mut perm,
            &mut perm_inv,
            Par::Seq,
            MemStack::new(&mut buf),
            Default::default(),
        );
        // Reject (near-)singular bases: a tiny pivot in U means a column nearly dependent.
        if !diagonal_spread_within((0..m).map(|i| lu[(i, i)].to64()), 1e-12) {
            return None;
        }
        Some(Self { lu, perm })
    }

    /// X = B⁻¹X for a block of right-hand sides.
    pub(super) fn solve_mat(&self, x: &mut Mat<f64>) {
        let m = x.nrows();
        let mut p = Mat::<T>::from_fn(m, x.ncols(), |i, c| T::from64(x[(self.perm[i], c)]));
        solve_unit_lower_triangular_in_place(self.lu.as_ref(), p.as_mut(), Par::Seq);
        solve_upper_triangular_in_place(self.lu.as_ref(), p.as_mut(), Par::Seq);
        for c in 0..x.ncols() {
            for i in 0..m {
                x[(i, c)] = p[(i, c)].to64();
            }
        }
    }

    /// x = B⁻¹b, in place.
    pub(super) fn solve(&self, x: &mut Col<f64>) {
        let m = x.nrows();
        let mut p = Col::<T>::from_fn(m, |i| T::from64(x[self.perm[i]]));
        solve_unit_lower_triangular_in_place(self.lu.as_ref(), p.as_mat_mut(), Par::Seq);
        solve_upper_triangular_in_place(self.lu.as_ref(), p.as_mat_mut(), Par::Seq);
        for i in 0..m {
            x[i] = p[i].to64();
        }
    }

    /// y = B⁻ᵀc, in place: B = Pᵀ L U, so Bᵀ y = c is Uᵀ Lᵀ (P y) = c.
    pub(super) fn solve_transpose(&self, c: &mut Col<f64>) {
        let m = c.nrows();
        let mut p = Col::<T>::from_fn(m, |i| T::from64(c[i]));
        solve_lower_triangular_in_place(self.lu.transpose(), p.as_mat_mut(), Par::Seq);
        solve_unit_upper_triangular_in_place(self.lu.transpose(), p.as_mat_mut(), Par::Seq);
        for i in 0..m {
            c[self.perm[i]] = p[i].to64();
        }
    }
}

/// The anchor basis B₀ = A_S₀ as the restricted simplex uses it: solves with B₀ and B₀ᵀ, and the
/// columns B₀⁻¹A_k of the candidates.
pub(super) trait Anchor {
    /// Whether its dual can be far off (f32: then `LOST` applies).
    const LOSSY: bool;
    /// Whether a failed certificate without a pivot is final (f64 LU: nothing more precise).
    const FINAL: bool;
    /// x = B₀⁻¹x.
    fn solve(&self, dct: &mut Dct, idx: &[usize], x: &mut Col<f64>);
    /// c = B₀⁻ᵀc.
    fn solve_transpose(&self, dct: &mut Dct, idx: &[usize], c: &mut Col<f64>);
    /// Appends B₀⁻¹A_ks to `out`: m entries per entry of `ks`, column after column.
    fn columns(&self, dct: &Dct, idx: &[usize], ks: &[usize], out: &mut Vec<f64>);
    /// B₀⁻¹h, the restricted problem's right-hand side (`ath` = Aᵀh on all n frequencies, which
    /// the caller has formed already); appends the first candidates' columns B₀⁻¹A_ks to `out`
    /// as [`Anchor::columns`] does.
    fn start(
        &self,
        dct: &mut Dct,
        idx: &[usize],
        h: &[f64],
        _ath: &[f64],
        ks: &[usize],
        out: &mut Vec<f64>,
    ) -> Col<f64> {
        let mut theta0 = Col::<f64>::from_fn(idx.len(), |r| h[r]);
        self.solve(dct, idx, &mut theta0);
        self.columns(dct, idx, ks, out);
        theta0
    }
}

impl<T: Real> Anchor for Basis<T> {
    const LOSSY: bool = !T::DOUBLE;
    const FINAL: bool = T::DOUBLE;
    fn solve(&self, _: &mut Dct, _: &[usize], x: &mut Col<f64>) {
        Basis::solve(self, x);
    }
    fn solve_transpose(&self, _: &mut Dct, _: &[usize], c: &mut Col<f64>) {
        Basis::solve_transpose(self, c);
    }
    fn columns(&self, dct: &Dct, idx: &[usize], ks: &[usize], out: &mut Vec<f64>) {
        let mut a = Mat::<f64>::zeros(idx.len(), ks.len());
        f64::fill_basis(dct, idx, ks, &mut a);
        self.solve_mat(&mut a);
        for c in 0..ks.len() {
            out.extend(a.col(c).iter().copied());
        }
    }
}

/// Whether a triangular factor's diagonal is free of NaN and its smallest magnitude exceeds
/// `ratio` times its largest (a near-singular factor fails).
pub(super) fn diagonal_spread_within(diag: impl Iterator<Item = f64>, ratio: f64) -> bool {
    let (mut dmax, mut dmin) = (0.0f64, f64::INFINITY);
    for d in diag {
        dmax = dmax.max(d.abs());
        dmin = dmin.min(d.abs());
    }
    !dmin.is_nan() && dmin > ratio * dmax
}

#[cfg(test)]
mod tests {
    use super::*;

    /// agrees with the single one.
    #[test]
    fn basis_solves_invert_the_sampled_dct() {
        let n = 97;
        let dct = Dct::new(n);
        let m = 32;
        let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, m, 3)
            .indices(n)
            .unwrap();
        // Low frequencies: a well-conditioned basis.
        let support: Vec<usize> = (0..m).map(|c| (c * 7) % 41).collect();
        let basis = Basis::<f64>::factor(&dct, &idx, &support).expect("non-singular");
        let b = Mat::<f64>::from_fn(m, m, |r, c| dct.basis(idx[r], support[c]));
        let rhs = Col::<f64>::from_fn(m, |r| (r as f64 * 0.37).sin());
        let mut x = rhs.clone();
        basis.solve(&mut x);
        let ax = &b * &x;
        let mut y = rhs.clone();
        basis.solve_transpose(&mut y);
        let aty = b.transpose() * &y;
        let mut block = Mat::<f64>::from_fn(m, 2, |r, c| if c == 0 { rhs[r] } else { 1.0 });
        basis.solve_mat(&mut block);
        for r in 0..m {
            assert!((ax[r] - rhs[r]).abs() < 1e-10, "solve row {r}");
            assert!((aty[r] - rhs[r]).abs() < 1e-10, "transpose row {r}");
            assert!((block[(r, 0)] - x[r]).abs() < 1e-12, "block row {r}");
        }
        // The f32 anchor solves the same system to its precision (refinement removes the rest).
        let single = Basis::<f32>::factor(&dct, &idx, &support).expect("non-singular");
        let mut xs = rhs.clone();
        single.solve(&mut xs);
        let mut ys = rhs.clone();
        single.solve_transpose(&mut ys);
        for r in 0..m {
            assert!(
                (xs[r] - x[r]).abs() < 1e-4 * (1.0 + x[r].abs()),
                "f32 solve row {r}"
            );
            assert!(
                (ys[r] - y[r]).abs() < 1e-4 * (1.0 + y[r].abs()),
                "f32 transpose row {r}"
            );
        }
        // A repeated column is singular and refused.
        let mut twice = support.clone();
        twice[1] = twice[0];
        assert!(Basis::<f64>::factor(&dct, &idx, &twice).is_none());
    }
}
