//! Dense Cholesky factorization G = LLᵀ of the BP exact finish's Gram anchor (m x m, m ≈ 600 at
//! the bench's m = 600) on AVX2 and FMA, and the solve G⁻¹X of a block of right-hand sides with
//! its factor ([`gram_solve_rows_avx2`], the simplex's first block). Where the CPU has AVX-512F,
//! [`super::chol512`] runs the same algorithms on 512-bit registers.
//!
//! faer's kernels reach ~90 % of the FMA peak on a large gemm, but its Cholesky of 600 x 600
//! (recursive, through its triangular solve and products) reached 34-37 GF on the Zen 3 host
//! where the peak is ~50: the triangular solve on a row-major right-hand side, the triangular
//! products and the many small blocks of the recursion lose the rest. Here:
//! - right-looking, in panels of [`NB`] columns: nearly all the work (~55 of the 72 MFLOP at
//!   m = 600) is the lower rank-96 update of the trailing matrix, one 8 x 4 register tile at a
//!   time (46-49 GF on Zen 3, against ~36 for faer's recursive symmetric product at these
//!   sizes; an 8 x 6 tile was no faster, a 12 x 4 one spilled registers and ran at 22);
//! - each panel is factored left-looking in groups of 4 columns (the 4 x 4 diagonal block in
//!   scalar, the rows below solved in registers), through the same tile;
//! - the panel is packed once, in 8-row strips k-major, as it is computed: the packed strips are
//!   both operands of the trailing update (a group of 4 rows lies in one strip), so nothing is
//!   packed twice.
//!
//! Only the lower triangle is meaningful. Tiles that straddle the diagonal also write entries
//! above it (in the diagonal blocks of panels and trailing updates): the upper triangle is
//! scratch, never read by the solves that use L.
use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::{Accum, MatMut, MatRef, Par};
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// Columns per panel (a multiple of 8). Measured at m = 600 on Zen 3 with `csmetro bench chol`
/// (best of 201, the width from a temporary environment variable): 64 1.73 ms, 80 1.68, 96
/// 1.71-1.72, 112 1.71, 128 1.72-1.74: flat.
const NB: usize = 96;

/// G = LLᵀ in place on the lower triangle of the column-major `l` (m x m, columns `ld` apart):
/// [`super::chol512::cholesky_lower_avx512`] where the CPU has AVX-512F, [`cholesky_lower_avx2`]
/// where it has AVX2 and FMA (`csmetro bench chol` at m = 600 on Zen 3, best of 101: 1.64-1.73
/// ms against 1.95-2.11 for [`cholesky_lower`]), else faer's.
pub fn factor_lower(l: &mut [f64], m: usize, ld: usize) -> bool {
    #[cfg(target_arch = "x86_64")]
    if super::simd::has_avx512f() {
        let mut pack = CHOL_PACK.take();
        // SAFETY: AVX-512F is present (checked).
        let ok = unsafe { super::chol512::cholesky_lower_avx512(l, m, ld, &mut pack) };
        CHOL_PACK.set(pack);
        return ok;
    }
    #[cfg(target_arch = "x86_64")]
    if super::simd::has_avx2_fma() {
        let mut pack = CHOL_PACK.take();
        // SAFETY: AVX2 and FMA are present (checked).
        let ok = unsafe { cholesky_lower_avx2(l, m, ld, &mut pack) };
        CHOL_PACK.set(pack);
        return ok;
    }
    cholesky_lower(MatMut::from_column_major_slice_with_stride_mut(l, m, m, ld))
}

/// Columns below which [`cholesky_lower`] factors directly.
const CHOL_LEAF: usize = 16;

