//! A split-format (separate re and im arrays) complex f32 FFT of a power-of-two length in AVX-512
//! (and in AVX2, [`SplitFft8`]), for convolutions: the forward transform (decimation in
//! frequency) leaves the spectrum in bit-reversed order and the inverse (decimation in time) takes
//! it back from that order, so no permutation pass is ever made; the pointwise product between
//! them works in bit-reversed order ([`mirror`] pairs bin q with bin −q there). Both transforms
//! are unnormalized, like rustfft's.
//!
//! Stages whose butterfly span is ≥ 16 run between whole vectors (radix 4, one radix-2 stage at
//! span 16 when their count is odd); the last four (spans 8, 4, 2, 1) run inside each vector with
//! lane permutes. A convolution zero-padded to L ≥ 2H − 1 has its input's upper half zero and
//! needs only the lower half of its output: the first forward stage and the last inverse one
//! skip that half (`zero_upper`, `lower_half`).
//!
//! Measured at L = 2048 against rustfft's AVX2 FFT on interleaved data (a loop of forward +
//! inverse): 2.48 µs per transform, 2.0 µs with the half skipped, against 2.93 µs. In the BP
//! ranking projection (four per projection, [`super::fused`]), with 64-byte-aligned buffers.
//! The AVX2 kernels on an AMD EPYC (Zen 3), forward + inverse with the halves skipped:
//! 3.75-3.9 µs a pair against rustfft's 4.8-5.0 (copy-in loops, best of 40 000).

use std::arch::x86_64::{__m512, __mmask16};

mod avx2;
pub use avx2::SplitFft8;

/// An f32 buffer aligned to 64 bytes, so that no 16-lane load or store at a multiple of 16
/// straddles two cache lines (with malloc's 16-byte alignment three in four did; measured in the
/// BP ranking loop: a projection 14.3 → 10.6 µs).
#[derive(Clone)]
pub struct Aligned(Vec<Line>);

#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Line([f32; 16]);

impl Aligned {
    /// `len` zeros; `len` a multiple of 16.
    pub fn zeros(len: usize) -> Self {
        assert!(
            len.is_multiple_of(16),
            "{len} is not a whole number of lines"
        );
        Self(vec![Line([0.0; 16]); len / 16])
    }

    pub fn from_fn(len: usize, mut f: impl FnMut(usize) -> f32) -> Self {
        let mut v = Self::zeros(len);
        v.iter_mut().zip(0..).for_each(|(x, k)| *x = f(k));
        v
    }

    fn as_mut_full(&mut self) -> &mut [f32] {
        // SAFETY: Line is 16 f32 with no padding (repr(C), size 64).
        unsafe {
            std::slice::from_raw_parts_mut(self.0.as_mut_ptr() as *mut f32, self.0.len() * 16)
        }
    }
}

impl std::ops::Deref for Aligned {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        // SAFETY: as in `as_mut_full`.
        unsafe { std::slice::from_raw_parts(self.0.as_ptr() as *const f32, self.0.len() * 16) }
    }
}

impl std::ops::DerefMut for Aligned {
    fn deref_mut(&mut self) -> &mut [f32] {
        self.as_mut_full()
    }
}

/// Position i of a bit-reversed spectrum holds bin `bit_reverse(i)`.
pub fn bit_reverse(i: usize, len: usize) -> usize {
    i.reverse_bits() >> (usize::BITS - len.trailing_zeros())
}

/// The position of bin −q in a bit-reversed spectrum, for the bin q at position i: bins 0 and
/// L/2 are their own mirrors, and the positions [2^s, 2^(s+1)) are mirrored within that octave.
pub fn mirror(i: usize) -> usize {
    if i < 2 {
        return i;
    }
    let top = 1usize << (usize::BITS - 1 - i.leading_zeros());
    3 * top - 1 - i
}

/// Twiddles of one radix-4 stage (spans s and s/2): W1 = ω^j, W2 = ω^2j, W3 = ω^3j with
/// ω = e^(−2πi/2s), j < s/2, each as re and im arrays.
struct Radix4 {
    span: usize,
    w: [Aligned; 6],
}

