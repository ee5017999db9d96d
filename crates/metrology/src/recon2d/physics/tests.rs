use super::*;

#[test]
fn axis_roughness_recovers_line_offsets_and_adds_nothing_to_white_noise() {
    // 200 lines, 6 samples each: offsets of 0.1 µm scale under 0.01 µm noise, then noise only.
    let mut seed = 7u64;
    let mut unif = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let n = 200;
    let off: Vec<f64> = (0..n).map(|i| 0.1 * (i as f64 * 0.7).sin()).collect();
    let idx: Vec<usize> = (0..6 * n).map(|k| k % n).collect();
    let noisy: Vec<f64> = idx.iter().map(|&i| off[i] + 0.02 * unif()).collect();
    let got = axis_roughness(n, &idx, &noisy);
    let err = got
        .iter()
        .zip(&off)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 0.02, "max error {err} µm");
    let white: Vec<f64> = idx.iter().map(|_| 0.02 * unif()).collect();
    let got = axis_roughness(n, &idx, &white);
    let most = got.iter().map(|v| v.abs()).fold(0.0, f64::max);
    assert!(most < 0.004, "white noise gave offsets up to {most} µm");
}

#[test]
fn nearest_neighbours_match_brute_force() {
    // A clustered, anisotropic scatter (most points in one corner) and a few far ones.
    let mut pts: Vec<(f64, f64)> = (0..400)
        .map(|i| {
            let t = i as f64;
            ((t * 7.31).sin().abs() * 50.0, (t * 3.17).cos().abs() * 20.0)
        })
        .collect();
    pts.extend([(4000.0, 3000.0), (3990.0, 2990.0), (0.0, 3000.0)]);
    // Points on one line: the cells are bounded, the neighbours still exact.
    let line: Vec<(f64, f64)> = (0..300).map(|i| ((i * i % 997) as f64, 5.0)).collect();
    for pts in [pts, line] {
        let nb = nearest_neighbours(&pts, 4);
        for (i, &(x, y)) in pts.iter().enumerate() {
            let d2 = |j: usize| (pts[j].0 - x).powi(2) + (pts[j].1 - y).powi(2);
            let mut all: Vec<usize> = (0..pts.len()).filter(|&j| j != i).collect();
            all.sort_by(|&a, &b| d2(a).total_cmp(&d2(b)));
            let want: Vec<f64> = all[..4].iter().map(|&j| d2(j)).collect();
            let got: Vec<f64> = nb[i].iter().map(|&j| d2(j)).collect();
            assert_eq!(got, want, "point {i}");
        }
    }
    assert!(nearest_neighbours(&[(1.0, 1.0)], 4)[0].is_empty());
}

#[test]
fn the_cubic_b_spline_basis_is_a_nonnegative_partition_of_unity() {
    let sp = Spline::new(-3.0, 17.0, 1.7);
    for k in 0..200 {
        let x = -3.0 + 20.0 * k as f64 / 199.0;
        let (_, v) = sp.eval(x);
        assert!((v.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(v.iter().all(|&b| b >= 0.0));
    }
}

#[test]
fn an_exact_model_is_recovered_from_noise_free_samples() {
    // A map that lies in the model's span up to spline error: smooth F, G, H, K.
    let g = Grid2::new("0:10:2000".parse().unwrap(), "0:10:1000".parse().unwrap()).unwrap();
    let truth = |x: f64, y: f64| {
        0.3 * (x / 700.0).sin() + 0.2 * (y / 300.0).cos() + 1e-4 * y * (x / 900.0).cos()
            - 2e-5 * x * y / 1000.0
    };
    let mut s = MapSamples::default();
    let mut state = 12345u64;
    let mut seen = std::collections::HashSet::new();
    while s.len() < 1500 {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let (ix, iy) = (
            (state >> 33) as usize % g.x.n,
            (state >> 13) as usize % g.y.n,
        );
        if seen.insert((ix, iy)) {
            let (x, y) = (g.x.position(ix), g.y.position(iy));
            s.ix.push(ix);
            s.iy.push(iy);
            s.ex.push(truth(x, y));
            s.ey.push(-truth(y * 2.0, x / 2.0));
        }
    }
    let (fit, _) = select(&g, &s).unwrap();
    let map = fit.evaluate(&g);
    let mut worst: f64 = 0.0;
    for j in 0..g.y.n {
        for i in 0..g.x.n {
            let (x, y) = (g.x.position(i), g.y.position(j));
            worst = worst.max((map.ex[j * g.x.n + i] - truth(x, y)).abs());
        }
    }
    assert!(worst < 2e-3, "max |error| {worst} µm");
}
