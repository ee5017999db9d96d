//! Real DFT of prime length p by Rader's algorithm, for the DCT of prime-length grids (the paper's
//! 0:5:9500 µm grid has p = 1901 points).
//!
//! A prime length has no factorization for an FFT to exploit, and a real FFT of odd length is a
//! full complex FFT, so the DCT at p = 1901 cost 2.5x the DCT at 1900. Rader re-indexes the
//! non-zero frequencies by powers of a primitive root g, which turns the DFT into a cyclic
//! convolution of length p − 1 (1900 = 2²·5²·19, fast), with the kernel's spectrum precomputed.
//! The convolution folds in half into two real convolutions of (p − 1)/2 points ([`Fold`]): in
//! f32 both run as one complex convolution zero-padded to a power of two ([`Padded`]; at 1901,
//! FFTs of 2048 instead of ones with the factor 19, which runs on a scalar butterfly), in f64 the
//! negacyclic half as a complex convolution of (p − 1)/4 ([`Halved`]). DCT pair at 1901
//! (`bench dct`): f64 47 → 32 µs, f32 36 → 21 µs.
use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftNum, FftPlanner};

/// Whether `p` is prime (trial division; p is a grid length).
pub fn is_prime(p: usize) -> bool {
    if p < 2 {
        return false;
    }
    let mut d = 2;
    while d * d <= p {
        if p.is_multiple_of(d) {
            return false;
        }
        d += 1;
    }
    true
}

/// Whether the DCT of length n should run on Rader's real FFT: n prime and not tiny (measured at
/// 1901: DCT pair 48 → 34 µs against rustdct; below ~64 the convolution's overhead dominates).
pub fn pays_off(n: usize) -> bool {
    n >= 64 && is_prime(n)
}

fn pow_mod(mut b: u64, mut e: u64, p: u64) -> u64 {
    let mut r = 1;
    b %= p;
    while e > 0 {
        if e & 1 == 1 {
            r = r * b % p;
        }
        b = b * b % p;
        e >>= 1;
    }
    r
}

/// The smallest primitive root modulo the prime p.
fn primitive_root(p: usize) -> usize {
    let m = p - 1;
    let mut factors = Vec::new();
    let (mut r, mut d) = (m, 2);
    while d * d <= r {
        if r.is_multiple_of(d) {
            factors.push(d);
            while r.is_multiple_of(d) {
                r /= d;
            }
        }
        d += 1;
    }
    if r > 1 {
        factors.push(r);
    }
    (2..p)
        .find(|&g| {
            factors
                .iter()
                .all(|&q| pow_mod(g as u64, (m / q) as u64, p as u64) != 1)
        })
        .unwrap_or(1)
}

/// Rader's index orders for the prime p with its smallest primitive root g: (g^(−l), g^l) mod p
/// for l < p − 1 (input order, output order).
pub(super) fn generator_orders(p: usize) -> (Vec<usize>, Vec<usize>) {
    let g = primitive_root(p);
    let ginv = pow_mod(g as u64, (p - 2) as u64, p as u64) as usize;
    let (mut in_idx, mut out_idx) = (Vec::with_capacity(p - 1), Vec::with_capacity(p - 1));
    let (mut gi, mut go) = (1usize, 1usize);
    for _ in 0..p - 1 {
        in_idx.push(gi);
        out_idx.push(go);
        gi = gi * ginv % p;
        go = go * g % p;
    }
    (in_idx, out_idx)
}

/// The folded kernel's phases 2π g^s / p, s < (p − 1)/2, from the output order.
pub(super) fn kernel_phases(p: usize, out_idx: &[usize]) -> Vec<f64> {
    out_idx[..(p - 1) / 2]
        .iter()
        .map(|&e| 2.0 * std::f64::consts::PI * e as f64 / p as f64)
        .collect()
}