/// The radix-4 stages between whole vectors, largest span first: `vector_stages / 2` of them
/// from span len/2 down (the odd stage left, if any, is the caller's radix-2 one).
fn radix4_stages(len: usize, vector_stages: usize) -> Vec<Radix4> {
    let mut radix4 = Vec::new();
    let mut span = len / 2;
    for _ in 0..vector_stages / 2 {
        let w = std::array::from_fn(|t| {
            // Tables W1re, W1im, W2re, W2im, W3re, W3im.
            let k = t / 2 + 1;
            // Whole lines: the 8-lane kernels' last stage has 8 (the rest is not read).
            Aligned::from_fn((span / 2).next_multiple_of(16), |j| {
                let (c, s) = twiddle(k * j, 2 * span);
                if t % 2 == 0 {
                    c
                } else {
                    s
                }
            })
        });
        radix4.push(Radix4 { span, w });
        span /= 4;
    }
    radix4
}

/// ω^j = e^(−2πij/n) as (re, im) in f32.
fn twiddle(j: usize, n: usize) -> (f32, f32) {
    let a = -2.0 * std::f64::consts::PI * j as f64 / n as f64;
    (a.cos() as f32, a.sin() as f32)
}

pub struct SplitFft {
    len: usize,
    /// Forward order (largest span first); the inverse runs them backwards.
    radix4: Vec<Radix4>,
    /// The radix-2 stage at span 16 when the vector stages are odd in number: ω^j, j < 16.
    radix2: Option<[[f32; 16]; 2]>,
    /// In-vector stages s = 8, 4: twiddle re and im per lane (1 on the lanes that take the
    /// sum), and the sign per lane (+1 sum, −1 difference) for s = 8, 4, 2, 1.
    lane_tw: [[[f32; 16]; 2]; 2],
    lane_sign: [[f32; 16]; 4],
}

impl SplitFft {
    /// For a power-of-two length ≥ 64 (`None` otherwise).
    pub fn new(len: usize) -> Option<Self> {
        if len < 64 || !len.is_power_of_two() {
            return None;
        }
        let vector_stages = len.trailing_zeros() as usize - 4;
        let radix4 = radix4_stages(len, vector_stages);
        let radix2 = (vector_stages % 2 == 1).then(|| {
            let w: [(f32, f32); 16] = std::array::from_fn(|j| twiddle(j, 32));
            [w.map(|t| t.0), w.map(|t| t.1)]
        });
        let mut lane_tw = [[[0.0; 16]; 2]; 2];
        let mut lane_sign = [[0.0; 16]; 4];
        for (t, s) in [8usize, 4, 2, 1].into_iter().enumerate() {
            for l in 0..16 {
                let high = l & s != 0;
                lane_sign[t][l] = if high { -1.0 } else { 1.0 };
                if t < 2 {
                    let (c, sn) = if high {
                        twiddle(l % s, 2 * s)
                    } else {
                        (1.0, 0.0)
                    };
                    lane_tw[t][0][l] = c;
                    lane_tw[t][1][l] = sn;
                }
            }
        }
        Some(Self {
            len,
            radix4,
            radix2,
            lane_tw,
            lane_sign,
        })
    }

