//! BP's f32 ranking ADMM for a prime n, on vectors kept in Rader's order.
//!
//! Each ADMM iteration projects onto {Aθ = h} with one DCT pair. Through [`super::dct::Makhoul`]
//! and [`super::rader::RaderReal`] that pair spends more time permuting than transforming: the
//! Makhoul and Rader index maps gather and scatter every entry four times, around four FFTs of
//! 2048 (measured at n = 1901: a 21 µs pair, 10 µs of it FFTs). The ADMM update is elementwise, so
//! it does not care in which order the coefficients are stored. Here they are stored in the order
//! the forward transform's folded convolution produces them (a coefficient pair k, n − k per
//! convolution output), and the signal is never formed at all: the forward convolution's input is
//! the inverse convolution's output, read backwards (a Rader input index is the negative of an
//! output index), plus the sample corrections h − g at the m sampled points. Every pass is then
//! sequential; only the m sample corrections are scattered. Measured at n = 1901 (`bench dct`): a
//! projection 16-17 µs against 21 µs for the f32 transform pair alone, and ~0.9 ms less per BP
//! solve at m = 600 (100 ranking iterations).
//!
//! On x86-64 with AVX-512F, or with AVX2 and FMA, the same projection runs on
//! [`super::split_fft`] with the buffers in split format (re and im arrays) and the spectra in
//! bit-reversed order: 9.5-9.6 µs on AVX-512 (~0.5 ms less per BP solve at m = 600); in AVX2 on
//! an AMD EPYC (Zen 3) ~0.2 ms less per solve than the AVX2 passes around rustfft's FFTs that
//! it replaced. Other CPUs, and primes below 19 (FFTs shorter than 32), take the portable path.
//!
//! Layout of a coefficient vector X (length n = 2H + 1): X[0] = θ₀, X[1 + l] = θ_(k_l),
//! X[1 + H + l] = θ_(n − k_l), where k_l ∈ 1..=H is the DCT frequency of forward output l.
use std::sync::Arc;

use realfft::num_complex::Complex;
use rustfft::Fft;

use super::dct::makhoul_order;
use super::rader::{generator_orders, is_prime, kernel_phases, Padded};

type C32 = Complex<f32>;

/// Where a sampled grid point sits in the inverse convolution's output.
#[derive(Clone, Copy)]
struct SamplePos {
    /// Inverse output index j (its value is V₀ + 2 Re W_j + `g_im`·Im W_j), or usize::MAX for
    /// grid point 0 (V₀ + 2·Σ).
    j: usize,
    g_im: f32,
    /// Forward input index l = −j mod H, and the sign with which a correction enters Im there.
    l: usize,
    f_im: f32,
}

/// The sampled grid points of a problem and their values, located for [`RaderAdmm::project`]:
/// one entry per sample, and spread over the forward inputs ([`ByInput`]).
pub struct Samples {
    pos: Vec<SamplePos>,
    /// The sample at grid point 0 (no Rader index), if any.
    zero: Option<usize>,
    by_input: ByInput,
    /// The values, in the order of the samples.
    h: Vec<f32>,
}

impl Samples {
    /// The value at grid point 0 after the samples are set: its sample, or V₀ + 2·Σ (`dc`).
    fn first(&self, v0: f32, dc: f32) -> f32 {
        self.zero.map_or(v0 + 2.0 * dc, |k| self.h[k])
    }
}

/// The sample values by forward input l, for the split-format projections: the grid points
/// ±(Rader's j) for j = −l mod H are members A (g_im = −2) and B (g_im = +2), each with its value
/// and a weight of 1 where sampled, 0 elsewhere. Their corrections then enter the forward input
/// in the same sequential pass that builds it, instead of one scattered update per sample (that
/// scalar loop was about half of the AVX2 projection's time outside the FFTs).
struct ByInput {
    h: [Vec<f32>; 2],
    w: [Vec<f32>; 2],
}

impl ByInput {
    /// Forward input l ≥ 1 (re, im) from a = Re W_j, b = Im W_j (j = −l mod H) with the
    /// corrections d = w·(h − g) of members A and B, g = V₀ + 2a ∓ 2b their current values:
    /// (2V₀ + 4a + d_A + d_B, 4b − d_A + d_B). At l = 0 the caller flips the sign of Im.
    #[inline(always)]
    fn forward_input(&self, l: usize, v0: f32, a: f32, b: f32) -> (f32, f32) {
        let ([ha, hb], [wa, wb]) = (&self.h, &self.w);
        let base = v0 + 2.0 * a;
        let da = (ha[l] - (base - 2.0 * b)) * wa[l];
        let db = (hb[l] - (base + 2.0 * b)) * wb[l];
        (2.0 * v0 + 4.0 * a + da + db, 4.0 * b - da + db)
    }

    /// h_A, h_B, w_A, w_B, each of length `hh` (asserted: the vector passes load them
    /// unchecked).
    fn arrays(&self, hh: usize) -> [&[f32]; 4] {
        let a = [
            &self.h[0][..],
            &self.h[1][..],
            &self.w[0][..],
            &self.w[1][..],
        ];
        assert!(a.iter().all(|t| t.len() == hh));
        a
    }

