//! The split-format FFT of the parent module in 8-lane AVX2 (with FMA), for CPUs without
//! AVX-512F: the same stages and orders (forward DIF to bit-reversed, inverse DIT back, the zero
//! upper input half and the unused upper output half skipped), with the in-vector stages at
//! spans 4, 2, 1 and the vector stages from span 8 up.

use std::arch::x86_64::__m256;

use super::{radix4_stages, twiddle, Radix4};

pub struct SplitFft8 {
    len: usize,
    /// Forward order (largest span first); the inverse runs them backwards.
    radix4: Vec<Radix4>,
    /// The radix-2 stage at span 8 when the vector stages are odd in number: ω^j, j < 8.
    radix2: Option<[[f32; 8]; 2]>,
    /// In-vector stage s = 4: twiddle re and im per lane (1 on the lanes that take the sum), and
    /// the sign per lane (+1 sum, −1 difference) for s = 4, 2, 1.
    lane_tw: [[f32; 8]; 2],
    lane_sign: [[f32; 8]; 3],
}

type V2 = (__m256, __m256);

/// The in-vector stages' constants.
struct Lanes {
    w4r: __m256,
    w4i: __m256,
    sign: [__m256; 3],
    /// The radix-2 stage at span 8 (re, im twiddles), when there is one.
    r2: Option<V2>,
}