    /// Forward FFT of (re, im) in place, natural order in, bit-reversed order out. With
    /// `zero_upper` the input's upper half is taken as zero (not read).
    ///
    /// # Safety
    /// The CPU must have AVX-512F; `re` and `im` must be `len` long.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn forward(&self, re: &mut [f32], im: &mut [f32], zero_upper: bool) {
        use std::arch::x86_64::*;
        self.forward_vertical(re, im, zero_upper);
        let c = self.lanes();
        let (r, i) = (re.as_mut_ptr(), im.as_mut_ptr());
        for b in (0..self.len).step_by(32) {
            let ld = |o: usize| (_mm512_loadu_ps(r.add(o)), _mm512_loadu_ps(i.add(o)));
            let (x, y) = forward_last(&c, ld(b), ld(b + 16));
            _mm512_storeu_ps(r.add(b), x.0);
            _mm512_storeu_ps(i.add(b), x.1);
            _mm512_storeu_ps(r.add(b + 16), y.0);
            _mm512_storeu_ps(i.add(b + 16), y.1);
        }
    }

    /// The forward stages between whole vectors (spans ≥ 16 but the radix-2 one).
    #[target_feature(enable = "avx512f")]
    unsafe fn forward_vertical(&self, re: &mut [f32], im: &mut [f32], zero_upper: bool) {
        use std::arch::x86_64::*;
        assert!(re.len() == self.len && im.len() == self.len);
        let (r, i) = (re.as_mut_ptr(), im.as_mut_ptr());
        let n = self.len;
        for (st, stage) in self.radix4.iter().enumerate() {
            let s = stage.span;
            let h = s / 2;
            let w = &stage.w;
            let first = st == 0 && zero_upper;
            for b in (0..n).step_by(2 * s) {
                for j in (0..h).step_by(16) {
                    let ld = |p: *mut f32, o: usize| _mm512_loadu_ps(p.add(b + j + o));
                    let tw = |t: usize| _mm512_loadu_ps(w[t].as_ptr().add(j));
                    let (a0r, a0i, a1r, a1i) = (ld(r, 0), ld(i, 0), ld(r, h), ld(i, h));
                    let (t0r, t0i, t1r, t1i, t2r, t2i, dr, di);
                    if first {
                        (t0r, t0i, t1r, t1i, t2r, t2i) = (a0r, a0i, a1r, a1i, a0r, a0i);
                        (dr, di) = (a1r, a1i);
                    } else {
                        let (a2r, a2i, a3r, a3i) = (ld(r, s), ld(i, s), ld(r, s + h), ld(i, s + h));
                        t0r = _mm512_add_ps(a0r, a2r);
                        t0i = _mm512_add_ps(a0i, a2i);
                        t2r = _mm512_sub_ps(a0r, a2r);
                        t2i = _mm512_sub_ps(a0i, a2i);
                        t1r = _mm512_add_ps(a1r, a3r);
                        t1i = _mm512_add_ps(a1i, a3i);
                        dr = _mm512_sub_ps(a1r, a3r);
                        di = _mm512_sub_ps(a1i, a3i);
                    }
                    // t3 = −i·d = (di, −dr).
                    let st =
                        |p: *mut f32, o: usize, v: __m512| _mm512_storeu_ps(p.add(b + j + o), v);
                    st(r, 0, _mm512_add_ps(t0r, t1r));
                    st(i, 0, _mm512_add_ps(t0i, t1i));
                    let (xr, xi) = (_mm512_sub_ps(t0r, t1r), _mm512_sub_ps(t0i, t1i));
                    let (yr, yi) = cmul(xr, xi, tw(2), tw(3));
                    st(r, h, yr);
                    st(i, h, yi);
                    let (xr, xi) = (_mm512_add_ps(t2r, di), _mm512_sub_ps(t2i, dr));
                    let (yr, yi) = cmul(xr, xi, tw(0), tw(1));
                    st(r, s, yr);
                    st(i, s, yi);
                    let (xr, xi) = (_mm512_sub_ps(t2r, di), _mm512_add_ps(t2i, dr));
                    let (yr, yi) = cmul(xr, xi, tw(4), tw(5));
                    st(r, s + h, yr);
                    st(i, s + h, yi);
                }
            }
        }
    }

    /// Inverse FFT (unnormalized) of (re, im) in place, bit-reversed order in, natural order
    /// out. With `lower_half` only the output's lower half is computed (the upper is garbage).
    ///
    /// # Safety
    /// The CPU must have AVX-512F; `re` and `im` must be `len` long.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn inverse(&self, re: &mut [f32], im: &mut [f32], lower_half: bool) {
        use std::arch::x86_64::*;
        assert!(re.len() == self.len && im.len() == self.len);
        let (r, i) = (re.as_mut_ptr(), im.as_mut_ptr());
        let n = self.len;
        let c = self.lanes();
        for b in (0..n).step_by(32) {
            let ld = |o: usize| (_mm512_loadu_ps(r.add(o)), _mm512_loadu_ps(i.add(o)));
            let (x, y) = inverse_first(&c, ld(b), ld(b + 16));
            _mm512_storeu_ps(r.add(b), x.0);
            _mm512_storeu_ps(i.add(b), x.1);
            _mm512_storeu_ps(r.add(b + 16), y.0);
            _mm512_storeu_ps(i.add(b + 16), y.1);
        }
        self.inverse_vertical(re, im, lower_half);
    }

    /// The inverse stages between whole vectors (spans ≥ 16 but the radix-2 one).
    #[target_feature(enable = "avx512f")]
    unsafe fn inverse_vertical(&self, re: &mut [f32], im: &mut [f32], lower_half: bool) {
        use std::arch::x86_64::*;
        let (r, i) = (re.as_mut_ptr(), im.as_mut_ptr());
        let n = self.len;
        let stages = self.radix4.len();
        for (st, stage) in self.radix4.iter().rev().enumerate() {
            let s = stage.span;
            let h = s / 2;
            let w = &stage.w;
            let last = st + 1 == stages && lower_half;
            for b in (0..n).step_by(2 * s) {
                for j in (0..h).step_by(16) {
                    let ld = |p: *mut f32, o: usize| _mm512_loadu_ps(p.add(b + j + o));
                    let tw = |t: usize| _mm512_loadu_ps(w[t].as_ptr().add(j));
                    let (a0r, a0i) = (ld(r, 0), ld(i, 0));
                    let (p1r, p1i) = cmul_conj(ld(r, h), ld(i, h), tw(2), tw(3));
                    let (p2r, p2i) = cmul_conj(ld(r, s), ld(i, s), tw(0), tw(1));
                    let (p3r, p3i) = cmul_conj(ld(r, s + h), ld(i, s + h), tw(4), tw(5));
                    let (b0r, b0i) = (_mm512_add_ps(a0r, p1r), _mm512_add_ps(a0i, p1i));
                    let (b1r, b1i) = (_mm512_sub_ps(a0r, p1r), _mm512_sub_ps(a0i, p1i));
                    let (er, ei) = (_mm512_add_ps(p2r, p3r), _mm512_add_ps(p2i, p3i));
                    let (fr, fi) = (_mm512_sub_ps(p2r, p3r), _mm512_sub_ps(p2i, p3i));
                    let st =
                        |p: *mut f32, o: usize, v: __m512| _mm512_storeu_ps(p.add(b + j + o), v);
                    // c0 = b0 + e, c1 = b1 + i·f, c2 = b0 − e, c3 = b1 − i·f (i·f = (−fi, fr)).
                    st(r, 0, _mm512_add_ps(b0r, er));
                    st(i, 0, _mm512_add_ps(b0i, ei));
                    st(r, h, _mm512_sub_ps(b1r, fi));
                    st(i, h, _mm512_add_ps(b1i, fr));
                    if !last {
                        st(r, s, _mm512_sub_ps(b0r, er));
                        st(i, s, _mm512_sub_ps(b0i, ei));
                        st(r, s + h, _mm512_add_ps(b1r, fi));
                        st(i, s + h, _mm512_sub_ps(b1i, fr));
                    }
                }
            }
        }
    }
}