    /// The forward input's entries a vector pass of `lanes` leaves to scalars: l = 0 (where the
    /// sign of Im flips), the first line (1..lanes, so that the vector stores start on one) and
    /// the tail from `tail`; then the zero padding up to half the FFT length.
    fn scalar_entries(&self, sp: &mut Split, hh: usize, v0: f32, lanes: usize, tail: usize) {
        let (re0, im0) = self.forward_input(0, v0, sp.wr[0], sp.wi[0]);
        // At l = 0: im = −4 Im W₀ + d_A − d_B.
        (sp.zr[0], sp.zi[0]) = (re0, -im0);
        for l in (1..lanes.min(hh)).chain(tail..hh) {
            (sp.zr[l], sp.zi[l]) = self.forward_input(l, v0, sp.wr[hh - l], sp.wi[hh - l]);
        }
        let half = sp.zr.len() / 2;
        sp.zr[hh..half].fill(0.0);
        sp.zi[hh..half].fill(0.0);
    }

    fn new(pos: &[SamplePos], h: &[f32], len: usize) -> Self {
        let mut t = ByInput {
            h: [vec![0.0; len], vec![0.0; len]],
            w: [vec![0.0; len], vec![0.0; len]],
        };
        for (s, &hv) in pos.iter().zip(h) {
            if s.j == usize::MAX {
                continue;
            }
            let member = usize::from(s.g_im > 0.0);
            assert!(t.w[member][s.l] == 0.0, "a grid point sampled twice");
            t.h[member][s.l] = hv;
            t.w[member][s.l] = 1.0;
        }
        t
    }
}

/// The projection v ↦ v + Aᵀ(h − Av) in f32, in Rader's order (the ADMM loop around it is
/// `bp::ranking_loop`).
pub struct RaderAdmm {
    n: usize,
    h: usize,
    fft: Arc<dyn Fft<f32>>,
    ifft: Arc<dyn Fft<f32>>,
    /// Spectra of the folded kernels (see [`Padded`]): W = IFFT(Z·p + conj(Z_rev)·q).
    p: Vec<C32>,
    q: Vec<C32>,
    z: Vec<C32>,
    w: Vec<C32>,
    scratch: Vec<C32>,
    /// Inverse convolution input j from the layout pair (P, Q) at l = −j mod H:
    /// re = a·P + b·Q, im = c·P + d·Q (Makhoul's twiddle, scale and Rader's conjugation); one
    /// array per coefficient a, b, c, d.
    pack: [Vec<f32>; 4],
    /// Forward output l to the layout pair: with a = v₀ + Re W_l, P = u0·a + u1·Im W_l,
    /// Q = u2·a + u3·Im W_l; one array per coefficient.
    unpack: [Vec<f32>; 4],
    /// V₀ = a0·θ₀; θ₀ = s0·(v₀ + Σ).
    a0: f32,
    s0: f32,
    /// Natural coefficient index of each layout position.
    coef: Vec<usize>,
    /// Position of each grid point (signal index) in the inverse output.
    sig: Vec<SamplePos>,
    /// The AVX-512 path's state, when the CPU has AVX-512F.
    #[cfg(target_arch = "x86_64")]
    split: Option<Split>,
}

/// The projection's buffers and tables in split format (re and im arrays) for
/// [`super::split_fft::SplitFft`], the spectra in its bit-reversed order.
#[cfg(target_arch = "x86_64")]
use super::split_fft::Aligned;

#[cfg(target_arch = "x86_64")]
struct Split {
    fft: Kernel,
    zr: Aligned,
    zi: Aligned,
    wr: Aligned,
    wi: Aligned,
    /// Vector 0 holds the octaves below 16, each mirrored within itself: its lane permutation.
    mirror0: [i32; 16],
}

/// The split-format FFT in the widest vectors the CPU has (one per projection state, so the
/// variants' size difference costs nothing), with p and q (see [`RaderAdmm`]) at bit-reversed
/// positions in the layout its product loop reads.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::large_enum_variant)]
enum Kernel {
    /// p and q as four arrays (re and im of each).
    Avx512 {
        fft: super::split_fft::SplitFft,
        pr: Aligned,
        pi: Aligned,
        qr: Aligned,
        qi: Aligned,
    },
    /// p and q interleaved by 8-lane vector (pr, pi, qr, qi of vector v at 32·v): one pointer
    /// instead of four in [`Split::convolve8`]'s product loop, which spilled sixteen advancing
    /// pointers to the stack with four arrays.
    Avx2 {
        fft: super::split_fft::SplitFft8,
        pq8: Aligned,
    },
}

#[cfg(target_arch = "x86_64")]
impl Kernel {
    /// The AVX-512 kernel for p and q (of a power-of-two length ≥ 64).
    fn avx512(p: &[C32], q: &[C32]) -> Option<Self> {
        use super::split_fft::bit_reverse;
        let len = p.len();
        let br =
            |v: &[C32], f: fn(&C32) -> f32| Aligned::from_fn(len, |i| f(&v[bit_reverse(i, len)]));
        Some(Kernel::Avx512 {
            fft: super::split_fft::SplitFft::new(len)?,
            pr: br(p, |c| c.re),
            pi: br(p, |c| c.im),
            qr: br(q, |c| c.re),
            qi: br(q, |c| c.im),
        })
    }

    /// The AVX2 kernel for p and q (of a power-of-two length ≥ 32).
    fn avx2(p: &[C32], q: &[C32]) -> Option<Self> {
        use super::split_fft::bit_reverse;
        let len = p.len();
        Some(Kernel::Avx2 {
            fft: super::split_fft::SplitFft8::new(len)?,
            pq8: Aligned::from_fn(4 * len, |i| {
                let (v, part, lane) = (i / 32, i / 8 % 4, i % 8);
                let c = [p, q][part / 2][bit_reverse(8 * v + lane, len)];
                if part % 2 == 0 {
                    c.re
                } else {
                    c.im
                }
            }),
        })
    }
}

