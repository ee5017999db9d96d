//! Verification of an XY map's compensation (`csmetro verify ID` of a `[map]` campaign): both
//! axes measured at random XY points the map campaign never visited, without (plain moves) and
//! with the map's compensation, in each of the map's directions, `cycles` times.
//!
//! **The points.** A lattice of `columns` random x positions × `rows` random y positions
//! (stratified: one in each equal share of the span), every one strictly between two grid
//! lines of the map (at least 20 % of a step from either), inside the span the map campaign
//! measured (its samples' bounding box). The map campaign only ever stood on grid points, so
//! none of these was visited. Lines of points (a column shares x, a row shares y) are what ISO
//! 230-1 measures straightness and squareness on: an axis's own short-period error (its
//! roughness, between grid points) is one constant along the other axis's line and does not
//! tilt the line.
//!
//! **The figures**, per axis, over every approach: mean and max |error| before and after.
//! ISO 230-1 from the per-point means (over cycles): along each column e_x = α_column + s·y,
//! along each row e_y = β_row + a·x (one slope each, pooled over the lines and directions, an
//! offset per line and direction); squareness X to Y = −(a + s) (µrad, as the map campaign's own
//! figure, see [`crate::report::iso230_1`]); straightness of X (e_y along x) and of Y (e_x along
//! y): the largest peak-to-valley about a line's own least-squares line, at the measured points
//! only (a few per line: a lower bound of the line's straightness). A few lines sample the
//! stage's short-period straightness (the demo's 400 µm harmonics, ~0.3 µm) at a few phases,
//! which tilts the uncompensated lines by tens of µrad: the map campaign's own squareness
//! (whole grid) is reported beside them, and the compensated squareness against it.
//!
//! **The verdict**, per axis: mean |after| ≤ mean |before| / 10, and max |after| ≤ the expected
//! residual E = 3 × the map's cross-validation error (held-out RMS over e_x and e_y, sensor
//! noise included; the worst of the directions served) + the unidirectional repeatability R
//! (4 × the largest standard deviation over cycles at one point and direction, from the
//! uncompensated pass; 0 with one cycle) + the bilinear interpolation's bound between the map's
//! grid points ([`crate::compensation::map::MapTable::interpolation_bound_um`]); or `--expected-um`.
use std::collections::BTreeMap;
use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use serde_json::Value;
use tokio::sync::watch;

use super::{precheck, run_passes, Sink, VerifyError, MAX_CYCLES};
use crate::campaign::engine::Control;
use crate::campaign::plan::{Batch, Plan};
use crate::campaign::rig;
use crate::campaign::spec::Campaign;
use crate::compensation::Compensation;
use crate::grid::Grid;
use crate::report::iso230_1::ls_straightness;
use crate::report::verification::{verify_chart_png, verify_chart_svg, TargetCheck, VerifyChart};
use crate::types::{AxisId, Direction, Phase, RunKey, SampleRecord, Target};

/// Most points a map verification accepts.
pub const MAX_POINTS: usize = 1000;

#[derive(Debug, Clone)]
pub struct MapVerifyOptions {
    /// Points wanted (a lattice of columns × rows with at least this many points).
    pub points: usize,
    pub cycles: u32,
    pub seed: u64,
    pub expected_um: Option<f64>,
    /// The span the map campaign measured, x and y (its samples' bounding box), µm.
    pub measured_span_um: [Option<(f64, f64)>; 2],
}

/// The bounding box of a map campaign's samples: x and y spans, µm.
pub fn measured_span(samples: &[SampleRecord]) -> [Option<(f64, f64)>; 2] {
    let mut out: [Option<(f64, f64)>; 2] = [None, None];
    for s in samples.iter().filter(|s| s.target.run.phase == Phase::Map) {
        for (k, p) in [s.target.target_x_um, s.target.target_y_um]
            .into_iter()
            .enumerate()
        {
            out[k] = Some(out[k].map_or((p, p), |(lo, hi)| (lo.min(p), hi.max(p))));
        }
    }
    out
}

/// (columns, rows) of the lattice for `n` points: about twice as many columns as rows, at
/// least 2 of each.
pub fn lattice(n: usize) -> (usize, usize) {
    let rows = ((n as f64 / 2.0).sqrt().round() as usize).max(2);
    let cols = n.div_ceil(rows).max(2);
    (cols, rows)
}

