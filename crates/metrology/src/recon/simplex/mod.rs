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
//! there on, through its Gram matrix (`Gram`): one DCT gives B₀ᵀB₀ without forming B₀, and its
//! f64 Cholesky costs about what the f32 LU does (m³/3 flops at half the rate) with ~1e-9 error,
//! so the anchors that f32 could not certify (1-3 curves in 20 at m = 600, 10-16 ms each) do not
//! occur. Last, an f64 LU.
//!
//! Optimality is never taken from the factorizations alone: the final θ and y are checked against
//! the transforms (primal residual by one inverse DCT, |Aᵀy| ≤ 1 + tol by one forward DCT, and
//! ||θ||₁ = hᵀy), so rounding can cost a failed finish but never a wrong "optimal".
mod basis;
pub mod denoise;
mod gram;
mod pricing;
mod ratio;
mod refine;
mod restricted;

use faer::{Col, ColRef};

use super::dct::Dct;
use basis::{Anchor, Basis};
use gram::Gram;
use pricing::Pricer;
use ratio::{long_step, ratio_pass};
pub use refine::SimplexResult;
use refine::{verify, Candidate, Refine};
use restricted::{contiguous, generate, register_columns, sign, t_column, Restricted};

/// Pivots between recomputations of the basic solution from scratch (the running update drifts).
const REFRESH: usize = 16;

/// Dual slack below which off-K columns wait for the refined dual before they join (the f32
/// anchor's dual is good to ~1e-5; a column joining needlessly costs one triangular solve pair).
const LOOSE: f64 = 1e-4;

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
    // T: room for the first block and a generation round.
    let t_cols = ranked.len() - m + restricted::GENERATE_MAX;
    let mut lp = Restricted::new(m, n, &s0, t_cols);
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
    let mut pricer = Pricer::new(m);
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
            dst.copy_from_slice(t_column(&lp.t, m, j));
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

#[cfg(test)]
mod tests {
    use super::refine::signal_of;
    use super::*;

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