/// A = LLᵀ in place on the lower triangle (the upper one is not read); false when A is not
/// numerically positive definite. Recursive splitting (Gustavson's recursive Cholesky), so that
/// nearly all the work is one triangular solve and one symmetric product per level through
/// faer's kernels (the product itself halved, [`syrk_lower`]). At 600 x 600, split in halves:
/// 1.43 ms against 1.60 ms for faer's `cholesky_in_place` on a random SPD matrix, 1.56 against
/// 1.65 ms inside the BP solve (Intel Xeon); on the AMD EPYC (Zen 4) 1.57 against 1.64 (faer's:
/// 1.64); on Zen 3 2.06-2.09 ms, 1.97-1.99 split at three fifths.
pub fn cholesky_lower(a: MatMut<'_, f64>) -> bool {
    let n = a.nrows();
    if n <= CHOL_LEAF {
        let mut a = a;
        for j in 0..n {
            let d = a[(j, j)];
            if d.is_nan() || d <= 0.0 {
                return false;
            }
            let d = d.sqrt();
            a[(j, j)] = d;
            for i in j + 1..n {
                a[(i, j)] /= d;
            }
            for k in j + 1..n {
                let f = a[(k, j)];
                for i in k..n {
                    let v = a[(i, j)];
                    a[(i, k)] -= v * f;
                }
            }
        }
        return true;
    }
    // Three fifths first: at 600 the top-level trsm (faer's, ~36 GF here) is then 360² x 240
    // and the product it feeds 240² x 360. Measured at 600 on Zen 3 (best of 100, interleaved,
    // 3 runs): halves 2.06-2.09 ms, 0.55 2.08, 0.6 1.97-1.99, 0.65 2.01-2.03, 0.7 2.01.
    let n1 = (n * 3 / 5).next_multiple_of(8).min(n - 1);
    let (mut a11, _, mut a21, mut a22) = a.split_at_mut(n1, n1);
    if !cholesky_lower(a11.as_mut()) {
        return false;
    }
    // A21 ← A21·L11⁻ᵀ, i.e. L11·A21ᵀ = A21ᵀ.
    solve_lower_triangular_in_place(a11.as_ref(), a21.as_mut().transpose_mut(), Par::Seq);
    syrk_lower(a22.as_mut(), a21.as_ref());
    cholesky_lower(a22)
}

/// Columns up to which [`syrk_lower`] leaves the product to faer's triangular kernel.
const SYRK_LEAF: usize = 64;

/// C ← C − A·Aᵀ on the lower triangle. Halving C puts its off-diagonal block in one gemm, which
/// faer runs near the FMA peak, where its triangular product does not: at 600 x 600 the
/// Cholesky took 1.57-1.58 ms against 1.64-1.66 ms (hot, best of 100; gemm 57 GF, the
/// triangular product 49 GF, the machine's peak 55-57).
fn syrk_lower(c: MatMut<'_, f64>, a: MatRef<'_, f64>) {
    let n = c.nrows();
    if n <= SYRK_LEAF {
        triangular::matmul(
            c,
            BlockStructure::TriangularLower,
            Accum::Add,
            a,
            BlockStructure::Rectangular,
            a.transpose(),
            BlockStructure::Rectangular,
            -1.0,
            Par::Seq,
        );
        return;
    }
    let h = (n / 2).next_multiple_of(8).min(n - 1);
    let (c11, _, c21, c22) = c.split_at_mut(h, h);
    let (a1, a2) = a.split_at_row(h);
    syrk_lower(c11, a1);
    matmul(c21, Accum::Add, a2, a1.transpose(), -1.0, Par::Seq);
    syrk_lower(c22, a2);
}

thread_local! {
    /// The AVX2 route's packed panel, for the next factorization on this thread (~0.5 MB at
    /// m = 600: fresh, it would come from mmap and fault its pages in at every solve).
    static CHOL_PACK: std::cell::Cell<Vec<f64>> = const { std::cell::Cell::new(Vec::new()) };
}

/// Grows the kept scratch `buf` to hold `len` entries from its first 64-byte line and returns
/// that line's offset: kernels that load 32 bytes at a time then split no cache lines (at the
/// allocator's 16-byte offset every other load did). The buffer only grows.
pub fn line_offset(buf: &mut Vec<f64>, len: usize) -> usize {
    if buf.len() < len + 8 {
        buf.resize(len + 8, 0.0);
    }
    buf.as_ptr().align_offset(64).min(8)
}

/// Factors the lower triangle of the column-major n x n matrix in `a` (columns `ld` ≥ n apart)
/// in place; false when it is not numerically positive definite (a pivot ≤ 0 or NaN). `pack`
/// is scratch, kept by the caller from call to call.
///
/// # Safety
/// AVX2 and FMA must be present.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn cholesky_lower_avx2(a: &mut [f64], n: usize, ld: usize, pack: &mut Vec<f64>) -> bool {
    blocked_cholesky(a, n, ld, pack, panel, trailing_update)
}

/// A panel kernel of the blocked Cholesky: see [`panel`].
#[cfg(target_arch = "x86_64")]
pub(super) type PanelKernel = unsafe fn(*mut f64, usize, usize, usize, *mut f64, usize) -> bool;
/// A trailing-update kernel of the blocked Cholesky: see [`trailing_update`].
#[cfg(target_arch = "x86_64")]
pub(super) type TrailingKernel = unsafe fn(*mut f64, usize, usize, usize, *const f64, usize);

