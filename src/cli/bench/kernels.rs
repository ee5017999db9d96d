//! `bench chol` and `bench dct`: the dense kernels under the BP solver, timed alone.
use std::time::Instant;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Mat, MatMut, MatRef, Par};
use serde_json::json;

use super::median;
use crate::recon::dct::Dct;

/// Best and median ms of `repeat` runs of `f` on a fresh copy of `from` (plus a warm-up run).
fn time_on(from: &[f64], repeat: usize, f: &mut dyn FnMut(&mut [f64])) -> (f64, f64) {
    let mut a = from.to_vec();
    let mut t = Vec::with_capacity(repeat + 1);
    for _ in 0..=repeat {
        a.copy_from_slice(from);
        let t0 = Instant::now();
        f(&mut a);
        t.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    t.remove(0); // warm-up
    let best = t.iter().copied().fold(f64::INFINITY, f64::min);
    (best, median(&mut t))
}

/// G = LLᵀ in place (column-major m x m, lower triangle) by faer's Cholesky, single-threaded as
/// the solver runs it; false when G is not numerically positive definite.
fn cholesky(a: &mut [f64], m: usize, scratch: &mut MemBuffer) -> bool {
    cholesky_in_place(
        MatMut::from_column_major_slice_mut(a, m, m),
        Default::default(),
        Par::Seq,
        MemStack::new(scratch),
        Default::default(),
    )
    .is_ok()
}

pub(super) fn chol(ms: &[usize], repeat: usize, rhs: usize) -> serde_json::Value {
    use rand::{Rng, SeedableRng};
    let mut rows = Vec::new();
    for &m in ms {
        // G = XXᵀ/m + I/2, column-major.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(m as u64);
        let x = Mat::<f64>::from_fn(m, m, |_, _| rng.random::<f64>() - 0.5);
        let g = &x * x.transpose() / (m as f64) + Mat::<f64>::identity(m, m) * 0.5;
        let src: Vec<f64> = (0..m * m).map(|k| g[(k % m, k / m)]).collect();
        let mut scratch = MemBuffer::new(cholesky_in_place_scratch::<f64>(
            m,
            Par::Seq,
            Default::default(),
        ));
        let flop = (m as f64).powi(3) / 3.0;
        let (best, med) = time_on(&src, repeat, &mut |a| {
            assert!(cholesky(a, m, &mut scratch), "the SPD test matrix factors")
        });
        rows.push(
            json!({"m": m, "route": "faer_cholesky", "best_ms": best, "median_ms": med,
            "best_gflops": flop / best / 1e6, "repeat": repeat}),
        );
        // The block solve on the factor of G.
        let mut l = src.clone();
        assert!(
            cholesky(&mut l, m, &mut scratch),
            "the SPD test matrix factors"
        );
        let b: Vec<f64> = (0..m * rhs).map(|_| rng.random::<f64>() - 0.5).collect();
        let flop = 2.0 * (m * m * rhs) as f64;
        let lr = MatRef::from_column_major_slice(&l, m, m);
        let (best, med) = time_on(&b, repeat, &mut |x| {
            // Column-major m x rhs.
            let mut v = MatMut::from_column_major_slice_mut(x, m, rhs);
            solve_lower_triangular_in_place(lr, v.as_mut(), Par::Seq);
            solve_upper_triangular_in_place(lr.transpose(), v, Par::Seq);
        });
        rows.push(
            json!({"m": m, "route": "solve_faer", "rhs": rhs, "best_ms": best, "median_ms": med,
            "best_gflops": flop / best / 1e6, "repeat": repeat}),
        );
    }
    json!({"benchmark": "chol", "threads": 1, "rows": rows})
}

pub(super) fn dct_pairs(repeat: usize) -> serde_json::Value {
    let mut rows = Vec::new();
    // Each sample times a batch long enough (~20 ms) for the clock.
    let time_pairs = |n: usize, pair: &mut dyn FnMut()| {
        let batch = (2_000_000 / n).max(1);
        let mut times = Vec::new();
        for _ in 0..=repeat {
            let t = Instant::now();
            for _ in 0..batch {
                pair();
            }
            times.push(t.elapsed().as_secs_f64() * 1e6 / batch as f64);
        }
        times.remove(0); // warm-up
        median(&mut times)
    };
    for n in [1900usize, 1901, 2048, 65_536] {
        // The real FFT under Makhoul's path: Bluestein's algorithm where n has a large prime
        // factor, realfft otherwise.
        let real_fft = if crate::recon::dct::bluestein_pays_off(n) {
            "bluestein"
        } else {
            "realfft"
        };
        for makhoul in [false, true] {
            let mut d = Dct::with_backend(n, makhoul);
            let mut v: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
            let us = time_pairs(n, &mut || {
                d.inverse(&mut v);
                d.forward(&mut v);
            });
            rows.push(json!({
                "n": n, "backend": if makhoul { "makhoul_realfft" } else { "rustdct" },
                "real_fft": makhoul.then_some(real_fft),
                "median_pair_us": us, "repeat": repeat,
            }));
        }
        // The real-FFT path in f32 (BP's ranking iterations).
        let mut d = Dct::new(n);
        let mut v: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
        let us = time_pairs(n, &mut || {
            d.single().inverse(&mut v);
            d.single().forward(&mut v);
        });
        rows.push(json!({
            "n": n, "backend": "makhoul_f32", "real_fft": real_fft,
            "median_pair_us": us, "repeat": repeat,
        }));
    }
    json!({"benchmark": "dct", "threads": 1, "rows": rows})
}

#[cfg(test)]
mod tests {
    /// The Cholesky row times a factorization that is right: LLᵀ reproduces G.
    #[test]
    fn faer_cholesky_factors_the_test_matrix() {
        let m = 37;
        let g = faer::Mat::<f64>::from_fn(m, m, |i, j| {
            if i == j {
                2.0 + i as f64 * 0.01
            } else {
                0.3 / (1.0 + i.abs_diff(j) as f64)
            }
        });
        let mut a: Vec<f64> = (0..m * m).map(|k| g[(k % m, k / m)]).collect();
        let mut scratch = faer::dyn_stack::MemBuffer::new(super::cholesky_in_place_scratch::<f64>(
            m,
            faer::Par::Seq,
            Default::default(),
        ));
        assert!(super::cholesky(&mut a, m, &mut scratch));
        let l = faer::Mat::<f64>::from_fn(m, m, |i, j| if i >= j { a[j * m + i] } else { 0.0 });
        let back = &l * l.transpose();
        for i in 0..m {
            for j in 0..m {
                assert!((back[(i, j)] - g[(i, j)]).abs() < 1e-12, "({i}, {j})");
            }
        }
        let row = super::chol(&[40], 2, 8);
        let routes: Vec<&str> = row["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["route"].as_str().unwrap())
            .collect();
        assert_eq!(routes, ["faer_cholesky", "solve_faer"]);
    }
}
