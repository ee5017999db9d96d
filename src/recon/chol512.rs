//! [`super::chol`]'s Cholesky and block solve in AVX-512 (eight f64 lanes per register), for the
//! CPUs that have it. Same algorithms and packed 8-row strips. The block solve does the same
//! operations in the same order in every lane as the AVX2 kernel, hence the same bits; the
//! factor's panel works in groups of 8 columns instead of 4, which changes the last bits of L.
//!
//! Why separate kernels: a 256-bit FMA does half the work of a 512-bit one, and on the Intel
//! Xeon (Emerald Rapids) the project ran on in session 24 the core retires two 512-bit FMAs per
//! cycle (87 GF against 42-47 for 256-bit, same loop). The register tiles are wider to keep
//! enough independent FMAs in flight (latency 4, two pipes: at least eight accumulators):
//! - trailing update: 16 rows (two strips) x 8 columns, 16 accumulators (32 registers);
//! - panel: 16 rows x 8 columns, groups of 8 columns;
//! - block solve: 8 rows x 16 right-hand sides, 16 accumulators.
//!
//! Partial strips and rows use masked loads and stores instead of the AVX2 path's staging copies.

use std::arch::x86_64::*;

/// The lanes of the first `rows` (≤ 8, more means all) entries.
#[inline]
fn mask(rows: usize) -> __mmask8 {
    if rows >= 8 {
        0xff
    } else {
        ((1u32 << rows) - 1) as __mmask8
    }
}

/// Factors the lower triangle of the column-major n x n matrix in `a` (columns `ld` ≥ n apart)
/// in place; false when it is not numerically positive definite. As
/// [`super::chol::cholesky_lower_avx2`], `pack` is scratch kept by the caller.
///
/// # Safety
/// AVX-512F must be present.
#[target_feature(enable = "avx512f")]
pub unsafe fn cholesky_lower_avx512(
    a: &mut [f64],
    n: usize,
    ld: usize,
    pack: &mut Vec<f64>,
) -> bool {
    super::chol::blocked_cholesky(a, n, ld, pack, panel, trailing_update)
}

/// acc[c][s] = Σ_kk a_s[kk][0..8]·b[8·kk + c] for c < C, strips s < S (strip s at a + s·ss):
/// the (8·S) x C tile of a k-step product, both operands packed k-major in 8s.
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn tile<const S: usize, const C: usize>(
    a: *const f64,
    ss: usize,
    b: *const f64,
    k: usize,
) -> [[__m512d; S]; C] {
    let mut acc = [[_mm512_setzero_pd(); S]; C];
    let (mut a, mut b) = (a, b);
    for _ in 0..k {
        let mut av = [_mm512_setzero_pd(); S];
        for (s, v) in av.iter_mut().enumerate() {
            *v = _mm512_loadu_pd(a.add(s * ss));
        }
        for (c, acc) in acc.iter_mut().enumerate() {
            let v = _mm512_set1_pd(*b.add(c));
            for (x, a) in acc.iter_mut().zip(&av) {
                *x = _mm512_fmadd_pd(*a, v, *x);
            }
        }
        a = a.add(8);
        b = b.add(8);
    }
    acc
}

/// f(s, acc) for each strip s of `strips`, acc its 8 x 8 tile against the 8 columns at `bp`
/// over k steps ([`tile`]): two strips per tile (16 accumulators), the last one alone.
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn strip_tiles(
    pk: *const f64,
    stride: usize,
    bp: *const f64,
    k: usize,
    strips: std::ops::Range<usize>,
    mut f: impl FnMut(usize, [__m512d; 8]),
) {
    let mut s = strips.start;
    while s + 1 < strips.end {
        let acc = tile::<2, 8>(pk.add(s * stride), stride, bp, k);
        f(s, acc.map(|a| a[0]));
        f(s + 1, acc.map(|a| a[1]));
        s += 2;
    }
    if s < strips.end {
        let acc = tile::<1, 8>(pk.add(s * stride), stride, bp, k);
        f(s, acc.map(|a| a[0]));
    }
}

