//! The anchor through its Gram matrix G = B₀ᵀB₀: one DCT forms G without forming B₀, faer's
//! Cholesky factors it, faer's triangular solves apply G⁻¹.
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Col, MatMut, MatRef, Par};

use super::basis::{diagonal_spread_within, Anchor};
use crate::recon::dct::Dct;

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
pub(super) struct Gram {
    /// L (column-major m x m, lower triangle) with G = LLᵀ; the upper triangle holds zeros.
    l_buf: Vec<f64>,
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
    /// its pages in at every solve cost ~117 page faults).
    fn block(&self, ks: &[usize], w: Option<&[f64]>, out: &mut Vec<f64>) -> Option<Col<f64>> {
        let m = self.sorted.len();
        let k = ks.len();
        let nc = k + usize::from(w.is_some());
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

    /// v = G⁻¹v (rows in sorted order).
    fn solve_gram(&self, mut v: MatMut<'_, f64>) {
        let m = self.sorted.len();
        let l = MatRef::from_column_major_slice(&self.l_buf[..m * m], m, m);
        solve_lower_triangular_in_place(l, v.as_mut(), Par::Seq);
        solve_upper_triangular_in_place(l.transpose(), v, Par::Seq);
    }
}

thread_local! {
    /// The last Gram anchor's L buffer, for the next one on this thread.
    static L_SPARE: std::cell::Cell<Vec<f64>> = const { std::cell::Cell::new(Vec::new()) };
}

impl Drop for Gram {
    fn drop(&mut self) {
        L_SPARE.set(std::mem::take(&mut self.l_buf));
    }
}

/// The lower triangle of G (sorted frequencies s, `hg` = c²·½g) into the column-major `g`
/// (leading dimension `ld`): G_ab = hg[s_a − s_b] + hg[s_a + s_b] for a ≥ b (frequency 0's
/// weight is the caller's).
pub(super) fn gram_lower(hg: &[f64], s: &[u32], g: &mut [f64], ld: usize) {
    let m = s.len();
    assert!(s.is_sorted() && (m == 0 || (s[m - 1] as usize) * 2 < hg.len()));
    assert!(m == 0 || g.len() >= (m - 1) * ld + m);
    for b in 0..m {
        let kb = s[b] as usize;
        let hi = &hg[kb..];
        for (o, &ka) in g[b * ld + b..b * ld + m].iter_mut().zip(&s[b..]) {
            let ka = ka as usize;
            *o = hg[ka - kb] + hi[ka];
        }
    }
}

/// The table c_k²·½g(d), d < 2n, from which [`gram_lower`] fills any Gram block of sampled DCT
/// columns (one DCT of the samples' indicator), and c_0 / c_k, frequency 0's relative weight.
pub(super) fn half_gram(dct: &mut Dct, idx: &[usize]) -> (Vec<f64>, f64) {
    let n = dct.len();
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
    (half_g, w0 / wk)
}

impl Gram {
    /// The Gram anchor of the sampled DCT columns `support`; `None` when G is not numerically
    /// positive definite.
    pub(super) fn factor(dct: &mut Dct, idx: &[usize], support: &[usize]) -> Option<Self> {
        let m = support.len();
        let (half_g, r0) = half_gram(dct, idx);
        assert!(
            support.is_sorted(),
            "the Gram anchor's support in increasing frequency"
        );
        let sorted = support.to_vec();
        let s32: Vec<u32> = sorted.iter().map(|&k| k as u32).collect();
        // The thread's last buffer, zeroed (a fresh 2.9 MB at m = 600 would fault its pages in
        // at every solve); the upper triangle stays zero.
        let mut l_buf = L_SPARE.take();
        l_buf.clear();
        l_buf.resize(m * m, 0.0);
        gram_lower(&half_g, &s32, &mut l_buf, m);
        if sorted[0] == 0 {
            // Frequency 0 has its own weight: scale its column (the lower triangle's row 0 is
            // the diagonal entry alone).
            l_buf[..m].iter_mut().for_each(|v| *v *= r0);
            l_buf[0] *= r0;
        }
        let mut scratch = MemBuffer::new(cholesky_in_place_scratch::<f64>(
            m,
            Par::Seq,
            Default::default(),
        ));
        let factored = cholesky_in_place(
            MatMut::from_column_major_slice_mut(&mut l_buf, m, m),
            Default::default(),
            Par::Seq,
            MemStack::new(&mut scratch),
            Default::default(),
        );
        let gram = Self {
            l_buf,
            sorted,
            half_g,
            w0: r0,
        };
        // κ(G) ≥ (max/min diagonal of L)²: beyond ~1e12 f64 has no digits left for the simplex.
        let l = &gram.l_buf;
        let spread_ok = diagonal_spread_within((0..m).map(|i| l[i * m + i]), 1e-6);
        (factored.is_ok() && spread_ok).then_some(gram)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::simplex::basis::Basis;

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
        // A few columns and a larger block, frequency 0 among them.
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
}