/// Forward (real → half spectrum) and inverse (half spectrum → real, unnormalized) DFT of prime
/// length p ≥ 3, with realfft's conventions: p real values ⇄ (p + 1) / 2 complex bins.
pub struct RaderReal<T: FftNum> {
    /// Tables composed with the caller's permutation `perm` (v_j = src[perm[j]]; the inverse
    /// writes v_j to dst[perm[j]]), so that each pass is a plain gather or scatter:
    /// gather[l] = perm[g^(−l)], scatter[q] = perm[g^q] (l, q < p − 1), first = perm[0].
    gather: Vec<usize>,
    scatter: Vec<usize>,
    first: usize,
    /// Forward output: convolution entry q < (p − 1)/2 is bin k = g^q or its mirror p − k,
    /// whichever is ≤ (p − 1)/2: (bin, ±1 on the imaginary part).
    bins_out: Vec<(usize, i8)>,
    /// Inverse input: a_l = V_(g^(−l)) read from the lower half (bin, ±1 on the imaginary part).
    bins_in: Vec<(usize, i8)>,
    conv: Conv<T>,
}

/// The cyclic convolution with the kernel b_s = e^(−2πi g^s / p), s < p − 1.
enum Conv<T: FftNum> {
    Full(Box<Full<T>>),
    Folded(Box<dyn Fold<T>>),
}

/// Forms of the convolution.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Form {
    /// Length p − 1: the reference the tests compare the folded forms with.
    #[cfg_attr(not(test), allow(dead_code))]
    Full,
    /// Folded, the negacyclic half as a complex convolution of (p − 1)/4 ((p − 1)/2 even).
    Halved,
    /// Folded, both halves in one complex convolution zero-padded to a power of two.
    Padded,
}

/// The convolution folded in half: with H = (p − 1)/2, g^H = −1 for any odd prime, so the
/// kernel's cosine part c_s = cos(2π g^s / p) is H-periodic and its sine part d_s is
/// H-antiperiodic, and the length-(p − 1) complex convolution of real data becomes a real cyclic
/// one of length H with c and a real negacyclic one of length H with d. `convolve` takes
/// re ← re ⊛ c and im ← im ⊛ d, and returns Σ re of the input (a DC bin it computes anyway: the
/// sums Rader's transforms need come free).
trait Fold<T>: Send + Sync {
    fn bufs(&mut self) -> (&mut [T], &mut [T]);
    fn convolve(&mut self) -> T;
}

/// The convolution as it stands (the reference form): one real and one complex FFT of length
/// p − 1 per direction.
struct Full<T: FftNum> {
    r2c: Arc<dyn RealToComplex<T>>,
    c2r: Arc<dyn ComplexToReal<T>>,
    fft: Arc<dyn Fft<T>>,
    ifft: Arc<dyn Fft<T>>,
    /// DFT of b_l = e^(∓2πi g^l / p) over p − 1 points, divided by p − 1 (the inverse FFT's
    /// normalization folded in): forward and inverse kernels.
    kernel_fwd: Vec<Complex<T>>,
    kernel_inv: Vec<Complex<T>>,
    a: Vec<T>,
    half: Vec<Complex<T>>,
    work: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
}

/// The folded convolution for f32 ([`Halved`] for f64): both halves as one complex linear
/// convolution zero-padded to a power of two L ≥ 2H − 1: z = x + iy, Z = FFT(z),
/// W_q = Z_q·P_q + conj(Z_(L−q))·Q_q with P = (Ĉ + D̂)/2L, Q = (Ĉ − D̂)/2L the spectra of the
/// kernels extended cyclically (c) and anti-cyclically (d) over negative lags, w = IFFT(W):
/// Re w = x ⊛ c, Im w = y ⊛ d on the first H points. At 1901: two complex FFTs of 2048 (radix 2,
/// SIMD) per direction instead of FFTs of 950 and 475, whose factor 19 runs on a scalar
/// butterfly (39 % of a DCT pair). Measured at 1901 (`bench dct`): f32 pair 25.3 → 21.7 µs, but
/// f64 31.9 → 37.9 µs (f64 FFTs of 2048 are the slower part there).
pub(super) struct Padded<T: FftNum> {
    pub(super) h: usize,
    pub(super) fft: Arc<dyn Fft<T>>,
    pub(super) ifft: Arc<dyn Fft<T>>,
    pub(super) p: Vec<Complex<T>>,
    pub(super) q: Vec<Complex<T>>,
    /// The cyclic part's input and output (H reals), the negacyclic part's (H reals).
    pub(super) re: Vec<T>,
    pub(super) im: Vec<T>,
    pub(super) z: Vec<Complex<T>>,
    pub(super) w: Vec<Complex<T>>,
    pub(super) scratch: Vec<Complex<T>>,
}

