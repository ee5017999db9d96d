//! Orthonormal DCT pair: Ψ (inverse, DCT-III) and Ψᵀ (forward, DCT-II).
//!
//! With this scaling Ψ is orthogonal, so a sampled Ψ has orthonormal rows (A·Aᵀ = I): the
//! structure the fast basis-pursuit solver relies on.
//!
//! Even lengths use Makhoul's algorithm on a real FFT of length n (realfft: one complex FFT of
//! n/2 on rustfft's SIMD kernels), 1.7-1.8x faster than rustdct at 1900, 2048 and 65 536
//! (`cargo run --release -- bench dct`, BENCHMARKS.md). Prime lengths ≥ 64 (the paper's n = 1901)
//! take the same path with the real FFT done by Rader's algorithm ([`super::rader`]), 2.2x faster
//! than rustdct at 1901; other odd lengths go through rustdct (there the real FFT is a full
//! complex one and the two paths tie).
use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustdct::{DctPlanner, TransformType2And3};
use rustfft::FftNum;

use super::fused::RaderAdmm;
use super::rader::RaderReal;

/// A real FFT pair of length n: realfft's plans, or Rader's algorithm for a prime n.
enum RealPair<T: FftNum> {
    Plans {
        r2c: Arc<dyn RealToComplex<T>>,
        c2r: Arc<dyn ComplexToReal<T>>,
    },
    Rader(Box<RaderReal<T>>),
}

/// Makhoul's input order: v_j = x_(order[j]), the even indices ascending, then the odd ones
/// descending.
pub(super) fn makhoul_order(n: usize) -> Vec<usize> {
    let h = n.div_ceil(2);
    (0..n)
        .map(|j| if j < h { 2 * j } else { 2 * (n - 1 - j) + 1 })
        .collect()
}

impl<T: FftNum> RealPair<T> {
    fn new(n: usize) -> Self {
        // Rader's tables absorb Makhoul's permutation v_j = g_(2j) (j < ⌈n/2⌉),
        // g_(2(n−1−j)+1) (the rest).
        if super::rader::pays_off(n) {
            if let Some(r) = RaderReal::with_permutation(n, &makhoul_order(n)) {
                return RealPair::Rader(Box::new(r));
            }
        }
        let mut planner = RealFftPlanner::<T>::new();
        RealPair::Plans {
            r2c: planner.plan_fft_forward(n),
            c2r: planner.plan_fft_inverse(n),
        }
    }

    fn scratch_len(&self) -> usize {
        match self {
            RealPair::Plans { r2c, c2r } => r2c.get_scratch_len().max(c2r.get_scratch_len()),
            RealPair::Rader(_) => 0,
        }
    }
}

fn real<T: FftNum>(v: f64) -> T {
    T::from_f64(v).unwrap_or_else(T::zero)
}

/// Makhoul's permutation and twiddle passes around the real FFT (n = buf.len() throughout). The
/// provided bodies are the scalar loops ([`scalar`]); f64 (BPDN, BP above the exact finish's m,
/// every f64 transform) runs them in AVX2 where the CPU has it: the compiled loops stayed scalar
/// (the crate's baseline is SSE2) and were 25-28 % of an n = 65 536 BP solve.
pub trait Passes: FftNum {
    /// v = the evens of buf forward, then its odds backward.
    fn split_even_odd(buf: &[Self], v: &mut [Self]) {
        scalar::split_from(buf, v, 0)
    }

    /// The inverse of [`Passes::split_even_odd`].
    fn merge_even_odd(v: &[Self], buf: &mut [Self]) {
        scalar::merge_from(v, buf, 0)
    }

    /// For 1 ≤ k < ⌈n/2⌉ with (a, b) = spec_k and (c, s) = w_k: buf[k] = sk·(ac + bs),
    /// buf[n − k] = sk·(as − bc).
    fn untwiddle(spec: &[Complex<Self>], w: &[Complex<Self>], sk: Self, buf: &mut [Self]) {
        scalar::untwiddle_from(spec, w, sk, buf, 1)
    }

    /// For 1 ≤ k < ⌈n/2⌉: spec_k = (x + iy)·w_k with x = ak·buf[k], y = −ak·buf[n − k].
    fn twiddle_in(buf: &[Self], w: &[Complex<Self>], ak: Self, spec: &mut [Complex<Self>]) {
        scalar::twiddle_in_from(buf, w, ak, spec, 1)
    }
}

impl Passes for f32 {}