/// `n` stratified random positions in [lo, hi], each strictly between two lines of grid `g`
/// (in `n` distinct cells, at least 20 % of a step from either line), ascending; `None` when
/// [lo, hi] holds fewer than `n` whole cells.
fn positions(rng: &mut ChaCha8Rng, g: &Grid, (lo, hi): (f64, f64), n: usize) -> Option<Vec<f64>> {
    // Cells [i, i + 1] inside [lo, hi] and inside the grid.
    let i_lo = ((lo - g.start_um) / g.step_um - 1e-9).ceil().max(0.0) as usize;
    let i_hi = (((hi - g.start_um) / g.step_um + 1e-9).floor() as usize).min(g.n.saturating_sub(1));
    let cells = i_hi.checked_sub(i_lo)?;
    if cells < n || n == 0 {
        return None;
    }
    Some(
        (0..n)
            .map(|k| {
                let (a, b) = (i_lo + k * cells / n, i_lo + (k + 1) * cells / n);
                let i = rng.random_range(a..b);
                g.start_um + g.step_um * (i as f64 + rng.random_range(0.2..0.8))
            })
            .collect(),
    )
}

/// Why a map verification has no points to measure.
#[derive(Debug, thiserror::Error)]
pub enum PointsError {
    #[error("not a map campaign")]
    NotMap,
    #[error("not a map compensation")]
    NotMapCompensation,
    #[error(
        "the map measured {axis} over [{lo}, {hi}] µm: fewer than {n} grid cells to put points in"
    )]
    TooFewCells {
        axis: &'static str,
        lo: f64,
        hi: f64,
        n: usize,
    },
}

/// The verification's points: (x, y) of the lattice, rows ascending in y, x ascending in a
/// row; and the lattice's (columns, rows).
pub fn points(
    c: &Campaign,
    comp: &Compensation,
    opts: &MapVerifyOptions,
) -> Result<(Vec<[f64; 2]>, usize, usize), PointsError> {
    let mp = c.map().ok_or(PointsError::NotMap)?;
    let m = comp.map().ok_or(PointsError::NotMapCompensation)?;
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x4d41_5056);
    let (cols, rows) = lattice(opts.points);
    let mut axes = Vec::new();
    for (k, g) in [mp.grid.x, mp.grid.y].iter().enumerate() {
        // Inside the grid, the measured span and every direction's map.
        let mut span = (g.start_um, g.end_um());
        if let Some((lo, hi)) = opts.measured_span_um[k] {
            span = (span.0.max(lo), span.1.min(hi));
        }
        for t in [&m.forward, &m.backward].into_iter().flatten() {
            let (lo, hi) = t.span_um()[k];
            span = (span.0.max(lo), span.1.min(hi));
        }
        let n = [cols, rows][k];
        let p = positions(&mut rng, g, span, n).ok_or(PointsError::TooFewCells {
            axis: ["x", "y"][k],
            lo: span.0,
            hi: span.1,
            n,
        })?;
        axes.push(p);
    }
    let mut out = Vec::new();
    for &y in &axes[1] {
        for &x in &axes[0] {
            out.push([x, y]);
        }
    }
    Ok((out, cols, rows))
}

/// One pass's plan: per cycle and map direction, one run over every point (backward: in
/// reverse order).
fn plan_of(c: &Campaign, pts: &[[f64; 2]], cycles: u32, seq0: u64) -> Plan {
    let mut seq = seq0;
    let mut batches = Vec::new();
    let dirs = c
        .map()
        .as_ref()
        .map(|m| m.directions.clone())
        .unwrap_or_default();
    for cycle in 0..cycles {
        for &direction in &dirs {
            let run = RunKey {
                phase: Phase::Map,
                axis: AxisId::X,
                direction,
                cycle,
            };
            let mut order: Vec<usize> = (0..pts.len()).collect();
            if direction == Direction::Backward {
                order.reverse();
            }
            let targets = order
                .into_iter()
                .map(|k| {
                    let t = Target {
                        seq,
                        run,
                        grid_index: k,
                        target_x_um: pts[k][0],
                        target_y_um: pts[k][1],
                    };
                    seq += 1;
                    t
                })
                .collect();
            batches.push(Batch {
                run,
                index: 0,
                targets,
                target_error_um: None,
            });
        }
    }
    Plan { batches }
}

