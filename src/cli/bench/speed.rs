//! `bench speed`: solve times of the reconstruction methods, single-threaded.
use csmetro_sim::ReferenceCurveParams;
use serde_json::json;

use super::{median, percentile};
use crate::grid::Grid;
use crate::recon::{self, Method, ReconSettings, Solver};
use crate::sampling::{Design, DesignKind};
use crate::synth;

/// Curve `r` of the speed rows: the paper-like curve of seed r over the grid, m random samples
/// (design seed 2000 + r), 0.01 µm noise. The sustained row solves the same curves as the others.
fn speed_problem(grid: &Grid, m: usize, r: u64) -> anyhow::Result<synth::SynthProblem> {
    let params = ReferenceCurveParams {
        travel_um: [grid.start_um, grid.end_um()],
        ..Default::default()
    };
    synth::problem(
        grid,
        r,
        &params,
        &Design::new(DesignKind::Random, m, 2000 + r),
        0.01,
    )
    .map_err(anyhow::Error::msg)
}

fn time_method(
    grid: &Grid,
    m: usize,
    method: Method,
    solver: Solver,
    repeat: usize,
) -> anyhow::Result<serde_json::Value> {
    let mut times = Vec::new();
    let mut iters = Vec::new();
    let mut status = Vec::new();
    let mut solver_used = String::new();
    let mut max_gap = f64::NAN;
    let mut problems = Vec::new();
    for r in 0..repeat {
        let p = speed_problem(grid, m, r as u64)?;
        let s = ReconSettings {
            method,
            solver,
            ..Default::default()
        };
        let out = recon::reconstruct(grid, &p.samples, &s)?;
        times.push(out.solve_ms);
        solver_used = out.solver.clone();
        iters.push(out.iterations as f64);
        status.push(out.status.map(|s| format!("{s:?}")).unwrap_or_default());
        if let Some(g) = out.relative_gap {
            max_gap = max_gap.max(g);
        }
        problems.push((p.samples, s));
    }
    // Per curve, the best of this pass and two more: the solver's own time with the host's
    // noise (other VMs' bursts, first-pass cache and allocator effects) filtered out. Only at
    // the n = 1901 sizes with the fast solvers, where a pass takes well under a second.
    let best_of_3 = (grid.n < 10_000 && solver != Solver::Clarabel).then(|| {
        let mut best = times.clone();
        for _ in 0..2 {
            for (b, (samples, s)) in best.iter_mut().zip(&problems) {
                if let Ok(out) = recon::reconstruct(grid, samples, s) {
                    *b = b.min(out.solve_ms);
                }
            }
        }
        median(&mut best)
    });
    status.sort();
    status.dedup();
    // The first solve of a length plans its transforms; later ones reuse the thread's plans.
    let first = times.first().copied();
    Ok(json!({
        "method": method.as_str(), "solver": solver_used, "n": grid.n, "m": m,
        "repeat": repeat, "median_ms": median(&mut times.clone()), "p90_ms": percentile(&mut times, 0.9),
        "first_ms": first, "median_best_of_3_ms": best_of_3,
        "median_iterations": median(&mut iters), "statuses": status,
        "max_relative_gap": max_gap.is_finite().then_some(max_gap),
        // No longer measured (inline-assembly probes, removed); kept for the rows' readers.
        "core_clock_ghz": null, "fma_gflops": null, "fma512_gflops": null,
        "median_mcycles": null,
    }))
}

/// Fast BP at `m` solved without pause for `secs` seconds, the `repeat` curves of
/// [`speed_problem`] in turn. A row of [`time_method`] takes its 20 solves within a second or two,
/// all inside whatever spell the shared host's other tenants are in (a busy SMT sibling slowed
/// every kernel 1.35-1.69x in session 25); this median is over thousands of solves spread over
/// minutes, and the window medians show the spells.
fn sustained(grid: &Grid, m: usize, repeat: usize, secs: f64) -> anyhow::Result<serde_json::Value> {
    const WINDOWS: usize = 10;
    let problems = (0..repeat.max(1) as u64)
        .map(|r| speed_problem(grid, m, r))
        .collect::<Result<Vec<_>, _>>()?;
    let s = ReconSettings {
        method: Method::Bp,
        solver: Solver::Fast,
        ..Default::default()
    };
    // The first solve plans the transforms (`first_ms` of the other rows): not timed here.
    recon::reconstruct(grid, &problems[0].samples, &s)?;
    let mut times = Vec::new();
    let mut windows = vec![Vec::new(); WINDOWS];
    let mut status = Vec::new();
    let t0 = std::time::Instant::now();
    for p in problems.iter().cycle() {
        let at = t0.elapsed().as_secs_f64();
        if at >= secs {
            break;
        }
        let out = recon::reconstruct(grid, &p.samples, &s)?;
        times.push(out.solve_ms);
        windows[((at / secs * WINDOWS as f64) as usize).min(WINDOWS - 1)].push(out.solve_ms);
        status.push(out.status.map(|s| format!("{s:?}")).unwrap_or_default());
    }
    status.sort();
    status.dedup();
    let window_medians: Vec<Option<f64>> = windows
        .iter_mut()
        .map(|w| (!w.is_empty()).then(|| median(w)))
        .collect();
    Ok(json!({
        "method": "bp", "solver": "fast", "n": grid.n, "m": m, "curves": problems.len(),
        "sustain_s": secs, "solves": times.len(), "statuses": status,
        "p10_ms": percentile(&mut times, 0.1), "median_ms": median(&mut times),
        "p90_ms": percentile(&mut times, 0.9), "window_medians_ms": window_medians,
    }))
}

