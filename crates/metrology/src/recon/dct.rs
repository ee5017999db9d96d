//! Orthonormal DCT pair: Ψ (inverse, DCT-III) and Ψᵀ (forward, DCT-II).
//!
//! With this scaling Ψ is orthogonal, so a sampled Ψ has orthonormal rows (A·Aᵀ = I): the
//! structure the fast basis-pursuit solver relies on.
//!
//! Two backends, both thin wrappers: rustdct's DCT-II/III plans, and Makhoul's algorithm on a
//! real FFT of length n (its permutation and twiddle passes are plain loops; the FFTs are
//! rustfft's, with its own SIMD dispatch). [`Dct::new`] takes the faster one per length
//! (`cargo run --release -- bench dct` times both). Lengths with a large prime factor (the
//! paper's n = 1901 is prime) take rustfft's Bluestein algorithm on a power-of-two FFT: its
//! planner's Rader path for 1901 runs on 1900 = 2²·5²·19, whose radix-19 butterfly has no
//! vector kernel (a quarter of a BP solve's time in a profile at m = 600).
use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustdct::{DctPlanner, TransformType2And3};
use rustfft::algorithm::BluesteinsAlgorithm;
use rustfft::{Fft, FftNum, FftPlanner};

fn real<T: FftNum>(v: f64) -> T {
    T::from_f64(v).unwrap_or_else(T::zero)
}

/// Orthonormal DCT pair of any length n ≥ 2 by Makhoul's algorithm on a real FFT of length n:
/// v = (g₀, g₂, …, g₃, g₁) (evens up, odds down), X_k = Re(e^{-iπk/2n}·FFT(v)_k).
/// Generic so that the basis-pursuit ranking can run in f32 ([`Dct::single`]).
/// The real FFT of length n under [`Makhoul`]: realfft's plans, or a complex FFT of the real
/// signal through Bluestein's algorithm ([`bluestein_pays_off`]).
enum RealFft<T: FftNum> {
    Plans {
        r2c: Arc<dyn RealToComplex<T>>,
        c2r: Arc<dyn ComplexToReal<T>>,
    },
    Bluestein {
        fwd: Arc<dyn Fft<T>>,
        inv: Arc<dyn Fft<T>>,
        work: Vec<Complex<T>>,
    },
}

/// Whether n has a prime factor of at least 64: then Bluestein on a power-of-two FFT beats
/// rustfft's plan for n (Rader's algorithm on n − 1, which need not factor into vector radices).
pub fn bluestein_pays_off(n: usize) -> bool {
    let (mut rest, mut p, mut largest) = (n, 2, 1);
    while p * p <= rest {
        while rest.is_multiple_of(p) {
            rest /= p;
            largest = p;
        }
        p += 1;
    }
    largest.max(rest) >= 64 && n % 2 == 1
}

pub struct Makhoul<T: FftNum> {
    n: usize,
    fft: RealFft<T>,
    v: Vec<T>,
    spec: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
    /// e^(iπk/2n) for k ≤ n/2.
    twiddle: Vec<Complex<T>>,
    s0: T,
    sk: T,
}