/// The folded convolution for f64 ([`Padded`] for f32), H even (p ≡ 1 mod 4): the negacyclic
/// half is a complex cyclic convolution of length H/2 after the right-angle twist w^l,
/// w = e^(iπ/H) (t^H + 1 = (t^(H/2) − i)(t^(H/2) + i), and real data need only one factor). At
/// 1901: FFTs of 950 (real) and 475 (complex) instead of 1900 (real) and 1900 (complex).
struct Halved<T: FftNum> {
    h: usize,
    r2c: Arc<dyn RealToComplex<T>>,
    c2r: Arc<dyn ComplexToReal<T>>,
    fft: Arc<dyn Fft<T>>,
    ifft: Arc<dyn Fft<T>>,
    /// Spectrum of c over H points, divided by H.
    cyc: Vec<Complex<T>>,
    /// Spectrum of the twisted (d_l + i·d_(l+H/2))·w^l over H/2 points, divided by H/2.
    neg: Vec<Complex<T>>,
    /// w^l, l < H/2.
    twist: Vec<Complex<T>>,
    /// The cyclic part's input and output (H reals), the negacyclic part's (H reals).
    re: Vec<T>,
    im: Vec<T>,
    spec: Vec<Complex<T>>,
    z: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
}

fn cx<T: FftNum>(re: f64, im: f64) -> Complex<T> {
    Complex::new(
        T::from_f64(re).unwrap_or_else(T::zero),
        T::from_f64(im).unwrap_or_else(T::zero),
    )
}

impl<T: FftNum> Padded<T> {
    /// `phase[s]` = 2π g^s / p for s < H.
    pub(super) fn new(phase: &[f64]) -> Self {
        let h = phase.len();
        let l = (2 * h - 1).next_power_of_two();
        // The kernels over lags −(H−1)..H−1, negative lags wrapped to the top of the buffer.
        let mut planner64 = FftPlanner::<f64>::new();
        let f64fft = planner64.plan_fft_forward(l);
        let mut ct = vec![Complex::new(0.0, 0.0); l];
        let mut dt = vec![Complex::new(0.0, 0.0); l];
        for (j, &ph) in phase.iter().enumerate() {
            ct[j].re = ph.cos();
            dt[j].re = ph.sin();
            if j > 0 {
                ct[l - j].re = phase[h - j].cos();
                dt[l - j].re = -phase[h - j].sin();
            }
        }
        f64fft.process(&mut ct);
        f64fft.process(&mut dt);
        let norm = 1.0 / (2.0 * l as f64);
        let p = ct
            .iter()
            .zip(&dt)
            .map(|(c, d)| cx((c.re + d.re) * norm, (c.im + d.im) * norm))
            .collect();
        let q = ct
            .iter()
            .zip(&dt)
            .map(|(c, d)| cx((c.re - d.re) * norm, (c.im - d.im) * norm))
            .collect();
        let mut planner = FftPlanner::<T>::new();
        let (fft, ifft) = (planner.plan_fft_forward(l), planner.plan_fft_inverse(l));
        let scratch_len = fft
            .get_inplace_scratch_len()
            .max(ifft.get_inplace_scratch_len());
        Self {
            h,
            fft,
            ifft,
            p,
            q,
            re: vec![T::zero(); h],
            im: vec![T::zero(); h],
            z: vec![cx(0.0, 0.0); l],
            w: vec![cx(0.0, 0.0); l],
            scratch: vec![cx(0.0, 0.0); scratch_len],
        }
    }
}

impl<T: FftNum> Fold<T> for Padded<T> {
    fn bufs(&mut self) -> (&mut [T], &mut [T]) {
        (&mut self.re, &mut self.im)
    }