/// The right-looking blocked Cholesky over panels of [`NB`] columns, on the given kernels (the
/// AVX2 ones here, the AVX-512 ones in [`super::chol512`]).
///
/// # Safety
/// The kernels' instruction sets must be present.
#[cfg(target_arch = "x86_64")]
pub(super) unsafe fn blocked_cholesky(
    a: &mut [f64],
    n: usize,
    ld: usize,
    pack: &mut Vec<f64>,
    panel: PanelKernel,
    trailing_update: TrailingKernel,
) -> bool {
    assert!(ld >= n && (n == 0 || a.len() >= (n - 1) * ld + n));
    let base = a.as_mut_ptr();
    // The first panel's strips are the largest. Every entry read below is written first in this
    // call (see `panel`): the buffer only grows, never zeroed again (resizing it per panel
    // zero-filled ~0.4 MB per solve, ~0.6 % of a BP solve at m = 600).
    // The strips start on a 64-byte line: each 8-entry row of a strip is then one line.
    let need = n.div_ceil(8) * NB.min(n) * 8;
    // (The offset first: growing the buffer may move it.)
    let off = line_offset(pack, need);
    let packed = pack.as_mut_ptr().add(off);
    let mut j = 0;
    while j < n {
        let b = NB.min(n - j);
        let r = n - j;
        let stride = b * 8;
        let p = base.add(j * ld + j);
        if !panel(p, ld, r, b, packed, stride) {
            return false;
        }
        if r > b {
            trailing_update(p.add(b * ld + b), ld, r - b, b, packed, stride);
        }
        j += b;
    }
    true
}

/// acc[c] (8 rows as two vectors) = Σ_kk a[kk][0..8]·b[kk·bs + c] for c < 4: the 8 x 4 tile of
/// a k-step product, `a` packed k-major in 8s.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn tile(a: *const f64, b: *const f64, bs: usize, k: usize) -> [[__m256d; 2]; 4] {
    // Eight named accumulators: LLVM keeps them in registers (a 12 x 4 tile, 16 registers,
    // spilled and ran at half the rate).
    let z = _mm256_setzero_pd();
    let (mut c00, mut c01, mut c10, mut c11) = (z, z, z, z);
    let (mut c20, mut c21, mut c30, mut c31) = (z, z, z, z);
    let (mut a, mut b) = (a, b);
    for _ in 0..k {
        let a0 = _mm256_loadu_pd(a);
        let a1 = _mm256_loadu_pd(a.add(4));
        let v = _mm256_broadcast_sd(&*b);
        c00 = _mm256_fmadd_pd(a0, v, c00);
        c01 = _mm256_fmadd_pd(a1, v, c01);
        let v = _mm256_broadcast_sd(&*b.add(1));
        c10 = _mm256_fmadd_pd(a0, v, c10);
        c11 = _mm256_fmadd_pd(a1, v, c11);
        let v = _mm256_broadcast_sd(&*b.add(2));
        c20 = _mm256_fmadd_pd(a0, v, c20);
        c21 = _mm256_fmadd_pd(a1, v, c21);
        let v = _mm256_broadcast_sd(&*b.add(3));
        c30 = _mm256_fmadd_pd(a0, v, c30);
        c31 = _mm256_fmadd_pd(a1, v, c31);
        a = a.add(8);
        b = b.add(bs);
    }
    [[c00, c01], [c10, c11], [c20, c21], [c30, c31]]
}

/// The `rows` (≤ 8) entries from `col` as two vectors, zero beyond.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn load8(col: *const f64, rows: usize) -> [__m256d; 2] {
    if rows == 8 {
        [_mm256_loadu_pd(col), _mm256_loadu_pd(col.add(4))]
    } else {
        let mut t = [0.0f64; 8];
        std::ptr::copy_nonoverlapping(col, t.as_mut_ptr(), rows);
        [
            _mm256_loadu_pd(t.as_ptr()),
            _mm256_loadu_pd(t.as_ptr().add(4)),
        ]
    }
}

/// Stores the first `rows` (≤ 8) lanes of v to `col`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn store8(col: *mut f64, rows: usize, v: [__m256d; 2]) {
    if rows == 8 {
        _mm256_storeu_pd(col, v[0]);
        _mm256_storeu_pd(col.add(4), v[1]);
    } else {
        let mut t = [0.0f64; 8];
        _mm256_storeu_pd(t.as_mut_ptr(), v[0]);
        _mm256_storeu_pd(t.as_mut_ptr().add(4), v[1]);
        std::ptr::copy_nonoverlapping(t.as_ptr(), col, rows);
    }
}

