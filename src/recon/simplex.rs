//! Exact finish for basis pursuit: a simplex for min ||θ||₁ s.t. Aθ = h on the sampled orthonormal
//! DCT, restricted to candidate columns K = S₀ ∪ E with column generation over all n columns.
//!
//! A short ADMM run ranks the columns; S₀ (the top m) gives a non-singular basis B₀ = A_S₀ and E
//! (the next k) the columns most likely to replace part of it. Multiplying the constraints by B₀⁻¹
//! turns the LP restricted to K into min ||x||₁ s.t. [I T] x = θ₀ with T = B₀⁻¹A_E, θ₀ = B₀⁻¹h:
//! one dense LU and one multi-right-hand-side triangular solve (BLAS-3 work), after which a pivot
//! costs O(m·k) instead of two O(m²) triangular solves with an updated B (measured: 5-10x cheaper
//! per pivot at m = 600, the same number of pivots). The simplex basis of the small problem is the
//! identity with the columns of rows R replaced by T columns C, so its solves reduce to the
//! |R| x |R| block T_{R,C}, refactored at each pivot (|R| stays at a few dozen).
//!
//! The ratio test is the long-step rule of l1 simplex methods (pass breakpoints while the
//! objective still decreases). Once the restricted problem is optimal, its dual ŷ maps back to
//! y = B₀⁻ᵀŷ and one DCT prices every column outside K; violators join E and the simplex carries
//! on from its basis.
//!
//! The anchor B₀ is factored in one of three ways. Up to `gram_min_m` samples, as an f32 LU (half
//! the memory traffic of f64, twice the SIMD width; refinement against the f64 transforms removes
//! its ~1e-4 rounding, and a second f32 anchor or an f64 one takes over when it cannot). From
//! there on, through its Gram matrix ([`Gram`]): one DCT gives B₀ᵀB₀ without forming B₀, and its
//! f64 Cholesky costs about what the f32 LU does (m³/3 flops at half the rate) with ~1e-9 error,
//! so the anchors that f32 could not certify (1-3 curves in 20 at m = 600, 10-16 ms each) do not
//! occur. Last, an f64 LU.
//!
//! Optimality is never taken from the factorizations alone: the final θ and y are checked against
//! the transforms (primal residual by one inverse DCT, |Aᵀy| ≤ 1 + tol by one forward DCT, and
//! ||θ||₁ = hᵀy), so rounding can cost a failed finish but never a wrong "optimal".
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::lu::partial_pivoting::factor::{lu_in_place, lu_in_place_scratch};
use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_unit_lower_triangular_in_place,
    solve_unit_upper_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Accum, Col, ColMut, ColRef, Mat, MatMut, MatRef, Par};

use super::dct::Dct;

/// Result of a certified simplex finish.
pub struct SimplexResult {
    pub theta: Vec<f64>,
    /// Ψθ, the curve on the whole grid (formed to check the samples).
    pub signal: Vec<f64>,
    /// hᵀy of the certifying dual point (equals ||θ||₁ up to rounding).
    pub dual_objective: f64,
    pub pivots: usize,
    /// max |Aᵀy| of the certificate (≤ 1 + tol).
    pub dual_inf_norm: f64,
}

/// Scalar of a factorization: f64, or f32 for the anchor basis (half the memory traffic and
/// twice the SIMD width; its rounding is removed by refinement against the f64 transforms).
trait Real: faer::traits::RealField + Copy {
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
struct Basis<T: Real = f64> {
    /// L (unit lower, below the diagonal) and U (upper) of P·B in one matrix.
    lu: Mat<T>,
    /// Row i of P·B is row `perm[i]` of B.
    perm: Vec<usize>,
}

impl<T: Real> Basis<T> {
    /// LU of B = A_S, the sampled DCT columns `support`.
    fn factor(dct: &Dct, idx: &[usize], support: &[usize]) -> Option<Self> {
        let m = idx.len();
        let mut lu = Mat::<T>::zeros(m, m);
        T::fill_basis(dct, idx, support, &mut lu);
        Self::from_matrix(lu)
    }