/// Where the AVX2 kernel `avx2::$f` stopped (it does whole blocks only), or `None` where the CPU
/// lacks AVX2 and FMA: the scalar loop takes over from there.
macro_rules! avx2_prefix {
    ($f:ident($($a:expr),*)) => {{
        #[cfg(target_arch = "x86_64")]
        let done = super::simd::has_avx2_fma()
            // SAFETY: AVX2 and FMA are present (checked).
            .then(|| unsafe { avx2::$f($($a),*) });
        #[cfg(not(target_arch = "x86_64"))]
        let done: Option<usize> = None;
        done
    }};
}

/// The f64 passes in AVX2 when the CPU has it, each entry rounded as in the scalar loop (unfused).
impl Passes for f64 {
    fn split_even_odd(buf: &[f64], v: &mut [f64]) {
        let j0 = avx2_prefix!(split_even_odd(buf, v)).unwrap_or(0);
        scalar::split_from(buf, v, j0)
    }

    fn merge_even_odd(v: &[f64], buf: &mut [f64]) {
        let j0 = avx2_prefix!(merge_even_odd(v, buf)).unwrap_or(0);
        scalar::merge_from(v, buf, j0)
    }

    fn untwiddle(spec: &[Complex<f64>], w: &[Complex<f64>], sk: f64, buf: &mut [f64]) {
        let k0 = avx2_prefix!(untwiddle(spec, w, sk, buf)).unwrap_or(1);
        scalar::untwiddle_from(spec, w, sk, buf, k0)
    }

    fn twiddle_in(buf: &[f64], w: &[Complex<f64>], ak: f64, spec: &mut [Complex<f64>]) {
        let k0 = avx2_prefix!(twiddle_in(buf, w, ak, spec)).unwrap_or(1);
        scalar::twiddle_in_from(buf, w, ak, spec, k0)
    }
}

/// The passes' scalar loops from pair j0 (frequency k0) on: the definitions, which [`avx2`] must
/// match bit for bit, and the vector loops' tails.
mod scalar {
    use realfft::num_complex::Complex;
    use rustfft::FftNum;

    pub fn split_from<T: FftNum>(buf: &[T], v: &mut [T], j0: usize) {
        let n = buf.len();
        for j in j0..n.div_ceil(2) {
            v[j] = buf[2 * j];
        }
        for j in j0..n / 2 {
            v[n - 1 - j] = buf[2 * j + 1];
        }
    }

    pub fn merge_from<T: FftNum>(v: &[T], buf: &mut [T], j0: usize) {
        let n = buf.len();
        for j in j0..n.div_ceil(2) {
            buf[2 * j] = v[j];
        }
        for j in j0..n / 2 {
            buf[2 * j + 1] = v[n - 1 - j];
        }
    }

    pub fn untwiddle_from<T: FftNum>(
        spec: &[Complex<T>],
        w: &[Complex<T>],
        sk: T,
        buf: &mut [T],
        k0: usize,
    ) {
        let n = buf.len();
        for k in k0..n.div_ceil(2) {
            let (c, s) = (w[k].re, w[k].im);
            let (a, b) = (spec[k].re, spec[k].im);
            buf[k] = sk * (a * c + b * s);
            buf[n - k] = sk * (a * s - b * c);
        }
    }

    pub fn twiddle_in_from<T: FftNum>(
        buf: &[T],
        w: &[Complex<T>],
        ak: T,
        spec: &mut [Complex<T>],
        k0: usize,
    ) {
        let n = buf.len();
        for k in k0..n.div_ceil(2) {
            let (c, s) = (w[k].re, w[k].im);
            let (x, y) = (ak * buf[k], T::zero() - ak * buf[n - k]);
            spec[k] = Complex::new(x * c - y * s, x * s + y * c);
        }
    }
}