/// Factors the panel of rows 0..r, columns 0..b at p (its top b x b block on the diagonal, all
/// earlier panels' updates applied), left-looking in groups of 4 columns, and writes its rows
/// packed to `pk`: strip s (rows 8s..8s+8) at pk + s·stride, column c at + 8c.
///
/// Entries of `pk` read here are written first: the tile of group g reads columns < 4g of the
/// strips from 4g / 8 down, which earlier groups wrote (they write every strip from their own
/// first one); a partial last strip's lanes beyond r start from zeros and stay finite.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn panel(p: *mut f64, ld: usize, r: usize, b: usize, pk: *mut f64, stride: usize) -> bool {
    let strips = r.div_ceil(8);
    for c0 in (0..b).step_by(4) {
        let w = 4.min(b - c0);
        let s0 = c0 / 8;
        // Rows c0..c0 + 4 as the tile's second operand: one strip, lanes c0 % 8 ∈ {0, 4}.
        let bp = pk.add(s0 * stride + c0 % 8);
        // The diagonal strip first: its update, then the w x w diagonal block in scalar.
        let rows0 = 8.min(r - 8 * s0);
        let acc = tile(pk.add(s0 * stride), bp, 8, c0);
        for (c, acc) in acc.iter().enumerate().take(w) {
            let col = p.add((c0 + c) * ld + 8 * s0);
            let v = load8(col, rows0);
            store8(
                col,
                rows0,
                [_mm256_sub_pd(v[0], acc[0]), _mm256_sub_pd(v[1], acc[1])],
            );
        }
        let mut lt = [[0.0f64; 4]; 4];
        let mut inv = [0.0f64; 4];
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
        // Every strip from the diagonal one: X ← (X − update)·L_gg⁻ᵀ, in registers.
        for s in s0..strips {
            let rows = 8.min(r - 8 * s);
            let acc = if s == s0 {
                [[_mm256_setzero_pd(); 2]; 4]
            } else {
                tile(pk.add(s * stride), bp, 8, c0)
            };
            let mut xs = [[_mm256_setzero_pd(); 2]; 4];
            for c in 0..w {
                let col = p.add((c0 + c) * ld + 8 * s);
                let v = load8(col, rows);
                let (mut v0, mut v1) = (
                    _mm256_sub_pd(v[0], acc[c][0]),
                    _mm256_sub_pd(v[1], acc[c][1]),
                );
                for q in 0..c {
                    let f = _mm256_set1_pd(lt[c][q]);
                    v0 = _mm256_fnmadd_pd(xs[q][0], f, v0);
                    v1 = _mm256_fnmadd_pd(xs[q][1], f, v1);
                }
                let d = _mm256_set1_pd(inv[c]);
                xs[c] = [_mm256_mul_pd(v0, d), _mm256_mul_pd(v1, d)];
            }
            if s == s0 {
                // The diagonal rows take L_gg itself (rows above c0 are scratch).
                let mut t = [[0.0f64; 8]; 4];
                for c in 0..w {
                    _mm256_storeu_pd(t[c].as_mut_ptr(), xs[c][0]);
                    _mm256_storeu_pd(t[c].as_mut_ptr().add(4), xs[c][1]);
                    for i in c..w {
                        t[c][c0 % 8 + i] = lt[i][c];
                    }
                    xs[c] = [
                        _mm256_loadu_pd(t[c].as_ptr()),
                        _mm256_loadu_pd(t[c].as_ptr().add(4)),
                    ];
                }
            }
            for (c, x) in xs.iter().enumerate().take(w) {
                store8(p.add((c0 + c) * ld + 8 * s), rows, *x);
                let q = pk.add(s * stride + (c0 + c) * 8);
                _mm256_storeu_pd(q, x[0]);
                _mm256_storeu_pd(q.add(4), x[1]);
            }
        }
    }
    true
}