    /// LU of a square matrix; `None` when (nearly) singular.
    fn from_matrix(mut lu: Mat<T>) -> Option<Self> {
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
    fn solve_mat(&self, x: &mut Mat<f64>) {
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
    fn solve(&self, x: &mut Col<f64>) {
        let m = x.nrows();
        let mut p = Col::<T>::from_fn(m, |i| T::from64(x[self.perm[i]]));
        solve_unit_lower_triangular_in_place(self.lu.as_ref(), p.as_mat_mut(), Par::Seq);
        solve_upper_triangular_in_place(self.lu.as_ref(), p.as_mat_mut(), Par::Seq);
        for i in 0..m {
            x[i] = p[i].to64();
        }
    }

    /// y = B⁻ᵀc, in place: B = Pᵀ L U, so Bᵀ y = c is Uᵀ Lᵀ (P y) = c.
    fn solve_transpose(&self, c: &mut Col<f64>) {
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
trait Anchor {
    /// Whether its dual can be far off (f32: then [`LOST`] applies).
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

/// The anchor through its Gram matrix G = B₀ᵀB₀, Cholesky-factored in f64.
///
/// Sampled DCT columns have inner products Σ_i cos(ja_i)cos(ka_i) = ½[g(j − k) + g(j + k)] with
/// g(d) = Σ_i cos(d·a_i), a_i = π(2x_i + 1)/2n: one DCT of the samples' indicator gives every
/// entry of G (and of B₀ᵀA_k), so B₀ itself is never formed. B₀⁻¹x = G⁻¹B₀ᵀx and B₀⁻ᵀc = B₀G⁻¹c,
/// with the products by B₀ and B₀ᵀ through the transforms. κ(G) = κ(B₀)² (~4e6 at m = 600,
/// n = 1901) leaves ~1e-9 relative error in f64, against ~1e-4 for the f32 LU of B₀.
///
/// The support comes in increasing frequency (`finish` sorts S₀), so that j − k ≥ 0 below the
/// diagonal of G and its solves need no permutation.
struct Gram {
    /// L (column-major m x m, lower triangle) with G = LLᵀ, in `l_buf[l_off..]` with columns
    /// `l_ld` apart.
    l_buf: Vec<f64>,
    l_off: usize,
    l_ld: usize,
    /// The support, in increasing frequency.
    sorted: Vec<usize>,
    /// c_k²·½g(d) for d < 2n (c_k = √(2/n), the DCT weight of k > 0).
    half_g: Vec<f64>,
    /// c_0 / c_k: frequency 0's weight relative to the others.
    w0: f64,
}

impl Gram {
    /// Entry (j, k) of B₀ᵀA: ½c_jc_k[g(j − k) + g(j + k)], frequency 0's weight applied to the
    /// column, then to the row (a weight of exactly 1 elsewhere leaves the sum's bits).
    fn cross_entry(&self, j: usize, k: usize) -> f64 {
        let hg = &self.half_g;
        let weight = |f: usize| if f == 0 { self.w0 } else { 1.0 };
        (hg[j.abs_diff(k)] + hg[j + k]) * weight(k) * weight(j)
    }

    /// Appends column k of B₀ᵀA (B₀'s columns in sorted order) to `out`.
    fn cross(&self, k: usize, out: &mut Vec<f64>) {
        out.extend(self.sorted.iter().map(|&j| self.cross_entry(j, k)));
    }

    /// Appends G⁻¹B₀ᵀA_ks to `out` (column after column, rows in support order); with w (= B₀ᵀ of
    /// something, on all n frequencies) also returns G⁻¹w_S, in the same order. Solved in place
    /// at the end of `out` (w's column taken off again after), which is T: the caller's buffer,
    /// kept from solve to solve (a fresh ~250 KB block at m = 600 came from mmap, and faulting
    /// its pages in at every solve cost ~117 page faults). From [`GRAM_KERNEL_COLS`] columns on
    /// AVX2, through [`Gram::block_rows`].
    fn block(&self, ks: &[usize], w: Option<&[f64]>, out: &mut Vec<f64>) -> Option<Col<f64>> {
        let m = self.sorted.len();
        let k = ks.len();
        let nc = k + usize::from(w.is_some());
        #[cfg(target_arch = "x86_64")]
        if nc >= GRAM_KERNEL_COLS && super::simd::has_avx2_fma() {
            return self.block_rows(ks, w, out);
        }
        // Filled by extending, not zero-filled first: a memset of ~160 KB at the first block
        // was ~1 % of an m = 600 solve.
        let start = out.len();
        out.reserve(m * nc);
        for &kc in ks {
            self.cross(kc, out);
        }
        if let Some(w) = w {
            out.extend(self.sorted.iter().map(|&f| w[f]));
        }
        self.solve_gram(MatMut::from_column_major_slice_mut(
            &mut out[start..],
            m,
            nc,
        ));
        let last = w.map(|_| Col::<f64>::from_fn(m, |r| out[start + k * m + r]));
        out.truncate(start + m * k);
        last
    }

    /// [`Gram::block`] through [`super::chol::gram_solve_rows_avx2`]: the right-hand sides
    /// filled row by row (padded with zero columns to a multiple of 8), solved, and appended to
    /// `out` column after column. The first block at m = 600 (32 columns) took ~0.08 ms less per
    /// BP solve than faer's solves on the same columns (hot harness, Zen 3: 4.40-4.48 ms against
    /// 4.49-4.59).
    #[cfg(target_arch = "x86_64")]
    fn block_rows(&self, ks: &[usize], w: Option<&[f64]>, out: &mut Vec<f64>) -> Option<Col<f64>> {
        let m = self.sorted.len();
        let k = ks.len();
        let nc = k + usize::from(w.is_some());
        let wd = nc.next_multiple_of(8);
        // Every entry is written below: the buffer only grows (zero-filling it was a memset of
        // ~150 KB per solve at m = 600). X starts on a 64-byte line like L, so that the
        // kernel's 32-byte loads split no lines (see [`Restricted::tmat`] for what that cost).
        let mut buf = ROWS_SPARE.take();
        let off = super::chol::line_offset(&mut buf, m * wd);
        let x = &mut buf[off..off + m * wd];
        for (r, &j) in self.sorted.iter().enumerate() {
            let row = &mut x[r * wd..(r + 1) * wd];
            for (v, &kc) in row.iter_mut().zip(ks) {
                *v = self.cross_entry(j, kc);
            }
            if let Some(w) = w {
                row[k] = w[j];
            }
            row[nc..].fill(0.0);
        }
        let l = &self.l_buf[self.l_off..];
        // SAFETY: AVX2 and FMA present (the caller checked), AVX-512F where it is taken (checked
        // here); L holds m columns `l_ld` apart, x holds m rows of wd entries, wd a multiple of 8.
        unsafe {
            if super::simd::has_avx512f() {
                super::chol512::gram_solve_rows_avx512(l, self.l_ld, m, x, wd)
            } else {
                super::chol::gram_solve_rows_avx2(l, self.l_ld, m, x, wd)
            }
        };
        out.reserve(m * k);
        for c in 0..k {
            out.extend((0..m).map(|r| x[r * wd + c]));
        }
        let last = w.map(|_| Col::<f64>::from_fn(m, |r| x[r * wd + k]));
        ROWS_SPARE.set(buf);
        last
    }

    /// v = G⁻¹v (rows in sorted order).
    fn solve_gram(&self, mut v: MatMut<'_, f64>) {
        let m = self.sorted.len();
        #[cfg(target_arch = "x86_64")]
        if v.ncols() < GRAM_KERNEL_COLS && super::simd::has_avx2_fma() && v.row_stride() == 1 {
            let (k, cs) = (v.ncols(), v.col_stride());
            if k <= 1 || cs == m as isize {
                let l = &self.l_buf[self.l_off..];
                assert!(m == 0 || l.len() >= (m - 1) * self.l_ld + m);
                // SAFETY: the k columns of m rows are contiguous (unit row stride, column
                // stride m or a single column), so they are one slice of m·k entries.
                let x = unsafe { std::slice::from_raw_parts_mut(v.as_ptr_mut(), m * k) };
                // SAFETY: AVX2 and FMA present (checked); L holds m columns `l_ld` apart
                // (asserted).
                unsafe { gram_solve_columns_avx2(l, self.l_ld, x, m) };
                return;
            }
        }
        let l =
            MatRef::from_column_major_slice_with_stride(&self.l_buf[self.l_off..], m, m, self.l_ld);
        solve_lower_triangular_in_place(l, v.as_mut(), Par::Seq);
        solve_upper_triangular_in_place(l.transpose(), v, Par::Seq);
    }
}

/// Right-hand sides from which [`Gram::block`] takes the row kernel
/// ([`super::chol::gram_solve_rows_avx2`]; faer's blocked triangular solves without AVX2) and
/// [`Gram::solve_gram`] faer's, instead of [`gram_solve_columns_avx2`] (measured at m = 600 on
/// Zen 3: level with faer at 8 columns; with L's panels shared by the groups, that kernel for
/// the first block of 33 columns still cost ~0.1 ms more per BP solve than faer).
const GRAM_KERNEL_COLS: usize = 8;

thread_local! {
    /// The last Gram anchor's L buffer, for the next one on this thread.
    static L_SPARE: std::cell::Cell<Vec<f64>> = const { std::cell::Cell::new(Vec::new()) };
    /// The last restricted problem's T, for the next one on this thread (see [`Gram::block`]).
    static T_SPARE: std::cell::Cell<Vec<f64>> = const { std::cell::Cell::new(Vec::new()) };
    /// [`Gram::block_rows`]'s right-hand sides, for the next block on this thread.
    #[cfg(target_arch = "x86_64")]
    static ROWS_SPARE: std::cell::Cell<Vec<f64>> = const { std::cell::Cell::new(Vec::new()) };
}

impl Drop for Gram {
    fn drop(&mut self) {
        L_SPARE.set(std::mem::take(&mut self.l_buf));
    }
}

/// The lower triangle of G (sorted frequencies s, `hg` = c²·½g) into the column-major `g`
/// (leading dimension `ld`): G_ab = hg[s_a − s_b] + hg[s_a + s_b] for a ≥ b (frequency 0's
/// weight is the caller's). Scalar loads: AVX2 gathers were slower on both hosts measured at
/// m = 600, AMD's Zen 4 (0.16-0.20 ms against 0.10-0.17) and the Intel Xeon (Emerald Rapids)
/// of session 25 (best of 200: 79-119 µs against 65-108).
fn gram_lower(hg: &[f64], s: &[u32], g: &mut [f64], ld: usize) {
    let m = s.len();
    assert!(s.is_sorted() && (m == 0 || (s[m - 1] as usize) * 2 < hg.len()));
    assert!(m == 0 || g.len() >= (m - 1) * ld + m);
    for b in 0..m {
        let kb = s[b] as usize;
        let (lo, hi) = (hg, &hg[kb..]);
        for (o, &ka) in g[b * ld + b..b * ld + m].iter_mut().zip(&s[b..]) {
            let ka = ka as usize;
            // SAFETY: s is sorted, so kb ≤ ka ≤ s[m - 1] and ka + kb < hg.len() (asserted).
            *o = unsafe { lo.get_unchecked(ka - kb) + hi.get_unchecked(ka) };
        }
    }
}

/// x ← L⁻ᵀL⁻¹x for the lower triangle of the column-major `l` (leading dimension `ld`) and the
/// k = x.len() / m columns of the column-major x (m rows, contiguous). L is taken in panels of
/// 8 columns; each panel serves every right-hand side, in groups of 4 (then 3, 2 or 1), before
/// the next, so that L streams through once per sweep however many columns there are, and a
/// panel (38 KB at m = 600) is reread from L2 by the groups after the first. The forward sweep
/// updates the rows below a panel from its 8 columns at once; the backward sweep takes TQ·R dot
/// products per pass over the rows (TQ·R ≤ 8 accumulators).
///
/// With one column this is the kernel the pricing and refinement solves take: at m = 600 (L
/// 2.9 MB, out of L2) 41-44 µs against 67-70 µs for faer's pair of `solve_*_triangular_in_place`
/// (AMD EPYC, Zen 4). With 4 a column costs about a quarter of that, where faer's pair on a few
/// columns costs nearly its one-column time per column (Zen 3, best of 200: 4 columns 103
/// against 171 µs, 2 columns 60 against 146).
///
/// # Safety
/// AVX2 and FMA must be present, and `l` must hold m columns `ld` ≥ m apart.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn gram_solve_columns_avx2(l: &[f64], ld: usize, x: &mut [f64], m: usize) {
    let k = x.len().checked_div(m).unwrap_or(0);
    assert!(m == 0 || l.len() >= (m - 1) * ld + m);
    let (lp, xp) = (l.as_ptr(), x.as_mut_ptr());
    let group = |c: usize| -> [*mut f64; 4] { std::array::from_fn(|r| xp.add((c + r) * m)) };
    let (full, rest) = (k / 4 * 4, k % 4);
    let mut j0 = 0;
    while j0 < m {
        for c in (0..full).step_by(4) {
            forward_panel::<4>(lp, ld, group(c), j0, m);
        }
        let g = group(full);
        match rest {
            3 => forward_panel::<3>(lp, ld, [g[0], g[1], g[2]], j0, m),
            2 => forward_panel::<2>(lp, ld, [g[0], g[1]], j0, m),
            1 => forward_panel::<1>(lp, ld, [g[0]], j0, m),
            _ => {}
        }
        j0 += PANEL.min(m - j0);
    }
    let mut j1 = m;
    while j1 > 0 {
        for c in (0..full).step_by(4) {
            backward_panel::<4, 2>(lp, ld, group(c), j1, m);
        }
        let g = group(full);
        match rest {
            3 => backward_panel::<3, 2>(lp, ld, [g[0], g[1], g[2]], j1, m),
            2 => backward_panel::<2, 4>(lp, ld, [g[0], g[1]], j1, m),
            1 => backward_panel::<1, 8>(lp, ld, [g[0]], j1, m),
            _ => {}
        }
        j1 -= PANEL.min(j1);
    }
}

/// Columns of L per panel of [`gram_solve_columns_avx2`].
const PANEL: usize = 8;

/// The forward sweep (L y = x) over the panel of L's columns from j0, for the R right-hand sides
/// `xc` (m entries each).
///
/// # Safety
/// As [`gram_solve_columns_avx2`]; `xc` point to R columns of m entries.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn forward_panel<const R: usize>(
    lp: *const f64,
    ld: usize,
    xc: [*mut f64; R],
    j0: usize,
    m: usize,
) {
    use std::arch::x86_64::*;
    const B: usize = PANEL;
    let jb = B.min(m - j0);
    let r0 = j0 + jb;
    // The right-hand sides interleave in the scalar part, so that their division chains overlap.
    for j in j0..r0 {
        let col = lp.add(j * ld);
        let d = *col.add(j);
        let xj: [f64; R] = std::array::from_fn(|c| *xc[c].add(j) / d);
        for c in 0..R {
            *xc[c].add(j) = xj[c];
        }
        for i in j + 1..r0 {
            let li = *col.add(i);
            for c in 0..R {
                *xc[c].add(i) -= xj[c] * li;
            }
        }
    }
    if jb == B {
        let cs: [*const f64; B] = std::array::from_fn(|t| lp.add((j0 + t) * ld));
        let bc: [[__m256d; R]; B] =
            std::array::from_fn(|t| std::array::from_fn(|c| _mm256_set1_pd(*xc[c].add(j0 + t))));
        let mut i = r0;
        while i + 4 <= m {
            let mut a: [__m256d; R] = std::array::from_fn(|c| _mm256_loadu_pd(xc[c].add(i)));
            for t in 0..B {
                let lv = _mm256_loadu_pd(cs[t].add(i));
                for c in 0..R {
                    a[c] = _mm256_fnmadd_pd(bc[t][c], lv, a[c]);
                }
            }
            for c in 0..R {
                _mm256_storeu_pd(xc[c].add(i), a[c]);
            }
            i += 4;
        }
        for i in i..m {
            for xp in xc {
                let mut v = *xp.add(i);
                for (t, col) in cs.iter().enumerate() {
                    v -= *xp.add(j0 + t) * *col.add(i);
                }
                *xp.add(i) = v;
            }
        }
    } else {
        for xp in xc {
            for j in j0..r0 {
                let xj = *xp.add(j);
                for i in r0..m {
                    *xp.add(i) -= xj * *lp.add(j * ld + i);
                }
            }
        }
    }
}

/// The backward sweep (Lᵀ z = y) over the panel of L's columns that ends at j1, for the R
/// right-hand sides `xc`.
///
/// # Safety
/// As [`forward_panel`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn backward_panel<const R: usize, const TQ: usize>(
    lp: *const f64,
    ld: usize,
    xc: [*mut f64; R],
    j1: usize,
    m: usize,
) {
    use std::arch::x86_64::*;
    const B: usize = PANEL;
    let jb = B.min(j1);
    let j0 = j1 - jb;
    let mut acc = [[0.0f64; R]; B];
    if jb == B {
        for tq in (0..B).step_by(TQ) {
            let cs: [*const f64; TQ] = std::array::from_fn(|t| lp.add((j0 + tq + t) * ld));
            let mut va = [[_mm256_setzero_pd(); R]; TQ];
            let mut i = j1;
            while i + 4 <= m {
                let xv: [__m256d; R] = std::array::from_fn(|c| _mm256_loadu_pd(xc[c].add(i)));
                for t in 0..TQ {
                    let lv = _mm256_loadu_pd(cs[t].add(i));
                    for c in 0..R {
                        va[t][c] = _mm256_fmadd_pd(lv, xv[c], va[t][c]);
                    }
                }
                i += 4;
            }
            for t in 0..TQ {
                for c in 0..R {
                    let mut b = [0.0f64; 4];
                    _mm256_storeu_pd(b.as_mut_ptr(), va[t][c]);
                    let mut s = (b[0] + b[1]) + (b[2] + b[3]);
                    for r in i..m {
                        s += *cs[t].add(r) * *xc[c].add(r);
                    }
                    acc[tq + t][c] = s;
                }
            }
        }
    } else {
        for (t, a) in acc.iter_mut().enumerate().take(jb) {
            let col = lp.add((j0 + t) * ld);
            for c in 0..R {
                a[c] = (j1..m).map(|r| *col.add(r) * *xc[c].add(r)).sum();
            }
        }
    }
    for j in (j0..j1).rev() {
        let col = lp.add(j * ld);
        let mut v: [f64; R] = std::array::from_fn(|c| *xc[c].add(j) - acc[j - j0][c]);
        for i in j + 1..j1 {
            let li = *col.add(i);
            for c in 0..R {
                v[c] -= li * *xc[c].add(i);
            }
        }
        let d = *col.add(j);
        for c in 0..R {
            *xc[c].add(j) = v[c] / d;
        }
    }
}

impl Gram {
    /// The Gram anchor of the sampled DCT columns `support`; `None` when G is not numerically
    /// positive definite.
    fn factor(dct: &mut Dct, idx: &[usize], support: &[usize]) -> Option<Self> {
        let n = dct.len();
        let m = support.len();
        let (w0, wk) = (dct.basis(0, 0), (2.0 / n as f64).sqrt());
        let mut ind = vec![0.0; n];
        for &i in idx {
            ind[i] = 1.0;
        }
        dct.forward(&mut ind);
        // The orthonormal DCT of the indicator is c_d·g(d); g(n) = 0 and g(2n − d) = −g(d).
        let mut half_g = vec![0.0; 2 * n];
        half_g[0] = 0.5 * ind[0] / w0 * wk * wk;
        for d in 1..n {
            let v = 0.5 * ind[d] * wk;
            half_g[d] = v;
            half_g[2 * n - d] = -v;
        }
        assert!(
            support.is_sorted(),
            "the Gram anchor's support in increasing frequency"
        );
        let sorted = support.to_vec();
        let s32: Vec<u32> = sorted.iter().map(|&k| k as u32).collect();
        // Columns on 64-byte lines: faer's kernels load them without splitting lines. The
        // buffer is the thread's last one: only the lower triangle is written and read, so
        // the stale rest needs no zeroing (zeroing 2.9 MB was ~0.15 ms of a solve at m = 600).
        let ld = m.next_multiple_of(8);
        let mut l_buf = L_SPARE.take();
        let l_off = super::chol::line_offset(&mut l_buf, ld * m);
        let l = &mut l_buf[l_off..];
        gram_lower(&half_g, &s32, l, ld);
        let r0 = w0 / wk;
        if sorted[0] == 0 {
            // Frequency 0 has its own weight: scale its column (the lower triangle's row 0 is
            // the diagonal entry alone).
            l[..m].iter_mut().for_each(|v| *v *= r0);
            l[0] *= r0;
        }
        if !super::chol::factor_lower(l, m, ld) {
            return None;
        }
        // κ(G) ≥ (max/min diagonal of L)²: beyond ~1e12 f64 has no digits left for the simplex.
        if !diagonal_spread_within((0..m).map(|i| l[i * ld + i]), 1e-6) {
            return None;
        }
        Some(Self {
            l_buf,
            l_off,
            l_ld: ld,
            sorted,
            half_g,
            w0: r0,
        })
    }
}

impl Anchor for Gram {
    const LOSSY: bool = false;
    const FINAL: bool = false;

    fn solve(&self, dct: &mut Dct, idx: &[usize], x: &mut Col<f64>) {
        let mut w = vec![0.0; dct.len()];
        dct.adjoint(idx, |r| x[r], &mut w);
        *x = Col::<f64>::from_fn(self.sorted.len(), |j| w[self.sorted[j]]);
        self.solve_gram(x.as_mat_mut());
    }

    fn solve_transpose(&self, dct: &mut Dct, idx: &[usize], c: &mut Col<f64>) {
        self.solve_gram(c.as_mat_mut());
        let mut theta = vec![0.0; dct.len()];
        for (j, &k) in self.sorted.iter().enumerate() {
            theta[k] = c[j];
        }
        let y = dct.sample(&mut theta, idx);
        for (r, v) in y.into_iter().enumerate() {
            c[r] = v;
        }
    }

    fn columns(&self, _: &Dct, _: &[usize], ks: &[usize], out: &mut Vec<f64>) {
        self.block(ks, None, out);
    }

    /// One block solve for both: B₀ᵀh = (Aᵀh)_S₀ joins B₀ᵀA_ks as a last column.
    fn start(
        &self,
        dct: &mut Dct,
        _: &[usize],
        _: &[f64],
        ath: &[f64],
        ks: &[usize],
        out: &mut Vec<f64>,
    ) -> Col<f64> {
        assert_eq!(ath.len(), dct.len(), "Aᵀh on all n frequencies");
        self.block(ks, Some(ath), out)
            .expect("a block with w returns its column")
    }
}

/// Whether a triangular factor's diagonal is free of NaN and its smallest magnitude exceeds
/// `ratio` times its largest (a near-singular factor fails).
fn diagonal_spread_within(diag: impl Iterator<Item = f64>, ratio: f64) -> bool {
    let (mut dmax, mut dmin) = (0.0f64, f64::INFINITY);
    for d in diag {
        dmax = dmax.max(d.abs());
        dmin = dmin.min(d.abs());
    }
    !dmin.is_nan() && dmin > ratio * dmax
}

fn finite(v: &Col<f64>) -> bool {
    (0..v.nrows()).all(|i| v[i].is_finite())
}

fn sign(v: f64) -> f64 {
    if v >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// Columns added to E per column-generation round (the most violated first).
const GENERATE_MAX: usize = 32;
/// Pivots between recomputations of the basic solution from scratch (the running update drifts).
const REFRESH: usize = 16;

/// Long-step ratio test over the breakpoints `tb` (t per basic variable, ∞ for none) with slope
/// increases `inc(b)`: pass them in increasing t (equal t: lower index first) while the objective
/// still decreases; returns (b, t) where the slope turns non-negative. Usually it turns within
/// the first few, which [`smallest_breaks`] finds in one pass; only otherwise are all of them
/// collected into `breaks` and passed by [`pass_in_order`].
fn long_step(
    tb: &[f64],
    inc: impl Fn(usize) -> f64,
    slope: f64,
    breaks: &mut Vec<(f64, usize, f64)>,
) -> Option<(usize, f64)> {
    let (near, count) = smallest_breaks(tb);
    let mut s = slope;
    for &(t, b) in &near[..count] {
        s += inc(b);
        if s >= 0.0 {
            return Some((b, t));
        }
    }
    if count < NEAR_BREAKS {
        return None;
    }
    // Breakpoints at t = ∞ (d = 0) change no slope: left out.
    breaks.clear();
    breaks.extend(
        tb.iter()
            .enumerate()
            .filter(|&(_, &t)| t < f64::INFINITY)
            .map(|(b, &t)| (t, b, inc(b))),
    );
    pass_in_order(breaks, slope)
}

/// Passes the breakpoints (t, basic variable, slope increase) in increasing t from `slope` until
/// it turns non-negative; returns that one. For the long steps that pass more than
/// [`smallest_breaks`] holds (measured at m = 600: about two per solve, ~34 of ~340 breakpoints
/// passed), in sorted chunks cut off by selection: a full sort of them all, after eight minimum
/// scans, was ~25 µs each.
fn pass_in_order(breaks: &mut [(f64, usize, f64)], mut slope: f64) -> Option<(usize, f64)> {
    let by = |a: &(f64, usize, f64), b: &(f64, usize, f64)| a.0.total_cmp(&b.0);
    let mut rest = breaks;
    let mut chunk = 4 * NEAR_BREAKS;
    while !rest.is_empty() {
        let k = chunk.min(rest.len());
        if k < rest.len() {
            rest.select_nth_unstable_by(k - 1, by);
        }
        let (head, tail) = rest.split_at_mut(k);
        head.sort_unstable_by(by);
        for &(t, b, inc) in head.iter() {
            slope += inc;
            if slope >= 0.0 {
                return Some((b, t));
            }
        }
        rest = tail;
        chunk *= 4;
    }
    None
}

/// Breakpoints [`smallest_breaks`] collects for the long step's first try.
const NEAR_BREAKS: usize = 8;

/// The (t, index) of the [`NEAR_BREAKS`] smallest finite breakpoints of `tb` in increasing t
/// (equal t: lower index first), and how many there are. One pass with a short insertion list:
/// collecting every breakpoint and scanning for the minimum repeatedly cost ~8 µs per long step
/// at m = 600 (about one pivot in four).
fn smallest_breaks(tb: &[f64]) -> ([(f64, usize); NEAR_BREAKS], usize) {
    let mut near = [(f64::INFINITY, usize::MAX); NEAR_BREAKS];
    let mut count = 0;
    for (b, &t) in tb.iter().enumerate() {
        // The list's last entry is ∞ until it is full: one comparison rejects the rest.
        if t < near[NEAR_BREAKS - 1].0 {
            let mut p = count.min(NEAR_BREAKS - 1);
            while p > 0 && near[p - 1].0 > t {
                near[p] = near[p - 1];
                p -= 1;
            }
            near[p] = (t, b);
            count = (count + 1).min(NEAR_BREAKS);
        }
    }
    (near, count)
}

/// One pass of the ratio test over basic values `x` with directions `d` (times `sj`): the
/// slope's change (−sign(x)·d for a live variable, |d| for a degenerate one, which any step
/// drives from zero), the largest |d|, and each variable's breakpoint t = x/d into `t` (∞ unless
/// live and t > 0). Separate accumulators and no index-carrying state let it vectorise: the
/// single pass that also tracked the first breakpoint ran ~2.8 µs per pivot at m = 600.
fn ratio_pass(x: &[f64], d: &[f64], sj: f64, zero_tol: f64, t: &mut [f64]) -> (f64, f64) {
    const L: usize = 4;
    let (mut slope, mut dmax) = ([0.0f64; L], [0.0f64; L]);
    let lane = |x: f64, d: f64, slope: &mut f64, dmax: &mut f64| {
        let d = sj * d;
        let ad = d.abs();
        *dmax = dmax.max(ad);
        let live = x.abs() > zero_tol;
        *slope += if live { -(1f64.copysign(x) * d) } else { ad };
        let q = x / d;
        if live & (q > 0.0) {
            q
        } else {
            f64::INFINITY
        }
    };
    let n = x.len().min(d.len()).min(t.len());
    let (xs, ds, ts) = (&x[..n], &d[..n], &mut t[..n]);
    let mut xc = xs.chunks_exact(L);
    let mut dc = ds.chunks_exact(L);
    let mut tc = ts.chunks_exact_mut(L);
    for ((xa, da), ta) in (&mut xc).zip(&mut dc).zip(&mut tc) {
        for k in 0..L {
            ta[k] = lane(xa[k], da[k], &mut slope[k], &mut dmax[k]);
        }
    }
    for ((&xv, &dv), tv) in xc
        .remainder()
        .iter()
        .zip(dc.remainder())
        .zip(tc.into_remainder())
    {
        *tv = lane(xv, dv, &mut slope[0], &mut dmax[0]);
    }
    (
        slope.iter().sum(),
        dmax.iter().fold(0.0, |a: f64, &b| a.max(b)),
    )
}

/// A faer column's entries as a slice (owned columns are contiguous).
fn contiguous(c: &Col<f64>) -> &[f64] {
    c.try_as_col_major()
        .expect("owned faer columns are contiguous")
        .as_slice()
}

/// The restricted LP min ||x||₁ s.t. [I T] x = θ₀ and its simplex basis: the identity with the
/// columns of rows R replaced by the T columns C.
struct Restricted {
    m: usize,
    /// DCT column of each T column, and whether a DCT column is in K = S₀ ∪ E.
    e_cols: Vec<usize>,
    in_k: Vec<bool>,
    /// T = B₀⁻¹A_E, column-major m x ke, in `t[t_off..]` (see [`Restricted::tmat`]).
    t: Vec<f64>,
    t_off: usize,
    ke: usize,
    /// Identity rows whose column is non-basic, and each row's position in `r` (or usize::MAX).
    r: Vec<usize>,
    r_pos: Vec<usize>,
    /// Basic T columns, each column's position in `c` (or usize::MAX), and T_{:,C} in that order.
    c: Vec<usize>,
    c_pos: Vec<usize>,
    tc: Mat<f64>,
    /// LU of T_{R,C}.
    small: Option<Basis<f64>>,
}

/// Column e of T (m entries each) in the buffer `t` whose entries start at `t_off`.
fn t_column(t: &[f64], t_off: usize, m: usize, e: usize) -> &[f64] {
    &t[t_off + e * m..t_off + (e + 1) * m]
}

impl Restricted {
    /// T's entries, column after column. They start on a 64-byte line when the buffer did not
    /// move since (its capacity is reserved up front): with m = 600 every column does, and
    /// the AVX2 kernels' loads split no lines. Measured on Zen 3 (hot harness, BP m = 600,
    /// together with the Cholesky's strips and the row kernel's buffer, not one by one): median
    /// of best ~0.15-0.2 ms lower than at the allocator's 16-byte offset, where every other
    /// 32-byte load straddled two lines.
    fn tmat(&self) -> &[f64] {
        &self.t[self.t_off..]
    }

    fn tcol(&self, e: usize) -> &[f64] {
        t_column(&self.t, self.t_off, self.m, e)
    }

    fn tc_ref(&self) -> MatRef<'_, f64> {
        self.tc.as_ref().subcols(0, self.c.len())
    }

    fn refactor(&mut self) -> bool {
        let q = self.r.len();
        if q == 0 {
            self.small = None;
            return true;
        }
        let mat = Mat::<f64>::from_fn(q, q, |a, b| self.tc[(self.r[a], b)]);
        self.small = Basis::from_matrix(mat);
        self.small.is_some()
    }

    /// (xi, xc) = B_r⁻¹ b: xi over identity rows (zero on R), xc per entry of C.
    fn ftran(&self, b: ColRef<'_, f64>, xi: &mut Col<f64>, xc: &mut Col<f64>) {
        let q = self.c.len();
        xc.resize_with(q, |_| 0.0);
        for (p, &i) in self.r.iter().enumerate() {
            xc[p] = b[i];
        }
        if let Some(lu) = &self.small {
            lu.solve(xc);
        }
        xi.copy_from(b);
        if q > 0 {
            matmul(
                xi.as_mut(),
                Accum::Add,
                self.tc_ref(),
                xc.as_ref(),
                -1.0,
                Par::Seq,
            );
        }
        for &i in &self.r {
            xi[i] = 0.0;
        }
    }

    /// y = B_r⁻ᵀ c_B for basic costs ci (identity rows; entries on R ignored) and cc (C).
    fn btran(&self, ci: &Col<f64>, cc: &Col<f64>, y: &mut Col<f64>) {
        y.copy_from(ci);
        for &i in &self.r {
            y[i] = 0.0;
        }
        if self.small.is_some() {
            // T_{R,C}ᵀ y_R = cc - T_{:,C}ᵀ y (y still zero on R).
            let mut rhs = cc.clone();
            matmul(
                rhs.as_mut(),
                Accum::Add,
                self.tc_ref().transpose(),
                y.as_ref(),
                -1.0,
                Par::Seq,
            );
            self.dual_rows(rhs, y);
        }
    }

    /// y_R from T_{R,C}ᵀ y_R = rhs (rhs indexed by C), written into y on the rows R; returns y_R.
    fn dual_rows(&self, mut rhs: Col<f64>, y: &mut Col<f64>) -> Col<f64> {
        if let Some(lu) = &self.small {
            lu.solve_transpose(&mut rhs);
        }
        for (p, &i) in self.r.iter().enumerate() {
            y[i] = rhs[p];
        }
        rhs
    }

    /// The basic variables in basis order: identity rows outside R (index i), then the entries
    /// of C (index m + p). θ_S, the support list and the refinement residuals use this order.
    fn basics(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.m)
            .filter(|&i| self.r_pos[i] == usize::MAX)
            .chain(self.m..self.m + self.c.len())
    }
}

impl Drop for Restricted {
    fn drop(&mut self) {
        T_SPARE.set(std::mem::take(&mut self.t));
    }
}

/// The simplex's dual during pivots, y = ĉ + (y_R on the rows R), where ĉ holds the identity
/// rows' basic costs sign(x_i) with R zeroed. Keeping s = Tᵀĉ across pivots turns btran's
/// T_{:,C}ᵀĉ into s_C and pricing's Tᵀy into s + T_{R,:}ᵀy_R: a pivot changes ĉ on a few rows
/// (the leaving and entering ones, signs flipped by a long step), so two m x ke products per
/// pivot become a few row updates (measured at m = 600: ~8 µs of a ~26 µs pivot).
struct Pricer {
    chat: Vec<f64>,
    s: Vec<f64>,
}

/// ĉ_i ← sign(x_i) on the identity rows outside R (`r_pos` = usize::MAX), 0 on R, pushing
/// (i, new − old) for each row that changes. The definition is [`chat_changes_from`]; with AVX2
/// the rows are compared four at a time and only a group with a change takes the scalar loop
/// (the compiled loop branched on the random signs: ~2.2 µs of a ~13 µs pivot at m = 600).
fn chat_changes(x: &[f64], r_pos: &[usize], chat: &mut [f64], changed: &mut Vec<(usize, f64)>) {
    assert!(x.len() >= chat.len() && r_pos.len() >= chat.len());
    #[cfg(target_arch = "x86_64")]
    if super::simd::has_avx2_fma() {
        // SAFETY: AVX2 is present (checked); x and r_pos are at least chat's length (asserted).
        unsafe { chat_changes_avx2(x, r_pos, chat, changed) };
        return;
    }
    chat_changes_from(0, chat.len(), x, r_pos, chat, changed);
}

/// [`chat_changes`] on the rows `start..end`.
fn chat_changes_from(
    start: usize,
    end: usize,
    x: &[f64],
    r_pos: &[usize],
    chat: &mut [f64],
    changed: &mut Vec<(usize, f64)>,
) {
    for i in start..end {
        let c = if r_pos[i] == usize::MAX {
            sign(x[i])
        } else {
            0.0
        };
        if c != chat[i] {
            changed.push((i, c - chat[i]));
            chat[i] = c;
        }
    }
}

/// [`chat_changes`] in AVX2: c = (x ≥ 0 ? 1 : −1) masked to +0 on R, as `sign` and the
/// scalar loop give it (NaN fails x ≥ 0 in both).
///
/// # Safety
/// AVX2 must be present, and x and r_pos at least chat's length.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn chat_changes_avx2(
    x: &[f64],
    r_pos: &[usize],
    chat: &mut [f64],
    changed: &mut Vec<(usize, f64)>,
) {
    use std::arch::x86_64::*;
    let m = chat.len();
    let (one, minus, zero) = (
        _mm256_set1_pd(1.0),
        _mm256_set1_pd(-1.0),
        _mm256_setzero_pd(),
    );
    let none = _mm256_set1_epi64x(-1);
    let mut i = 0;
    while i + 4 <= m {
        let xv = _mm256_loadu_pd(x.as_ptr().add(i));
        let rv = _mm256_loadu_si256(r_pos.as_ptr().add(i) as *const __m256i);
        let outside = _mm256_castsi256_pd(_mm256_cmpeq_epi64(rv, none));
        let s = _mm256_blendv_pd(minus, one, _mm256_cmp_pd::<_CMP_GE_OQ>(xv, zero));
        let c = _mm256_and_pd(s, outside);
        let old = _mm256_loadu_pd(chat.as_ptr().add(i));
        if _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NEQ_UQ>(c, old)) != 0 {
            chat_changes_from(i, i + 4, x, r_pos, chat, changed);
        }
        i += 4;
    }
    chat_changes_from(i, m, x, r_pos, chat, changed);
}