#[cfg(target_arch = "x86_64")]
impl Split {
    /// z ← FFT(z) (bit-reversed), w ← IFFT(Z·p + conj(Z_−q)·q) on its lower half; returns Σ of
    /// the input's real parts. z's upper half is not read.
    #[target_feature(enable = "avx512f")]
    unsafe fn convolve(&mut self) -> f32 {
        use std::arch::x86_64::*;
        let Kernel::Avx512 {
            fft,
            pr: kpr,
            pi: kpi,
            qr: kqr,
            qi: kqi,
        } = &self.fft
        else {
            unreachable!("the AVX-512 convolution on the AVX-512 kernel")
        };
        fft.forward(&mut self.zr, &mut self.zi, true);
        let dc = self.zr[0];
        let rev = _mm512_set_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let v0_idx = _mm512_loadu_si512(self.mirror0.as_ptr() as *const _);
        let len = self.zr.len();
        for v in 0..len / 16 {
            let (mv, perm) = if v == 0 {
                (0, v0_idx)
            } else {
                let top = 1usize << (usize::BITS - 1 - v.leading_zeros());
                (3 * top - 1 - v, rev)
            };
            let ld = |t: &Aligned, at: usize| _mm512_loadu_ps(t.as_ptr().add(16 * at));
            let (zr, zi) = (ld(&self.zr, v), ld(&self.zi, v));
            let mr = _mm512_permutexvar_ps(perm, ld(&self.zr, mv));
            let mi = _mm512_permutexvar_ps(perm, ld(&self.zi, mv));
            let (pr, pi, qr, qi) = (ld(kpr, v), ld(kpi, v), ld(kqr, v), ld(kqi, v));
            // Z·p + conj(M)·q.
            let re = _mm512_fmadd_ps(
                mi,
                qi,
                _mm512_fmadd_ps(mr, qr, _mm512_fmsub_ps(zr, pr, _mm512_mul_ps(zi, pi))),
            );
            let im = _mm512_fnmadd_ps(
                mi,
                qr,
                _mm512_fmadd_ps(mr, qi, _mm512_fmadd_ps(zr, pi, _mm512_mul_ps(zi, pr))),
            );
            _mm512_storeu_ps(self.wr.as_mut_ptr().add(16 * v), re);
            _mm512_storeu_ps(self.wi.as_mut_ptr().add(16 * v), im);
        }
        fft.inverse(&mut self.wr, &mut self.wi, true);
        dc
    }

    /// [`Split::convolve`] in AVX2 (8 lanes). Vectors v and mirror(v) are each other's mirror,
    /// so the product takes them in pairs: each loaded and permuted once for both outputs, on
    /// pointers taken out of the loop (through `self` the compiler reloaded them at every
    /// store). With both, the n = 1901 projection (two convolutions) took 10.6 → 10.3-10.5 µs
    /// on Zen 3 (`bench dct`).
    #[target_feature(enable = "avx2,fma")]
    unsafe fn convolve8(&mut self) -> f32 {
        use std::arch::x86_64::*;
        let Kernel::Avx2 { fft, pq8 } = &self.fft else {
            unreachable!("the AVX2 convolution on the AVX2 kernel")
        };
        fft.forward(&mut self.zr, &mut self.zi, true);
        let dc = self.zr[0];
        let rev = _mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0);
        // Vector 0 holds the octaves below 8, each mirrored within itself.
        let v0_idx = _mm256_setr_epi32(0, 1, 3, 2, 7, 6, 5, 4);
        let vecs = self.zr.len() / 8;
        let lens = [&self.zi, &self.wr, &self.wi];
        assert!(lens.iter().all(|t| t.len() == 8 * vecs) && pq8.len() == 32 * vecs);
        let (zr, zi) = (self.zr.as_ptr(), self.zi.as_ptr());
        let (wr, wi) = (self.wr.as_mut_ptr(), self.wi.as_mut_ptr());
        let pq = pq8.as_ptr();
        // W_v = Z_v·p_v + conj(M)·q_v with M the mirror vector, permuted.
        let out = |v: usize, zr_v: __m256, zi_v: __m256, mr: __m256, mi: __m256| {
            let k = pq.add(32 * v);
            let (pr, pi, qr, qi) = (
                _mm256_load_ps(k),
                _mm256_load_ps(k.add(8)),
                _mm256_load_ps(k.add(16)),
                _mm256_load_ps(k.add(24)),
            );
            let re = _mm256_fmadd_ps(
                mi,
                qi,
                _mm256_fmadd_ps(mr, qr, _mm256_fmsub_ps(zr_v, pr, _mm256_mul_ps(zi_v, pi))),
            );
            let im = _mm256_fnmadd_ps(
                mi,
                qr,
                _mm256_fmadd_ps(mr, qi, _mm256_fmadd_ps(zr_v, pi, _mm256_mul_ps(zi_v, pr))),
            );
            _mm256_store_ps(wr.add(8 * v), re);
            _mm256_store_ps(wi.add(8 * v), im);
        };
        let ld = |t: *const f32, v: usize| _mm256_load_ps(t.add(8 * v));
        // Vectors 0 and 1 are their own mirrors.
        for (v, perm) in [(0, v0_idx), (1, rev)].into_iter().take(vecs) {
            let (a_r, a_i) = (ld(zr, v), ld(zi, v));
            let m_r = _mm256_permutevar8x32_ps(a_r, perm);
            let m_i = _mm256_permutevar8x32_ps(a_i, perm);
            out(v, a_r, a_i, m_r, m_i);
        }
        // Octave [top, 2·top): v and 3·top − 1 − v.
        let mut top = 2;
        while top < vecs {
            for v in top..top + top / 2 {
                let mv = 3 * top - 1 - v;
                let (a_r, a_i, b_r, b_i) = (ld(zr, v), ld(zi, v), ld(zr, mv), ld(zi, mv));
                let (ra_r, ra_i) = (
                    _mm256_permutevar8x32_ps(a_r, rev),
                    _mm256_permutevar8x32_ps(a_i, rev),
                );
                let (rb_r, rb_i) = (
                    _mm256_permutevar8x32_ps(b_r, rev),
                    _mm256_permutevar8x32_ps(b_i, rev),
                );
                out(v, a_r, a_i, rb_r, rb_i);
                out(mv, b_r, b_i, ra_r, ra_i);
            }
            top *= 2;
        }
        fft.inverse(&mut self.wr, &mut self.wi, true);
        dc
    }

    fn new(p: &[C32], q: &[C32]) -> Option<Self> {
        use super::split_fft::mirror;
        let len = p.len();
        // The AVX-512 kernel needs a length ≥ 64; shorter ones (primes below ~32) take AVX2's.
        let fft = match super::simd::has_avx512f()
            .then(|| Kernel::avx512(p, q))
            .flatten()
        {
            Some(k) => k,
            None if super::simd::has_avx2_fma() => Kernel::avx2(p, q)?,
            None => return None,
        };
        Some(Self {
            fft,
            zr: Aligned::zeros(len),
            zi: Aligned::zeros(len),
            wr: Aligned::zeros(len),
            wi: Aligned::zeros(len),
            mirror0: std::array::from_fn(|l| mirror(l) as i32),
        })
    }
}