/// The f64 passes in AVX2, 4 entries (pairs, frequencies) at a time; each returns the pair or
/// frequency where its whole blocks end, for [`scalar`] to finish.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use realfft::num_complex::Complex;

    /// (re, im) of 4 complex f64 at p (Complex is repr(C): re then im).
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn load_split(p: *const Complex<f64>) -> (__m256d, __m256d) {
        let x = _mm256_loadu_pd(p as *const f64);
        let y = _mm256_loadu_pd((p as *const f64).add(4));
        (
            _mm256_permute4x64_pd::<0xD8>(_mm256_unpacklo_pd(x, y)),
            _mm256_permute4x64_pd::<0xD8>(_mm256_unpackhi_pd(x, y)),
        )
    }

    /// 4 entries in reverse order.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn rev(v: __m256d) -> __m256d {
        _mm256_permute4x64_pd::<0x1B>(v)
    }

    #[target_feature(enable = "avx2")]
    pub unsafe fn split_even_odd(buf: &[f64], v: &mut [f64]) -> usize {
        let n = buf.len();
        assert!(v.len() == n);
        let (b, o) = (buf.as_ptr(), v.as_mut_ptr());
        // Pairs j = 4i..4i + 3 from buf[8i..8i + 8]: evens to v[4i..], odds to v[n − 4 − 4i..]
        // reversed.
        let blocks = n / 8;
        for i in 0..blocks {
            let x = _mm256_loadu_pd(b.add(8 * i));
            let y = _mm256_loadu_pd(b.add(8 * i + 4));
            // unpacklo: (x0, y0, x2, y2) → (x0, x2, y0, y2); unpackhi: (x1, y1, x3, y3) →
            // reversed odds (y3, y1, x3, x1).
            let ev = _mm256_permute4x64_pd::<0xD8>(_mm256_unpacklo_pd(x, y));
            let od = _mm256_permute4x64_pd::<0x27>(_mm256_unpackhi_pd(x, y));
            _mm256_storeu_pd(o.add(4 * i), ev);
            _mm256_storeu_pd(o.add(n - 4 - 4 * i), od);
        }
        4 * blocks
    }

    #[target_feature(enable = "avx2")]
    pub unsafe fn merge_even_odd(v: &[f64], buf: &mut [f64]) -> usize {
        let n = buf.len();
        assert!(v.len() == n);
        let (s, o) = (v.as_ptr(), buf.as_mut_ptr());
        let blocks = n / 8;
        for i in 0..blocks {
            let ev = _mm256_loadu_pd(s.add(4 * i));
            let od = rev(_mm256_loadu_pd(s.add(n - 4 - 4 * i)));
            let lo = _mm256_unpacklo_pd(ev, od);
            let hi = _mm256_unpackhi_pd(ev, od);
            _mm256_storeu_pd(o.add(8 * i), _mm256_permute2f128_pd::<0x20>(lo, hi));
            _mm256_storeu_pd(o.add(8 * i + 4), _mm256_permute2f128_pd::<0x31>(lo, hi));
        }
        4 * blocks
    }

    #[target_feature(enable = "avx2")]
    pub unsafe fn untwiddle(
        spec: &[Complex<f64>],
        w: &[Complex<f64>],
        sk: f64,
        buf: &mut [f64],
    ) -> usize {
        let n = buf.len();
        let h = n.div_ceil(2);
        assert!(spec.len() >= h && w.len() >= h);
        let skv = _mm256_set1_pd(sk);
        let o = buf.as_mut_ptr();
        let mut k = 1;
        // Frequencies k..k + 3 < h; their mirrors n − k − 3..=n − k lie at or above h.
        while k + 4 <= h {
            let (a, b) = load_split(spec.as_ptr().add(k));
            let (c, s) = load_split(w.as_ptr().add(k));
            let d = _mm256_mul_pd(skv, _mm256_add_pd(_mm256_mul_pd(a, c), _mm256_mul_pd(b, s)));
            let e = _mm256_mul_pd(skv, _mm256_sub_pd(_mm256_mul_pd(a, s), _mm256_mul_pd(b, c)));
            _mm256_storeu_pd(o.add(k), d);
            _mm256_storeu_pd(o.add(n - k - 3), rev(e));
            k += 4;
        }
        k
    }

    #[target_feature(enable = "avx2")]
    pub unsafe fn twiddle_in(
        buf: &[f64],
        w: &[Complex<f64>],
        ak: f64,
        spec: &mut [Complex<f64>],
    ) -> usize {
        let n = buf.len();
        let h = n.div_ceil(2);
        assert!(spec.len() >= h && w.len() >= h);
        let akv = _mm256_set1_pd(ak);
        let zero = _mm256_setzero_pd();
        let (b, o) = (buf.as_ptr(), spec.as_mut_ptr() as *mut f64);
        let mut k = 1;
        while k + 4 <= h {
            let (c, s) = load_split(w.as_ptr().add(k));
            let x = _mm256_mul_pd(akv, _mm256_loadu_pd(b.add(k)));
            let y = _mm256_sub_pd(
                zero,
                _mm256_mul_pd(akv, rev(_mm256_loadu_pd(b.add(n - k - 3)))),
            );
            let re = _mm256_sub_pd(_mm256_mul_pd(x, c), _mm256_mul_pd(y, s));
            let im = _mm256_add_pd(_mm256_mul_pd(x, s), _mm256_mul_pd(y, c));
            let lo = _mm256_unpacklo_pd(re, im);
            let hi = _mm256_unpackhi_pd(re, im);
            _mm256_storeu_pd(o.add(2 * k), _mm256_permute2f128_pd::<0x20>(lo, hi));
            _mm256_storeu_pd(o.add(2 * k + 4), _mm256_permute2f128_pd::<0x31>(lo, hi));
            k += 4;
        }
        k
    }
}