/// Changed rows of ĉ beyond which s is recomputed rather than updated.
const PRICER_ROWS: usize = 24;

impl Pricer {
    /// ĉ for the current basic solution and R; s to match (in full when `full`, which bounds
    /// the drift of the updates, or when many rows changed).
    fn update(&mut self, lp: &Restricted, xi: &Col<f64>, full: bool) {
        let m = lp.m;
        let mut changed = Vec::new();
        chat_changes(
            contiguous(xi),
            &lp.r_pos[..m],
            &mut self.chat[..m],
            &mut changed,
        );
        let old = if full || changed.len() > PRICER_ROWS {
            0
        } else {
            self.s.len().min(lp.ke)
        };
        for (e, se) in self.s[..old].iter_mut().enumerate() {
            let col = lp.tcol(e);
            for &(i, d) in &changed {
                *se += d * col[i];
            }
        }
        // Columns generated since the last update (all of them after a reset), by one product.
        if old < lp.ke {
            self.s.resize(lp.ke, 0.0);
            let t = MatRef::from_column_major_slice(&lp.tmat()[old * m..], m, lp.ke - old);
            matmul(
                ColMut::from_slice_mut(&mut self.s[old..]).as_mat_mut(),
                Accum::Replace,
                t.transpose(),
                ColRef::from_slice(&self.chat).as_mat(),
                1.0,
                Par::Seq,
            );
        }
    }