impl<T: FftNum> Makhoul<T> {
    pub fn new(n: usize) -> Self {
        let (fft, len) = if bluestein_pays_off(n) {
            let mut planner = FftPlanner::<T>::new();
            let inner = (2 * n - 1).next_power_of_two();
            let fwd: Arc<dyn Fft<T>> =
                Arc::new(BluesteinsAlgorithm::new(n, planner.plan_fft_forward(inner)));
            let inv: Arc<dyn Fft<T>> =
                Arc::new(BluesteinsAlgorithm::new(n, planner.plan_fft_inverse(inner)));
            let len = fwd
                .get_inplace_scratch_len()
                .max(inv.get_inplace_scratch_len());
            let work = vec![Complex::new(T::zero(), T::zero()); n];
            (RealFft::Bluestein { fwd, inv, work }, len)
        } else {
            let mut planner = RealFftPlanner::<T>::new();
            let (r2c, c2r) = (planner.plan_fft_forward(n), planner.plan_fft_inverse(n));
            let len = r2c.get_scratch_len().max(c2r.get_scratch_len());
            (RealFft::Plans { r2c, c2r }, len)
        };
        let twiddle = (0..=n / 2)
            .map(|k| {
                let phi = std::f64::consts::PI * k as f64 / (2.0 * n as f64);
                Complex::new(real(phi.cos()), real(phi.sin()))
            })
            .collect();
        let zero = Complex::new(T::zero(), T::zero());
        Self {
            n,
            fft,
            v: vec![T::zero(); n],
            spec: vec![zero; n / 2 + 1],
            scratch: vec![zero; len],
            twiddle,
            s0: real((1.0 / n as f64).sqrt()),
            sk: real((2.0 / n as f64).sqrt()),
        }
    }

    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// θ = Ψᵀ g (in place).
    pub fn forward(&mut self, buf: &mut [T]) {
        let (n, s0, sk) = (self.n, self.s0, self.sk);
        let (v, spec) = (&mut self.v, &mut self.spec);
        for (j, x) in buf.iter().step_by(2).enumerate() {
            v[j] = *x;
        }
        for (j, x) in buf.iter().skip(1).step_by(2).enumerate() {
            v[n - 1 - j] = *x;
        }
        match &mut self.fft {
            RealFft::Plans { r2c, .. } => r2c
                .process_with_scratch(v, spec, &mut self.scratch)
                .expect("buffer lengths fixed at planning"),
            RealFft::Bluestein { fwd, work, .. } => {
                for (b, &x) in work.iter_mut().zip(v.iter()) {
                    *b = Complex::new(x, T::zero());
                }
                fwd.process_with_scratch(work, &mut self.scratch);
                let half = spec.len();
                spec.copy_from_slice(&work[..half]);
            }
        }
        buf[0] = s0 * spec[0].re;
        for k in 1..n.div_ceil(2) {
            let (w, s) = (self.twiddle[k], spec[k]);
            buf[k] = sk * (s.re * w.re + s.im * w.im);
            buf[n - k] = sk * (s.re * w.im - s.im * w.re);
        }
        if n % 2 == 0 {
            buf[n / 2] = sk * spec[n / 2].re * real::<T>(std::f64::consts::FRAC_1_SQRT_2);
        }
    }

    /// g = Ψ θ (in place).
    pub fn inverse(&mut self, buf: &mut [T]) {
        let (n, s0, sk) = (self.n, self.s0, self.sk);
        let (v, spec) = (&mut self.v, &mut self.spec);
        // The inverse of the forward map: with X = θ / c (unnormalized DCT-II values),
        // FFT(v)_k = e^{iπk/2n}(X_k - i X_{n-k}), Hermitian, so one inverse real FFT.
        let inv_n: T = real(1.0 / n as f64);
        let (a0, ak) = (inv_n / s0, inv_n / sk);
        spec[0] = Complex::new(a0 * buf[0], T::zero());
        for k in 1..n.div_ceil(2) {
            let w = self.twiddle[k];
            let (x, y) = (ak * buf[k], T::zero() - ak * buf[n - k]);
            spec[k] = Complex::new(x * w.re - y * w.im, x * w.im + y * w.re);
        }
        if n % 2 == 0 {
            spec[n / 2] = Complex::new(
                ak * buf[n / 2] * real::<T>(std::f64::consts::SQRT_2),
                T::zero(),
            );
        }
        match &mut self.fft {
            RealFft::Plans { c2r, .. } => c2r
                .process_with_scratch(spec, v, &mut self.scratch)
                .expect("buffer lengths fixed at planning"),
            RealFft::Bluestein { inv, work, .. } => {
                // The Hermitian spectrum in full (n odd: no Nyquist bin), one inverse FFT.
                work[..spec.len()].copy_from_slice(spec);
                for k in 1..spec.len() {
                    work[n - k] = spec[k].conj();
                }
                inv.process_with_scratch(work, &mut self.scratch);
                for (x, b) in v.iter_mut().zip(work.iter()) {
                    *x = b.re;
                }
            }
        }
        for (j, x) in buf.iter_mut().step_by(2).enumerate() {
            *x = v[j];
        }
        for (j, x) in buf.iter_mut().skip(1).step_by(2).enumerate() {
            *x = v[n - 1 - j];
        }
    }
}

enum Backend {
    Rustdct {
        plan: Arc<dyn TransformType2And3<f64>>,
        scratch: Vec<f64>,
    },
    Makhoul(Box<Makhoul<f64>>),
}

pub struct Dct {
    n: usize,
    backend: Backend,
    /// The same transform in f32, planned on first use ([`Dct::single`]).
    single: Option<Box<Makhoul<f32>>>,
    s0: f64,
    sk: f64,
    /// cos(π j / 2n), j < 4n: basis entries are table lookups (dense bases are built often).
    cos_table: Vec<f64>,
    /// ⌊(2⁶⁴ - 1) / 4n⌋: Barrett reduction of the table index (a hardware division per entry
    /// was most of the cost of building an m x m basis).
    barrett: u64,
}