pub(super) fn speed(
    repeat: usize,
    clarabel_m: Option<usize>,
    sustain_s: Option<f64>,
) -> anyhow::Result<serde_json::Value> {
    let grid: Grid = "0:5:9500".parse().map_err(anyhow::Error::msg)?;
    let mut rows = vec![
        time_method(&grid, 600, Method::Bp, Solver::Fast, repeat)?,
        time_method(&grid, 100, Method::Bp, Solver::Fast, repeat)?,
        time_method(&grid, 600, Method::Bpdn, Solver::Fast, repeat)?,
        time_method(&grid, 300, Method::Bpdn, Solver::Fast, repeat)?,
        time_method(&grid, 600, Method::Auto, Solver::Fast, repeat)?,
        time_method(&grid, 100, Method::Auto, Solver::Fast, repeat)?,
    ];
    if let Some(m) = clarabel_m {
        rows.push(time_method(&grid, m, Method::Bp, Solver::Clarabel, 1)?);
    }
    if let Some(secs) = sustain_s {
        rows.push(sustained(&grid, 600, repeat, secs)?);
    }
    // Scale: n = 65 536 at 10 % sampling: BP to its certified gap (the default 1e-3), and
    // the physics model `auto` picks at this size.
    let big = Grid::new(0.0, 0.25, 0.25 * 65535.0).map_err(anyhow::Error::msg)?;
    rows.push(time_method(
        &big,
        6554,
        Method::Bp,
        Solver::Fast,
        repeat.min(3),
    )?);
    rows.push(time_method(
        &big,
        6554,
        Method::Physics,
        Solver::Fast,
        repeat.min(3),
    )?);
    Ok(json!({"benchmark": "speed", "threads": 1, "rows": rows}))
}

#[cfg(test)]
mod tests {
    /// A speed row carries the fields lab scripts read; the probes' fields, no longer measured,
    /// are null.
    #[test]
    fn speed_row_reports_times_and_null_probes() {
        use crate::recon::{Method, Solver};
        let grid: crate::grid::Grid = "0:5:9500".parse().unwrap();
        let row = super::time_method(&grid, 100, Method::Bp, Solver::Fast, 3).unwrap();
        let num = |k: &str| row[k].as_f64().unwrap_or_else(|| panic!("{k} in {row}"));
        let ms = num("median_ms");
        // Per curve the best of three is at most its first-pass time, so their medians too.
        assert!(ms > 0.0 && num("median_best_of_3_ms") <= ms);
        assert_eq!(row["statuses"], serde_json::json!(["Optimal"]));
        assert_eq!((num("n"), num("m"), num("repeat")), (1901.0, 100.0, 3.0));
        for probe in [
            "core_clock_ghz",
            "fma_gflops",
            "fma512_gflops",
            "median_mcycles",
        ] {
            assert!(row[probe].is_null(), "{probe} in {row}");
        }
    }

    /// A sustained row solves for the span asked (and not just once), every solve certified,
    /// with ordered percentiles and one median per tenth of the span.
    #[test]
    fn sustained_row_spans_its_time_and_reports_percentiles() {
        let grid: crate::grid::Grid = "0:5:9500".parse().unwrap();
        let t0 = std::time::Instant::now();
        // 2 s: a debug-build solve took 0.74 s on a loaded 2-core host, and the row needs two.
        let row = super::sustained(&grid, 100, 3, 2.0).unwrap();
        assert!(t0.elapsed().as_secs_f64() >= 2.0, "ran the span");
        let num = |k: &str| row[k].as_f64().unwrap_or_else(|| panic!("{k} in {row}"));
        assert!(num("solves") >= 2.0, "{row}");
        assert!(num("p10_ms") <= num("median_ms") && num("median_ms") <= num("p90_ms"));
        assert_eq!(row["statuses"], serde_json::json!(["Optimal"]));
        assert_eq!(
            row["window_medians_ms"].as_array().map(|w| w.len()),
            Some(10)
        );
        assert_eq!((num("n"), num("m"), num("curves")), (1901.0, 100.0, 3.0));
    }
}