    /// Tᵀy on the non-basic T columns for y = ĉ + y_R (basic columns' entries are left stale).
    fn price(&self, lp: &Restricted, yr: &Col<f64>, w: &mut Vec<f64>) {
        w.clear();
        w.extend_from_slice(&self.s);
        // Row by row: the entries of w accumulate independently (no serial sum per column).
        let t = lp.tmat();
        for (&i, &v) in lp.r.iter().zip(yr.iter()) {
            for (e, we) in w.iter_mut().enumerate() {
                *we += t[e * lp.m + i] * v;
            }
        }
    }

    /// y = B_r⁻ᵀc_B for the basic costs sign(x) ([`Restricted::btran`] with T_{:,C}ᵀĉ = s_C);
    /// returns y_R.
    fn dual(&self, lp: &Restricted, xc: &Col<f64>, y: &mut Col<f64>) -> Col<f64> {
        for (i, &c) in self.chat.iter().enumerate() {
            y[i] = c;
        }
        let rhs = Col::<f64>::from_fn(lp.c.len(), |p| sign(xc[p]) - self.s[lp.c[p]]);
        lp.dual_rows(rhs, y)
    }
}

/// Dual slack below which off-K columns wait for the refined dual before they join (the f32
/// anchor's dual is good to ~1e-5; a column joining needlessly costs one triangular solve pair).
const LOOSE: f64 = 1e-4;

