//! The restricted LP min ||x||₁ s.t. [I T] x = θ₀ over the candidate columns K, its simplex basis,
//! and column generation into it.
use faer::linalg::matmul::matmul;
use faer::{Accum, Col, ColRef, Mat, MatRef, Par};

use super::basis::{Anchor, Basis};
use crate::recon::dct::Dct;

pub(super) fn finite(v: &Col<f64>) -> bool {
    (0..v.nrows()).all(|i| v[i].is_finite())
}

pub(super) fn sign(v: f64) -> f64 {
    if v >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// Columns added to E per column-generation round (the most violated first).
pub(super) const GENERATE_MAX: usize = 32;

/// A faer column's entries as a slice (owned columns are contiguous).
pub(super) fn contiguous(c: &Col<f64>) -> &[f64] {
    c.try_as_col_major()
        .expect("owned faer columns are contiguous")
        .as_slice()
}

/// The restricted LP min ||x||₁ s.t. [I T] x = θ₀ and its simplex basis: the identity with the
/// columns of rows R replaced by the T columns C.
pub(super) struct Restricted {
    pub(super) m: usize,
    /// DCT column of each T column, and whether a DCT column is in K = S₀ ∪ E.
    pub(super) e_cols: Vec<usize>,
    pub(super) in_k: Vec<bool>,
    /// T = B₀⁻¹A_E, column-major m x ke.
    pub(super) t: Vec<f64>,
    pub(super) ke: usize,
    /// Identity rows whose column is non-basic, and each row's position in `r` (or usize::MAX).
    pub(super) r: Vec<usize>,
    pub(super) r_pos: Vec<usize>,
    /// Basic T columns, each column's position in `c` (or usize::MAX), and T_{:,C} in that order.
    pub(super) c: Vec<usize>,
    pub(super) c_pos: Vec<usize>,
    pub(super) tc: Mat<f64>,
    /// LU of T_{R,C}.
    pub(super) small: Option<Basis<f64>>,
}

/// Column e of T (m entries each) in the buffer `t`.
pub(super) fn t_column(t: &[f64], m: usize, e: usize) -> &[f64] {
    &t[e * m..(e + 1) * m]
}

impl Restricted {
    /// The restricted problem around the anchor's columns `s0` (none of E yet), on n DCT
    /// columns; T's buffer is the thread's last one, with room for `t_cols` columns.
    pub(super) fn new(m: usize, n: usize, s0: &[usize], t_cols: usize) -> Self {
        let mut in_k = vec![false; n];
        for &k in s0 {
            in_k[k] = true;
        }
        let mut t = T_SPARE.take();
        t.clear();
        t.reserve(m * t_cols);
        Self {
            m,
            e_cols: Vec::new(),
            in_k,
            t,
            ke: 0,
            r: Vec::new(),
            r_pos: vec![usize::MAX; m],
            c: Vec::new(),
            c_pos: Vec::new(),
            tc: Mat::zeros(m, 0),
            small: None,
        }
    }

    /// T's entries, column after column.
    pub(super) fn tmat(&self) -> &[f64] {
        &self.t
    }

    pub(super) fn tcol(&self, e: usize) -> &[f64] {
        t_column(&self.t, self.m, e)
    }

    pub(super) fn tc_ref(&self) -> MatRef<'_, f64> {
        self.tc.as_ref().subcols(0, self.c.len())
    }

    pub(super) fn refactor(&mut self) -> bool {
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
    pub(super) fn ftran(&self, b: ColRef<'_, f64>, xi: &mut Col<f64>, xc: &mut Col<f64>) {
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
    pub(super) fn btran(&self, ci: &Col<f64>, cc: &Col<f64>, y: &mut Col<f64>) {
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
    pub(super) fn dual_rows(&self, mut rhs: Col<f64>, y: &mut Col<f64>) -> Col<f64> {
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
    pub(super) fn basics(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.m)
            .filter(|&i| self.r_pos[i] == usize::MAX)
            .chain(self.m..self.m + self.c.len())
    }
}

thread_local! {
    /// The last restricted problem's T, for the next one on this thread (a fresh ~250 KB block
    /// at m = 600 came from mmap and faulted its pages in at every solve).
    static T_SPARE: std::cell::Cell<Vec<f64>> = const { std::cell::Cell::new(Vec::new()) };
}

impl Drop for Restricted {
    fn drop(&mut self) {
        T_SPARE.set(std::mem::take(&mut self.t));
    }
}

/// Adds columns to E: T columns B₀⁻¹a_k by one block triangular solve.
fn add_columns<B: Anchor>(dct: &Dct, idx: &[usize], basis: &B, lp: &mut Restricted, new: &[usize]) {
    basis.columns(dct, idx, new, &mut lp.t);
    register_columns(lp, new);
}

/// Enters columns `new` in E, their T columns B₀⁻¹A_new having just been appended to `lp.t`.
pub(super) fn register_columns(lp: &mut Restricted, new: &[usize]) {
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
pub(super) fn generate<B: Anchor>(
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