/// [`super::chol`]'s panel step in groups of 8 columns instead of 4: factors the panel of rows
/// 0..r, columns 0..b at p, left-looking, and writes its rows packed to `pk` (strip s at
/// pk + s·stride). The update tiles are 16 x 8 (16 accumulators) and each group's diagonal block
/// is a whole strip. Against groups of 4 (16 x 4 tiles), `bench chol --m 600 --repeat 301`,
/// quiet-spell bests: 0.846-0.895 ms against 0.969-0.982.
#[target_feature(enable = "avx512f")]
unsafe fn panel(p: *mut f64, ld: usize, r: usize, b: usize, pk: *mut f64, stride: usize) -> bool {
    let strips = r.div_ceil(8);
    for c0 in (0..b).step_by(8) {
        let w = 8.min(b - c0);
        let s0 = c0 / 8;
        // Rows c0..c0 + 8 as the tiles' second operand: lane 0 of strip s0. Lanes beyond b (a
        // partial last group) are finite scratch and feed only columns not stored.
        let bp = pk.add(s0 * stride);
        let m0 = mask(r - 8 * s0);
        let acc = tile::<1, 8>(pk.add(s0 * stride), stride, bp, c0);
        for (c, acc) in acc.iter().enumerate().take(w) {
            let col = p.add((c0 + c) * ld + 8 * s0);
            let v = _mm512_maskz_loadu_pd(m0, col);
            _mm512_mask_storeu_pd(col, m0, _mm512_sub_pd(v, acc[0]));
        }
        let mut lt = [[0.0f64; 8]; 8];
        let mut inv = [0.0f64; 8];
        for c in 0..w {
            let d = *p.add((c0 + c) * ld + c0 + c);
            let d = lt[c][..c].iter().fold(d, |d, v| d - v * v);
            if d.is_nan() || d <= 0.0 {
                return false;
            }
            let d = d.sqrt();
            lt[c][c] = d;
            inv[c] = 1.0 / d;
            for i in c + 1..w {
                let v = *p.add((c0 + c) * ld + c0 + i);
                let v = (0..c).fold(v, |v, q| v - lt[i][q] * lt[c][q]);
                lt[i][c] = v / d;
            }
        }
        let solve = |s: usize, acc: [__m512d; 8]| {
            let mk = mask(r - 8 * s);
            let mut xs = [_mm512_setzero_pd(); 8];
            for c in 0..w {
                let col = p.add((c0 + c) * ld + 8 * s);
                let mut v = _mm512_sub_pd(_mm512_maskz_loadu_pd(mk, col), acc[c]);
                for q in 0..c {
                    v = _mm512_fnmadd_pd(xs[q], _mm512_set1_pd(lt[c][q]), v);
                }
                xs[c] = _mm512_mul_pd(v, _mm512_set1_pd(inv[c]));
            }
            for (c, x) in xs.iter().enumerate().take(w) {
                _mm512_mask_storeu_pd(p.add((c0 + c) * ld + 8 * s), mk, *x);
                _mm512_storeu_pd(pk.add(s * stride + (c0 + c) * 8), *x);
            }
        };
        // The diagonal strip is the block itself: L_gg (rows above the diagonal are scratch).
        #[allow(clippy::needless_range_loop)] // c picks a column of lt (row-major) and of p.
        for c in 0..w {
            let col = p.add((c0 + c) * ld + 8 * s0);
            let t: [f64; 8] = std::array::from_fn(|i| if i < w { lt[i][c] } else { 0.0 });
            let x = _mm512_loadu_pd(t.as_ptr());
            _mm512_mask_storeu_pd(col, m0, x);
            _mm512_storeu_pd(pk.add(s0 * stride + (c0 + c) * 8), x);
        }
        strip_tiles(pk, stride, bp, c0, s0 + 1..strips, solve);
    }
    true
}

/// C (r x r, lower, at c) −= PPᵀ for the panel rows below its diagonal block (strips from b / 8
/// of `pk`, k = b columns, b a multiple of 8), in groups of 8 trailing columns.
#[target_feature(enable = "avx512f")]
unsafe fn trailing_update(
    c: *mut f64,
    ld: usize,
    r: usize,
    b: usize,
    pk: *const f64,
    stride: usize,
) {
    debug_assert!(b.is_multiple_of(8));
    let strips = (r + b).div_ceil(8);
    for t in (0..r).step_by(8) {
        let w = 8.min(r - t);
        // Trailing row t is panel row b + t: lane 0 of strip (b + t) / 8. Lanes beyond r of a
        // partial last strip are finite scratch and feed only the columns not stored.
        let bp = pk.add(((b + t) / 8) * stride);
        let apply = |s: usize, acc: [__m512d; 8]| {
            let row0 = 8 * s - b;
            let mk = mask(r - row0);
            for (q, acc) in acc.iter().enumerate().take(w) {
                let col = c.add((t + q) * ld + row0);
                let v = _mm512_maskz_loadu_pd(mk, col);
                _mm512_mask_storeu_pd(col, mk, _mm512_sub_pd(v, *acc));
            }
        };
        strip_tiles(pk, stride, bp, b, (b + t) / 8..strips, apply);
    }
}