/// C (r x r, lower, at c) −= PPᵀ for the panel rows below its diagonal block (strips from b / 8
/// of `pk`, k = b columns).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn trailing_update(
    c: *mut f64,
    ld: usize,
    r: usize,
    b: usize,
    pk: *const f64,
    stride: usize,
) {
    let strips = (r + b).div_ceil(8);
    for t in (0..r).step_by(4) {
        let w = 4.min(r - t);
        // Trailing row t is panel row b + t: strip (b + t) / 8, lane t % 8 ∈ {0, 4}.
        let bp = pk.add(((b + t) / 8) * stride + t % 8);
        for s in (b + t) / 8..strips {
            let row0 = 8 * s - b;
            let rows = 8.min(r - row0);
            let acc = tile(pk.add(s * stride), bp, 8, b);
            for (q, acc) in acc.iter().enumerate().take(w) {
                let col = c.add((t + q) * ld + row0);
                let v = load8(col, rows);
                store8(
                    col,
                    rows,
                    [_mm256_sub_pd(v[0], acc[0]), _mm256_sub_pd(v[1], acc[1])],
                );
            }
        }
    }
}

/// Rows per diagonal block of [`gram_solve_rows_avx2`]. Measured at m = 600, 32 right-hand sides
/// on Zen 3 (best of 300): 16 0.59 ms, 24-48 0.55, 64 0.59, 96 0.62.
const ROW_BLOCK: usize = 32;

/// X ← G⁻¹X = L⁻ᵀL⁻¹X with X stored row by row (m rows of `w` entries, w a multiple of 8) and L
/// the lower triangle of the column-major `l` (m columns `ld` apart, only entries on and below
/// the diagonal of the first m rows read).
///
/// The vectors run along a row of X, 8 right-hand sides at a time, with 4 rows of X per 8 x 4
/// register tile as in the factorization; L's entries are broadcast. Forward, L's column k feeds
/// the rows below block k (4 consecutive entries per tile, contiguous); backward, four columns
/// of L are read down a block of rows at once. Both sweeps go a block of [`ROW_BLOCK`] rows at a
/// time: the diagonal block row after row (32 right-hand sides per pass, eight independent
/// accumulators), then the rest of X updated from it. With the right-hand sides in columns (lanes
/// down a column of X, [`faer`]'s and the simplex's one-column kernel), each diagonal entry
/// solved is a sequential step; here it is the whole row at once. `csmetro bench chol`, m = 600,
/// 32 right-hand sides, Zen 3, best of 201: 0.51 ms against 0.65 for faer's two triangular solves.
///
/// # Safety
/// AVX2 and FMA must be present.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn gram_solve_rows_avx2(l: &[f64], ld: usize, m: usize, x: &mut [f64], w: usize) {
    row_sweeps(l, ld, m, x, w, rows_diag, rows_update_range)
}

/// The diagonal-row kernel of the block solve: see [`rows_diag`].
#[cfg(target_arch = "x86_64")]
pub(super) type RowsDiag = unsafe fn(*const f64, usize, *const f64, *mut f64, usize, usize, f64);
/// The update kernel of the block solve: see [`rows_update_range`].
#[cfg(target_arch = "x86_64")]
pub(super) type RowsUpdate =
    unsafe fn(*const f64, usize, usize, *const f64, *mut f64, usize, usize, std::ops::Range<usize>);

/// The two sweeps of [`gram_solve_rows_avx2`] a block of [`ROW_BLOCK`] rows at a time, on the
/// given kernels (the AVX2 ones here, the AVX-512 ones in [`super::chol512`]).
///
/// # Safety
/// The kernels' instruction sets must be present.
#[cfg(target_arch = "x86_64")]
pub(super) unsafe fn row_sweeps(
    l: &[f64],
    ld: usize,
    m: usize,
    x: &mut [f64],
    w: usize,
    rows_diag: RowsDiag,
    rows_update_range: RowsUpdate,
) {
    assert!(
        w.is_multiple_of(8) && x.len() >= m * w,
        "m rows of a multiple of 8 entries"
    );
    assert!(ld >= m && (m == 0 || l.len() >= (m - 1) * ld + m));
    let (lp, xp) = (l.as_ptr(), x.as_mut_ptr());
    // L y = x.
    let mut k0 = 0;
    while k0 < m {
        let kb = ROW_BLOCK.min(m - k0);
        for i in k0..k0 + kb {
            // Row i of the block: L[i][k] for k ≥ k0 along row i, ld apart.
            let b = lp.add(k0 * ld + i);
            let inv = 1.0 / *lp.add(i * ld + i);
            rows_diag(b, ld, xp.add(k0 * w), xp.add(i * w), w, i - k0, inv);
        }
        // Rows below: L[i][k0 + k] in column k0 + k (ld apart), row i at + i.
        rows_update_range(
            lp.add(k0 * ld),
            1,
            ld,
            xp.add(k0 * w),
            xp,
            w,
            kb,
            k0 + kb..m,
        );
        k0 += kb;
    }
    // Lᵀ x = y, from the last block up.
    let mut j1 = m;
    while j1 > 0 {
        let kb = ROW_BLOCK.min(j1);
        let j0 = j1 - kb;
        for j in (j0..j1).rev() {
            // Column j of L below the diagonal, within the block.
            let inv = 1.0 / *lp.add(j * ld + j);
            rows_diag(
                lp.add(j * ld + j + 1),
                1,
                xp.add((j + 1) * w),
                xp.add(j * w),
                w,
                j1 - j - 1,
                inv,
            );
        }
        // Rows above: L[j0 + k][i] in column i (at + i·ld), rows j0.. contiguous.
        rows_update_range(lp.add(j0), ld, 1, xp.add(j0 * w), xp, w, kb, 0..j0);
        j1 = j0;
    }
}