    fn convolve(&mut self) -> T {
        let (h, l) = (self.h, self.z.len());
        for ((z, &r), &i) in self.z.iter_mut().zip(&self.re).zip(&self.im) {
            *z = Complex::new(r, i);
        }
        self.z[h..].fill(Complex::new(T::zero(), T::zero()));
        self.fft
            .process_with_scratch(&mut self.z, &mut self.scratch);
        let dc = self.z[0].re;
        // Bin 0 apart: the loop over Z_(L−q) without a wrapped index vectorises (a masked index
        // in one loop made the f32 DCT pair 21 → 30 µs).
        self.w[0] = self.z[0] * self.p[0] + self.z[0].conj() * self.q[0];
        for k in 1..l {
            self.w[k] = self.z[k] * self.p[k] + self.z[l - k].conj() * self.q[k];
        }
        self.ifft
            .process_with_scratch(&mut self.w, &mut self.scratch);
        for ((w, r), i) in self.w.iter().zip(&mut self.re).zip(&mut self.im) {
            *r = w.re;
            *i = w.im;
        }
        dc
    }
}

impl<T: FftNum> Halved<T> {
    /// `phase[s]` = 2π g^s / p for s < H.
    fn new(phase: &[f64]) -> Self {
        let h = phase.len();
        let k = h / 2;
        let mut rp = RealFftPlanner::<T>::new();
        let (r2c, c2r) = (rp.plan_fft_forward(h), rp.plan_fft_inverse(h));
        let mut cp = FftPlanner::<T>::new();
        let (fft, ifft) = (cp.plan_fft_forward(k), cp.plan_fft_inverse(k));
        let scratch_len = [
            r2c.get_scratch_len(),
            c2r.get_scratch_len(),
            fft.get_inplace_scratch_len(),
            ifft.get_inplace_scratch_len(),
        ]
        .into_iter()
        .max()
        .unwrap_or(0);
        let mut scratch = vec![cx(0.0, 0.0); scratch_len];
        let mut c: Vec<T> = phase
            .iter()
            .map(|&f| T::from_f64(f.cos() / h as f64).unwrap_or_else(T::zero))
            .collect();
        let mut cyc = r2c.make_output_vec();
        r2c.process_with_scratch(&mut c, &mut cyc, &mut scratch)
            .expect("buffer lengths fixed at planning");
        let twist64: Vec<(f64, f64)> = (0..k)
            .map(|l| {
                let a = std::f64::consts::PI * l as f64 / h as f64;
                (a.cos(), a.sin())
            })
            .collect();
        let mut neg: Vec<Complex<T>> = (0..k)
            .map(|l| {
                let (d0, d1) = (phase[l].sin(), phase[l + k].sin());
                let (wc, ws) = twist64[l];
                cx(
                    (d0 * wc - d1 * ws) / k as f64,
                    (d0 * ws + d1 * wc) / k as f64,
                )
            })
            .collect();
        fft.process_with_scratch(&mut neg, &mut scratch);
        Self {
            h,
            r2c,
            c2r,
            fft,
            ifft,
            cyc,
            neg,
            twist: twist64.iter().map(|&(c, s)| cx(c, s)).collect(),
            re: vec![T::zero(); h],
            im: vec![T::zero(); h],
            spec: vec![cx(0.0, 0.0); h / 2 + 1],
            z: vec![cx(0.0, 0.0); k],
            scratch,
        }
    }
}

impl<T: FftNum> Fold<T> for Halved<T> {
    fn bufs(&mut self) -> (&mut [T], &mut [T]) {
        (&mut self.re, &mut self.im)
    }