/// X ← G⁻¹X = L⁻ᵀL⁻¹X, as [`super::chol::gram_solve_rows_avx2`] (X row by row, m rows of `w`
/// entries, w a multiple of 8; L the lower triangle of the column-major `l`).
///
/// # Safety
/// AVX-512F must be present.
#[target_feature(enable = "avx512f")]
pub unsafe fn gram_solve_rows_avx512(l: &[f64], ld: usize, m: usize, x: &mut [f64], w: usize) {
    super::chol::row_sweeps(l, ld, m, x, w, rows_diag, rows_update_range)
}

/// Rows `rows` of X (at `xp`, w apart) −= Σ_k b[i·cs + k·ks]·x[k·w..] over k < kk: 8 rows and
/// 16 columns per tile, then 8 columns.
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn rows_update_range(
    b: *const f64,
    cs: usize,
    ks: usize,
    x: *const f64,
    xp: *mut f64,
    w: usize,
    kk: usize,
    rows: std::ops::Range<usize>,
) {
    let mut i0 = rows.start;
    while i0 < rows.end {
        let r = 8.min(rows.end - i0);
        let (bi, y) = (b.add(i0 * cs), xp.add(i0 * w));
        let mut g = 0;
        while g + 16 <= w {
            rows_update::<2>(bi, cs, ks, x.add(g), y.add(g), w, kk, r);
            g += 16;
        }
        if g < w {
            rows_update::<1>(bi, cs, ks, x.add(g), y.add(g), w, kk, r);
        }
        i0 += r;
    }
}

/// Rows c < r ≤ 8 of y (w apart, 8·V entries each) −= Σ_k b[c·cs + k·ks]·x[k·w..][0..8·V].
#[target_feature(enable = "avx512f")]
#[inline]
#[allow(clippy::too_many_arguments)]
unsafe fn rows_update<const V: usize>(
    b: *const f64,
    cs: usize,
    ks: usize,
    x: *const f64,
    y: *mut f64,
    w: usize,
    kk: usize,
    r: usize,
) {
    match r {
        8 => rows_tile::<8, V>(b, cs, ks, x, y, w, kk),
        7 => rows_tile::<7, V>(b, cs, ks, x, y, w, kk),
        6 => rows_tile::<6, V>(b, cs, ks, x, y, w, kk),
        5 => rows_tile::<5, V>(b, cs, ks, x, y, w, kk),
        4 => rows_tile::<4, V>(b, cs, ks, x, y, w, kk),
        3 => rows_tile::<3, V>(b, cs, ks, x, y, w, kk),
        2 => rows_tile::<2, V>(b, cs, ks, x, y, w, kk),
        1 => rows_tile::<1, V>(b, cs, ks, x, y, w, kk),
        _ => {}
    }
}

/// The R x (8·V) register tile of [`rows_update`].
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn rows_tile<const R: usize, const V: usize>(
    b: *const f64,
    cs: usize,
    ks: usize,
    x: *const f64,
    y: *mut f64,
    w: usize,
    kk: usize,
) {
    let mut acc = [[_mm512_setzero_pd(); V]; R];
    for (c, acc) in acc.iter_mut().enumerate() {
        for (v, a) in acc.iter_mut().enumerate() {
            *a = _mm512_loadu_pd(y.add(c * w + 8 * v));
        }
    }
    let mut x = x;
    for k in 0..kk {
        let mut xv = [_mm512_setzero_pd(); V];
        for (v, xv) in xv.iter_mut().enumerate() {
            *xv = _mm512_loadu_pd(x.add(8 * v));
        }
        let o = k * ks;
        for (c, acc) in acc.iter_mut().enumerate() {
            let f = _mm512_set1_pd(*b.add(c * cs + o));
            for (a, xv) in acc.iter_mut().zip(&xv) {
                *a = _mm512_fnmadd_pd(*xv, f, *a);
            }
        }
        x = x.add(w);
    }
    for (c, acc) in acc.iter().enumerate() {
        for (v, a) in acc.iter().enumerate() {
            _mm512_storeu_pd(y.add(c * w + 8 * v), *a);
        }
    }
}