/// ISO 230-1 figures from the verification's points.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct LineFigures {
    pub squareness_urad: f64,
    /// d e_y / d x along the rows and d e_x / d y along the columns, µrad.
    pub slope_x_urad: f64,
    pub slope_y_urad: f64,
    pub straightness_x_um: f64,
    pub straightness_y_um: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct MapAxisVerdict {
    pub axis: String,
    pub mean_abs_before_um: f64,
    pub mean_abs_after_um: f64,
    pub max_abs_before_um: f64,
    pub max_abs_after_um: f64,
    /// mean |before| / mean |after|.
    pub mean_reduction: f64,
    pub expected_um: f64,
    /// `map` (3 cv + R + interpolation) or `given`.
    pub expected_from: &'static str,
    pub cv_error_um: Option<f64>,
    pub repeatability_um: Option<f64>,
    pub interpolation_um: f64,
    pub passed: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct MapVerdict {
    pub campaign: i64,
    /// `map`.
    pub kind: &'static str,
    pub passed: bool,
    pub axes: Vec<MapAxisVerdict>,
    pub iso230_1_before: LineFigures,
    pub iso230_1_after: LineFigures,
    /// |squareness after| / |squareness before| (both from the points).
    pub squareness_ratio: f64,
    /// The map campaign's own squareness (whole grid, first direction), µrad, and
    /// |squareness after| / |that|: the points' before figure is the noisier one (a few lines
    /// sample the short-period straightness, see the module doc).
    pub squareness_map_urad: Option<f64>,
    pub squareness_after_over_map: Option<f64>,
    pub stage: String,
    pub compensation: String,
    pub points_um: Vec<[f64; 2]>,
    pub columns: usize,
    pub rows: usize,
    pub directions: Vec<&'static str>,
    pub cycles: u32,
    pub measured_span_um: [Option<(f64, f64)>; 2],
    pub acquisition_s: f64,
    pub samples: [usize; 2],
    pub command_compute_us_max: f64,
    #[serde(skip)]
    pub raw: Vec<(bool, SampleRecord)>,
}

/// Per (point index, forward): the mean error of each axis over cycles and the standard
/// deviations (n ≥ 2).
type PerPoint = BTreeMap<(usize, bool), ([f64; 2], [Option<f64>; 2])>;

/// Lines of the lattice: (is a column, index, forward) → (positions along it, errors across).
type Lines = BTreeMap<(bool, usize, bool), (Vec<f64>, Vec<f64>)>;

fn per_point(s: &[SampleRecord]) -> PerPoint {
    let mut g: BTreeMap<(usize, bool), Vec<[f64; 2]>> = BTreeMap::new();
    for r in s {
        let key = (
            r.target.grid_index,
            r.target.run.direction == Direction::Forward,
        );
        g.entry(key)
            .or_default()
            .push([r.error_um(AxisId::X), r.error_um(AxisId::Y)]);
    }
    g.into_iter()
        .map(|(k, v)| {
            let n = v.len() as f64;
            let mean = [0, 1].map(|a| v.iter().map(|e| e[a]).sum::<f64>() / n);
            let sd = [0, 1].map(|a| {
                (v.len() >= 2).then(|| {
                    (v.iter().map(|e| (e[a] - mean[a]).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
                })
            });
            (k, (mean, sd))
        })
        .collect()
}

/// Squareness and straightness from the per-point means (see the module doc).
fn line_figures(pts: &[[f64; 2]], cols: usize, means: &PerPoint) -> LineFigures {
    // Lines: (is a column, index, direction) → (position along the line, error across).
    let mut lines: Lines = BTreeMap::new();
    for (&(k, fwd), (m, _)) in means {
        let (col, row) = (k % cols, k / cols);
        let e = lines.entry((true, col, fwd)).or_default();
        e.0.push(pts[k][1]);
        e.1.push(m[0]);
        let e = lines.entry((false, row, fwd)).or_default();
        e.0.push(pts[k][0]);
        e.1.push(m[1]);
    }
    // Pooled within-line slopes.
    let mut sxy = [0.0f64; 2];
    let mut sxx = [0.0f64; 2];
    let mut straight = [0.0f64; 2];
    for (&(is_col, _, _), (p, v)) in &lines {
        let a = usize::from(is_col);
        let n = p.len() as f64;
        if p.len() < 2 {
            continue;
        }
        let (mp, mv) = (p.iter().sum::<f64>() / n, v.iter().sum::<f64>() / n);
        sxy[a] += p
            .iter()
            .zip(v)
            .map(|(x, y)| (x - mp) * (y - mv))
            .sum::<f64>();
        sxx[a] += p.iter().map(|x| (x - mp) * (x - mp)).sum::<f64>();
        straight[a] = straight[a].max(ls_straightness(p, v).1);
    }
    let slope = |a: usize| {
        if sxx[a] > 0.0 {
            sxy[a] / sxx[a]
        } else {
            f64::NAN
        }
    };
    let (sx, sy) = (slope(0), slope(1));
    LineFigures {
        squareness_urad: -(sx + sy) * 1e6,
        slope_x_urad: sx * 1e6,
        slope_y_urad: sy * 1e6,
        straightness_x_um: straight[0],
        straightness_y_um: straight[1],
    }
}

/// Runs the verification of map campaign `id` (campaign `c`, its map compensation `comp`):
/// a pass of plain moves, then a compensated pass; every compensated command is computed (any
/// refused) before the stage moves.
pub async fn run(
    id: i64,
    c: &Campaign,
    comp: Arc<Compensation>,
    opts: &MapVerifyOptions,
    control: watch::Receiver<Control>,
    sink: &mut dyn Sink,
) -> Result<MapVerdict, VerifyError> {
    use VerifyError::{Failed, Refused};
    if opts.cycles == 0 || opts.cycles > MAX_CYCLES {
        return Err(Refused(format!("cycles must be 1..={MAX_CYCLES}")));
    }
    if opts.points < 4 || opts.points > MAX_POINTS {
        return Err(Refused(format!("points must be 4..={MAX_POINTS}")));
    }
    let Some(mp) = c.map() else {
        return Err(Refused(format!("campaign {id} is not a map campaign")));
    };
    let Some(m) = comp.map() else {
        return Err(Refused(format!(
            "{}: not a map compensation (a map campaign is verified with its compensation_map_<direction>.csv)",
            comp.source
        )));
    };
    comp.check_stage(&c.spec().campaign.stage)
        .map_err(|e| Refused(e.to_string()))?;
    for &d in &mp.directions {
        if m.served_direction(d) != d {
            return Err(Refused(format!(
                "{}: no {} map, and the campaign measured {} (approached from the other side, backlash would stay)",
                comp.source,
                d.as_str(),
                d.as_str()
            )));
        }
    }
    let (pts, cols, rows) = points(c, &comp, opts).map_err(|e| Refused(e.to_string()))?;
    let before_plan = plan_of(c, &pts, opts.cycles, 0);
    let after_plan = plan_of(c, &pts, opts.cycles, before_plan.total() as u64);
    let mut rig = rig::build(c)
        .await
        .map_err(|e| Failed(format!("hardware: {e}")))?;
    let limits = [AxisId::X, AxisId::Y].map(|a| rig.axis(a).soft_limits_um());
    let points = mp
        .directions
        .iter()
        .flat_map(|&d| pts.iter().map(move |p| (d, *p)));
    let checked = precheck(&mut rig, points, |_, (d, p)| {
        comp.command_point(d, p, limits).map(drop)
    });
    let compute_us_max = match checked {
        Ok(us) => us,
        Err(e) => {
            rig.close().await;
            return Err(Refused(format!("compensation: {e}")));
        }
    };
    let (passes, acquisition_s) = run_passes(
        c,
        rig,
        &comp,
        [&before_plan, &after_plan],
        control,
        &BTreeMap::new(),
        sink,
    )
    .await?;
    let [before, after] = &passes;
    let (pb, pa) = (per_point(before), per_point(after));
    let interp = [&m.forward, &m.backward]
        .into_iter()
        .flatten()
        .map(|t| t.interpolation_bound_um())
        .fold([0.0f64; 2], |a, b| [a[0].max(b[0]), a[1].max(b[1])]);
    let cv = mp
        .directions
        .iter()
        .filter_map(|&d| m.cv_of(d))
        .reduce(f64::max);
    let mut axes = Vec::new();
    for (a, axis) in [AxisId::X, AxisId::Y].into_iter().enumerate() {
        let stats = |s: &[SampleRecord]| {
            let v: Vec<f64> = s.iter().map(|r| r.error_um(axis).abs()).collect();
            let n = v.len().max(1) as f64;
            (
                v.iter().sum::<f64>() / n,
                v.iter().copied().fold(0.0, f64::max),
            )
        };
        let (mean_b, max_b) = stats(before);
        let (mean_a, max_a) = stats(after);
        let repeat = pb
            .values()
            .filter_map(|(_, sd)| sd[a])
            .reduce(f64::max)
            .map(|s| 4.0 * s);
        let (expected, from) = match opts.expected_um {
            Some(e) => (e, "given"),
            None => (
                3.0 * cv.unwrap_or(f64::NAN) + repeat.unwrap_or(0.0) + interp[a],
                "map",
            ),
        };
        let passed = expected.is_finite() && max_a <= expected && mean_a <= mean_b / 10.0;
        axes.push(MapAxisVerdict {
            axis: axis.as_str().into(),
            mean_abs_before_um: mean_b,
            mean_abs_after_um: mean_a,
            max_abs_before_um: max_b,
            max_abs_after_um: max_a,
            mean_reduction: mean_b / mean_a,
            expected_um: expected,
            expected_from: from,
            cv_error_um: cv,
            repeatability_um: repeat,
            interpolation_um: interp[a],
            passed,
        });
    }
    let (fb, fa) = (line_figures(&pts, cols, &pb), line_figures(&pts, cols, &pa));
    let map_sq = mp.directions.first().and_then(|&d| {
        m.squareness_urad[usize::from(m.served_direction(d) == Direction::Backward)]
    });
    let raw = before
        .iter()
        .map(|s| (false, *s))
        .chain(after.iter().map(|s| (true, *s)))
        .collect();
    Ok(MapVerdict {
        campaign: id,
        kind: "map",
        passed: axes.iter().all(|a| a.passed),
        axes,
        iso230_1_before: fb,
        iso230_1_after: fa,
        squareness_ratio: (fa.squareness_urad / fb.squareness_urad).abs(),
        squareness_map_urad: map_sq,
        squareness_after_over_map: map_sq.map(|q| (fa.squareness_urad / q).abs()),
        stage: c.spec().campaign.stage.clone(),
        compensation: comp.source.clone(),
        points_um: pts,
        columns: cols,
        rows,
        directions: mp.directions.iter().map(|d| d.as_str()).collect(),
        cycles: opts.cycles,
        measured_span_um: opts.measured_span_um,
        acquisition_s,
        samples: [before.len(), after.len()],
        command_compute_us_max: compute_us_max,
        raw,
    })
}

fn opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.3}"))
}

/// The side-by-side table (`verify/summary.txt`).
pub fn table(v: &MapVerdict) -> String {
    let mut s = format!(
        "verification of map campaign {} on stage {} (compensation: {})\n{} never-visited points ({} x {} lattice between the map's grid lines), directions {}, {} cycles\n",
        v.campaign,
        v.stage,
        v.compensation,
        v.points_um.len(),
        v.columns,
        v.rows,
        v.directions.join(", "),
        v.cycles
    );
    s.push_str(&format!(
        "{:<5} {:>12} {:>12} {:>12} {:>12} {:>10}\n",
        "axis", "mean|e| bef", "mean|e| aft", "max|e| bef", "max|e| aft", "expected"
    ));
    for a in &v.axes {
        s.push_str(&format!(
            "{:<5} {:>12.3} {:>12.3} {:>12.3} {:>12.3} {:>10.3}\n",
            a.axis.to_uppercase(),
            a.mean_abs_before_um,
            a.mean_abs_after_um,
            a.max_abs_before_um,
            a.max_abs_after_um,
            a.expected_um
        ));
    }
    for a in &v.axes {
        let basis = match a.expected_from {
            "given" => "given".to_string(),
            _ => format!(
                "3 x map CV error {} + unidirectional R {} + interpolation {:.3}",
                opt(a.cv_error_um),
                opt(a.repeatability_um),
                a.interpolation_um
            ),
        };
        s.push_str(&format!(
            "{:<5} mean |error| reduced {:.1}x (needs ≥ 10x); max |after| {:.3} µm vs expected {:.3} µm ({basis}): {}\n",
            a.axis.to_uppercase(),
            a.mean_reduction,
            a.max_abs_after_um,
            a.expected_um,
            if a.passed { "passed" } else { "FAILED" }
        ));
    }
    let (b, f) = (&v.iso230_1_before, &v.iso230_1_after);
    s.push_str(&format!(
        "ISO 230-1 at these points (lines of the lattice): squareness X to Y {:+.2} → {:+.2} µrad ({:.1} % of before); straightness X (e_y along x) {:.3} → {:.3} µm, Y (e_x along y) {:.3} → {:.3} µm (at {} / {} points per line)\n",
        b.squareness_urad,
        f.squareness_urad,
        100.0 * v.squareness_ratio,
        b.straightness_x_um,
        f.straightness_x_um,
        b.straightness_y_um,
        f.straightness_y_um,
        v.columns,
        v.rows
    ));
    if let (Some(q), Some(r)) = (v.squareness_map_urad, v.squareness_after_over_map) {
        s.push_str(&format!(
            "the map's own squareness (whole grid) {q:+.2} µrad: after is {:.1} % of it\n",
            100.0 * r
        ));
    }
    s.push_str(if v.passed {
        "verification passed\n"
    } else {
        "verification FAILED\n"
    });
    s
}

pub fn json(v: &MapVerdict) -> Value {
    serde_json::to_value(v).unwrap_or(Value::Null)
}

/// Axis `axis`'s points as the line verification's chart draws its targets: each point at its
/// coordinate on that axis (a lattice's rows share those), its before/after means per direction,
/// the pass line ±expected, and every compensated reading.
fn chart_checks(
    v: &MapVerdict,
    axis: AxisId,
    expected_um: f64,
) -> (Vec<TargetCheck>, Vec<(f64, f64)>) {
    // (point, forward) -> (coordinate, before readings, after readings)
    type Readings = (f64, Vec<f64>, Vec<f64>);
    let mut g: BTreeMap<(usize, bool), Readings> = BTreeMap::new();
    let mut after_samples = Vec::new();
    for (after, r) in &v.raw {
        let at = match axis {
            AxisId::X => r.target.target_x_um,
            AxisId::Y => r.target.target_y_um,
        };
        let key = (
            r.target.grid_index,
            r.target.run.direction == Direction::Forward,
        );
        let e = g.entry(key).or_insert((at, Vec::new(), Vec::new()));
        let err = r.error_um(axis);
        if *after {
            e.2.push(err);
            after_samples.push((at, err));
        } else {
            e.1.push(err);
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let checks = g
        .into_iter()
        .filter(|(_, (_, b, a))| !b.is_empty() && !a.is_empty())
        .map(|((_, forward), (at, b, a))| {
            let max_after = a.iter().fold(0.0f64, |m, e| m.max(e.abs()));
            TargetCheck {
                target_um: at,
                direction: if forward { "forward" } else { "backward" },
                kind: "unvisited",
                mean_before_um: mean(&b),
                mean_after_um: mean(&a),
                max_abs_after_um: max_after,
                expected_um,
                passed: max_after <= expected_um,
            }
        })
        .collect();
    (checks, after_samples)
}

/// What a map's expected residual is made of, in words.
fn basis(a: &MapAxisVerdict) -> String {
    match a.expected_from {
        "given" => format!("expected {:.3} µm (given)", a.expected_um),
        _ => format!(
            "expected {:.3} µm at every point: 3 x map CV error {} + unidirectional R {} + interpolation {:.3} µm; mean |error| reduced {:.1}x (needs ≥ 10x)",
            a.expected_um,
            opt(a.cv_error_um),
            opt(a.repeatability_um),
            a.interpolation_um,
            a.mean_reduction
        ),
    }
}

/// `verify/report.html` of a map: before/after per axis (E n/a: ISO 230-2's E is a figure of
/// one line's targets, not of scattered XY points), ISO 230-1 squareness and straightness
/// before/after, every never-visited point's before/after means, the per-axis charts (`pngs`,
/// embedded; their SVG beside the page) and the text table.
pub fn page_html(v: &MapVerdict, pngs: &[(String, Vec<u8>)]) -> String {
    use crate::report::html::esc;
    use crate::report::verification::{verify_html, AxisPage};
    let checks: Vec<Vec<TargetCheck>> = v
        .axes
        .iter()
        .map(|a| {
            AxisId::parse(&a.axis).map_or_else(Vec::new, |ax| chart_checks(v, ax, a.expected_um).0)
        })
        .collect();
    let axes: Vec<AxisPage<'_>> = v
        .axes
        .iter()
        .zip(&checks)
        .map(|(a, c)| AxisPage {
            axis: &a.axis,
            e_before_um: f64::NAN,
            e_after_um: f64::NAN,
            mean_abs_before_um: a.mean_abs_before_um,
            mean_abs_after_um: a.mean_abs_after_um,
            max_abs_after_um: a.max_abs_after_um,
            expected_um: a.expected_um,
            expected_basis: basis(a),
            passed: a.passed,
            checks: c,
            png: pngs
                .iter()
                .find(|(n, _)| *n == a.axis)
                .map(|(_, b)| b.as_slice()),
            svg_name: Some(format!("verify_{}.svg", a.axis)),
        })
        .collect();
    let (b, f) = (&v.iso230_1_before, &v.iso230_1_after);
    let num = |x: f64, d: usize| {
        if x.is_finite() {
            format!("{x:.d$}")
        } else {
            "n/a".into()
        }
    };
    let mut extra = String::from(
        "<h2>ISO 230-1 at the points</h2>\n<table data-table=\"iso230-1\"><tr><th>figure</th><th>before</th><th>after</th></tr>\n",
    );
    for (name, x, y, d) in [
        (
            "squareness X to Y (µrad)",
            b.squareness_urad,
            f.squareness_urad,
            2,
        ),
        (
            "straightness X, e_y along x (µm)",
            b.straightness_x_um,
            f.straightness_x_um,
            3,
        ),
        (
            "straightness Y, e_x along y (µm)",
            b.straightness_y_um,
            f.straightness_y_um,
            3,
        ),
    ] {
        extra.push_str(&format!(
            "<tr><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>\n",
            esc(name),
            num(x, d),
            num(y, d)
        ));
    }
    extra.push_str("</table>\n");
    extra.push_str(&format!(
        "<p class=\"note\">From the lines of the {} x {} lattice (a few points per line: straightness is a lower bound). After / before squareness: {:.1} %.{}</p>\n",
        v.columns,
        v.rows,
        100.0 * v.squareness_ratio,
        match (v.squareness_map_urad, v.squareness_after_over_map) {
            (Some(q), Some(r)) => format!(
                " The map's own squareness (whole grid) {q:+.2} µrad: after is {:.1} % of it.",
                100.0 * r
            ),
            _ => String::new(),
        }
    ));
    // Each never-visited point: the mean error over cycles before and after, per direction.
    let mut pts: BTreeMap<(usize, bool), [[Vec<f64>; 2]; 2]> = BTreeMap::new();
    for (after, r) in &v.raw {
        let key = (
            r.target.grid_index,
            r.target.run.direction == Direction::Forward,
        );
        let e = pts.entry(key).or_default();
        for (k, ax) in [AxisId::X, AxisId::Y].into_iter().enumerate() {
            e[usize::from(*after)][k].push(r.error_um(ax));
        }
    }
    let mean = |x: &[f64]| {
        if x.is_empty() {
            f64::NAN
        } else {
            x.iter().sum::<f64>() / x.len() as f64
        }
    };
    extra.push_str(
        "<h2>Never-visited points</h2>\n<table data-table=\"points\"><tr><th>x (µm)</th><th>y (µm)</th><th>direction</th>\
         <th>e_x before (µm)</th><th>e_x after (µm)</th><th>e_y before (µm)</th><th>e_y after (µm)</th></tr>\n",
    );
    for ((i, forward), e) in &pts {
        let Some(p) = v.points_um.get(*i) else {
            continue;
        };
        extra.push_str(&format!(
            "<tr><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>\n",
            num(p[0], 1),
            num(p[1], 1),
            if *forward { "forward" } else { "backward" },
            num(mean(&e[0][0]), 3),
            num(mean(&e[1][0]), 3),
            num(mean(&e[0][1]), 3),
            num(mean(&e[1][1]), 3),
        ));
    }
    extra.push_str("</table>\n");
    verify_html(
        &format!(
            "Verification of map campaign {} on stage {}",
            v.campaign, v.stage
        ),
        &format!(
            "Compensation: {}. {} never-visited XY points, directions {}, {} cycles; E (ISO 230-2) n/a: not a figure of scattered XY points.",
            v.compensation,
            v.points_um.len(),
            v.directions.join(", "),
            v.cycles
        ),
        v.passed,
        &axes,
        &table(v),
        &extra,
    )
}

/// The verification's result files (relative to the campaign's results): the table, the
/// verdict, the samples, per axis the before/after chart with its pass line (SVG and PNG), and
/// `verify/report.html` with all of them.
pub fn files(v: &MapVerdict) -> Vec<(String, String, Vec<u8>)> {
    let mut csv = crate::samples::layout_header();
    for (after, r) in &v.raw {
        csv.push_str(&crate::samples::layout_row(r, Some(*after)));
    }
    let mut charts = Vec::new();
    let mut pngs = Vec::new();
    for a in &v.axes {
        let Some(axis) = AxisId::parse(&a.axis) else {
            continue;
        };
        let (checks, after_samples) = chart_checks(v, axis, a.expected_um);
        let chart = VerifyChart {
            axis: &a.axis,
            checks: &checks,
            after_samples: &after_samples,
            passed: a.passed,
        };
        // A chart that cannot be drawn leaves the verdict's files intact (logged).
        match verify_chart_svg(&chart, &super::output::CHART) {
            Ok(svg) => charts.push((
                format!("verify/verify_{}.svg", a.axis),
                "image/svg+xml".to_string(),
                svg.into_bytes(),
            )),
            Err(e) => tracing::warn!(axis = %a.axis, error = %e, "verification chart not drawn"),
        }
        match verify_chart_png(&chart, &super::output::CHART) {
            Ok(png) => {
                pngs.push((a.axis.clone(), png.clone()));
                charts.push((
                    format!("verify/verify_{}.png", a.axis),
                    "image/png".to_string(),
                    png,
                ));
            }
            Err(e) => tracing::warn!(axis = %a.axis, error = %e, "verification chart not drawn"),
        }
    }
    let mut files = vec![
        (
            "verify/summary.txt".to_string(),
            "text/plain".to_string(),
            table(v).into_bytes(),
        ),
        (
            super::VERDICT_FILE.into(),
            "application/json".into(),
            serde_json::to_vec_pretty(&json(v)).unwrap_or_default(),
        ),
        (
            "verify/samples.csv".into(),
            "text/csv".into(),
            csv.into_bytes(),
        ),
    ];
    files.extend(charts);
    files.push((
        super::REPORT_FILE.to_string(),
        "text/html; charset=utf-8".to_string(),
        page_html(v, &pngs).into_bytes(),
    ));
    files
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lattice_has_at_least_the_points_asked() {
        for n in [4, 10, 20, 40, 100] {
            let (c, r) = lattice(n);
            assert!(c * r >= n && c >= r, "{n}: {c} x {r}");
        }
        assert_eq!(lattice(20), (7, 3));
    }

    #[test]
    fn positions_are_between_grid_lines_and_inside_the_span() {
        let g = Grid::new(0.0, 50.0, 9500.0).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let p = positions(&mut rng, &g, (120.0, 9310.0), 30).unwrap();
        assert!(positions(&mut rng, &g, (120.0, 300.0), 4).is_none());
        assert_eq!(p.len(), 30);
        for x in &p {
            let off = x.rem_euclid(50.0);
            assert!((10.0 - 1e-9..=40.0 + 1e-9).contains(&off), "{x}");
            assert!((120.0..=9310.0).contains(x), "{x}");
        }
        assert!(p.windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn squareness_of_a_sheared_field_is_found_from_the_lines() {
        // e_x = 30e-6·y + roughness in x only; e_y = 10e-6·x + roughness in y only.
        let xs = [500.0, 2100.0, 4400.0, 7000.0, 9100.0];
        let ys = [300.0, 2000.0, 3900.0];
        let mut pts = Vec::new();
        for y in ys {
            for x in xs {
                pts.push([x, y]);
            }
        }
        let mut means = BTreeMap::new();
        for (k, p) in pts.iter().enumerate() {
            let (x, y) = (p[0], p[1]);
            let ex = 30e-6 * y + 0.1 * (x * 0.37f64).sin();
            let ey = 10e-6 * x + 0.1 * (y * 0.91f64).cos();
            means.insert((k, true), ([ex, ey], [None, None]));
        }
        let f = line_figures(&pts, 5, &means);
        assert!((f.squareness_urad + 40.0).abs() < 1e-6, "{f:?}");
        assert!(f.straightness_x_um < 1e-9 && f.straightness_y_um < 1e-9);
    }
}