/// Adds columns to E: T columns B₀⁻¹a_k by one block triangular solve.
fn add_columns<B: Anchor>(dct: &Dct, idx: &[usize], basis: &B, lp: &mut Restricted, new: &[usize]) {
    basis.columns(dct, idx, new, &mut lp.t);
    register_columns(lp, new);
}

/// Enters columns `new` in E, their T columns B₀⁻¹A_new having just been appended to `lp.t`.
fn register_columns(lp: &mut Restricted, new: &[usize]) {
    for &k in new {
        lp.in_k[k] = true;
        lp.e_cols.push(k);
        lp.c_pos.push(usize::MAX);
        lp.ke += 1;
    }
    debug_assert_eq!(lp.tmat().len(), lp.m * lp.ke);
}

/// Column generation: the columns outside K with |w| > 1 + slack join E, most violated first
/// (at most [`GENERATE_MAX`]). Returns whether any joined.
fn generate<B: Anchor>(
    dct: &Dct,
    idx: &[usize],
    basis: &B,
    lp: &mut Restricted,
    w: &[f64],
    slack: f64,
) -> bool {
    let mut viol: Vec<(f64, usize)> = (0..w.len())
        .filter(|&k| !lp.in_k[k] && w[k].abs() > 1.0 + slack)
        .map(|k| (w[k].abs(), k))
        .collect();
    if viol.is_empty() {
        return false;
    }
    viol.sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
    viol.truncate(GENERATE_MAX);
    let new: Vec<usize> = viol.iter().map(|v| v.1).collect();
    add_columns(dct, idx, basis, lp, &new);
    true
}

/// Iterative refinement of a basis's primal and dual in f64: residuals through the transforms,
/// corrections through the anchor B₀ (any [`Anchor`]) and the restricted basis (A_S = B₀·B_r).
struct Refine<'a, B: Anchor> {
    basis: &'a B,
    lp: &'a Restricted,
}

/// Refinement rounds (each gains ~4 digits at the anchor's κ·ε ≈ 1e-4).
const REFINE_MAX: usize = 6;
/// Residual (relative to max |h| for the primal, absolute on sign θ for the dual) at which
/// refinement stops: 100x inside [`verify`]'s 1e-10. The f64 Gram anchor's basic solutions start at
/// 1e-14 to 1e-12 (measured at m = 600), so they are certified as they are instead of paying a
/// correction (a Gram solve and two transforms per side) for digits no check or curve uses.
const REFINED: f64 = 1e-12;

impl<B: Anchor> Refine<'_, B> {
    /// θ_S with A_S θ_S = h to rounding: θ_S += B_r⁻¹B₀⁻¹(h − A_S θ_S). Returns the signal Ψθ of
    /// the final θ_S (the last residual's transform, for [`verify`] and the caller's curve) and
    /// its largest sample residual.
    fn primal(
        &self,
        dct: &mut Dct,
        idx: &[usize],
        h: &[f64],
        support: &[usize],
        theta_s: &mut Col<f64>,
    ) -> (Vec<f64>, f64) {
        let (n, m) = (dct.len(), idx.len());
        let scale = h.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
        let (mut di, mut dc) = (Col::<f64>::zeros(m), Col::<f64>::zeros(0));
        let mut signal = vec![0.0; n];
        for round in 0..=REFINE_MAX {
            signal_of(dct, support, theta_s, &mut signal);
            let mut r = Col::<f64>::from_fn(m, |i| h[i] - signal[idx[i]]);
            let worst = (0..m).map(|i| r[i].abs()).fold(0.0, f64::max);
            if worst <= REFINED * scale || round == REFINE_MAX || worst.is_nan() {
                return (signal, worst);
            }
            self.basis.solve(dct, idx, &mut r);
            self.lp.ftran(r.as_ref(), &mut di, &mut dc);
            self.apply(&di, &dc, theta_s);
        }
        unreachable!("the last round returns")
    }

    /// y with A_Sᵀ y = sign(θ_S) to rounding: y += B₀⁻ᵀB_r⁻ᵀ(sign − A_Sᵀy). `w` holds Aᵀy on entry
    /// (the caller has just priced with it) and on return.
    fn dual(
        &self,
        dct: &mut Dct,
        idx: &[usize],
        support: &[usize],
        theta_s: &Col<f64>,
        y: &mut Col<f64>,
        w: &mut [f64],
    ) {
        let m = idx.len();
        let lp = self.lp;
        for round in 0..=REFINE_MAX {
            if round > 0 {
                dct.adjoint(idx, |r| y[r], w);
            }
            if round == REFINE_MAX {
                break;
            }
            // Residuals on the basic variables, in the restricted basis's layout.
            let mut ci = Col::<f64>::zeros(m);
            let mut cc = Col::<f64>::zeros(lp.c.len());
            let mut worst = 0.0f64;
            for (q, b) in lp.basics().enumerate() {
                let r = sign(theta_s[q]) - w[support[q]];
                if b < m {
                    ci[b] = r;
                } else {
                    cc[b - m] = r;
                }
                worst = worst.max(r.abs());
            }
            if worst <= REFINED {
                break;
            }
            let mut d = Col::<f64>::zeros(m);
            lp.btran(&ci, &cc, &mut d);
            self.basis.solve_transpose(dct, idx, &mut d);
            for i in 0..m {
                y[i] += d[i];
            }
        }
    }

    /// θ_S += the correction (di on identity rows, dc on C), in basis order.
    fn apply(&self, di: &Col<f64>, dc: &Col<f64>, theta_s: &mut Col<f64>) {
        let m = self.lp.m;
        for (q, b) in self.lp.basics().enumerate() {
            theta_s[q] += if b < m { di[b] } else { dc[b - m] };
        }
    }
}

/// Dual infeasibility (|Aᵀy| − 1) of an f32 anchor's refined dual beyond which the anchor is
/// dropped for an f64 one. Its own view is good to ~1e-5 and a second f32 anchor settles
/// infeasibilities up to ~1e-2; far beyond (measured: 1.7 to 51 on an ill-conditioned start
/// basis, `bench speed`'s curve of seed 317 at m = 600) neither column generation nor a second f32
/// anchor helps: generation added 32 columns per round for 36 rounds (58 ms), and the f64 anchor
/// then started from a K of 1822 columns.
const LOST: f64 = 0.1;

