//! Orthonormal DCT pair through rustdct: Ψ (inverse, DCT-III) and Ψᵀ (forward, DCT-II).
//!
//! With this scaling Ψ is orthogonal, so a sampled Ψ has orthonormal rows (A·Aᵀ = I): the
//! structure the fast basis-pursuit solver relies on.
use std::sync::Arc;

use rustdct::{DctPlanner, TransformType2And3};

pub struct Dct {
    n: usize,
    plan: Arc<dyn TransformType2And3<f64>>,
    scratch: Vec<f64>,
    s0: f64,
    sk: f64,
    /// cos(π j / 2n), j < 4n: basis entries are table lookups (dense bases are built often).
    cos_table: Vec<f64>,
    /// ⌊(2⁶⁴ - 1) / 4n⌋: Barrett reduction of the table index (a hardware division per entry
    /// was most of the cost of building an m x m basis).
    barrett: u64,
}

impl Dct {
    pub fn new(n: usize) -> Self {
        let plan = DctPlanner::new().plan_dct2(n);
        let scratch = vec![0.0; plan.get_scratch_len()];
        let nf = n as f64;
        let cos_table = (0..4 * n)
            .map(|j| (std::f64::consts::PI * j as f64 / (2.0 * nf)).cos())
            .collect();
        Self {
            n,
            plan,
            scratch,
            s0: (1.0 / nf).sqrt(),
            sk: (2.0 / nf).sqrt(),
            cos_table,
            barrett: u64::MAX / (4 * n.max(1)) as u64,
        }
    }

    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// θ = Ψᵀ g (in place): coefficients of a signal.
    pub fn forward(&mut self, buf: &mut [f64]) {
        self.plan.process_dct2_with_scratch(buf, &mut self.scratch);
        buf[0] *= self.s0;
        for v in &mut buf[1..] {
            *v *= self.sk;
        }
    }

    /// g = Ψ θ (in place): the signal of coefficients.
    pub fn inverse(&mut self, buf: &mut [f64]) {
        // rustdct's DCT-III is x_n = X_0/2 + Σ X_k cos(..): fold the orthonormal weights in.
        buf[0] *= 2.0 * self.s0;
        for v in &mut buf[1..] {
            *v *= self.sk;
        }
        self.plan.process_dct3_with_scratch(buf, &mut self.scratch);
    }

    /// Ψ[i, k] = c_k cos(π k (2i + 1) / 2n): basis function k at grid point i.
    pub fn basis(&self, i: usize, k: usize) -> f64 {
        if k == 0 {
            self.s0
        } else {
            let j = (k * (2 * i + 1)) % (4 * self.n);
            self.sk * self.cos_table[j]
        }
    }

    /// Column k of Ψ at the given rows: out[r] = Ψ[rows[r], k].
    pub fn basis_column(&self, k: usize, rows: &[usize], out: &mut [f64]) {
        if k == 0 {
            out.fill(self.s0);
            return;
        }
        let p = 4 * self.n as u64;
        for (o, &i) in out.iter_mut().zip(rows) {
            let a = k as u64 * (2 * i as u64 + 1);
            // q undershoots a / p by at most 2, so at most two corrections.
            let q = ((a as u128 * self.barrett as u128) >> 64) as u64;
            let mut j = a - q * p;
            while j >= p {
                j -= p;
            }
            *o = self.sk * self.cos_table[j as usize];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transform_pair_is_orthonormal_and_matches_the_basis() {
        for &n in &[7usize, 64, 1901] {
            let mut d = Dct::new(n);
            let x: Vec<f64> = (0..n).map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.1).collect();
            let mut y = x.clone();
            d.forward(&mut y);
            let e0: f64 = x.iter().map(|v| v * v).sum();
            let e1: f64 = y.iter().map(|v| v * v).sum();
            assert!((e0 - e1).abs() < 1e-9 * e0.max(1.0), "Parseval n={n}");
            let mut z = y.clone();
            d.inverse(&mut z);
            for (a, b) in x.iter().zip(&z) {
                assert!((a - b).abs() < 1e-12);
            }
            // Column k of Ψ is the inverse of the unit vector e_k.
            for &k in &[0usize, 1, n / 2, n - 1] {
                let mut e = vec![0.0; n];
                e[k] = 1.0;
                d.inverse(&mut e);
                for &i in &[0usize, 3 % n, n - 1] {
                    assert!((e[i] - d.basis(i, k)).abs() < 1e-12, "n={n} i={i} k={k}");
                }
                let rows: Vec<usize> = (0..n).collect();
                let mut col = vec![0.0; n];
                d.basis_column(k, &rows, &mut col);
                for (i, (a, b)) in e.iter().zip(&col).enumerate() {
                    assert!((a - b).abs() < 1e-12, "column n={n} i={i} k={k}");
                }
            }
        }
    }

    /// The Barrett-reduced table index stays exact where k·(2i+1) is far beyond 4n.
    #[test]
    fn basis_column_matches_basis_at_large_n() {
        let n = 65_536;
        let d = Dct::new(n);
        let rows = [0usize, 1, 12_345, n / 2, n - 2, n - 1];
        let mut col = [0.0; 6];
        for k in [1usize, 2, 777, n / 3, n - 2, n - 1] {
            d.basis_column(k, &rows, &mut col);
            for (&i, &c) in rows.iter().zip(&col) {
                let exact = (2.0 / n as f64).sqrt()
                    * (std::f64::consts::PI * k as f64 * (2 * i + 1) as f64 / (2.0 * n as f64))
                        .cos();
                assert!((c - d.basis(i, k)).abs() < 1e-15, "i={i} k={k}");
                assert!((c - exact).abs() < 1e-12, "i={i} k={k}");
            }
        }
    }
}