/// Rows `rows` of X (at `xp`, w apart) −= Σ_k b[i·cs + k·ks]·x[k·w..] over k < kk, 4 rows and
/// 8 columns per [`rows_update`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
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
        let r = 4.min(rows.end - i0);
        for g in (0..w).step_by(8) {
            rows_update(
                b.add(i0 * cs),
                cs,
                ks,
                x.add(g),
                xp.add(i0 * w + g),
                w,
                kk,
                r,
            );
        }
        i0 += r;
    }
}

/// y = (y − Σ_k b[k·bs]·x[k·w..][0..w])·inv over k < kk, for one row y of w entries: 32 entries
/// at a time (eight independent accumulators: a single chain of FMAs is latency-bound), then 8.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
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
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    unsafe fn run<const V: usize>(
        b: *const f64,
        bs: usize,
        x: *const f64,
        y: *mut f64,
        w: usize,
        kk: usize,
        inv: __m256d,
    ) {
        let mut a = [_mm256_setzero_pd(); V];
        for (q, a) in a.iter_mut().enumerate() {
            *a = _mm256_loadu_pd(y.add(4 * q));
        }
        for k in 0..kk {
            let v = _mm256_broadcast_sd(&*b.add(k * bs));
            let xk = x.add(k * w);
            for (q, a) in a.iter_mut().enumerate() {
                *a = _mm256_fnmadd_pd(v, _mm256_loadu_pd(xk.add(4 * q)), *a);
            }
        }
        for (q, a) in a.iter().enumerate() {
            _mm256_storeu_pd(y.add(4 * q), _mm256_mul_pd(*a, inv));
        }
    }
    let inv = _mm256_set1_pd(inv);
    let mut g = 0;
    while g + 32 <= w {
        run::<8>(b, bs, x.add(g), y.add(g), w, kk, inv);
        g += 32;
    }
    while g < w {
        run::<2>(b, bs, x.add(g), y.add(g), w, kk, inv);
        g += 8;
    }
}