/// Times the restricted problem may be rebuilt around the simplex's current basis.
const MAX_ANCHORS: usize = 3;
/// Anchors factored in f32 before the f64 ones. A failed certificate is re-anchored around the
/// current basis; measured at n = 1901, m = 600 (20 seeds): 4 of the 5 curves whose first f32
/// anchor could not certify (dual infeasibility up to 1e-2 after refinement: an ill-conditioned
/// start basis) certify on a second f32 anchor, ~1 ms instead of ~5 ms in f64. Entering the
/// columns the refined dual prices out from the first anchor instead was tried: no certificate.
const F32_ANCHORS: usize = 2;

/// How one restricted run ended.
enum Outcome {
    Certified(SimplexResult),
    /// Optimal on K as far as the factorization of B₀ can tell, but the certificate failed (its
    /// precision, or a poorly conditioned start basis): rebuild around the current basis (its
    /// columns first, then the rest of K). `lost`: an f32 anchor's dual was far off; `pivoted`:
    /// the basis moved from B₀.
    Reanchor {
        ranked: Vec<usize>,
        lost: bool,
        pivoted: bool,
    },
}

/// How an anchor B₀ is factored.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Factoring {
    /// LU of B₀ in f32.
    Single,
    /// Cholesky of B₀ᵀB₀ in f64 ([`Gram`]).
    Gram,
    /// LU of B₀ in f64.
    Double,
}

/// Runs the restricted simplex with column generation from `order` (columns most likely basic
/// first; only the first m + `k0` are read: the first m are S₀, the next `k0` start in E), for
/// samples h at `idx` and their adjoint `ath` = Aᵀh (on all n frequencies). The first anchor is
/// the f32 LU, or from `gram_min_m` samples on the Gram anchor. `None` when the
/// start basis is singular or the pivot budget runs out without a certificate.
#[allow(clippy::too_many_arguments)]
pub fn finish(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    ath: &[f64],
    order: &[usize],
    k0: usize,
    max_pivots: usize,
    tol: f64,
    gram_min_m: usize,
) -> Option<SimplexResult> {
    let m = idx.len();
    let mut ranked = order[..(m + k0).min(order.len())].to_vec();
    let mut pivots = 0;
    let mut how = if m >= gram_min_m {
        Factoring::Gram
    } else {
        Factoring::Single
    };
    for anchor in 0..MAX_ANCHORS {
        // S₀ in increasing frequency, the order the Gram anchor takes it in (the basis is a
        // set; the pivots on the 20 bench curves at m = 600 are the same).
        ranked[..m].sort_unstable();
        let s0 = &ranked[..m];
        let outcome = match how {
            Factoring::Single => {
                let b = Basis::<f32>::factor(dct, idx, s0)?;
                run(dct, idx, h, ath, &ranked, &b, &mut pivots, max_pivots, tol)?
            }
            Factoring::Gram => match Gram::factor(dct, idx, s0) {
                Some(b) => run(dct, idx, h, ath, &ranked, &b, &mut pivots, max_pivots, tol)?,
                // G not numerically positive definite: B₀ is too ill-conditioned for the
                // normal equations, not necessarily for an LU.
                None => {
                    how = Factoring::Double;
                    continue;
                }
            },
            Factoring::Double => {
                let b = Basis::<f64>::factor(dct, idx, s0)?;
                run(dct, idx, h, ath, &ranked, &b, &mut pivots, max_pivots, tol)?
            }
        };
        match outcome {
            Outcome::Certified(r) => return Some(r),
            Outcome::Reanchor {
                ranked: next,
                lost,
                pivoted,
            } => {
                ranked = next;
                // A second f32 anchor around the basis where the first stopped, unless it was
                // far off; a Gram anchor again around a new basis; otherwise f64.
                how = match how {
                    Factoring::Single if anchor + 1 < F32_ANCHORS && !lost => Factoring::Single,
                    Factoring::Gram if pivoted => Factoring::Gram,
                    _ => Factoring::Double,
                };
            }
        }
    }
    None
}

/// One restricted simplex from the anchor `basis` (S₀ = ranked[..m]), E = ranked[m..], plus
/// generated columns.
#[allow(clippy::too_many_arguments)]
fn run<T: Anchor>(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    ath: &[f64],
    ranked: &[usize],
    basis: &T,
    pivots: &mut usize,
    max_pivots: usize,
    tol: f64,
) -> Option<Outcome> {
    let n = dct.len();
    let m = idx.len();
    let s0: Vec<usize> = ranked[..m].to_vec();
    let start_pivots = *pivots;
    let mut in_k = vec![false; n];
    for &k in &s0 {
        in_k[k] = true;
    }
    let mut lp = Restricted {
        m,
        e_cols: Vec::new(),
        in_k,
        t: T_SPARE.take(),
        t_off: 0,
        ke: 0,
        r: Vec::new(),
        r_pos: vec![usize::MAX; m],
        c: Vec::new(),
        c_pos: Vec::new(),
        tc: Mat::zeros(m, 0),
        small: None,
    };
    // T on 64-byte lines ([`Restricted::tmat`]): room for the first block and a generation
    // round, plus up to 7 entries of offset.
    lp.t.clear();
    lp.t.reserve(m * (ranked.len() - m + GENERATE_MAX) + 8);
    lp.t_off = lp.t.as_ptr().align_offset(64).min(8);
    lp.t.resize(lp.t_off, 0.0);
    let theta0 = basis.start(dct, idx, h, ath, &ranked[m..], &mut lp.t);
    register_columns(&mut lp, &ranked[m..]);

    let scale = (0..m)
        .map(|r| theta0[r].abs())
        .fold(0.0, f64::max)
        .max(1e-300);
    let zero_tol = 1e-13 * scale;
    let mut since_refresh = 0;
    let mut w_full = vec![0.0; n];
    let (mut xi, mut xc) = (Col::<f64>::zeros(m), Col::<f64>::zeros(0));
    let (mut di, mut dc) = (Col::<f64>::zeros(m), Col::<f64>::zeros(0));
    let mut y = Col::<f64>::zeros(m);
    let mut pricer = Pricer {
        chat: vec![0.0; m],
        s: Vec::new(),
    };
    let mut w = Vec::new();
    let mut unit = Col::<f64>::zeros(m);
    let mut breaks: Vec<(f64, usize, f64)> = Vec::new();
    let mut tb: Vec<f64> = Vec::new();
    lp.ftran(theta0.as_ref(), &mut xi, &mut xc);
    loop {
        if xi.iter().chain(xc.iter()).any(|v| !v.is_finite()) {
            return None;
        }
        pricer.update(&lp, &xi, since_refresh == 0);
        let yr = pricer.dual(&lp, &xc, &mut y);
        // Dantzig pricing over the restricted problem's non-basic columns.
        let (mut enter, mut best) = (None, 1.0 + tol);
        for &i in &lp.r {
            if y[i].abs() > best {
                best = y[i].abs();
                enter = Some((true, i, y[i]));
            }
        }
        pricer.price(&lp, &yr, &mut w);
        for (e, &we) in w.iter().enumerate() {
            if lp.c_pos[e] == usize::MAX && we.abs() > best {
                best = we.abs();
                enter = Some((false, e, we));
            }
        }
        let Some((is_id, j, wj)) = enter else {
            if since_refresh > 0 {
                // Candidate optimum: price again from an exact basic solution.
                lp.ftran(theta0.as_ref(), &mut xi, &mut xc);
                since_refresh = 0;
                continue;
            }
            // Optimal on K as far as the anchor tells: price every column with y = B₀⁻ᵀŷ, with a
            // margin for the anchor's rounding.
            let mut yf = y.clone();
            basis.solve_transpose(dct, idx, &mut yf);
            dct.adjoint(idx, |r| yf[r], &mut w_full);
            if generate(dct, idx, basis, &mut lp, &w_full, LOOSE) {
                continue;
            }
            // The basis's exact primal and dual, refined against the f64 transforms.
            let mut support = Vec::with_capacity(m);
            let mut theta_s = Col::<f64>::zeros(m);
            for (q, b) in lp.basics().enumerate() {
                if b < m {
                    theta_s[q] = xi[b];
                    support.push(s0[b]);
                } else {
                    theta_s[q] = xc[b - m];
                    support.push(lp.e_cols[lp.c[b - m]]);
                }
            }
            let refine = Refine { basis, lp: &lp };
            let (signal, resid) = refine.primal(dct, idx, h, &support, &mut theta_s);
            refine.dual(dct, idx, &support, &theta_s, &mut yf, &mut w_full);
            let lost = T::LOSSY && w_full.iter().any(|v| v.abs() > 1.0 + LOST);
            if !lost && generate(dct, idx, basis, &mut lp, &w_full, tol) {
                continue;
            }
            let candidate = Candidate {
                support: &support,
                theta_s: &theta_s,
                signal,
                resid,
                y: &yf,
                w: &w_full,
            };
            if let Some(r) = verify(n, h, candidate, *pivots, tol) {
                return Some(Outcome::Certified(r));
            }
            if T::FINAL && *pivots == start_pivots {
                return None;
            }
            let mut basic = vec![false; n];
            for &k in &support {
                basic[k] = true;
            }
            let mut next = support;
            next.extend(s0.iter().chain(&lp.e_cols).filter(|&&k| !basic[k]));
            return Some(Outcome::Reanchor {
                ranked: next,
                lost,
                pivoted: *pivots > start_pivots,
            });
        };
        if *pivots == max_pivots {
            return None;
        }
        let sj = sign(wj);
        if is_id {
            unit.fill(0.0);
            unit[j] = 1.0;
            lp.ftran(unit.as_ref(), &mut di, &mut dc);
        } else {
            let col = ColRef::from_slice(lp.tcol(j));
            lp.ftran(col, &mut di, &mut dc);
        }
        // Basic variables x_B(t) = x_B - t·sj·d_B as the entering variable grows to sj·t;
        // f'(0+) = 1 - |w_j| on a non-degenerate basis, +2|d_b| at each breakpoint passed (long
        // step). One branch-free pass over the identity rows and C (rows of R hold x = d = 0 and
        // count for nothing) gives the slope, the largest |d| and the first breakpoint, which
        // usually turns the slope non-negative; only otherwise are all breakpoints collected.
        // Measured at m = 600: collecting them at every pivot, branching on the random signs of
        // x and t, was ~7 µs of a ~22 µs pivot; now ~3.6.
        let nc = lp.c.len();
        let dir = |b: usize| sj * if b < m { di[b] } else { dc[b - m] };
        let basics = || {
            (0..m)
                .map(|i| (i, xi[i], sj * di[i]))
                .chain((0..nc).map(|p| (m + p, xc[p], sj * dc[p])))
        };
        // Every entry is written by the two passes: no zeroing (~5 KB per pivot at m = 600).
        tb.resize(m + nc, 0.0);
        let (si, mi) = ratio_pass(contiguous(&xi), contiguous(&di), sj, zero_tol, &mut tb[..m]);
        let (sc, mc) = ratio_pass(contiguous(&xc), contiguous(&dc), sj, zero_tol, &mut tb[m..]);
        let slope = 1.0 + si + sc;
        let dmax = mi.max(mc);
        // The first breakpoint: the smallest t, the lowest index among equals.
        let first = tb
            .iter()
            .enumerate()
            .fold((f64::INFINITY, usize::MAX), |f, (b, &t)| {
                if t < f.0 {
                    (t, b)
                } else {
                    f
                }
            });
        let (b, t) = if slope >= 0.0 {
            // Degenerate step: the degenerate basic with the largest |d| leaves at t = 0.
            let zero = basics()
                .filter(|&(_, x, d)| x.abs() <= zero_tol && d.abs() > 1e-12)
                .max_by(|a, b| a.2.abs().total_cmp(&b.2.abs()));
            match zero {
                Some((b, _, _)) => (b, 0.0),
                None => return None,
            }
        } else if first.1 != usize::MAX && slope + 2.0 * dir(first.1).abs() >= 0.0 {
            (first.1, first.0)
        } else {
            long_step(&tb, |b| 2.0 * dir(b).abs(), slope, &mut breaks)?
        };
        if dir(b).abs() < 1e-10 * dmax {
            return None;
        }
        // x_B -= t·sj·d_B; the entering variable takes sj·t, the leaving one drops out.
        for i in 0..m {
            xi[i] -= t * sj * di[i];
        }
        for p in 0..nc {
            xc[p] -= t * sj * dc[p];
        }
        if b < m {
            xi[b] = 0.0;
            lp.r_pos[b] = lp.r.len();
            lp.r.push(b);
        } else {
            let p = b - m;
            let last = nc - 1;
            lp.c_pos[lp.c[p]] = usize::MAX;
            lp.c.swap_remove(p);
            let moved = xc[last];
            xc[p] = moved;
            xc.resize_with(last, |_| 0.0);
            if p < last {
                lp.c_pos[lp.c[p]] = p;
                let (mut a, b2) = lp.tc.two_cols_mut(p, last);
                a.copy_from(&b2);
            }
        }
        if is_id {
            let p = lp.r_pos[j];
            lp.r.swap_remove(p);
            lp.r_pos[j] = usize::MAX;
            if p < lp.r.len() {
                lp.r_pos[lp.r[p]] = p;
            }
            xi[j] = sj * t;
        } else {
            let q = lp.c.len();
            lp.c_pos[j] = q;
            lp.c.push(j);
            if lp.tc.ncols() <= q {
                // faer reserves exactly what is asked: grow geometrically, or every new basic
                // T column would reallocate and copy the m x q block.
                lp.tc.reserve(m, (q + 1).next_power_of_two().max(16));
                lp.tc.resize_with(m, q + 1, |_, _| 0.0);
            }
            let dst = lp.tc.col_mut(q).try_as_col_major_mut();
            let dst = dst
                .expect("owned faer columns are contiguous")
                .as_slice_mut();
            // (T's fields directly, not `tcol`: `lp.tc` is borrowed mutably here.)
            dst.copy_from_slice(t_column(&lp.t, lp.t_off, m, j));
            xc.resize_with(q + 1, |_| sj * t);
            xc[q] = sj * t;
        }
        if !lp.refactor() {
            return None;
        }
        *pivots += 1;
        since_refresh += 1;
        if since_refresh >= REFRESH {
            lp.ftran(theta0.as_ref(), &mut xi, &mut xc);
            since_refresh = 0;
        }
    }
}