impl RaderAdmm {
    /// For a prime n ≥ 5 (`None` otherwise).
    pub fn new(n: usize) -> Option<Self> {
        if n < 5 || !is_prime(n) {
            return None;
        }
        let p = n;
        let h = (p - 1) / 2;
        let (in_idx, out_idx) = generator_orders(p);
        let perm = makhoul_order(n);
        let half_bin = |k: usize| if k <= h { (k, 1.0f64) } else { (p - k, -1.0) };
        let phase = kernel_phases(p, &out_idx);
        let conv = Padded::<f32>::new(&phase);
        let nf = n as f64;
        let (s0, sk) = ((1.0 / nf).sqrt(), (2.0 / nf).sqrt());
        let ak = 1.0 / nf / sk;
        let twiddle = |k: usize| {
            let phi = std::f64::consts::PI * k as f64 / (2.0 * nf);
            (phi.cos(), phi.sin())
        };
        let rev = |j: usize| (h - j) % h;
        let mut coef = vec![0usize; n];
        let mut unpack = Vec::with_capacity(h);
        for (l, &o) in out_idx[..h].iter().enumerate() {
            let (k, sg) = half_bin(o);
            coef[1 + l] = k;
            coef[1 + h + l] = n - k;
            let (c, s) = twiddle(k);
            let sigma = -sg;
            unpack.push([sk * c, sk * s * sigma, sk * s, -sk * c * sigma].map(|v| v as f32));
        }
        let mut pack = Vec::with_capacity(h);
        for (j, &i) in in_idx[..h].iter().enumerate() {
            let (k, sg) = half_bin(i);
            if coef[1 + rev(j)] != k {
                return None;
            }
            let (c, s) = twiddle(k);
            pack.push([ak * c, ak * s, sg * ak * s, -sg * ak * c].map(|v| v as f32));
        }
        let mut sig = vec![
            SamplePos {
                j: usize::MAX,
                g_im: 0.0,
                l: 0,
                f_im: 0.0
            };
            n
        ];
        for j in 0..h {
            let l = rev(j);
            // Forward input l = S0[−l] ± S1[−l]: for l = 0 re = S0 + S1, im = S0 − S1; otherwise
            // the roles swap (Rader's input index −l is output index l + H).
            let (f0, f1) = if l == 0 { (1.0, -1.0) } else { (-1.0, 1.0) };
            sig[perm[out_idx[j]]] = SamplePos {
                j,
                g_im: -2.0,
                l,
                f_im: f0,
            };
            sig[perm[out_idx[j + h]]] = SamplePos {
                j,
                g_im: 2.0,
                l,
                f_im: f1,
            };
        }
        let len = conv.z.len();
        #[cfg(target_arch = "x86_64")]
        let split = Split::new(&conv.p, &conv.q);
        Some(Self {
            n,
            h,
            fft: conv.fft,
            ifft: conv.ifft,
            p: conv.p,
            q: conv.q,
            z: vec![C32::new(0.0, 0.0); len],
            w: vec![C32::new(0.0, 0.0); len],
            scratch: conv.scratch,
            pack: std::array::from_fn(|i| pack.iter().map(|c| c[i]).collect()),
            unpack: std::array::from_fn(|i| unpack.iter().map(|u| u[i]).collect()),
            a0: (1.0 / nf / s0) as f32,
            s0: s0 as f32,
            coef,
            sig,
            #[cfg(target_arch = "x86_64")]
            split,
        })
    }

    /// Natural vector → layout.
    pub fn to_layout(&self, natural: &[f64]) -> Vec<f32> {
        self.coef.iter().map(|&k| natural[k] as f32).collect()
    }

    /// Layout → natural vector.
    pub fn to_natural(&self, layout: &[f32]) -> Vec<f64> {
        let mut out = vec![0.0; self.n];
        for (&k, &v) in self.coef.iter().zip(layout) {
            out[k] = f64::from(v);
        }
        out
    }