/// The in-vector stages' constants: twiddles of spans 8 and 4, the per-lane signs of spans 8,
/// 4, 2, 1 (+1 on the lanes that take the sum), and the lanes whose span-2 twiddle is ∓i.
struct Lanes {
    w8r: __m512,
    w8i: __m512,
    w4r: __m512,
    w4i: __m512,
    sign: [__m512; 4],
    rot: __mmask16,
    /// The radix-2 stage at span 16 (re, im twiddles), when there is one.
    r2: Option<(__m512, __m512)>,
}

type V2 = (__m512, __m512);

impl SplitFft {
    #[target_feature(enable = "avx512f")]
    #[inline]
    fn lanes(&self) -> Lanes {
        use std::arch::x86_64::*;
        // SAFETY: the tables are 16 f32 each.
        let ld = |t: &[f32; 16]| unsafe { _mm512_loadu_ps(t.as_ptr()) };
        Lanes {
            w8r: ld(&self.lane_tw[0][0]),
            w8i: ld(&self.lane_tw[0][1]),
            w4r: ld(&self.lane_tw[1][0]),
            w4i: ld(&self.lane_tw[1][1]),
            sign: std::array::from_fn(|t| ld(&self.lane_sign[t])),
            // Span 2: lane l % 4 = 3 is the high lane with j = 1, twiddle e^(∓iπ/2).
            rot: 0x8888,
            r2: self.radix2.as_ref().map(|w| (ld(&w[0]), ld(&w[1]))),
        }
    }
}

/// The forward transform's last pass on the vector pair (a, b) 16 apart: the radix-2 stage at
/// span 16 (if any), then the in-vector stages of each.
#[target_feature(enable = "avx512f")]
#[inline]
fn forward_last(c: &Lanes, a: V2, b: V2) -> (V2, V2) {
    use std::arch::x86_64::*;
    let Some((wr, wi)) = c.r2 else {
        return (lanes_forward(c, a.0, a.1), lanes_forward(c, b.0, b.1));
    };
    let x = lanes_forward(c, _mm512_add_ps(a.0, b.0), _mm512_add_ps(a.1, b.1));
    let (yr, yi) = cmul(_mm512_sub_ps(a.0, b.0), _mm512_sub_ps(a.1, b.1), wr, wi);
    (x, lanes_forward(c, yr, yi))
}