/// y = (y − Σ_k b[k·bs]·x[k·w..][0..w])·inv over k < kk, for one row y of w entries: 32
/// entries at a time (four independent accumulators), then 8.
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn rows_diag(
    b: *const f64,
    bs: usize,
    x: *const f64,
    y: *mut f64,
    w: usize,
    kk: usize,
    inv: f64,
) {
    #[target_feature(enable = "avx512f")]
    #[inline]
    unsafe fn run<const V: usize>(
        b: *const f64,
        bs: usize,
        x: *const f64,
        y: *mut f64,
        w: usize,
        kk: usize,
        inv: __m512d,
    ) {
        let mut a = [_mm512_setzero_pd(); V];
        for (q, a) in a.iter_mut().enumerate() {
            *a = _mm512_loadu_pd(y.add(8 * q));
        }
        for k in 0..kk {
            let v = _mm512_set1_pd(*b.add(k * bs));
            let xk = x.add(k * w);
            for (q, a) in a.iter_mut().enumerate() {
                *a = _mm512_fnmadd_pd(v, _mm512_loadu_pd(xk.add(8 * q)), *a);
            }
        }
        for (q, a) in a.iter().enumerate() {
            _mm512_storeu_pd(y.add(8 * q), _mm512_mul_pd(*a, inv));
        }
    }
    let inv = _mm512_set1_pd(inv);
    let mut g = 0;
    while g + 32 <= w {
        run::<4>(b, bs, x.add(g), y.add(g), w, kk, inv);
        g += 32;
    }
    while g < w {
        run::<1>(b, bs, x.add(g), y.add(g), w, kk, inv);
        g += 8;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::chol::{cholesky_lower_avx2, gram_solve_rows_avx2};
    use crate::recon::simd::{has_avx2_fma, has_avx512f};
    use rand::{Rng, SeedableRng};

    fn spd(n: usize, ld: usize, seed: u64) -> Vec<f64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let k = n + 3;
        let b: Vec<f64> = (0..n * k).map(|_| rng.random::<f64>() - 0.5).collect();
        let mut g = vec![f64::NAN; ld * n];
        for j in 0..n {
            for i in j..n {
                let s: f64 = (0..k).map(|q| b[i * k + q] * b[j * k + q]).sum();
                g[j * ld + i] = s + if i == j { 0.1 } else { 0.0 };
            }
        }
        g
    }

    /// The AVX-512 factor matches the AVX2 one to rounding, and the block solve on the same L
    /// gives the AVX2 kernel's bits (the same FMAs in the same order in every lane), at sizes
    /// that leave partial strips, panels, groups, tiles and row groups; and the factor refuses
    /// what the AVX2 one refuses.
    #[test]
    fn avx512_kernels_reproduce_the_avx2_ones() {
        if !(has_avx512f() && has_avx2_fma()) {
            eprintln!("no AVX-512F here: nothing to compare");
            return;
        }
        for (n, ld, w) in [
            (1, 1, 8),
            (7, 8, 16),
            (97, 104, 24),
            (203, 203, 40),
            (601, 608, 56),
        ] {
            let g = spd(n, ld, n as u64);
            let (mut a2, mut a5) = (g.clone(), g.clone());
            let (mut p2, mut p5) = (Vec::new(), Vec::new());
            // SAFETY: both instruction sets are present (checked).
            assert!(unsafe { cholesky_lower_avx2(&mut a2, n, ld, &mut p2) });
            assert!(unsafe { cholesky_lower_avx512(&mut a5, n, ld, &mut p5) });
            for j in 0..n {
                let scale = a2[j * ld + j].abs();
                for i in j..n {
                    let (x, y) = (a2[j * ld + i], a5[j * ld + i]);
                    assert!(
                        (x - y).abs() <= 1e-10 * scale,
                        "L[{i}][{j}] at n = {n}: {x} vs {y}"
                    );
                }
            }
            let mut rng = rand::rngs::StdRng::seed_from_u64(7);
            let rhs: Vec<f64> = (0..n * w).map(|_| rng.random::<f64>() - 0.5).collect();
            let (mut x2, mut x5) = (rhs.clone(), rhs);
            // SAFETY: as above; L holds n columns ld apart, x n rows of w entries.
            unsafe { gram_solve_rows_avx2(&a5, ld, n, &mut x2, w) };
            unsafe { gram_solve_rows_avx512(&a5, ld, n, &mut x5, w) };
            assert_eq!(x2, x5, "block solve at n = {n}, w = {w}");
        }
        let mut indefinite = spd(50, 50, 3);
        indefinite[30 * 50 + 30] = -1.0;
        // SAFETY: AVX-512F present.
        assert!(!unsafe { cholesky_lower_avx512(&mut indefinite, 50, 50, &mut Vec::new()) });
    }
}
