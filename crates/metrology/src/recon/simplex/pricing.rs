//! Pricing: the simplex's dual during pivots, kept up to date row by row.
use faer::linalg::matmul::matmul;
use faer::{Accum, Col, ColMut, ColRef, MatRef, Par};

use super::restricted::{contiguous, sign, Restricted};

/// The simplex's dual during pivots, y = ĉ + (y_R on the rows R), where ĉ holds the identity
/// rows' basic costs sign(x_i) with R zeroed. Keeping s = Tᵀĉ across pivots turns btran's
/// T_{:,C}ᵀĉ into s_C and pricing's Tᵀy into s + T_{R,:}ᵀy_R: a pivot changes ĉ on a few rows
/// (the leaving and entering ones, signs flipped by a long step), so two m x ke products per
/// pivot become a few row updates (measured at m = 600: ~8 µs of a ~26 µs pivot).
pub(super) struct Pricer {
    chat: Vec<f64>,
    s: Vec<f64>,
}

/// ĉ_i ← sign(x_i) on the identity rows outside R (`r_pos` = usize::MAX), 0 on R, pushing
/// (i, new − old) for each row that changes.
fn chat_changes(x: &[f64], r_pos: &[usize], chat: &mut [f64], changed: &mut Vec<(usize, f64)>) {
    for (i, ((&xi, &rp), ci)) in x.iter().zip(r_pos).zip(chat.iter_mut()).enumerate() {
        let c = if rp == usize::MAX { sign(xi) } else { 0.0 };
        if c != *ci {
            changed.push((i, c - *ci));
            *ci = c;
        }
    }
}

/// Changed rows of ĉ beyond which s is recomputed rather than updated.
const PRICER_ROWS: usize = 24;

impl Pricer {
    pub(super) fn new(m: usize) -> Self {
        Self {
            chat: vec![0.0; m],
            s: Vec::new(),
        }
    }

    /// ĉ for the current basic solution and R; s to match (in full when `full`, which bounds
    /// the drift of the updates, or when many rows changed).
    pub(super) fn update(&mut self, lp: &Restricted, xi: &Col<f64>, full: bool) {
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
    pub(super) fn price(&self, lp: &Restricted, yr: &Col<f64>, w: &mut Vec<f64>) {
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
    pub(super) fn dual(&self, lp: &Restricted, xc: &Col<f64>, y: &mut Col<f64>) -> Col<f64> {
        for (i, &c) in self.chat.iter().enumerate() {
            y[i] = c;
        }
        let rhs = Col::<f64>::from_fn(lp.c.len(), |p| sign(xc[p]) - self.s[lp.c[p]]);
        lp.dual_rows(rhs, y)
    }
}