impl SplitFft8 {
    /// For a power-of-two length ≥ 32 (`None` otherwise).
    pub fn new(len: usize) -> Option<Self> {
        if len < 32 || !len.is_power_of_two() {
            return None;
        }
        let vector_stages = len.trailing_zeros() as usize - 3;
        let radix4 = radix4_stages(len, vector_stages);
        let radix2 = (vector_stages % 2 == 1).then(|| {
            let w: [(f32, f32); 8] = std::array::from_fn(|j| twiddle(j, 16));
            [w.map(|t| t.0), w.map(|t| t.1)]
        });
        let mut lane_tw = [[0.0; 8]; 2];
        let mut lane_sign = [[0.0; 8]; 3];
        for (t, s) in [4usize, 2, 1].into_iter().enumerate() {
            for l in 0..8 {
                let high = l & s != 0;
                lane_sign[t][l] = if high { -1.0 } else { 1.0 };
                if t == 0 {
                    let (c, sn) = if high {
                        twiddle(l % s, 2 * s)
                    } else {
                        (1.0, 0.0)
                    };
                    lane_tw[0][l] = c;
                    lane_tw[1][l] = sn;
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

    #[target_feature(enable = "avx2,fma")]
    #[inline]
    fn lanes(&self) -> Lanes {
        use std::arch::x86_64::*;
        // SAFETY: the tables are 8 f32 each.
        let ld = |t: &[f32; 8]| unsafe { _mm256_loadu_ps(t.as_ptr()) };
        Lanes {
            w4r: ld(&self.lane_tw[0]),
            w4i: ld(&self.lane_tw[1]),
            sign: std::array::from_fn(|t| ld(&self.lane_sign[t])),
            r2: self.radix2.as_ref().map(|w| (ld(&w[0]), ld(&w[1]))),
        }
    }

    /// Forward FFT of (re, im) in place, natural order in, bit-reversed order out. With
    /// `zero_upper` the input's upper half is taken as zero (not read).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA; `re` and `im` must be `len` long.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn forward(&self, re: &mut [f32], im: &mut [f32], zero_upper: bool) {
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
                for j in (0..h).step_by(8) {
                    let ld = |p: *mut f32, o: usize| _mm256_loadu_ps(p.add(b + j + o));
                    let tw = |t: usize| _mm256_loadu_ps(w[t].as_ptr().add(j));
                    let (a0r, a0i, a1r, a1i) = (ld(r, 0), ld(i, 0), ld(r, h), ld(i, h));
                    let (t0r, t0i, t1r, t1i, t2r, t2i, dr, di);
                    if first {
                        (t0r, t0i, t1r, t1i, t2r, t2i) = (a0r, a0i, a1r, a1i, a0r, a0i);
                        (dr, di) = (a1r, a1i);
                    } else {
                        let (a2r, a2i, a3r, a3i) = (ld(r, s), ld(i, s), ld(r, s + h), ld(i, s + h));
                        t0r = _mm256_add_ps(a0r, a2r);
                        t0i = _mm256_add_ps(a0i, a2i);
                        t2r = _mm256_sub_ps(a0r, a2r);
                        t2i = _mm256_sub_ps(a0i, a2i);
                        t1r = _mm256_add_ps(a1r, a3r);
                        t1i = _mm256_add_ps(a1i, a3i);
                        dr = _mm256_sub_ps(a1r, a3r);
                        di = _mm256_sub_ps(a1i, a3i);
                    }
                    // t3 = −i·d = (di, −dr).
                    let st =
                        |p: *mut f32, o: usize, v: __m256| _mm256_storeu_ps(p.add(b + j + o), v);
                    st(r, 0, _mm256_add_ps(t0r, t1r));
                    st(i, 0, _mm256_add_ps(t0i, t1i));
                    let (yr, yi) = cmul(
                        _mm256_sub_ps(t0r, t1r),
                        _mm256_sub_ps(t0i, t1i),
                        tw(2),
                        tw(3),
                    );
                    st(r, h, yr);
                    st(i, h, yi);
                    let (yr, yi) =
                        cmul(_mm256_add_ps(t2r, di), _mm256_sub_ps(t2i, dr), tw(0), tw(1));
                    st(r, s, yr);
                    st(i, s, yi);
                    let (yr, yi) =
                        cmul(_mm256_sub_ps(t2r, di), _mm256_add_ps(t2i, dr), tw(4), tw(5));
                    st(r, s + h, yr);
                    st(i, s + h, yi);
                }
            }
        }
        let c = self.lanes();
        for b in (0..n).step_by(16) {
            let ld = |o: usize| (_mm256_loadu_ps(r.add(o)), _mm256_loadu_ps(i.add(o)));
            let (x, y) = forward_last(&c, ld(b), ld(b + 8));
            _mm256_storeu_ps(r.add(b), x.0);
            _mm256_storeu_ps(i.add(b), x.1);
            _mm256_storeu_ps(r.add(b + 8), y.0);
            _mm256_storeu_ps(i.add(b + 8), y.1);
        }
    }

    /// Inverse FFT (unnormalized) of (re, im) in place, bit-reversed order in, natural order
    /// out. With `lower_half` only the output's lower half is computed (the upper is garbage).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA; `re` and `im` must be `len` long.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn inverse(&self, re: &mut [f32], im: &mut [f32], lower_half: bool) {
        use std::arch::x86_64::*;
        assert!(re.len() == self.len && im.len() == self.len);
        let (r, i) = (re.as_mut_ptr(), im.as_mut_ptr());
        let n = self.len;
        let c = self.lanes();
        for b in (0..n).step_by(16) {
            let ld = |o: usize| (_mm256_loadu_ps(r.add(o)), _mm256_loadu_ps(i.add(o)));
            let (x, y) = inverse_first(&c, ld(b), ld(b + 8));
            _mm256_storeu_ps(r.add(b), x.0);
            _mm256_storeu_ps(i.add(b), x.1);
            _mm256_storeu_ps(r.add(b + 8), y.0);
            _mm256_storeu_ps(i.add(b + 8), y.1);
        }
        let stages = self.radix4.len();
        for (st, stage) in self.radix4.iter().rev().enumerate() {
            let s = stage.span;
            let h = s / 2;
            let w = &stage.w;
            let last = st + 1 == stages && lower_half;
            for b in (0..n).step_by(2 * s) {
                for j in (0..h).step_by(8) {
                    let ld = |p: *mut f32, o: usize| _mm256_loadu_ps(p.add(b + j + o));
                    let tw = |t: usize| _mm256_loadu_ps(w[t].as_ptr().add(j));
                    let (a0r, a0i) = (ld(r, 0), ld(i, 0));
                    let (p1r, p1i) = cmul_conj(ld(r, h), ld(i, h), tw(2), tw(3));
                    let (p2r, p2i) = cmul_conj(ld(r, s), ld(i, s), tw(0), tw(1));
                    let (p3r, p3i) = cmul_conj(ld(r, s + h), ld(i, s + h), tw(4), tw(5));
                    let (b0r, b0i) = (_mm256_add_ps(a0r, p1r), _mm256_add_ps(a0i, p1i));
                    let (b1r, b1i) = (_mm256_sub_ps(a0r, p1r), _mm256_sub_ps(a0i, p1i));
                    let (er, ei) = (_mm256_add_ps(p2r, p3r), _mm256_add_ps(p2i, p3i));
                    let (fr, fi) = (_mm256_sub_ps(p2r, p3r), _mm256_sub_ps(p2i, p3i));
                    let st =
                        |p: *mut f32, o: usize, v: __m256| _mm256_storeu_ps(p.add(b + j + o), v);
                    // c0 = b0 + e, c1 = b1 + i·f, c2 = b0 − e, c3 = b1 − i·f (i·f = (−fi, fr)).
                    st(r, 0, _mm256_add_ps(b0r, er));
                    st(i, 0, _mm256_add_ps(b0i, ei));
                    st(r, h, _mm256_sub_ps(b1r, fi));
                    st(i, h, _mm256_add_ps(b1i, fr));
                    if !last {
                        st(r, s, _mm256_sub_ps(b0r, er));
                        st(i, s, _mm256_sub_ps(b0i, ei));
                        st(r, s + h, _mm256_add_ps(b1r, fi));
                        st(i, s + h, _mm256_sub_ps(b1i, fr));
                    }
                }
            }
        }
    }
}