/// Orthonormal DCT pair of any length n ≥ 2 by Makhoul's algorithm on a real FFT of length n:
/// v = (g₀, g₂, …, g₃, g₁) (evens up, odds down), X_k = Re(e^{-iπk/2n}·FFT(v)_k).
/// Generic so that the basis-pursuit ranking can run in f32 ([`Dct::single`]).
pub struct Makhoul<T: FftNum> {
    n: usize,
    fft: RealPair<T>,
    v: Vec<T>,
    spec: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
    /// e^(iπk/2n) for k ≤ n/2.
    twiddle: Vec<Complex<T>>,
    s0: T,
    sk: T,
}

impl<T: Passes> Makhoul<T> {
    pub fn new(n: usize) -> Self {
        let fft = RealPair::new(n);
        let len = fft.scratch_len();
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
        let (spec, twiddle) = (&mut self.spec, &self.twiddle);
        match &mut self.fft {
            // Makhoul's permutation is in Rader's tables: read the signal in place.
            RealPair::Rader(r) => r.forward(buf, spec),
            RealPair::Plans { r2c, .. } => {
                let v = &mut self.v;
                T::split_even_odd(buf, v);
                r2c.process_with_scratch(v, spec, &mut self.scratch)
                    .expect("buffer lengths fixed at planning");
            }
        }
        buf[0] = s0 * spec[0].re;
        T::untwiddle(spec, twiddle, sk, buf);
        if n % 2 == 0 {
            buf[n / 2] = sk * spec[n / 2].re * real::<T>(std::f64::consts::FRAC_1_SQRT_2);
        }
    }

    /// g = Ψ θ (in place).
    pub fn inverse(&mut self, buf: &mut [T]) {
        let (n, s0, sk) = (self.n, self.s0, self.sk);
        let spec = &mut self.spec;
        // The inverse of the forward map: with X = θ / c (unnormalized DCT-II values),
        // FFT(v)_k = e^{iπk/2n}(X_k - i X_{n-k}), Hermitian, so one inverse real FFT.
        let inv_n: T = real(1.0 / n as f64);
        let (a0, ak) = (inv_n / s0, inv_n / sk);
        spec[0] = Complex::new(a0 * buf[0], T::zero());
        T::twiddle_in(buf, &self.twiddle, ak, spec);
        if n % 2 == 0 {
            spec[n / 2] = Complex::new(
                ak * buf[n / 2] * real::<T>(std::f64::consts::SQRT_2),
                T::zero(),
            );
        }
        match &mut self.fft {
            RealPair::Rader(r) => r.inverse(spec, buf),
            RealPair::Plans { c2r, .. } => {
                let v = &mut self.v;
                c2r.process_with_scratch(spec, v, &mut self.scratch)
                    .expect("buffer lengths fixed at planning");
                T::merge_even_odd(v, buf);
            }
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
    /// BP's f32 ADMM in Rader's order, planned on first use ([`Dct::rader_admm`]).
    fused: Option<Box<RaderAdmm>>,
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
    /// next call (the [`PLAN_CACHE`] most recently used lengths). Planning costs ~0.5 ms at
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
        Self::with_backend(
            n,
            (n.is_multiple_of(2) && n >= 2) || super::rader::pays_off(n),
        )
    }

    /// `makhoul`: the real-FFT path (any n ≥ 2; [`Dct::new`] takes it for even n, where it is
    /// 1.7-1.8x faster, and for primes ≥ 64 through Rader, 2.2x); otherwise rustdct.
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
            fused: None,
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

    /// The f32 ranking ADMM in Rader's order, for the prime lengths that take Rader's transform
    /// (`None` otherwise).
    pub fn rader_admm(&mut self) -> Option<&mut RaderAdmm> {
        if self.fused.is_none() && super::rader::pays_off(self.n) {
            self.fused = RaderAdmm::new(self.n).map(Box::new);
        }
        self.fused.as_deref_mut()
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
    /// for blocks of 16 rows held in registers, instead of a table lookup per entry (a Barrett
    /// reduction and a gather: 0.55 → 0.12 ms for a 600 x 600 basis at n = 1901). Its rounding
    /// grows as ~k²ε (≤ 2e-10 at n = 1901), far below f32's.
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
            #[cfg(target_arch = "x86_64")]
            if len == CHEB_ROWS && super::simd::has_avx2_fma() {
                // SAFETY: AVX2 and FMA are present (checked), and every column of `out` holds
                // rows r0..r0 + 16 (asserted above).
                unsafe { chebyshev_rows_avx2(&x2, &at, (w0, wk), out, r0) };
                continue;
            }
            chebyshev_rows(&x2, &at, (w0, wk), out, r0, len);
        }
    }