/// The inverse transform's first pass on the vector pair (a, b) 16 apart: the in-vector stages
/// of each, then the radix-2 stage at span 16 (if any).
#[target_feature(enable = "avx512f")]
#[inline]
fn inverse_first(c: &Lanes, a: V2, b: V2) -> (V2, V2) {
    use std::arch::x86_64::*;
    let (a, b) = (lanes_inverse(c, a.0, a.1), lanes_inverse(c, b.0, b.1));
    let Some((wr, wi)) = c.r2 else {
        return (a, b);
    };
    let b = cmul_conj(b.0, b.1, wr, wi);
    (
        (_mm512_add_ps(a.0, b.0), _mm512_add_ps(a.1, b.1)),
        (_mm512_sub_ps(a.0, b.0), _mm512_sub_ps(a.1, b.1)),
    )
}

/// The forward in-vector stages (spans 8, 4, 2, 1) of one vector. Each: u = v·sign + partner
/// (a + b on the low lanes, a − b on the high ones), then the twiddle.
#[target_feature(enable = "avx512f")]
#[inline]
fn lanes_forward(c: &Lanes, vr: __m512, vi: __m512) -> (__m512, __m512) {
    use std::arch::x86_64::*;
    let ur = _mm512_fmadd_ps(vr, c.sign[0], _mm512_shuffle_f32x4::<0x4E>(vr, vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[0], _mm512_shuffle_f32x4::<0x4E>(vi, vi));
    let (vr, vi) = cmul(ur, ui, c.w8r, c.w8i);
    let ur = _mm512_fmadd_ps(vr, c.sign[1], _mm512_shuffle_f32x4::<0xB1>(vr, vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[1], _mm512_shuffle_f32x4::<0xB1>(vi, vi));
    let (vr, vi) = cmul(ur, ui, c.w4r, c.w4i);
    let ur = _mm512_fmadd_ps(vr, c.sign[2], _mm512_permute_ps::<0x4E>(vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[2], _mm512_permute_ps::<0x4E>(vi));
    // ·(−i) on the rotated lanes: (re, im) → (im, −re).
    let vr = _mm512_mask_blend_ps(c.rot, ur, ui);
    let vi = _mm512_mask_sub_ps(ui, c.rot, _mm512_setzero_ps(), ur);
    let ur = _mm512_fmadd_ps(vr, c.sign[3], _mm512_permute_ps::<0xB1>(vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[3], _mm512_permute_ps::<0xB1>(vi));
    (ur, ui)
}

/// The inverse in-vector stages (spans 1, 2, 4, 8) of one vector: the conjugate twiddle on the
/// high lanes, then u = v·sign + partner (a + w·b low, a − w·b high).
#[target_feature(enable = "avx512f")]
#[inline]
fn lanes_inverse(c: &Lanes, vr: __m512, vi: __m512) -> (__m512, __m512) {
    use std::arch::x86_64::*;
    let ur = _mm512_fmadd_ps(vr, c.sign[3], _mm512_permute_ps::<0xB1>(vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[3], _mm512_permute_ps::<0xB1>(vi));
    // ·(+i) on the rotated lanes: (re, im) → (−im, re).
    let vr = _mm512_mask_sub_ps(ur, c.rot, _mm512_setzero_ps(), ui);
    let vi = _mm512_mask_blend_ps(c.rot, ui, ur);
    let ur = _mm512_fmadd_ps(vr, c.sign[2], _mm512_permute_ps::<0x4E>(vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[2], _mm512_permute_ps::<0x4E>(vi));
    let (vr, vi) = cmul_conj(ur, ui, c.w4r, c.w4i);
    let ur = _mm512_fmadd_ps(vr, c.sign[1], _mm512_shuffle_f32x4::<0xB1>(vr, vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[1], _mm512_shuffle_f32x4::<0xB1>(vi, vi));
    let (vr, vi) = cmul_conj(ur, ui, c.w8r, c.w8i);
    let ur = _mm512_fmadd_ps(vr, c.sign[0], _mm512_shuffle_f32x4::<0x4E>(vr, vr));
    let ui = _mm512_fmadd_ps(vi, c.sign[0], _mm512_shuffle_f32x4::<0x4E>(vi, vi));
    (ur, ui)
}

/// (xr + i·xi)(wr + i·wi).
#[target_feature(enable = "avx512f")]
#[inline]
fn cmul(xr: __m512, xi: __m512, wr: __m512, wi: __m512) -> (__m512, __m512) {
    use std::arch::x86_64::*;
    (
        _mm512_fmsub_ps(xr, wr, _mm512_mul_ps(xi, wi)),
        _mm512_fmadd_ps(xr, wi, _mm512_mul_ps(xi, wr)),
    )
}

/// (xr + i·xi)·conj(wr + i·wi).
#[target_feature(enable = "avx512f")]
#[inline]
fn cmul_conj(xr: __m512, xi: __m512, wr: __m512, wi: __m512) -> (__m512, __m512) {
    use std::arch::x86_64::*;
    (
        _mm512_fmadd_ps(xr, wr, _mm512_mul_ps(xi, wi)),
        _mm512_fmsub_ps(xi, wr, _mm512_mul_ps(xr, wi)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use rustfft::{num_complex::Complex, FftPlanner};

    /// The AVX-512 kernels against rustfft ([`check_against_rustfft`]), at lengths with and
    /// without the radix-2 stage.
    #[test]
    fn transforms_match_rustfft_in_bit_reversed_order() {
        if !crate::recon::simd::has_avx512f() {
            eprintln!("skipped: no AVX-512F on this CPU");
            return;
        }
        assert!(SplitFft::new(32).is_none() && SplitFft::new(96).is_none());
        for len in [64usize, 128, 256, 2048, 4096] {
            let fft = SplitFft::new(len).expect("power of two");
            // SAFETY: AVX-512F is present (checked); the slices are len long.
            check_against_rustfft(
                len,
                |re, im, zero| unsafe { fft.forward(re, im, zero) },
                |re, im, zero| unsafe { fft.inverse(re, im, zero) },
            );
        }
    }

    /// The same for the 8-lane AVX2 kernels, at lengths with and without their radix-2 stage.
    #[test]
    fn avx2_transforms_match_rustfft_in_bit_reversed_order() {
        if !crate::recon::simd::has_avx2_fma() {
            eprintln!("skipped: no AVX2/FMA on this CPU");
            return;
        }
        assert!(SplitFft8::new(16).is_none() && SplitFft8::new(96).is_none());
        for len in [32usize, 64, 128, 256, 2048, 4096] {
            let fft = SplitFft8::new(len).expect("power of two");
            // SAFETY: AVX2 and FMA are present (checked); the slices are len long.
            check_against_rustfft(
                len,
                |re, im, zero| unsafe { fft.forward(re, im, zero) },
                |re, im, zero| unsafe { fft.inverse(re, im, zero) },
            );
        }
    }

    /// Forward: rustfft's spectrum in bit-reversed order; inverse: rustfft's inverse back in
    /// natural order; with the zero upper half and the lower-half output. Mirror pairs bin q
    /// with bin −q.
    fn check_against_rustfft(
        len: usize,
        forward: impl Fn(&mut [f32], &mut [f32], bool),
        inverse: impl Fn(&mut [f32], &mut [f32], bool),
    ) {
        let mut planner = FftPlanner::<f32>::new();
        let (fw, iv) = (planner.plan_fft_forward(len), planner.plan_fft_inverse(len));
        for zero in [false, true] {
            let x: Vec<Complex<f32>> = (0..len)
                .map(|k| {
                    if zero && k >= len / 2 {
                        Complex::new(0.0, 0.0)
                    } else {
                        Complex::new((k as f32 * 0.37).sin(), (k as f32 * 1.3).cos() - 0.2)
                    }
                })
                .collect();
            let mut want = x.clone();
            fw.process(&mut want);
            let mut re: Vec<f32> = x.iter().map(|c| c.re).collect();
            let mut im: Vec<f32> = x.iter().map(|c| c.im).collect();
            if zero {
                // Not read.
                re[len / 2..].fill(f32::NAN);
                im[len / 2..].fill(f32::NAN);
            }
            forward(&mut re, &mut im, zero);
            let tol = 1e-5 * len as f32;
            for i in 0..len {
                let q = bit_reverse(i, len);
                assert!((want[q].re - re[i]).abs() < tol, "len={len} i={i}");
                assert!((want[q].im - im[i]).abs() < tol, "len={len} i={i}");
                assert_eq!(bit_reverse(mirror(i), len), (len - q) % len);
            }
            let mut back = want.clone();
            iv.process(&mut back);
            inverse(&mut re, &mut im, zero);
            let top = if zero { len / 2 } else { len };
            for k in 0..top {
                assert!((back[k].re - re[k]).abs() < tol, "len={len} k={k}");
                assert!((back[k].im - im[k]).abs() < tol, "len={len} k={k}");
                assert!(
                    (x[k].re * len as f32 - re[k]).abs() < tol,
                    "len={len} k={k}"
                );
            }
        }
    }
}