/// `signal` ← Ψθ for θ = θ_S on the support, zero elsewhere.
fn signal_of(dct: &mut Dct, support: &[usize], theta_s: &Col<f64>, signal: &mut [f64]) {
    signal.fill(0.0);
    for (c, &k) in support.iter().enumerate() {
        signal[k] = theta_s[c];
    }
    dct.inverse(signal);
}

/// A basis's refined primal and dual, as [`verify`] checks them.
struct Candidate<'a> {
    support: &'a [usize],
    theta_s: &'a Col<f64>,
    /// Ψθ for θ = θ_S on the support, zero elsewhere.
    signal: Vec<f64>,
    /// max |h − (Ψθ)_idx|.
    resid: f64,
    y: &'a Col<f64>,
    /// Aᵀy.
    w: &'a [f64],
}

/// Checks a candidate optimum against the transforms: θ (zero off the support) must reproduce the
/// samples (its signal and residual come from the transform in [`Refine::primal`]), w = Aᵀy must
/// satisfy |w| ≤ 1 + tol everywhere (w on the support equal to sign θ), and the gap ||θ||₁ - hᵀy
/// must vanish up to rounding.
fn verify(n: usize, h: &[f64], c: Candidate<'_>, pivots: usize, tol: f64) -> Option<SimplexResult> {
    if !finite(c.theta_s) {
        return None;
    }
    let inf = c.w.iter().map(|v| v.abs()).fold(0.0, f64::max);
    if inf.is_nan() || inf > 1.0 + tol {
        return None;
    }
    let mut theta = vec![0.0; n];
    for (q, &k) in c.support.iter().enumerate() {
        theta[k] = c.theta_s[q];
    }
    let scale = h.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
    if c.resid.is_nan() || c.resid > 1e-10 * scale {
        return None;
    }
    let objective: f64 = theta.iter().map(|v| v.abs()).sum();
    let dual_objective: f64 = h.iter().enumerate().map(|(r, hr)| hr * c.y[r]).sum();
    if (objective - dual_objective).abs() > 1e-10 * objective.max(1e-300) {
        return None;
    }
    Some(SimplexResult {
        theta,
        signal: c.signal,
        dual_objective,
        pivots,
        dual_inf_norm: inf,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sequential LU solves match the basis: B·(B⁻¹b) = b, Bᵀ·(B⁻ᵀc) = c, and the block solve
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

    /// The Gram anchor solves the same systems as the f64 LU of B₀, for a support in no particular
    /// order that holds frequency 0 (its own weight) and high frequencies (the g(2n − d) fold);
    /// `start` equals a solve plus `columns`.
    #[test]
    fn gram_anchor_solves_like_the_lu() {
        let n = 97;
        let mut dct = Dct::new(n);
        let m = 32;
        let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, m, 3)
            .indices(n)
            .unwrap();
        let mut support: Vec<usize> = (0..m).map(|c| (c * 7) % 41).collect();
        support[5] = 96;
        support[9] = 90;
        support.sort_unstable();
        assert!(support.contains(&0));
        let lu = Basis::<f64>::factor(&dct, &idx, &support).expect("non-singular");
        let gram = Gram::factor(&mut dct, &idx, &support).expect("positive definite");
        let rhs = Col::<f64>::from_fn(m, |r| (r as f64 * 0.37).sin());
        let (mut x, mut y) = (rhs.clone(), rhs.clone());
        Basis::solve(&lu, &mut x);
        Basis::solve_transpose(&lu, &mut y);
        let (mut xg, mut yg) = (rhs.clone(), rhs.clone());
        Anchor::solve(&gram, &mut dct, &idx, &mut xg);
        Anchor::solve_transpose(&gram, &mut dct, &idx, &mut yg);
        let h: Vec<f64> = (0..m).map(|r| rhs[r]).collect();
        let mut ath = vec![0.0; n];
        dct.adjoint(&idx, |r| h[r], &mut ath);
        for r in 0..m {
            assert!(
                (xg[r] - x[r]).abs() < 1e-9 * (1.0 + x[r].abs()),
                "solve row {r}"
            );
            assert!(
                (yg[r] - y[r]).abs() < 1e-9 * (1.0 + y[r].abs()),
                "transpose row {r}"
            );
        }
        // Few columns (the one-column kernel's route) and a block of 8 or more (the row kernel
        // on AVX2, faer's solves elsewhere), frequency 0 among them.
        for ks in [
            &[0usize, 3, 50, 95][..],
            &[0, 1, 2, 3, 50, 60, 70, 80, 91, 93, 95],
        ] {
            let (mut cols_lu, mut cols_g, mut cols_start) = (Vec::new(), Vec::new(), vec![7.0]);
            Anchor::columns(&lu, &dct, &idx, ks, &mut cols_lu);
            Anchor::columns(&gram, &dct, &idx, ks, &mut cols_g);
            // Appended after what the vector held.
            assert_eq!(cols_g.len(), m * ks.len());
            let theta0 = gram.start(&mut dct, &idx, &h, &ath, ks, &mut cols_start);
            assert_eq!(cols_start.remove(0), 7.0);
            for r in 0..m {
                assert!(
                    (theta0[r] - x[r]).abs() < 1e-9 * (1.0 + x[r].abs()),
                    "start row {r}"
                );
                for c in 0..ks.len() {
                    let want = cols_lu[c * m + r];
                    let got = cols_g[c * m + r];
                    assert!(
                        (got - want).abs() < 1e-9 * (1.0 + want.abs()),
                        "{} columns: ({r}, {c}) {got} against {want}",
                        ks.len()
                    );
                    assert_eq!(cols_start[c * m + r], got, "{} columns", ks.len());
                }
            }
        }
        // A repeated column makes G singular: refused.
        let mut twice = support.clone();
        twice[1] = twice[0];
        assert!(Gram::factor(&mut dct, &idx, &twice).is_none());
    }

    /// The Gram fill writes G's lower triangle exactly, and nothing above it.
    #[test]
    fn gram_fill_agrees_with_the_formula() {
        let hg: Vec<f64> = (0..200)
            .map(|d| (d as f64 * 0.61).cos() / (1.0 + d as f64))
            .collect();
        let s: Vec<u32> = vec![0, 1, 2, 5, 9, 10, 11, 12, 13, 40, 41, 57, 70, 88, 99];
        let (m, ld) = (s.len(), 16);
        let want = |a: usize, b: usize| hg[(s[a] - s[b]) as usize] + hg[(s[a] + s[b]) as usize];
        let mut g = vec![f64::NAN; ld * m];
        gram_lower(&hg, &s, &mut g, ld);
        for b in 0..m {
            for a in 0..m {
                let v = g[b * ld + a];
                if a >= b {
                    assert_eq!(v, want(a, b), "({a}, {b})");
                } else {
                    assert!(v.is_nan(), "({a}, {b}) above the diagonal written");
                }
            }
        }
    }

    /// The Gram solve's AVX2 kernel agrees with faer's triangular pair, for sizes around its
    /// 8-column blocks and 4-row vectors, a padded leading dimension, and 1 to 9 right-hand
    /// sides (groups of 4, then 3, 2 or 1).
    #[test]
    fn gram_solve_kernel_matches_the_triangular_pair() {
        #[cfg(target_arch = "x86_64")]
        if super::super::simd::has_avx2_fma() {
            for m in [1usize, 5, 8, 13, 16, 37, 64, 101] {
                let ld = m + 3;
                let mut l = vec![f64::NAN; ld * m];
                for j in 0..m {
                    for i in j..m {
                        l[j * ld + i] = if i == j {
                            1.5 + (j as f64 * 0.3).sin()
                        } else {
                            0.2 * ((i * 7 + j * 3) as f64).cos()
                        };
                    }
                }
                let lt = Mat::<f64>::from_fn(m, m, |i, j| if i >= j { l[j * ld + i] } else { 0.0 });
                // 1-4 columns (one group), 5-9 (a group of 4 then the rest), 12 (three groups).
                for k in (1..=9).chain([12]) {
                    let b: Vec<f64> = (0..m * k).map(|i| (i as f64 * 0.37).sin() + 0.1).collect();
                    let mut x = b.clone();
                    // SAFETY: AVX2 checked; l holds m columns ld apart.
                    unsafe { gram_solve_columns_avx2(&l, ld, &mut x, m) };
                    let mut want = Mat::<f64>::from_fn(m, k, |i, c| b[c * m + i]);
                    solve_lower_triangular_in_place(lt.as_ref(), want.as_mut(), Par::Seq);
                    solve_upper_triangular_in_place(lt.transpose(), want.as_mut(), Par::Seq);
                    for c in 0..k {
                        for i in 0..m {
                            let (got, w) = (x[c * m + i], want[(i, c)]);
                            let tol = 1e-12 * w.abs().max(1.0);
                            assert!(
                                (got - w).abs() <= tol,
                                "m = {m}, k = {k}, column {c}, row {i}: {got} vs {w}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// The long step's fallback passes breakpoints in increasing t until the slope turns, across
    /// its sorted chunks, and reports none when the slope never turns.
    #[test]
    fn long_step_passes_breakpoints_in_order() {
        let n = 700;
        let breaks: Vec<(f64, usize, f64)> = (0..n)
            .map(|b| (((b * 389) % n) as f64 + 0.5, b, 1.0 + (b % 3) as f64))
            .collect();
        let mut sorted = breaks.clone();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let total: f64 = breaks.iter().map(|b| b.2).sum();
        for passed in [0usize, 1, 7, 31, 32, 33, 200, 699] {
            // A slope that turns exactly at the `passed`-th breakpoint (0-based).
            let before: f64 = sorted[..passed].iter().map(|b| b.2).sum();
            let slope = -(before + 0.5 * sorted[passed].2);
            let mut work = breaks.clone();
            let want = (sorted[passed].1, sorted[passed].0);
            assert_eq!(
                pass_in_order(&mut work, slope),
                Some(want),
                "passed {passed}"
            );
        }
        let mut work = breaks.clone();
        assert_eq!(pass_in_order(&mut work, -total - 1.0), None);
    }

    /// The long step's first breakpoints are the smallest finite ones in increasing t, equal t
    /// by lower index, however many (or few) there are.
    #[test]
    fn smallest_breaks_are_the_sorted_head() {
        let inf = f64::INFINITY;
        for len in [0usize, 1, 5, 8, 9, 40, 611] {
            let tb: Vec<f64> = (0..len)
                .map(|b| match (b * 37) % 11 {
                    0..=2 => inf,
                    k => ((b * 13) % 7) as f64 * 0.25 + k as f64 * 1e-3 * ((b % 3) as f64),
                })
                .collect();
            let mut want: Vec<(f64, usize)> = tb
                .iter()
                .enumerate()
                .filter(|(_, t)| t.is_finite())
                .map(|(b, &t)| (t, b))
                .collect();
            want.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            want.truncate(NEAR_BREAKS);
            let (near, count) = smallest_breaks(&tb);
            assert_eq!(&near[..count], &want[..], "len {len}");
        }
    }

    /// The vector scan of ĉ finds the same changes as the scalar definition, on R and off it,
    /// for signs of every kind (±0, NaN) and a length that leaves a tail.
    #[test]
    fn chat_changes_match_the_scalar_loop() {
        let m = 23;
        let x: Vec<f64> = (0..m)
            .map(|i| match i % 6 {
                0 => 0.0,
                1 => -0.0,
                2 => f64::NAN,
                3 => -(i as f64),
                _ => i as f64 * 0.5,
            })
            .collect();
        let r_pos: Vec<usize> = (0..m)
            .map(|i| if i % 5 == 0 { i / 5 } else { usize::MAX })
            .collect();
        let start: Vec<f64> = (0..m).map(|i| [1.0, -1.0, 0.0][i % 3]).collect();
        let (mut got, mut want) = (start.clone(), start);
        let (mut got_changes, mut want_changes) = (Vec::new(), Vec::new());
        chat_changes(&x, &r_pos, &mut got, &mut got_changes);
        chat_changes_from(0, m, &x, &r_pos, &mut want, &mut want_changes);
        assert_eq!(got_changes, want_changes);
        assert!(!want_changes.is_empty());
        assert_eq!(
            got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            want.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }

    /// From a poor ranking (the lowest frequencies first, few candidates, so column generation
    /// has to find most of the optimal basis) the simplex reaches a certified optimum; ranked
    /// first, the optimal basis certifies with zero pivots; and the verification rejects a
    /// candidate whose primal does not reproduce the samples or whose dual is infeasible.
    #[test]
    fn finish_certifies_and_verification_rejects_bad_candidates() {
        use rand::{Rng, SeedableRng};
        let (n, m) = (128, 40);
        let mut dct = Dct::new(n);
        let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, m, 5)
            .indices(n)
            .unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let h: Vec<f64> = (0..m).map(|_| rng.random_range(-1.0..1.0)).collect();
        let order: Vec<usize> = (0..n).collect();
        let mut ath = vec![0.0; n];
        dct.adjoint(&idx, |r| h[r], &mut ath);
        let r =
            finish(&mut dct, &idx, &h, &ath, &order, 4, 1000, 1e-9, usize::MAX).expect("certified");
        assert!(r.pivots > 0);
        assert!(r.dual_inf_norm <= 1.0 + 1e-9);
        let objective: f64 = r.theta.iter().map(|v| v.abs()).sum();
        assert!((objective - r.dual_objective).abs() < 1e-10 * objective);
        let mut g = r.theta.clone();
        dct.inverse(&mut g);
        for (&i, &hk) in idx.iter().zip(&h) {
            assert!((g[i] - hk).abs() < 1e-12);
        }
        // The Gram anchor reaches the same optimum.
        let g = finish(&mut dct, &idx, &h, &ath, &order, 4, 1000, 1e-9, 0).expect("certified");
        assert!((g.dual_objective - r.dual_objective).abs() < 1e-10 * objective);
        for k in 0..n {
            assert!((g.theta[k] - r.theta[k]).abs() < 1e-9, "coefficient {k}");
        }
        let optimal: Vec<usize> = (0..n).filter(|&k| r.theta[k] != 0.0).collect();
        assert_eq!(optimal.len(), m, "random data: a non-degenerate vertex");
        let mut ranked = optimal.clone();
        ranked.extend((0..n).filter(|k| !optimal.contains(k)));
        let again = finish(&mut dct, &idx, &h, &ath, &ranked, 8, 1000, 1e-9, usize::MAX)
            .expect("certified");
        assert_eq!(again.pivots, 0);
        assert!((again.dual_objective - r.dual_objective).abs() < 1e-10 * objective);

        // The returned curve is the certified θ's.
        let mut g = r.theta.clone();
        dct.inverse(&mut g);
        assert!(g.iter().zip(&r.signal).all(|(a, b)| (a - b).abs() < 1e-13));

        // The certificate's own y and w, with θ_S perturbed: primal residual, so rejected.
        let basis = Basis::<f64>::factor(&dct, &idx, &optimal).unwrap();
        let mut theta_s = Col::<f64>::from_fn(m, |c| r.theta[optimal[c]]);
        let mut y = Col::<f64>::from_fn(m, |c| sign(theta_s[c]));
        basis.solve_transpose(&mut y);
        let mut w = vec![0.0; n];
        dct.adjoint(&idx, |c| y[c], &mut w);
        // A candidate as `Refine::primal` hands it over: θ's signal and sample residual.
        let mut check = |theta_s: &Col<f64>, w: &[f64]| {
            let mut signal = vec![0.0; n];
            signal_of(&mut dct, &optimal, theta_s, &mut signal);
            let resid = idx
                .iter()
                .zip(&h)
                .map(|(&i, hk)| (signal[i] - hk).abs())
                .fold(0.0, f64::max);
            let c = Candidate {
                support: &optimal,
                theta_s,
                signal,
                resid,
                y: &y,
                w,
            };
            verify(n, &h, c, 0, 1e-9).is_some()
        };
        assert!(check(&theta_s, &w));
        theta_s[0] *= 1.0 + 1e-6;
        assert!(!check(&theta_s, &w));
        // ... and a dual that is infeasible somewhere (|w| > 1) is rejected as well.
        theta_s[0] = r.theta[optimal[0]];
        let mut w_bad = w.clone();
        let off = (0..n).find(|k| !optimal.contains(k)).unwrap();
        w_bad[off] = 1.0 + 1e-6;
        assert!(!check(&theta_s, &w_bad));
    }
}
