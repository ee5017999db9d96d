//! Real DFT of prime length p by Rader's algorithm, for the DCT of prime-length grids (the paper's
//! 0:5:9500 µm grid has p = 1901 points).
//!
//! A prime length has no factorization for an FFT to exploit, and a real FFT of odd length is a
//! full complex FFT, so the DCT at p = 1901 cost 2.5x the DCT at 1900. Rader re-indexes the
//! non-zero frequencies by powers of a primitive root g, which turns the DFT into a cyclic
//! convolution of length p − 1 (1900 = 2²·5²·19, fast): one real and one complex FFT of length
//! p − 1 per direction, with the kernel's spectrum precomputed.
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

/// Forward (real → half spectrum) and inverse (half spectrum → real, unnormalized) DFT of prime
/// length p ≥ 3, with realfft's conventions: p real values ⇄ (p + 1) / 2 complex bins.
pub struct RaderReal<T: FftNum> {
    p: usize,
    /// in_idx[l] = g^(−l) mod p and out_idx[q] = g^q mod p, l, q < p − 1.
    in_idx: Vec<usize>,
    out_idx: Vec<usize>,
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

impl<T: FftNum> RaderReal<T> {
    /// `None` unless p is an odd prime.
    pub fn new(p: usize) -> Option<Self> {
        if p < 3 || !is_prime(p) {
            return None;
        }
        let m = p - 1;
        let g = primitive_root(p);
        let ginv = pow_mod(g as u64, (p - 2) as u64, p as u64) as usize;
        let (mut in_idx, mut out_idx) = (Vec::with_capacity(m), Vec::with_capacity(m));
        let (mut gi, mut go) = (1usize, 1usize);
        for _ in 0..m {
            in_idx.push(gi);
            out_idx.push(go);
            gi = gi * ginv % p;
            go = go * g % p;
        }
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
                    Complex::new(
                        T::from_f64(phi.cos() / m as f64).unwrap_or_else(T::zero),
                        T::from_f64(phi.sin() / m as f64).unwrap_or_else(T::zero),
                    )
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
        Some(Self {
            p,
            in_idx,
            out_idx,
            r2c,
            c2r,
            fft,
            ifft,
            kernel_fwd,
            kernel_inv,
            a: vec![T::zero(); m],
            half: vec![Complex::new(T::zero(), T::zero()); m / 2 + 1],
            work: vec![Complex::new(T::zero(), T::zero()); m],
            scratch: vec![Complex::new(T::zero(), T::zero()); scratch_len],
        })
    }

    pub fn len(&self) -> usize {
        self.p
    }

    pub fn is_empty(&self) -> bool {
        false
    }

    /// out[k] = Σ_j v_j e^(−2πijk/p), k ≤ (p − 1) / 2.
    pub fn forward(&mut self, v: &[T], out: &mut [Complex<T>]) {
        self.forward_with(|j| v[j], |k, c| out[k] = c);
    }

    /// [`Self::forward`] with the input read through `v(j)` and each bin k ≤ (p − 1) / 2 handed
    /// to `emit(k, V_k)`, so that a caller's permutations fuse with Rader's (one pass each way).
    pub fn forward_with(
        &mut self,
        v: impl Fn(usize) -> T,
        mut emit: impl FnMut(usize, Complex<T>),
    ) {
        let (p, m) = (self.p, self.p - 1);
        let v0 = v(0);
        let mut sum = v0;
        for (a, &j) in self.a.iter_mut().zip(&self.in_idx) {
            *a = v(j);
            sum = sum + *a;
        }
        // V_{g^q} = v₀ + Σ_l a_l b_{q−l}: the cyclic convolution through the FFT.
        self.r2c
            .process_with_scratch(&mut self.a, &mut self.half, &mut self.scratch)
            .expect("buffer lengths fixed at planning");
        let (lo, hi) = self.work.split_at_mut(m / 2 + 1);
        for ((w, s), k) in lo.iter_mut().zip(&self.half).zip(&self.kernel_fwd) {
            *w = *s * *k;
        }
        // Upper bins of a real sequence's spectrum: conjugates of the lower ones, mirrored.
        for (f, (w, k)) in hi.iter_mut().zip(&self.kernel_fwd[m / 2 + 1..]).enumerate() {
            *w = self.half[m / 2 - 1 - f].conj() * *k;
        }
        self.ifft
            .process_with_scratch(&mut self.work, &mut self.scratch);
        emit(0, Complex::new(sum, T::zero()));
        let h = (p - 1) / 2;
        for (c, &k) in self.work.iter().zip(&self.out_idx) {
            // V_{p−k} = conj(V_k): only the lower half is emitted.
            if k <= h {
                emit(k, Complex::new(v0 + c.re, c.im));
            }
        }
    }

    /// out[j] = Σ_k V_k e^(2πijk/p) over all p bins of the Hermitian spectrum whose lower half
    /// is `spec` (unnormalized, as realfft's inverse).
    pub fn inverse(&mut self, spec: &[Complex<T>], out: &mut [T]) {
        self.inverse_with(|k| spec[k], |j, x| out[j] = x);
    }

    /// [`Self::inverse`] with bin k ≤ (p − 1) / 2 read through `spec(k)` and each output handed to
    /// `emit(j, v_j)`.
    pub fn inverse_with(
        &mut self,
        spec: impl Fn(usize) -> Complex<T>,
        mut emit: impl FnMut(usize, T),
    ) {
        let (p, m) = (self.p, self.p - 1);
        let h = (p - 1) / 2;
        let v0 = spec(0).re;
        let mut sum = v0;
        for (w, &k) in self.work.iter_mut().zip(&self.in_idx) {
            *w = if k <= h { spec(k) } else { spec(p - k).conj() };
            // Each bin k ≥ 1 appears once in the lower half: Σ_{k≥1} V_k + conj = 2 Σ Re V_k.
            if k <= h {
                sum = sum + w.re + w.re;
            }
        }
        self.fft
            .process_with_scratch(&mut self.work, &mut self.scratch);
        for ((o, w), k) in self.half.iter_mut().zip(&self.work).zip(&self.kernel_inv) {
            *o = *w * *k;
        }
        // The convolution is real, so its spectrum is Hermitian: the end bins are real up to
        // rounding, which realfft requires exactly.
        self.half[0].im = T::zero();
        self.half[m / 2].im = T::zero();
        self.c2r
            .process_with_scratch(&mut self.half, &mut self.a, &mut self.scratch)
            .expect("buffer lengths fixed at planning");
        emit(0, sum);
        for (&c, &j) in self.a.iter().zip(&self.out_idx) {
            emit(j, v0 + c);
        }
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

    /// Both directions against the realfft plans of the same odd length.
    #[test]
    fn matches_realfft_at_prime_lengths() {
        for p in [3usize, 5, 7, 13, 101, 1901] {
            let mut rader = RaderReal::<f64>::new(p).unwrap();
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
                assert!((a - b).norm() < 1e-9, "forward p={p} k={k}: {a} vs {b}");
            }
            let mut spec = want.clone();
            spec[0].im = 0.0;
            let mut back = vec![0.0; p];
            rader.inverse(&want, &mut back);
            let mut expect = c2r.make_output_vec();
            c2r.process(&mut spec, &mut expect).unwrap();
            for (j, (a, b)) in back.iter().zip(&expect).enumerate() {
                assert!((a - b).abs() < 1e-9, "inverse p={p} j={j}: {a} vs {b}");
            }
        }
    }
}