/// The forward transform's last pass on the vector pair (a, b) 8 apart: the radix-2 stage at
/// span 8 (if any), then the in-vector stages of each.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn forward_last(c: &Lanes, a: V2, b: V2) -> (V2, V2) {
    use std::arch::x86_64::*;
    let Some((wr, wi)) = c.r2 else {
        return (lanes_forward(c, a.0, a.1), lanes_forward(c, b.0, b.1));
    };
    let x = lanes_forward(c, _mm256_add_ps(a.0, b.0), _mm256_add_ps(a.1, b.1));
    let (yr, yi) = cmul(_mm256_sub_ps(a.0, b.0), _mm256_sub_ps(a.1, b.1), wr, wi);
    (x, lanes_forward(c, yr, yi))
}

/// The inverse transform's first pass on the vector pair (a, b) 8 apart: the in-vector stages
/// of each, then the radix-2 stage at span 8 (if any).
#[target_feature(enable = "avx2,fma")]
#[inline]
fn inverse_first(c: &Lanes, a: V2, b: V2) -> (V2, V2) {
    use std::arch::x86_64::*;
    let (a, b) = (lanes_inverse(c, a.0, a.1), lanes_inverse(c, b.0, b.1));
    let Some((wr, wi)) = c.r2 else {
        return (a, b);
    };
    let b = cmul_conj(b.0, b.1, wr, wi);
    (
        (_mm256_add_ps(a.0, b.0), _mm256_add_ps(a.1, b.1)),
        (_mm256_sub_ps(a.0, b.0), _mm256_sub_ps(a.1, b.1)),
    )
}