    fn convolve(&mut self) -> T {
        let (h, k) = (self.h, self.h / 2);
        for (l, z) in self.z.iter_mut().enumerate() {
            *z = Complex::new(self.im[l], self.im[l + k]) * self.twist[l];
        }
        self.r2c
            .process_with_scratch(&mut self.re, &mut self.spec, &mut self.scratch)
            .expect("buffer lengths fixed at planning");
        let dc = self.spec[0].re;
        for (s, c) in self.spec.iter_mut().zip(&self.cyc) {
            *s = *s * *c;
        }
        // Both end bins of a real sequence's spectrum are real; realfft requires it exactly.
        self.spec[0].im = T::zero();
        self.spec[h / 2].im = T::zero();
        self.c2r
            .process_with_scratch(&mut self.spec, &mut self.re, &mut self.scratch)
            .expect("buffer lengths fixed at planning");
        self.fft
            .process_with_scratch(&mut self.z, &mut self.scratch);
        for (z, n) in self.z.iter_mut().zip(&self.neg) {
            *z = *z * *n;
        }
        self.ifft
            .process_with_scratch(&mut self.z, &mut self.scratch);
        for (l, z) in self.z.iter().enumerate() {
            let t = *z * self.twist[l].conj();
            self.im[l] = t.re;
            self.im[l + k] = t.im;
        }
        dc
    }
}

impl<T: FftNum> Full<T> {
    /// `out_idx[s]` = g^s mod p for s < p − 1.
    fn new(p: usize, out_idx: &[usize]) -> Self {
        let m = p - 1;
        let mut rp = RealFftPlanner::<T>::new();
        let r2c = rp.plan_fft_forward(m);
        let c2r = rp.plan_fft_inverse(m);
        let mut cp = FftPlanner::<T>::new();
        let fft = cp.plan_fft_forward(m);
        let ifft = cp.plan_fft_inverse(m);
        let kernel = |sign: f64| {
            let mut k: Vec<Complex<T>> = out_idx
                .iter()
                .map(|&e| {
                    let phi = sign * 2.0 * std::f64::consts::PI * e as f64 / p as f64;
                    cx(phi.cos() / m as f64, phi.sin() / m as f64)
                })
                .collect();
            fft.process(&mut k);
            k
        };
        let (kernel_fwd, kernel_inv) = (kernel(-1.0), kernel(1.0));
        let scratch_len = [
            r2c.get_scratch_len(),
            c2r.get_scratch_len(),
            fft.get_inplace_scratch_len(),
            ifft.get_inplace_scratch_len(),
        ]
        .into_iter()
        .max()
        .unwrap_or(0);
        Self {
            r2c,
            c2r,
            fft,
            ifft,
            kernel_fwd,
            kernel_inv,
            a: vec![T::zero(); m],
            half: vec![cx(0.0, 0.0); m / 2 + 1],
            work: vec![cx(0.0, 0.0); m],
            scratch: vec![cx(0.0, 0.0); scratch_len],
        }
    }
}

impl<T: FftNum> RaderReal<T> {
    /// `None` unless p is an odd prime.
    pub fn new(p: usize) -> Option<Self> {
        let id: Vec<usize> = (0..p).collect();
        Self::with_permutation(p, &id)
    }

    /// The transform of v_j = src[perm[j]] (and, inverse, v_j written to dst[perm[j]]).
    pub fn with_permutation(p: usize, perm: &[usize]) -> Option<Self> {
        Self::build(p, perm, None)
    }

    /// `form`: the convolution's form, or `None` for the fastest measured (tests take each).
    fn build(p: usize, perm: &[usize], form: Option<Form>) -> Option<Self> {
        if p < 3 || !is_prime(p) || perm.len() != p {
            return None;
        }
        let (in_idx, out_idx) = generator_orders(p);
        let h = (p - 1) / 2;
        // Measured at 1901: the padded form is the faster in f32, the halved one in f64.
        let form = form.unwrap_or(if std::mem::size_of::<T>() == 4 || !h.is_multiple_of(2) {
            Form::Padded
        } else {
            Form::Halved
        });
        let phase = kernel_phases(p, &out_idx);
        let conv = match form {
            Form::Full => Conv::Full(Box::new(Full::new(p, &out_idx))),
            Form::Padded => Conv::Folded(Box::new(Padded::new(&phase)) as Box<dyn Fold<T>>),
            Form::Halved if h.is_multiple_of(2) => Conv::Folded(Box::new(Halved::new(&phase))),
            Form::Halved => return None,
        };
        let half_bin = |k: usize| if k <= h { (k, 1i8) } else { (p - k, -1i8) };
        Some(Self {
            gather: in_idx.iter().map(|&j| perm[j]).collect(),
            scatter: out_idx.iter().map(|&j| perm[j]).collect(),
            first: perm[0],
            bins_out: out_idx[..h].iter().map(|&k| half_bin(k)).collect(),
            bins_in: in_idx.iter().map(|&k| half_bin(k)).collect(),
            conv,
        })
    }