/// Plans kept per thread by [`Dct::with_cached`]: a campaign reconstructs its axes and directions
/// on the same grid, and `bench speed` repeats one n, so a plan outlives one solve.
const PLAN_CACHE: usize = 4;

thread_local! {
    static PLANS: std::cell::RefCell<Vec<Dct>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl Dct {
    /// Runs `f` with this thread's plan for length n, planned on first use and kept for the
    /// next call (the `PLAN_CACHE` most recently used lengths). Planning costs ~0.5 ms at
    /// n = 1901, 7 % of a basis pursuit solve at m = 600.
    pub fn with_cached<R>(n: usize, f: impl FnOnce(&mut Dct) -> R) -> R {
        // Taken out of the cache while in use, so that a nested call plans its own.
        let cached = PLANS.with(|p| {
            let mut p = p.borrow_mut();
            p.iter().position(|d| d.n == n).map(|i| p.remove(i))
        });
        let mut dct = cached.unwrap_or_else(|| Dct::new(n));
        let out = f(&mut dct);
        PLANS.with(|p| {
            let mut p = p.borrow_mut();
            // One plan per length (a nested call may have put one back meanwhile).
            p.retain(|d| d.n != n);
            if p.len() >= PLAN_CACHE {
                p.remove(0);
            }
            p.push(dct);
        });
        out
    }

    pub fn new(n: usize) -> Self {
        Self::with_backend(n, (n.is_multiple_of(2) && n >= 2) || bluestein_pays_off(n))
    }

    /// `makhoul`: the real-FFT path (any n ≥ 2; [`Dct::new`] takes it for even n, where the real
    /// FFT is half a complex one, and where [`bluestein_pays_off`]); otherwise rustdct.
    pub fn with_backend(n: usize, makhoul: bool) -> Self {
        let backend = if makhoul && n >= 2 {
            Backend::Makhoul(Box::new(Makhoul::new(n)))
        } else {
            let plan = DctPlanner::new().plan_dct2(n);
            let scratch = vec![0.0; plan.get_scratch_len()];
            Backend::Rustdct { plan, scratch }
        };
        let nf = n as f64;
        let cos_table = (0..4 * n)
            .map(|j| (std::f64::consts::PI * j as f64 / (2.0 * nf)).cos())
            .collect();
        Self {
            n,
            backend,
            single: None,
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

    /// The transform in single precision (n ≥ 2): for iterations whose result is only a ranking.
    pub fn single(&mut self) -> &mut Makhoul<f32> {
        let n = self.n;
        self.single.get_or_insert_with(|| Box::new(Makhoul::new(n)))
    }

    /// θ = Ψᵀ g (in place): coefficients of a signal.
    pub fn forward(&mut self, buf: &mut [f64]) {
        let (s0, sk) = (self.s0, self.sk);
        match &mut self.backend {
            Backend::Rustdct { plan, scratch } => {
                plan.process_dct2_with_scratch(buf, scratch);
                buf[0] *= s0;
                for v in &mut buf[1..] {
                    *v *= sk;
                }
            }
            Backend::Makhoul(t) => t.forward(buf),
        }
    }

    /// g = Ψ θ (in place): the signal of coefficients.
    pub fn inverse(&mut self, buf: &mut [f64]) {
        let (s0, sk) = (self.s0, self.sk);
        match &mut self.backend {
            Backend::Rustdct { plan, scratch } => {
                // rustdct's DCT-III is x_n = X_0/2 + Σ X_k cos(..): fold the orthonormal weights in.
                buf[0] *= 2.0 * s0;
                for v in &mut buf[1..] {
                    *v *= sk;
                }
                plan.process_dct3_with_scratch(buf, scratch);
            }
            Backend::Makhoul(t) => t.inverse(buf),
        }
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

    /// A·v for the sampled transform A = rows `idx` of Ψ: the signal of `v` at `idx`
    /// (`v` is transformed in place on the way).
    pub fn sample(&mut self, v: &mut [f64], idx: &[usize]) -> Vec<f64> {
        self.inverse(v);
        idx.iter().map(|&i| v[i]).collect()
    }

    /// w = Aᵀy for the sampled transform A = rows `idx` of Ψ: Ψᵀ of y scattered onto `idx`
    /// (`y(r)` is the r-th entry, so any vector type serves).
    pub fn adjoint(&mut self, idx: &[usize], y: impl Fn(usize) -> f64, w: &mut [f64]) {
        w.fill(0.0);
        for (r, &i) in idx.iter().enumerate() {
            w[i] = y(r);
        }
        self.forward(w);
    }

    /// Columns `cols` (distinct) of Ψ at `rows` in single precision, column c into `out[c]`
    /// (each at least rows.len() long), for single-precision factors. The
    /// Chebyshev recurrence cos((k+1)φ) = 2 cos φ cos kφ − cos((k−1)φ) runs over k ≤ max(cols)
    /// for blocks of 16 rows at a time (independent lanes the compiler vectorises), instead of a
    /// table lookup per entry. Its rounding grows as ~k²ε (≤ 2e-10 at n = 1901), far below f32's.
    pub fn basis_block_f32(&self, rows: &[usize], cols: &[usize], out: &mut [&mut [f32]]) {
        let Some(&kmax) = cols.iter().max() else {
            return;
        };
        assert!(out.len() == cols.len() && out.iter().all(|c| c.len() >= rows.len()));
        let mut at = vec![u32::MAX; kmax + 1];
        for (c, &k) in cols.iter().enumerate() {
            at[k] = c as u32;
        }
        let nf = self.n as f64;
        let (w0, wk) = (self.s0, self.sk);
        for r0 in (0..rows.len()).step_by(CHEB_ROWS) {
            let len = CHEB_ROWS.min(rows.len() - r0);
            let mut x2 = [0.0; CHEB_ROWS];
            for (x, &i) in x2.iter_mut().zip(&rows[r0..r0 + len]) {
                *x = 2.0 * (std::f64::consts::PI * (2 * i + 1) as f64 / (2.0 * nf)).cos();
            }
            chebyshev_rows(&x2, &at, (w0, wk), out, r0, len);
        }
    }

    /// Column k of Ψ at the given rows: `out[r] = Ψ[rows[r], k]`.
    pub fn basis_column(&self, k: usize, rows: &[usize], out: &mut [f64]) {
        if k == 0 {
            out.fill(self.s0);
            return;
        }
        let (p, k) = (4 * self.n as u64, k as u64);
        for (o, &i) in out.iter_mut().zip(rows) {
            let a = k * (2 * i as u64 + 1);
            // q undershoots a / p by at most 2: two corrections, branch-free (a loop here
            // mispredicted on every other entry, ~1/3 of the cost of building a basis).
            let q = ((a as u128 * self.barrett as u128) >> 64) as u64;
            let mut j = a - q * p;
            j -= if j >= p { p } else { 0 };
            j -= if j >= p { p } else { 0 };
            *o = self.sk * self.cos_table[j as usize];
        }
    }
}

/// Rows per register block of [`Dct::basis_block_f32`].
const CHEB_ROWS: usize = 16;

/// The recurrence for one block of rows (x2 = 2 cos φ per row), writing column `at[k]` of `out`
/// at each k that has one.
fn chebyshev_rows(
    x2: &[f64; CHEB_ROWS],
    at: &[u32],
    (w0, wk): (f64, f64),
    out: &mut [&mut [f32]],
    r0: usize,
    len: usize,
) {
    let mut prev = [1.0; CHEB_ROWS];
    let mut cur = [0.0; CHEB_ROWS];
    for (c, x) in cur.iter_mut().zip(x2) {
        *c = 0.5 * x;
    }
    for (k, &col) in at.iter().enumerate() {
        if col != u32::MAX {
            let (src, w) = if k == 0 { (&prev, w0) } else { (&cur, wk) };
            let dst = &mut out[col as usize][r0..r0 + len];
            for (d, v) in dst.iter_mut().zip(src) {
                *d = (w * v) as f32;
            }
        }
        if k >= 1 {
            for j in 0..CHEB_ROWS {
                let t = x2[j] * cur[j] - prev[j];
                prev[j] = cur[j];
                cur[j] = t;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A length's plan (with what it planned lazily) serves the next call on the thread, and a
    /// long-running service holds at most [`PLAN_CACHE`] lengths.
    #[test]
    fn plans_are_reused_and_the_cache_is_bounded() {
        Dct::with_cached(97, |d| {
            d.single();
        });
        Dct::with_cached(97, |d| assert!(d.single.is_some(), "plan reused"));
        // A nested call for the same length cannot share the plan in use: it plans its own.
        Dct::with_cached(97, |_| {
            Dct::with_cached(97, |d| assert!(d.single.is_none()))
        });
        PLANS.with(|p| assert_eq!(p.borrow().iter().filter(|d| d.n == 97).count(), 1));
        for n in 98..98 + PLAN_CACHE {
            Dct::with_cached(n, |_| ());
        }
        PLANS.with(|p| assert_eq!(p.borrow().len(), PLAN_CACHE));
        Dct::with_cached(97, |d| assert!(d.single.is_none(), "oldest length evicted"));
    }

    #[test]
    fn transform_pair_is_orthonormal_and_matches_the_basis() {
        for &n in &[7usize, 64, 1900, 1901] {
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

    /// Bluestein's path is taken at odd lengths with a prime factor of 64 or more (the paper's
    /// prime 1901, 381 = 3·127), and not where rustfft's radices serve.
    #[test]
    fn bluestein_where_a_large_prime_factor_is() {
        for n in [1901usize, 383, 381, 127 * 5] {
            assert!(bluestein_pays_off(n), "{n}");
            assert!(matches!(
                Makhoul::<f32>::new(n).fft,
                RealFft::Bluestein { .. }
            ));
        }
        for n in [2usize, 3, 61, 1900, 2048, 1875, 2 * 1901, 65_536] {
            assert!(!bluestein_pays_off(n), "{n}");
        }
    }

    /// Both backends compute the same transform pair (the even-length path against rustdct).
    #[test]
    fn makhoul_matches_rustdct() {
        for &n in &[2usize, 3, 4, 6, 7, 9, 17, 33, 35, 64, 381, 1900, 1901, 4096] {
            let mut a = Dct::with_backend(n, true);
            let mut b = Dct::with_backend(n, false);
            assert!(matches!(a.backend, Backend::Makhoul(_)));
            let x: Vec<f64> = (0..n).map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.1).collect();
            let (mut fa, mut fb) = (x.clone(), x.clone());
            a.forward(&mut fa);
            b.forward(&mut fb);
            let (mut ia, mut ib) = (x.clone(), x.clone());
            a.inverse(&mut ia);
            b.inverse(&mut ib);
            for k in 0..n {
                assert!((fa[k] - fb[k]).abs() < 1e-12, "forward n={n} k={k}");
                assert!((ia[k] - ib[k]).abs() < 1e-12, "inverse n={n} k={k}");
            }
        }
    }

    /// The f32 transform (the ranking's) is the same transform to single precision.
    #[test]
    fn single_precision_matches() {
        for &n in &[7usize, 64, 1900, 1901] {
            let mut d = Dct::new(n);
            let x: Vec<f64> = (0..n).map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.1).collect();
            let (mut f, mut g) = (x.clone(), x.clone());
            d.forward(&mut f);
            d.inverse(&mut g);
            let (mut fs, mut gs): (Vec<f32>, Vec<f32>) = (
                x.iter().map(|&v| v as f32).collect(),
                x.iter().map(|&v| v as f32).collect(),
            );
            d.single().forward(&mut fs);
            d.single().inverse(&mut gs);
            for k in 0..n {
                assert!((fs[k] as f64 - f[k]).abs() < 1e-5, "forward n={n} k={k}");
                assert!((gs[k] as f64 - g[k]).abs() < 1e-5, "inverse n={n} k={k}");
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

    /// The single-precision block (Chebyshev recurrence, full blocks of 16 rows and the
    /// tail) equals the exact columns to f32 rounding, in the caller's column order, at the
    /// paper's n with a row count that is not a multiple of 16 and k from 0 to n − 1.
    #[test]
    fn basis_block_f32_matches_the_columns() {
        let n = 1901;
        let d = Dct::new(n);
        let rows: Vec<usize> = (0..n)
            .filter(|i| i % 7 == 3 || *i == 0 || *i == n - 1)
            .collect();
        assert!(!rows.len().is_multiple_of(16));
        let cols = [n - 1, 0, 1, 950, 17, 1900 - 64, 2, 1234];
        let mut block = vec![vec![f32::NAN; rows.len()]; cols.len()];
        let mut out: Vec<&mut [f32]> = block.iter_mut().map(|c| c.as_mut_slice()).collect();
        d.basis_block_f32(&rows, &cols, &mut out);
        let mut col = vec![0.0; rows.len()];
        for (c, &k) in cols.iter().enumerate() {
            d.basis_column(k, &rows, &mut col);
            for (r, (&got, &want)) in block[c].iter().zip(&col).enumerate() {
                assert!(
                    (f64::from(got) - want).abs() < 1e-8,
                    "k={k} row {}: {got} vs {want}",
                    rows[r]
                );
            }
        }
    }
}