    /// Column k of Ψ at the given rows: out[r] = Ψ[rows[r], k].
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

/// [`chebyshev_rows`] for a full block, in AVX2 registers (the compiler's own vectorisation of
/// it spilled the block to the stack at every step).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn chebyshev_rows_avx2(
    x2: &[f64; CHEB_ROWS],
    at: &[u32],
    (w0, wk): (f64, f64),
    out: &mut [&mut [f32]],
    r0: usize,
) {
    use std::arch::x86_64::*;
    let xp = x2.as_ptr();
    let x = [
        _mm256_loadu_pd(xp),
        _mm256_loadu_pd(xp.add(4)),
        _mm256_loadu_pd(xp.add(8)),
        _mm256_loadu_pd(xp.add(12)),
    ];
    let half = _mm256_set1_pd(0.5);
    let mut prev = [_mm256_set1_pd(1.0); 4];
    let mut cur = [
        _mm256_mul_pd(half, x[0]),
        _mm256_mul_pd(half, x[1]),
        _mm256_mul_pd(half, x[2]),
        _mm256_mul_pd(half, x[3]),
    ];
    for (k, &col) in at.iter().enumerate() {
        if col != u32::MAX {
            let (src, w) = if k == 0 { (prev, w0) } else { (cur, wk) };
            let w = _mm256_set1_pd(w);
            let dst = out[col as usize].as_mut_ptr().add(r0);
            for (q, v) in src.iter().enumerate() {
                _mm_storeu_ps(dst.add(4 * q), _mm256_cvtpd_ps(_mm256_mul_pd(w, *v)));
            }
        }
        if k >= 1 {
            for q in 0..4 {
                let t = _mm256_fmsub_pd(x[q], cur[q], prev[q]);
                prev[q] = cur[q];
                cur[q] = t;
            }
        }
    }
}

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

    /// The f64 passes (AVX2 where present) equal the scalar loops bit for bit at every remainder of
    /// their 4- and 8-entry blocks.
    #[test]
    fn f64_passes_match_the_scalar_loops() {
        for n in (2usize..48).chain([1900, 1901, 4096]) {
            let x: Vec<f64> = (0..n)
                .map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.1 + i as f64)
                .collect();
            let spec: Vec<Complex<f64>> = (0..=n / 2)
                .map(|k| Complex::new(x[k] * 0.3 - 1.0, x[n - 1 - k] * 0.7))
                .collect();
            let w: Vec<Complex<f64>> = (0..=n / 2)
                .map(|k| Complex::new((k as f64 * 0.1).cos(), (k as f64 * 0.1).sin()))
                .collect();
            let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
            <f64 as Passes>::split_even_odd(&x, &mut a);
            scalar::split_from(&x, &mut b, 0);
            assert_eq!(a, b, "split n={n}");
            <f64 as Passes>::merge_even_odd(&x, &mut a);
            scalar::merge_from(&x, &mut b, 0);
            assert_eq!(a, b, "merge n={n}");
            <f64 as Passes>::untwiddle(&spec, &w, 0.7, &mut a);
            scalar::untwiddle_from(&spec, &w, 0.7, &mut b, 1);
            assert_eq!(a, b, "untwiddle n={n}");
            let zero = Complex::new(0.0, 0.0);
            let (mut sa, mut sb) = (vec![zero; n / 2 + 1], vec![zero; n / 2 + 1]);
            <f64 as Passes>::twiddle_in(&x, &w, 0.3, &mut sa);
            scalar::twiddle_in_from(&x, &w, 0.3, &mut sb, 1);
            assert_eq!(sa, sb, "twiddle_in n={n}");
        }
    }

    /// Both backends compute the same transform pair (the even-length path against rustdct).
    #[test]
    fn makhoul_matches_rustdct() {
        for &n in &[2usize, 3, 4, 6, 7, 9, 17, 33, 35, 64, 1900, 1901, 4096] {
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

    /// The single-precision block (Chebyshev recurrence, AVX2 blocks of 16 rows and the portable
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