    /// out[k] = Σ_j v_j e^(−2πijk/p), k ≤ (p − 1) / 2, for v_j = src[perm[j]].
    pub fn forward(&mut self, src: &[T], out: &mut [Complex<T>]) {
        let v0 = src[self.first];
        let sum;
        // V_{g^q} = v₀ + Σ_l a_l b_{q−l}, a_l = v_(g^(−l)): the cyclic convolution. Entries q and
        // q + (p−1)/2 are conjugate bins (g^((p−1)/2) = −1), so its first half fills the lower
        // half-spectrum exactly once.
        match &mut self.conv {
            Conv::Folded(f) => {
                // α = a_l + a_(l+H) meets c cyclically, β = a_l − a_(l+H) meets d negacyclically:
                // V = v₀ + (α ⊛ c) − i (β ⊛ d).
                let h = self.bins_out.len();
                let (lo, hi) = self.gather.split_at(h);
                let (re, im) = f.bufs();
                for (l, (&j0, &j1)) in lo.iter().zip(hi).enumerate() {
                    let (a0, a1) = (src[j0], src[j1]);
                    re[l] = a0 + a1;
                    im[l] = a0 - a1;
                }
                sum = v0 + f.convolve();
                let (re, im) = f.bufs();
                for ((&r, &i), &(k, sg)) in re.iter().zip(im.iter()).zip(&self.bins_out) {
                    let im = if sg > 0 { T::zero() - i } else { i };
                    out[k] = Complex::new(v0 + r, im);
                }
            }
            Conv::Full(f) => {
                let m = self.gather.len();
                for (a, &j) in f.a.iter_mut().zip(&self.gather) {
                    *a = src[j];
                }
                f.r2c
                    .process_with_scratch(&mut f.a, &mut f.half, &mut f.scratch)
                    .expect("buffer lengths fixed at planning");
                sum = v0 + f.half[0].re;
                let (lo, hi) = f.work.split_at_mut(m / 2 + 1);
                for ((w, s), k) in lo.iter_mut().zip(&f.half).zip(&f.kernel_fwd) {
                    *w = *s * *k;
                }
                // Upper bins of a real sequence's spectrum: conjugates of the lower ones, mirrored.
                for (i, (w, k)) in hi.iter_mut().zip(&f.kernel_fwd[m / 2 + 1..]).enumerate() {
                    *w = f.half[m / 2 - 1 - i].conj() * *k;
                }
                f.ifft.process_with_scratch(&mut f.work, &mut f.scratch);
                for (c, &(k, sg)) in f.work.iter().zip(&self.bins_out) {
                    let im = if sg > 0 { c.im } else { T::zero() - c.im };
                    out[k] = Complex::new(v0 + c.re, im);
                }
            }
        }
        out[0] = Complex::new(sum, T::zero());
    }