/// Rows c < r ≤ 4 of y (w apart, 8 entries each) −= Σ_k b[c·cs + k·ks]·x[k·w..][0..8] over
/// k < kk: the 8 x 4 tile, vectors along the rows.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
#[allow(clippy::too_many_arguments)]
unsafe fn rows_update(
    b: *const f64,
    cs: usize,
    ks: usize,
    x: *const f64,
    y: *mut f64,
    w: usize,
    kk: usize,
    r: usize,
) {
    if r < 4 {
        for c in 0..r {
            let yc = y.add(c * w);
            let (mut a0, mut a1) = (_mm256_loadu_pd(yc), _mm256_loadu_pd(yc.add(4)));
            for k in 0..kk {
                let v = _mm256_broadcast_sd(&*b.add(c * cs + k * ks));
                let xk = x.add(k * w);
                a0 = _mm256_fnmadd_pd(_mm256_loadu_pd(xk), v, a0);
                a1 = _mm256_fnmadd_pd(_mm256_loadu_pd(xk.add(4)), v, a1);
            }
            _mm256_storeu_pd(yc, a0);
            _mm256_storeu_pd(yc.add(4), a1);
        }
        return;
    }
    // Eight named accumulators, as in `tile`.
    let (mut c00, mut c01) = (_mm256_loadu_pd(y), _mm256_loadu_pd(y.add(4)));
    let (mut c10, mut c11) = (_mm256_loadu_pd(y.add(w)), _mm256_loadu_pd(y.add(w + 4)));
    let (mut c20, mut c21) = (
        _mm256_loadu_pd(y.add(2 * w)),
        _mm256_loadu_pd(y.add(2 * w + 4)),
    );
    let (mut c30, mut c31) = (
        _mm256_loadu_pd(y.add(3 * w)),
        _mm256_loadu_pd(y.add(3 * w + 4)),
    );
    let (b0, b1, b2, b3) = (b, b.add(cs), b.add(2 * cs), b.add(3 * cs));
    let mut x = x;
    for k in 0..kk {
        let a0 = _mm256_loadu_pd(x);
        let a1 = _mm256_loadu_pd(x.add(4));
        let o = k * ks;
        let v = _mm256_broadcast_sd(&*b0.add(o));
        c00 = _mm256_fnmadd_pd(a0, v, c00);
        c01 = _mm256_fnmadd_pd(a1, v, c01);
        let v = _mm256_broadcast_sd(&*b1.add(o));
        c10 = _mm256_fnmadd_pd(a0, v, c10);
        c11 = _mm256_fnmadd_pd(a1, v, c11);
        let v = _mm256_broadcast_sd(&*b2.add(o));
        c20 = _mm256_fnmadd_pd(a0, v, c20);
        c21 = _mm256_fnmadd_pd(a1, v, c21);
        let v = _mm256_broadcast_sd(&*b3.add(o));
        c30 = _mm256_fnmadd_pd(a0, v, c30);
        c31 = _mm256_fnmadd_pd(a1, v, c31);
        x = x.add(w);
    }
    for (c, v) in [
        (0, c00),
        (4, c01),
        (w, c10),
        (w + 4, c11),
        (2 * w, c20),
        (2 * w + 4, c21),
        (3 * w, c30),
        (3 * w + 4, c31),
    ] {
        _mm256_storeu_pd(y.add(c), v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    /// The recursive Cholesky reproduces A = LLᵀ past its leaf size and refuses an indefinite
    /// matrix.
    #[test]
    fn cholesky_lower_factors_spd_and_refuses_indefinite() {
        // Past the leaf size, and past the symmetric product's own leaf (its halving).
        for n in [3 * CHOL_LEAF + 5, 3 * SYRK_LEAF + 5] {
            let r = Mat::<f64>::from_fn(n, n, |i, j| ((i * 31 + j * 17) % 23) as f64 / 23.0 - 0.5);
            let a = &r * r.transpose() + Mat::<f64>::identity(n, n);
            let mut l = a.clone();
            assert!(cholesky_lower(l.as_mut()));
            let lower = Mat::<f64>::from_fn(n, n, |i, j| if i >= j { l[(i, j)] } else { 0.0 });
            let back = &lower * lower.transpose();
            for i in 0..n {
                for j in 0..n {
                    assert!(
                        (back[(i, j)] - a[(i, j)]).abs() < 1e-12 * n as f64,
                        "n = {n}: ({i}, {j})"
                    );
                }
            }
            let mut indefinite = a.clone();
            indefinite[(n - 1, n - 1)] = -1.0;
            assert!(!cholesky_lower(indefinite.as_mut()));
        }
    }

    #[cfg(target_arch = "x86_64")]
    mod avx2 {
        use super::super::*;

        /// A random SPD matrix XXᵀ + I/2 (column-major, columns `ld` apart): its lower triangle,
        /// the rest of each column NaN (the factor must not read it into the lower triangle).
        fn spd(n: usize, ld: usize, seed: u64) -> Vec<f64> {
            let mut s = seed;
            let mut rnd = || {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
            };
            let x: Vec<f64> = (0..n * n).map(|_| rnd()).collect();
            let mut g = vec![f64::NAN; ld * n];
            for j in 0..n {
                for i in j..n {
                    let v: f64 = (0..n).map(|k| x[i * n + k] * x[j * n + k]).sum();
                    g[j * ld + i] = v + if i == j { 0.5 } else { 0.0 };
                }
            }
            g
        }

        /// The plain (unblocked) Cholesky of `g`'s lower triangle, row-major n x n.
        fn reference(g: &[f64], n: usize, ld: usize) -> Vec<f64> {
            let mut l = vec![0.0; n * n];
            for j in 0..n {
                let mut d = g[j * ld + j];
                for k in 0..j {
                    d -= l[j * n + k] * l[j * n + k];
                }
                let d = d.sqrt();
                l[j * n + j] = d;
                for i in j + 1..n {
                    let mut v = g[j * ld + i];
                    for k in 0..j {
                        v -= l[i * n + k] * l[j * n + k];
                    }
                    l[i * n + j] = v / d;
                }
            }
            l
        }

        #[test]
        fn matches_the_plain_algorithm_at_awkward_sizes() {
            if !crate::recon::simd::has_avx2_fma() {
                return;
            }
            let mut pack = Vec::new();
            // Sizes around the panel width, the strip height and the group width, with padding
            // rows (ld > n) poisoned with NaN: the factor must neither read nor write past n rows.
            for &(n, ld) in &[
                (1, 1),
                (3, 5),
                (7, 8),
                (8, 8),
                (13, 13),
                (97, 97),
                (100, 104),
                (203, 208),
                (250, 250),
            ] {
                let g = spd(n, ld, n as u64);
                let want = reference(&g, n, ld);
                let mut a = g.clone();
                // SAFETY: AVX2 and FMA checked above.
                assert!(
                    unsafe { cholesky_lower_avx2(&mut a, n, ld, &mut pack) },
                    "n = {n}"
                );
                let scale = (0..n).map(|j| want[j * n + j]).fold(0.0f64, f64::max);
                for j in 0..n {
                    for i in j..n {
                        let (got, w) = (a[j * ld + i], want[i * n + j]);
                        assert!(
                            (got - w).abs() <= 1e-11 * scale,
                            "n = {n}, L[{i}][{j}] = {got} against {w}"
                        );
                    }
                    for i in n..ld {
                        assert!(
                            a[j * ld + i].is_nan(),
                            "n = {n}: padding row {i} of column {j} written"
                        );
                    }
                }
            }
        }

        #[test]
        fn row_solves_match_substitution_and_read_only_the_lower_triangle() {
            if !crate::recon::simd::has_avx2_fma() {
                return;
            }
            let mut pack = Vec::new();
            // Sizes around the row block (32) and the tile's 4 rows, with 8 to 40 right-hand
            // sides (one and several passes of 32), and padding rows.
            for &(n, ld, w) in &[
                (1, 1, 8),
                (3, 5, 8),
                (7, 8, 16),
                (33, 40, 8),
                (66, 66, 40),
                (97, 97, 32),
                (150, 152, 24),
            ] {
                let mut a = spd(n, ld, 100 + n as u64);
                // SAFETY: AVX2 and FMA checked above.
                assert!(unsafe { cholesky_lower_avx2(&mut a, n, ld, &mut pack) });
                // Poison what the solve must not read: the upper triangle and padding rows.
                for j in 0..n {
                    for i in (0..j).chain(n..ld) {
                        a[j * ld + i] = f64::NAN;
                    }
                }
                let b: Vec<f64> = (0..n * w)
                    .map(|e| ((e * 37 + 11) % 101) as f64 / 50.0 - 1.0)
                    .collect();
                // Forward and back substitution, column after column.
                let l = |i: usize, j: usize| a[j * ld + i];
                let mut want = b.clone();
                for c in 0..w {
                    let x = |r: usize| r * w + c;
                    for i in 0..n {
                        let s: f64 = (0..i).map(|k| l(i, k) * want[x(k)]).sum();
                        want[x(i)] = (want[x(i)] - s) / l(i, i);
                    }
                    for i in (0..n).rev() {
                        let s: f64 = (i + 1..n).map(|k| l(k, i) * want[x(k)]).sum();
                        want[x(i)] = (want[x(i)] - s) / l(i, i);
                    }
                }
                let mut got = b.clone();
                // SAFETY: as above.
                unsafe { gram_solve_rows_avx2(&a, ld, n, &mut got, w) };
                let scale = want.iter().fold(0.0f64, |s, v| s.max(v.abs()));
                for (e, (g, v)) in got.iter().zip(&want).enumerate() {
                    assert!(
                        (g - v).abs() <= 1e-10 * scale,
                        "n = {n}, w = {w}: row {}, column {}: {g} against {v}",
                        e / w,
                        e % w
                    );
                }
            }
        }

        #[test]
        fn reports_a_matrix_that_is_not_positive_definite() {
            if !crate::recon::simd::has_avx2_fma() {
                return;
            }
            let n = 150;
            let mut g = spd(n, n, 7);
            // A negative diagonal entry in the second panel (columns 96..150): the first panel
            // factors, the failure shows in a later one.
            g[120 * n + 120] = -1.0;
            let mut pack = Vec::new();
            // SAFETY: AVX2 and FMA checked above.
            assert!(!unsafe { cholesky_lower_avx2(&mut g, n, n, &mut pack) });
            let mut nan = spd(20, 20, 3);
            nan[5 * 20 + 9] = f64::NAN;
            nan[9 * 20 + 9] = f64::NAN;
            // SAFETY: as above.
            assert!(!unsafe { cholesky_lower_avx2(&mut nan, 20, 20, &mut pack) });
        }
    }
}