    /// The samples at the distinct grid indices `idx` with values `h`, for
    /// [`RaderAdmm::project`].
    pub fn samples(&self, idx: &[usize], h: &[f32]) -> Samples {
        assert_eq!(idx.len(), h.len(), "one value per sample");
        let pos: Vec<SamplePos> = idx.iter().map(|&i| self.sig[i]).collect();
        let zero = pos.iter().position(|s| s.j == usize::MAX);
        let by_input = ByInput::new(&pos, h, self.h);
        Samples {
            pos,
            zero,
            by_input,
            h: h.to_vec(),
        }
    }

    /// Inverse convolution input j from the layout pair (P, Q).
    #[inline(always)]
    fn pack_one(&self, j: usize, p: f32, q: f32) -> C32 {
        let [a, b, c, d] = &self.pack;
        C32::new(a[j] * p + b[j] * q, c[j] * p + d[j] * q)
    }

    /// The layout pair (P, Q) of forward output l = `wl`.
    #[inline(always)]
    fn unpack_one(&self, l: usize, first: f32, wl: C32) -> (f32, f32) {
        let [u0, u1, u2, u3] = &self.unpack;
        let a = first + wl.re;
        (u0[l] * a + u1[l] * wl.im, u2[l] * a + u3[l] * wl.im)
    }

    /// Inverse convolution input from layout `v` into z; returns V₀.
    #[inline(always)]
    fn pack_into_z(&mut self, v: &[f32]) -> f32 {
        let h = self.h;
        let (pl, ql) = (&v[1..1 + h], &v[1 + h..]);
        self.z[0] = self.pack_one(0, pl[0], ql[0]);
        for j in 1..h {
            self.z[j] = self.pack_one(j, pl[h - j], ql[h - j]);
        }
        self.z[h..].fill(C32::new(0.0, 0.0));
        self.a0 * v[0]
    }

    /// z ← FFT(z), w ← IFFT(z·p + conj(z_rev)·q); returns Σ of the input's real parts.
    #[inline(always)]
    fn convolve(&mut self) -> f32 {
        self.fft
            .process_with_scratch(&mut self.z, &mut self.scratch);
        let (z, w) = (&self.z, &mut self.w);
        let dc = z[0].re;
        w[0] = z[0] * self.p[0] + z[0].conj() * self.q[0];
        for ((((wk, &zk), &zr), &pk), &qk) in w[1..]
            .iter_mut()
            .zip(&z[1..])
            .zip(z[1..].iter().rev())
            .zip(&self.p[1..])
            .zip(&self.q[1..])
        {
            *wk = zk * pk + zr.conj() * qk;
        }
        self.ifft
            .process_with_scratch(&mut self.w, &mut self.scratch);
        dc
    }

    /// Projection of `v` onto {Aθ = h} into `x`, both in the layout ([`RaderAdmm::to_layout`]):
    /// the inverse transform, the samples set to their values, the forward transform.
    pub fn project(&mut self, v: &[f32], samples: &Samples, x: &mut [f32]) {
        let h = &samples.h;
        #[cfg(target_arch = "x86_64")]
        match self.split.as_ref().map(|s| &s.fft) {
            // SAFETY: each kernel exists only when the CPU has its features.
            Some(Kernel::Avx512 { .. }) => return unsafe { self.project_avx512(v, samples, x) },
            Some(Kernel::Avx2 { .. }) => return unsafe { self.project_split8(v, samples, x) },
            None => {}
        }
        self.project_impl(v, &samples.pos, h, x);
    }

