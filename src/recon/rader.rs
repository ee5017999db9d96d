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

/// Forward (real → half spectrum) and inverse (half spectrum → real, unnormalized) DFT of prime
/// length p ≥ 3, with realfft's conventions: p real values ⇄ (p + 1) / 2 complex bins.
pub struct RaderReal<T: FftNum> {
    p: usize,
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
        let id: Vec<usize> = (0..p).collect();
        Self::with_permutation(p, &id)
    }

    /// The transform of v_j = src[perm[j]] (and, inverse, v_j written to dst[perm[j]]).
    pub fn with_permutation(p: usize, perm: &[usize]) -> Option<Self> {
        if p < 3 || !is_prime(p) || perm.len() != p {
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
        let h = (p - 1) / 2;
        let half_bin = |k: usize| if k <= h { (k, 1i8) } else { (p - k, -1i8) };
        let bins_out = out_idx[..m / 2].iter().map(|&k| half_bin(k)).collect();
        let bins_in = in_idx.iter().map(|&k| half_bin(k)).collect();
        let gather = in_idx.iter().map(|&j| perm[j]).collect();
        let scatter = out_idx.iter().map(|&j| perm[j]).collect();
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
            gather,
            scatter,
            first: perm[0],
            bins_out,
            bins_in,
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

    /// out[k] = Σ_j v_j e^(−2πijk/p), k ≤ (p − 1) / 2, for v_j = src[perm[j]].
    pub fn forward(&mut self, src: &[T], out: &mut [Complex<T>]) {
        let m = self.p - 1;
        let v0 = src[self.first];
        let mut sum = v0;
        for (a, &j) in self.a.iter_mut().zip(&self.gather) {
            *a = src[j];
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
        out[0] = Complex::new(sum, T::zero());
        // g^(q + (p−1)/2) = −g^q: entries q and q + (p−1)/2 are conjugate bins, so the first
        // half of the convolution fills the lower half-spectrum exactly once.
        for (c, &(k, sg)) in self.work.iter().zip(&self.bins_out) {
            let im = if sg > 0 { c.im } else { T::zero() - c.im };
            out[k] = Complex::new(v0 + c.re, im);
        }
    }

    /// dst[perm[j]] = Σ_k V_k e^(2πijk/p) over all p bins of the Hermitian spectrum whose lower
    /// half is `spec` (unnormalized, as realfft's inverse).
    pub fn inverse(&mut self, spec: &[Complex<T>], dst: &mut [T]) {
        let (p, m) = (self.p, self.p - 1);
        let h = (p - 1) / 2;
        let v0 = spec[0].re;
        let mut re_sum = T::zero();
        for s in &spec[1..=h] {
            re_sum = re_sum + s.re;
        }
        for (w, &(k, sg)) in self.work.iter_mut().zip(&self.bins_in) {
            let s = spec[k];
            *w = Complex::new(s.re, if sg > 0 { s.im } else { T::zero() - s.im });
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
        dst[self.first] = v0 + re_sum + re_sum;
        for (&c, &j) in self.a.iter().zip(&self.scatter) {
            dst[j] = v0 + c;
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