/// The forward in-vector stages (spans 4, 2, 1) of one vector. Each: u = v·sign + partner
/// (a + b on the low lanes, a − b on the high ones), then the twiddle. Span 2's only
/// non-trivial twiddle, −i, falls on lanes 3 and 7.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn lanes_forward(c: &Lanes, vr: __m256, vi: __m256) -> V2 {
    use std::arch::x86_64::*;
    let ur = _mm256_fmadd_ps(vr, c.sign[0], _mm256_permute2f128_ps::<0x01>(vr, vr));
    let ui = _mm256_fmadd_ps(vi, c.sign[0], _mm256_permute2f128_ps::<0x01>(vi, vi));
    let (vr, vi) = cmul(ur, ui, c.w4r, c.w4i);
    let ur = _mm256_fmadd_ps(vr, c.sign[1], _mm256_permute_ps::<0x4E>(vr));
    let ui = _mm256_fmadd_ps(vi, c.sign[1], _mm256_permute_ps::<0x4E>(vi));
    // ·(−i) on lanes 3 and 7: (re, im) → (im, −re).
    let vr = _mm256_blend_ps::<0x88>(ur, ui);
    let vi = _mm256_blend_ps::<0x88>(ui, _mm256_sub_ps(_mm256_setzero_ps(), ur));
    let ur = _mm256_fmadd_ps(vr, c.sign[2], _mm256_permute_ps::<0xB1>(vr));
    let ui = _mm256_fmadd_ps(vi, c.sign[2], _mm256_permute_ps::<0xB1>(vi));
    (ur, ui)
}

/// The inverse in-vector stages (spans 1, 2, 4) of one vector: the conjugate twiddle on the
/// high lanes, then u = v·sign + partner (a + w·b low, a − w·b high).
#[target_feature(enable = "avx2,fma")]
#[inline]
fn lanes_inverse(c: &Lanes, vr: __m256, vi: __m256) -> V2 {
    use std::arch::x86_64::*;
    let ur = _mm256_fmadd_ps(vr, c.sign[2], _mm256_permute_ps::<0xB1>(vr));
    let ui = _mm256_fmadd_ps(vi, c.sign[2], _mm256_permute_ps::<0xB1>(vi));
    // ·(+i) on lanes 3 and 7: (re, im) → (−im, re).
    let vr = _mm256_blend_ps::<0x88>(ur, _mm256_sub_ps(_mm256_setzero_ps(), ui));
    let vi = _mm256_blend_ps::<0x88>(ui, ur);
    let ur = _mm256_fmadd_ps(vr, c.sign[1], _mm256_permute_ps::<0x4E>(vr));
    let ui = _mm256_fmadd_ps(vi, c.sign[1], _mm256_permute_ps::<0x4E>(vi));
    let (vr, vi) = cmul_conj(ur, ui, c.w4r, c.w4i);
    let ur = _mm256_fmadd_ps(vr, c.sign[0], _mm256_permute2f128_ps::<0x01>(vr, vr));
    let ui = _mm256_fmadd_ps(vi, c.sign[0], _mm256_permute2f128_ps::<0x01>(vi, vi));
    (ur, ui)
}

/// (xr + i·xi)(wr + i·wi).
#[target_feature(enable = "avx2,fma")]
#[inline]
fn cmul(xr: __m256, xi: __m256, wr: __m256, wi: __m256) -> V2 {
    use std::arch::x86_64::*;
    (
        _mm256_fmsub_ps(xr, wr, _mm256_mul_ps(xi, wi)),
        _mm256_fmadd_ps(xr, wi, _mm256_mul_ps(xi, wr)),
    )
}

/// (xr + i·xi)·conj(wr + i·wi).
#[target_feature(enable = "avx2,fma")]
#[inline]
fn cmul_conj(xr: __m256, xi: __m256, wr: __m256, wi: __m256) -> V2 {
    use std::arch::x86_64::*;
    (
        _mm256_fmadd_ps(xr, wr, _mm256_mul_ps(xi, wi)),
        _mm256_fmsub_ps(xi, wr, _mm256_mul_ps(xr, wi)),
    )
}