    /// [`RaderAdmm::project`] on the split-format AVX-512 FFT ([`super::split_fft`]): every pass
    /// in 16-lane vectors without the complex interleaving's shuffles, the spectra left in
    /// bit-reversed order, the zero upper half of each convolution's input and the unused upper
    /// half of its output skipped. At n = 1901 (`bench dct`): 15.1-15.5 → 9.5-9.6 µs against the
    /// AVX2 path. The sample corrections enter in the pass that builds the forward input, as in
    /// [`RaderAdmm::project_split8`]; gathers and scatters of one update per pair of samples
    /// were slower on the Intel Xeon (Emerald Rapids) of session 25, whose gathers are slow
    /// (m = 600, best of 2000 x 10 projections: 7.31-7.42 µs against 6.80-6.85).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn project_avx512(&mut self, v: &[f32], samples: &Samples, x: &mut [f32]) {
        use std::arch::x86_64::*;
        let hh = self.h;
        let (a0, s0) = (self.a0, self.s0);
        let ([u0, u1, u2, u3], [pa, pb, pc, pd]) = (&self.unpack, &self.pack);
        let sp = self.split.as_mut().expect("checked by the caller");
        let half = sp.zr.len() / 2;
        let rev = _mm512_set_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        // Pack: z_j = (a·P + b·Q, c·P + d·Q) with P, Q read backwards from the layout.
        let (pl, ql) = (&v[1..1 + hh], &v[1 + hh..]);
        let v0 = a0 * v[0];
        {
            let one = |j: usize, p: f32, q: f32| (pa[j] * p + pb[j] * q, pc[j] * p + pd[j] * q);
            (sp.zr[0], sp.zi[0]) = one(0, pl[0], ql[0]);
            // The first line in scalars (with the tail), so that the vector stores start on a
            // line (a store straddling two lines costs twice).
            let mut j = 16;
            while j + 16 <= hh {
                let pv = _mm512_permutexvar_ps(rev, _mm512_loadu_ps(pl.as_ptr().add(hh - j - 15)));
                let qv = _mm512_permutexvar_ps(rev, _mm512_loadu_ps(ql.as_ptr().add(hh - j - 15)));
                let ld = |t: &Vec<f32>| _mm512_loadu_ps(t.as_ptr().add(j));
                let re = _mm512_fmadd_ps(ld(pa), pv, _mm512_mul_ps(ld(pb), qv));
                let im = _mm512_fmadd_ps(ld(pc), pv, _mm512_mul_ps(ld(pd), qv));
                _mm512_storeu_ps(sp.zr.as_mut_ptr().add(j), re);
                _mm512_storeu_ps(sp.zi.as_mut_ptr().add(j), im);
                j += 16;
            }
            for j in (1..16.min(hh)).chain(j..hh) {
                (sp.zr[j], sp.zi[j]) = one(j, pl[hh - j], ql[hh - j]);
            }
        }
        sp.zr[hh..half].fill(0.0);
        sp.zi[hh..half].fill(0.0);
        let dc = sp.convolve();
        let first = samples.first(v0, dc);
        Self::forward_input_avx512(sp, hh, v0, samples);
        let dc = sp.convolve();
        x[0] = s0 * (first + dc);
        // Unpack: P = u0·a + u1·Im W_l, Q = u2·a + u3·Im W_l with a = first + Re W_l.
        let (xp, xq) = x[1..].split_at_mut(hh);
        let f = _mm512_set1_ps(first);
        let mut l = 0;
        while l + 16 <= hh {
            let a = _mm512_add_ps(_mm512_loadu_ps(sp.wr.as_ptr().add(l)), f);
            let im = _mm512_loadu_ps(sp.wi.as_ptr().add(l));
            let ld = |t: &Vec<f32>| _mm512_loadu_ps(t.as_ptr().add(l));
            let pv = _mm512_fmadd_ps(ld(u0), a, _mm512_mul_ps(ld(u1), im));
            let qv = _mm512_fmadd_ps(ld(u2), a, _mm512_mul_ps(ld(u3), im));
            _mm512_storeu_ps(xp.as_mut_ptr().add(l), pv);
            _mm512_storeu_ps(xq.as_mut_ptr().add(l), qv);
            l += 16;
        }
        for l in l..hh {
            let a = first + sp.wr[l];
            xp[l] = u0[l] * a + u1[l] * sp.wi[l];
            xq[l] = u2[l] * a + u3[l] * sp.wi[l];
        }
    }

    /// [`RaderAdmm::project_avx512`]'s forward input with the samples set to their values, in
    /// one sequential pass (see [`RaderAdmm::project_split8`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn forward_input_avx512(sp: &mut Split, hh: usize, v0: f32, samples: &Samples) {
        use std::arch::x86_64::*;
        let rev = _mm512_set_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let t = &samples.by_input;
        let [ha, hb, wa, wb] = t.arrays(hh);
        let two = _mm512_set1_ps(2.0);
        let four = _mm512_set1_ps(4.0);
        let vv0 = _mm512_set1_ps(v0);
        let shift = _mm512_set1_ps(2.0 * v0);
        let mut l = 16;
        while l + 16 <= hh {
            let a = _mm512_permutexvar_ps(rev, _mm512_loadu_ps(sp.wr.as_ptr().add(hh - l - 15)));
            let b = _mm512_permutexvar_ps(rev, _mm512_loadu_ps(sp.wi.as_ptr().add(hh - l - 15)));
            let ld = |t: &[f32]| _mm512_loadu_ps(t.as_ptr().add(l));
            let base = _mm512_fmadd_ps(two, a, vv0);
            let da = _mm512_mul_ps(
                _mm512_sub_ps(ld(ha), _mm512_fnmadd_ps(two, b, base)),
                ld(wa),
            );
            let db = _mm512_mul_ps(_mm512_sub_ps(ld(hb), _mm512_fmadd_ps(two, b, base)), ld(wb));
            let re = _mm512_add_ps(_mm512_fmadd_ps(a, four, shift), _mm512_add_ps(da, db));
            let im = _mm512_add_ps(_mm512_fmsub_ps(b, four, da), db);
            _mm512_storeu_ps(sp.zr.as_mut_ptr().add(l), re);
            _mm512_storeu_ps(sp.zi.as_mut_ptr().add(l), im);
            l += 16;
        }
        t.scalar_entries(sp, hh, v0, 16, l);
    }

    /// [`RaderAdmm::project_avx512`] in AVX2 (8 lanes) on [`super::split_fft::SplitFft8`], the
    /// sample corrections folded into the pass that builds the forward input ([`ByInput`]; AMD's
    /// gathers are slower than scalar loads, and AVX2 has no scatter).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn project_split8(&mut self, v: &[f32], samples: &Samples, x: &mut [f32]) {
        use std::arch::x86_64::*;
        let hh = self.h;
        let (a0, s0) = (self.a0, self.s0);
        let ([u0, u1, u2, u3], [pa, pb, pc, pd]) = (&self.unpack, &self.pack);
        let sp = self.split.as_mut().expect("checked by the caller");
        let half = sp.zr.len() / 2;
        let rev = _mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0);
        let (pl, ql) = (&v[1..1 + hh], &v[1 + hh..]);
        let v0 = a0 * v[0];
        // Pack: z_j = (a·P + b·Q, c·P + d·Q) with P, Q read backwards from the layout.
        {
            let one = |j: usize, p: f32, q: f32| (pa[j] * p + pb[j] * q, pc[j] * p + pd[j] * q);
            (sp.zr[0], sp.zi[0]) = one(0, pl[0], ql[0]);
            // The first line in scalars (with the tail), so that the vector stores are aligned.
            let mut j = 8;
            while j + 8 <= hh {
                let pv =
                    _mm256_permutevar8x32_ps(_mm256_loadu_ps(pl.as_ptr().add(hh - j - 7)), rev);
                let qv =
                    _mm256_permutevar8x32_ps(_mm256_loadu_ps(ql.as_ptr().add(hh - j - 7)), rev);
                let ld = |t: &Vec<f32>| _mm256_loadu_ps(t.as_ptr().add(j));
                let re = _mm256_fmadd_ps(ld(pa), pv, _mm256_mul_ps(ld(pb), qv));
                let im = _mm256_fmadd_ps(ld(pc), pv, _mm256_mul_ps(ld(pd), qv));
                _mm256_storeu_ps(sp.zr.as_mut_ptr().add(j), re);
                _mm256_storeu_ps(sp.zi.as_mut_ptr().add(j), im);
                j += 8;
            }
            for j in (1..8.min(hh)).chain(j..hh) {
                (sp.zr[j], sp.zi[j]) = one(j, pl[hh - j], ql[hh - j]);
            }
        }
        sp.zr[hh..half].fill(0.0);
        sp.zi[hh..half].fill(0.0);
        let dc = sp.convolve8();
        // Forward input with the samples set to their values, in one sequential pass over l
        // (j = −l mod H): re_l = 2V₀ + 4 Re W_j + d_A + d_B, im_l = 4 Im W_j − d_A + d_B (l ≥ 1;
        // at l = 0 the signs of Im flip), where d = w·(h − g) is member A's or B's correction,
        // g = V₀ + 2 Re W_j ∓ 2 Im W_j its current value.
        let first = samples.first(v0, dc);
        {
            let t = &samples.by_input;
            let [ha, hb, wa, wb] = t.arrays(hh);
            let two = _mm256_set1_ps(2.0);
            let four = _mm256_set1_ps(4.0);
            let vv0 = _mm256_set1_ps(v0);
            let shift = _mm256_set1_ps(2.0 * v0);
            let mut l = 8;
            while l + 8 <= hh {
                let a =
                    _mm256_permutevar8x32_ps(_mm256_loadu_ps(sp.wr.as_ptr().add(hh - l - 7)), rev);
                let b =
                    _mm256_permutevar8x32_ps(_mm256_loadu_ps(sp.wi.as_ptr().add(hh - l - 7)), rev);
                let ld = |t: &[f32]| _mm256_loadu_ps(t.as_ptr().add(l));
                let base = _mm256_fmadd_ps(two, a, vv0);
                let da = _mm256_mul_ps(
                    _mm256_sub_ps(ld(ha), _mm256_fnmadd_ps(two, b, base)),
                    ld(wa),
                );
                let db =
                    _mm256_mul_ps(_mm256_sub_ps(ld(hb), _mm256_fmadd_ps(two, b, base)), ld(wb));
                let re = _mm256_add_ps(_mm256_fmadd_ps(a, four, shift), _mm256_add_ps(da, db));
                let im = _mm256_add_ps(_mm256_fmsub_ps(b, four, da), db);
                _mm256_storeu_ps(sp.zr.as_mut_ptr().add(l), re);
                _mm256_storeu_ps(sp.zi.as_mut_ptr().add(l), im);
                l += 8;
            }
            t.scalar_entries(sp, hh, v0, 8, l);
        }
        let dc = sp.convolve8();
        x[0] = s0 * (first + dc);
        // Unpack: P = u0·a + u1·Im W_l, Q = u2·a + u3·Im W_l with a = first + Re W_l.
        let (xp, xq) = x[1..].split_at_mut(hh);
        let f = _mm256_set1_ps(first);
        let mut l = 0;
        while l + 8 <= hh {
            let a = _mm256_add_ps(_mm256_loadu_ps(sp.wr.as_ptr().add(l)), f);
            let im = _mm256_loadu_ps(sp.wi.as_ptr().add(l));
            let ld = |t: &Vec<f32>| _mm256_loadu_ps(t.as_ptr().add(l));
            let pv = _mm256_fmadd_ps(ld(u0), a, _mm256_mul_ps(ld(u1), im));
            let qv = _mm256_fmadd_ps(ld(u2), a, _mm256_mul_ps(ld(u3), im));
            _mm256_storeu_ps(xp.as_mut_ptr().add(l), pv);
            _mm256_storeu_ps(xq.as_mut_ptr().add(l), qv);
            l += 8;
        }
        for l in l..hh {
            let a = first + sp.wr[l];
            xp[l] = u0[l] * a + u1[l] * sp.wi[l];
            xq[l] = u2[l] * a + u3[l] * sp.wi[l];
        }
    }

    /// The samples set to h: corrections h − g at the sampled points added to the forward
    /// input z; returns the value at grid point 0's position (V₀ + 2Σ, or its sample).
    #[inline(always)]
    fn correct_samples(&mut self, v0: f32, dc: f32, samples: &[SamplePos], h: &[f32]) -> f32 {
        let (z, w) = (&mut self.z, &self.w);
        let mut first = v0 + 2.0 * dc;
        for (s, &hv) in samples.iter().zip(h) {
            if s.j == usize::MAX {
                first = hv;
                continue;
            }
            let wj = w[s.j];
            let d = hv - (v0 + 2.0 * wj.re + s.g_im * wj.im);
            z[s.l].re += d;
            z[s.l].im += s.f_im * d;
        }
        first
    }

    #[inline(always)]
    fn project_impl(&mut self, v: &[f32], samples: &[SamplePos], h: &[f32], x: &mut [f32]) {
        let hh = self.h;
        let v0 = self.pack_into_z(v);
        let dc = self.convolve();
        // Forward input: re_l = S0 + S1 = 2V₀ + 4 Re W_(−l), im_l = ±(S0 − S1) = ∓4 Im W_(−l).
        let (z, w) = (&mut self.z, &self.w);
        z[0] = C32::new(2.0 * v0 + 4.0 * w[0].re, -4.0 * w[0].im);
        for (zl, wj) in z[1..hh].iter_mut().zip(w[1..hh].iter().rev()) {
            *zl = C32::new(2.0 * v0 + 4.0 * wj.re, 4.0 * wj.im);
        }
        z[hh..].fill(C32::new(0.0, 0.0));
        let first = self.correct_samples(v0, dc, samples, h);
        let dc = self.convolve();
        let w = &self.w;
        x[0] = self.s0 * (first + dc);
        let (xp, xq) = x[1..].split_at_mut(hh);
        for (l, (p, q)) in xp.iter_mut().zip(xq).enumerate() {
            (*p, *q) = self.unpack_one(l, first, w[l]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::dct::Dct;

    /// The AVX-512 projection equals the portable one, at lengths with every vector remainder
    /// and FFT lengths with and without the radix-2 stage (128 ... 8192).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx512_projection_matches_the_portable_one() {
        if !crate::recon::simd::has_avx512f() {
            eprintln!("skipped: no AVX-512F on this CPU");
            return;
        }
        for n in [67usize, 101, 131, 383, 557, 1901, 4099] {
            let mut fused = RaderAdmm::new(n).expect("prime");
            assert!(fused.split.is_some(), "n={n}");
            let v: Vec<f32> = (0..n).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.1).collect();
            let mut idx: Vec<usize> = (0..n).step_by(3).collect();
            idx.push(n - 1);
            idx.dedup();
            let h: Vec<f32> = idx.iter().map(|&i| (i as f32 * 0.3).cos()).collect();
            let samples = fused.samples(&idx, &h);
            let (mut a, mut b) = (vec![0.0f32; n], vec![0.0f32; n]);
            fused.project_impl(&v, &samples.pos, &h, &mut a);
            // Twice: the second call sees the buffers the first left behind.
            for _ in 0..2 {
                // SAFETY: AVX-512F is present (checked).
                unsafe { fused.project_avx512(&v, &samples, &mut b) };
                let scale = a.iter().map(|v| v.abs()).fold(0.0, f32::max);
                for k in 0..n {
                    assert!(
                        (a[k] - b[k]).abs() <= 1e-5 * scale,
                        "n={n} k={k}: {} vs {}",
                        a[k],
                        b[k]
                    );
                }
            }
        }
    }

    /// The AVX2 split-format projection equals the portable one, at lengths with every 8-lane
    /// remainder and FFT lengths with and without the radix-2 stage (64 ... 8192).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn split8_projection_matches_the_portable_one() {
        if !crate::recon::simd::has_avx2_fma() {
            eprintln!("skipped: no AVX2/FMA on this CPU");
            return;
        }
        for n in [19usize, 37, 67, 101, 131, 383, 557, 1901, 4099] {
            let mut fused = RaderAdmm::new(n).expect("prime");
            // The AVX2 kernel even where the CPU has AVX-512F (the split's buffers do not
            // depend on the kernel).
            let split = fused.split.as_mut().expect("AVX2 present");
            split.fft = Kernel::avx2(&fused.p, &fused.q).expect("power of two");
            let v: Vec<f32> = (0..n).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.1).collect();
            let mut idx: Vec<usize> = (0..n).step_by(3).collect();
            idx.push(n - 1);
            idx.dedup();
            let h: Vec<f32> = idx.iter().map(|&i| (i as f32 * 0.3).cos()).collect();
            let samples = fused.samples(&idx, &h);
            let (mut a, mut b) = (vec![0.0f32; n], vec![0.0f32; n]);
            fused.project_impl(&v, &samples.pos, &h, &mut a);
            // Twice: the second call sees the buffers the first left behind.
            for _ in 0..2 {
                // SAFETY: AVX2 and FMA are present (checked).
                unsafe { fused.project_split8(&v, &samples, &mut b) };
                let scale = a.iter().map(|v| v.abs()).fold(0.0, f32::max);
                for k in 0..n {
                    assert!(
                        (a[k] - b[k]).abs() <= 1e-5 * scale,
                        "n={n} k={k}: {} vs {}",
                        a[k],
                        b[k]
                    );
                }
            }
        }
    }

    /// One projection in Rader's order equals the natural-order one (inverse DCT, samples set,
    /// forward DCT) at prime lengths, including a sample at grid point 0.
    #[test]
    fn projection_matches_the_natural_order() {
        for n in [5usize, 7, 13, 101, 383, 1901] {
            let mut fused = RaderAdmm::new(n).expect("prime");
            let mut dct = Dct::new(n);
            let v: Vec<f64> = (0..n)
                .map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.1 + (i as f64 * 0.7).sin())
                .collect();
            let mut idx: Vec<usize> = (0..n).step_by(3).collect();
            idx.push(n - 1);
            idx.dedup();
            let h: Vec<f64> = idx.iter().map(|&i| (i as f64 * 0.3).cos()).collect();
            let mut want = v.clone();
            dct.inverse(&mut want);
            for (&i, &hv) in idx.iter().zip(&h) {
                want[i] = hv;
            }
            dct.forward(&mut want);
            let hs: Vec<f32> = h.iter().map(|&x| x as f32).collect();
            let samples = fused.samples(&idx, &hs);
            let mut x = vec![0.0f32; n];
            let vl = fused.to_layout(&v);
            fused.project(&vl, &samples, &mut x);
            let got = fused.to_natural(&x);
            let scale = want.iter().map(|v| v.abs()).fold(0.0, f64::max);
            for k in 0..n {
                assert!(
                    (got[k] - want[k]).abs() < 2e-5 * scale,
                    "n={n} k={k}: {} vs {}",
                    got[k],
                    want[k]
                );
            }
        }
    }
}