    /// dst[perm[j]] = Σ_k V_k e^(2πijk/p) over all p bins of the Hermitian spectrum whose lower
    /// half is `spec` (unnormalized, as realfft's inverse).
    pub fn inverse(&mut self, spec: &[Complex<T>], dst: &mut [T]) {
        let h = self.bins_out.len();
        let v0 = spec[0].re;
        // dst[first] = V₀ + 2 Σ_(k=1..h) Re V_k.
        let re_sum = match &mut self.conv {
            Conv::Folded(f) => {
                // A_l = V_(g^(−l)) = P_l + i Q_l with P H-periodic and Q H-antiperiodic:
                // v_(g^q) = V₀ + 2 (P ⊛ c)_q ∓ 2 (Q ⊛ d)_q for q and q + H.
                let (re, im) = f.bufs();
                for (l, &(k, sg)) in self.bins_in[..h].iter().enumerate() {
                    let s = spec[k];
                    re[l] = s.re;
                    im[l] = if sg > 0 { s.im } else { T::zero() - s.im };
                }
                let re_sum = f.convolve();
                let (re, im) = f.bufs();
                let (lo, hi) = self.scatter.split_at(h);
                for (((&r, &i), &j0), &j1) in re.iter().zip(im.iter()).zip(lo).zip(hi) {
                    let (r2, i2) = (r + r, i + i);
                    dst[j0] = v0 + r2 - i2;
                    dst[j1] = v0 + r2 + i2;
                }
                re_sum
            }
            Conv::Full(f) => {
                let m = self.gather.len();
                for (w, &(k, sg)) in f.work.iter_mut().zip(&self.bins_in) {
                    let s = spec[k];
                    *w = Complex::new(s.re, if sg > 0 { s.im } else { T::zero() - s.im });
                }
                f.fft.process_with_scratch(&mut f.work, &mut f.scratch);
                for ((o, w), k) in f.half.iter_mut().zip(&f.work).zip(&f.kernel_inv) {
                    *o = *w * *k;
                }
                // The convolution is real, so its spectrum is Hermitian: the end bins are real up
                // to rounding, which realfft requires exactly.
                f.half[0].im = T::zero();
                f.half[m / 2].im = T::zero();
                f.c2r
                    .process_with_scratch(&mut f.half, &mut f.a, &mut f.scratch)
                    .expect("buffer lengths fixed at planning");
                for (&c, &j) in f.a.iter().zip(&self.scatter) {
                    dst[j] = v0 + c;
                }
                spec[1..=h].iter().fold(T::zero(), |a, s| a + s.re)
            }
        };
        dst[self.first] = v0 + re_sum + re_sum;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitive_roots_generate_the_group() {
        for p in [3usize, 5, 7, 11, 13, 1901, 7919] {
            let g = primitive_root(p);
            let mut seen = vec![false; p];
            let mut x = 1;
            for _ in 0..p - 1 {
                assert!(!seen[x], "p={p} g={g}");
                seen[x] = true;
                x = x * g % p;
            }
        }
        assert!(!is_prime(1) && is_prime(2) && !is_prime(1900) && is_prime(1901));
    }

    /// Both directions, in every form of the convolution, against the realfft plans of the
    /// same odd length.
    #[test]
    fn matches_realfft_at_prime_lengths() {
        let cases = [3usize, 5, 7, 13, 17, 101, 383, 1901]
            .into_iter()
            .flat_map(|p| [(p, Form::Full), (p, Form::Halved), (p, Form::Padded)]);
        for (p, fold) in cases {
            let id: Vec<usize> = (0..p).collect();
            let Some(mut rader) = RaderReal::<f64>::build(p, &id, Some(fold)) else {
                assert!(fold == Form::Halved && p % 4 == 3, "p={p} {fold:?}");
                continue;
            };
            let mut planner = RealFftPlanner::<f64>::new();
            let (r2c, c2r) = (planner.plan_fft_forward(p), planner.plan_fft_inverse(p));
            let x: Vec<f64> = (0..p)
                .map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.1 + (i as f64).sin())
                .collect();
            let mut want = r2c.make_output_vec();
            r2c.process(&mut x.clone(), &mut want).unwrap();
            let mut got = vec![Complex::new(0.0, 0.0); p.div_ceil(2)];
            rader.forward(&x, &mut got);
            for (k, (a, b)) in got.iter().zip(&want).enumerate() {
                assert!(
                    (a - b).norm() < 1e-9,
                    "forward p={p} {fold:?} k={k}: {a} vs {b}"
                );
            }
            let mut spec = want.clone();
            spec[0].im = 0.0;
            let mut back = vec![0.0; p];
            rader.inverse(&want, &mut back);
            let mut expect = c2r.make_output_vec();
            c2r.process(&mut spec, &mut expect).unwrap();
            for (j, (a, b)) in back.iter().zip(&expect).enumerate() {
                assert!(
                    (a - b).abs() < 1e-9,
                    "inverse p={p} {fold:?} j={j}: {a} vs {b}"
                );
            }
        }
    }
}
