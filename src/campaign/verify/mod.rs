//! Verification run: measure a characterised axis again, without and with its compensation, at
//! ISO 230-2 style targets (from the characterisation's grid, repeated cycles, both directions)
//! and at random targets between grid points the characterisation never visited; report the
//! ISO 230-2 figures and the residual errors before and after side by side.
use std::collections::BTreeMap;
use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use serde_json::{json, Value};
use tokio::sync::watch;

use super::engine::{Control, EndState, Engine, Recorder};
use super::plan::{Batch, Plan};
use super::rig::{self, Rig};
use super::spec::{AxisPlan, Campaign};
use crate::compensation::Compensation;
use crate::iso230::{evaluate, Approach, Iso230Summary};
use crate::types::{AxisId, Direction, Phase, RunKey, SampleRecord, Target};

/// What a verification measures and what it expects.
#[derive(Debug, Clone)]
pub struct VerifyOptions {
    /// Measurement cycles per direction (ISO 230-2: 5).
    pub cycles: u32,
    /// Targets chosen from the characterisation's grid (ISO 230-2: at least 5 per metre, 5 at
    /// least).
    pub iso_targets: usize,
    /// Random targets between grid points (never visited by the characterisation).
    pub unvisited_targets: usize,
    pub seed: u64,
    /// Largest |residual| that passes, µm; default per axis: 3 × the characterisation's CV error
    /// estimate + the repeatability R.
    pub expected_um: Option<f64>,
    /// Per axis (x, y): the span the characterisation measured in every direction, µm. The
    /// grid beyond it holds the reconstruction's extrapolation, not a measured correction: the
    /// ISO and never-visited targets are drawn inside it, the grid's ends outside it are
    /// measured and reported apart ([`AxisVerdict::extrapolated_targets_um`]).
    pub measured_span_um: [Option<(f64, f64)>; 2],
}

impl Default for VerifyOptions {
    fn default() -> Self {
        Self {
            cycles: 5,
            iso_targets: 11,
            unvisited_targets: 10,
            seed: 1,
            expected_um: None,
            measured_span_um: [None, None],
        }
    }
}

/// The span of `axis` every measured direction of `samples` covers: (largest first target,
/// smallest last target), µm; `None` without samples of that axis.
pub fn measured_span(samples: &[SampleRecord], axis: AxisId) -> Option<(f64, f64)> {
    let mut per: [Option<(f64, f64)>; 2] = [None, None];
    for s in samples.iter().filter(|s| s.target.run.axis == axis) {
        let t = s.target.target_um();
        let d = &mut per[usize::from(s.target.run.direction == Direction::Backward)];
        *d = Some(d.map_or((t, t), |(lo, hi)| (lo.min(t), hi.max(t))));
    }
    per.into_iter()
        .flatten()
        .reduce(|a, b| (a.0.max(b.0), a.1.min(b.1)))
        .filter(|(lo, hi)| lo <= hi)
}

/// Most targets and cycles a verification accepts (bounds on what a flag can ask).
pub const MAX_TARGETS: usize = 1000;
pub use super::spec::MAX_VERIFY_CYCLES as MAX_CYCLES;

/// The verification targets of one axis, µm, ascending: (ISO targets on the grid, unvisited,
/// the grid's ends outside the measured span).
pub fn targets(ax: &AxisPlan, opts: &VerifyOptions) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let g = ax.grid;
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ ((ax.axis as u64 + 1) * 0x5DEE_CE66));
    // Grid indices [i0, i0 + span] inside the measured span (the whole grid when unknown).
    let (i0, i1) = match opts.measured_span_um[ax.axis as usize] {
        Some((lo, hi)) => {
            let i = |p: f64, up: bool| {
                let u = (p - g.start_um) / g.step_um;
                let u = if up {
                    (u - 1e-6).ceil()
                } else {
                    (u + 1e-6).floor()
                };
                u.clamp(0.0, (g.n - 1) as f64) as usize
            };
            let (a, b) = (i(lo, true), i(hi, false));
            if b > a {
                (a, b)
            } else {
                (0, g.n - 1)
            }
        }
        None => (0, g.n - 1),
    };
    let ext: Vec<f64> = [0, g.n - 1]
        .into_iter()
        .filter(|&i| i < i0 || i > i1)
        .map(|i| g.position(i))
        .collect();
    let n = opts.iso_targets.clamp(2, i1 - i0 + 1);
    // Evenly spread grid indices, each moved by a random fraction of the spacing (ISO 230-2
    // spaces targets unevenly so that periodic errors are not sampled at one phase).
    let span = (i1 - i0) as f64;
    let mut iso: Vec<usize> = (0..n)
        .map(|i| {
            let base = span * i as f64 / (n - 1) as f64;
            let jitter = if i == 0 || i == n - 1 {
                0.0
            } else {
                rng.random_range(-0.3..0.3) * span / (n - 1) as f64
            };
            i0 + (base + jitter).round().clamp(0.0, span) as usize
        })
        .collect();
    iso.sort_unstable();
    iso.dedup();
    let iso: Vec<f64> = iso.into_iter().map(|i| g.position(i)).collect();
    let mut un: Vec<f64> = (0..opts.unvisited_targets)
        .map(|_| {
            // Strictly between two grid points, at least 20 % of a step from either.
            let i = rng.random_range(i0..i1);
            g.position(i) + g.step_um * rng.random_range(0.2..0.8)
        })
        .collect();
    un.sort_by(f64::total_cmp);
    (iso, un, ext)
}

/// An axis's verification targets: (axis, ISO targets, never-visited targets, extrapolated
/// grid ends), µm.
type TargetSet = (AxisId, Vec<f64>, Vec<f64>, Vec<f64>);

/// The runs of one pass: per axis, cycle and direction, one sweep over all its targets.
fn plan_of(c: &Campaign, opts: &VerifyOptions, seq0: u64) -> (Plan, Vec<TargetSet>) {
    let mut batches = Vec::new();
    let mut seq = seq0;
    let mut sets = Vec::new();
    for ax in c.axes() {
        let (iso, un, ext) = targets(ax, opts);
        let mut all: Vec<f64> = iso.iter().chain(&un).chain(&ext).copied().collect();
        all.sort_by(f64::total_cmp);
        for cycle in 0..opts.cycles {
            for &direction in &c.spec().acquisition.directions {
                let run = RunKey {
                    phase: Phase::Full,
                    axis: ax.axis,
                    direction,
                    cycle,
                };
                let mut order = all.clone();
                if direction == Direction::Backward {
                    order.reverse();
                }
                let targets = order
                    .into_iter()
                    .map(|p| {
                        let (tx, ty) = match ax.axis {
                            AxisId::X => (p, ax.other_at_um),
                            AxisId::Y => (ax.other_at_um, p),
                        };
                        let t = Target {
                            seq,
                            run,
                            grid_index:
                                (((p - ax.grid.start_um) / ax.grid.step_um).round().max(0.0)
                                    as usize)
                                    .min(ax.grid.n - 1),
                            target_x_um: tx,
                            target_y_um: ty,
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
        sets.push((ax.axis, iso, un, ext));
    }
    (Plan { batches }, sets)
}

/// Where a verification's samples and events go besides its verdict: the CLI prints progress,
/// a verification campaign commits them to its store.
pub trait Sink: Send {
    /// Commits one sample; `Ok(false)` when its target was stored already.
    fn sample(&mut self, s: &SampleRecord) -> Result<bool, String>;
    fn event(&mut self, kind: &str, data: &Value);
}

/// Progress only: samples are kept in the verdict, events go to a callback.
pub struct Progress<F: FnMut(&str, &Value) + Send>(pub F);

impl<F: FnMut(&str, &Value) + Send> Sink for Progress<F> {
    fn sample(&mut self, _: &SampleRecord) -> Result<bool, String> {
        Ok(true)
    }
    fn event(&mut self, kind: &str, data: &Value) {
        (self.0)(kind, data);
    }
}

/// Keeps the samples; commits them and the events to the sink.
struct Collect<'a> {
    samples: Vec<SampleRecord>,
    sink: &'a mut dyn Sink,
}

impl Recorder for Collect<'_> {
    fn sample(&mut self, s: &SampleRecord) -> Result<bool, String> {
        let fresh = self.sink.sample(s)?;
        self.samples.push(*s);
        Ok(fresh)
    }
    fn event(&mut self, kind: &str, data: Value) {
        self.sink.event(kind, &data);
    }
    fn run_done(&mut self, _run: RunKey) {}
    fn cv_error_um(&mut self, _run: RunKey) -> Option<f64> {
        None
    }
}

/// ISO 230-2 figures as the verification reports them (fixed names).
#[derive(Debug, Clone, Serialize)]
pub struct Figures {
    pub a_um: f64,
    pub b_um: Option<f64>,
    pub e_um: f64,
    pub m_um: Option<f64>,
    pub r_um: Option<f64>,
}

impl From<&Iso230Summary> for Figures {
    fn from(s: &Iso230Summary) -> Self {
        Self {
            a_um: s.a_um,
            b_um: s.b_um,
            e_um: s.e_um,
            m_um: s.m_um,
            r_um: s.r_um,
        }
    }
}

/// Before/after of one axis.
#[derive(Debug, Clone, Serialize)]
pub struct AxisVerdict {
    pub axis: String,
    pub before: Figures,
    pub after: Figures,
    pub max_abs_after_um: f64,
    /// The expected residual: a given figure, 3 × CV error + R for the axis (`cv`), or with a
    /// pointwise band (`band`) 3 u(target) + R at the target with the smallest margin
    /// (`worst_target_um`), every measured approach checked against its own.
    pub expected_um: f64,
    pub expected_from: &'static str,
    pub worst_target_um: Option<f64>,
    /// Mean of the compensation table's u (k = 1), µm, when it has one.
    pub u_mean_um: Option<f64>,
    pub passed: bool,
    pub max_abs_before_um: f64,
    pub mean_abs_before_um: f64,
    pub mean_abs_after_um: f64,
    /// At the random targets between grid points only.
    pub max_abs_after_unvisited_um: f64,
    pub max_abs_before_unvisited_um: f64,
    /// before.e_um / after.e_um.
    pub e_reduction: f64,
    /// What `expected_um` was made of (when not given).
    pub cv_error_um: Option<f64>,
    pub repeatability_um: Option<f64>,
    pub iso_targets_um: Vec<f64>,
    pub unvisited_targets_um: Vec<f64>,
    /// The span the characterisation measured in every direction, µm (when known): the
    /// figures above are taken inside it.
    pub measured_span_um: Option<(f64, f64)>,
    /// Grid ends outside that span, where the table is the reconstruction's extrapolation:
    /// measured, reported here, not part of the figures or the verdict.
    pub extrapolated_targets_um: Vec<f64>,
    pub max_abs_before_extrapolated_um: Option<f64>,
    pub max_abs_after_extrapolated_um: Option<f64>,
    /// RMS over targets and directions of the mean compensated deviation, µm: what the
    /// characterisation's `cv_error_um` estimates (the check of the expected residual).
    pub rms_after_um: f64,
    /// Measurements per run of the characterisation and its grid points (when known).
    pub characterisation_m: Option<u64>,
    pub grid_points: Option<u64>,
    pub cycles: u32,
    /// Every reported target and direction against its own pass line (the figures above are
    /// their extremes).
    pub per_target: Vec<crate::report::verification::TargetCheck>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Verdict {
    pub campaign: i64,
    pub passed: bool,
    pub axes: Vec<AxisVerdict>,
    pub stage: String,
    pub compensation: String,
    /// Physical time of both passes, s.
    pub acquisition_s: f64,
    /// Samples per pass (before, after) and compensated commands computed, with their time.
    pub samples: [usize; 2],
    pub command_compute_us_max: f64,
    #[serde(skip)]
    pub raw: Vec<(bool, SampleRecord)>,
}

/// What the characterisation says about an axis: the driving components' CV error estimate
/// (worst direction) and the measured unidirectional repeatability, when it had repeated cycles.
#[derive(Debug, Clone, Copy, Default)]
pub struct Prior {
    pub cv_error_um: Option<f64>,
    pub repeatability_um: Option<f64>,
    /// Measurements per run of the driving components (largest) and the grid's points.
    pub m: Option<u64>,
    pub grid_points: Option<u64>,
}

/// Reads [`Prior`] of `axis` from a results summary (`summary.json`).
pub fn prior_from_summary(summary: &Value, axis: AxisId) -> Prior {
    let a = axis.as_str();
    let own = format!("_{a}{a}");
    let ax = summary["axes"]
        .as_array()
        .and_then(|v| v.iter().find(|x| x["axis"] == a));
    let cv = ax
        .and_then(|x| x["components"].as_array())
        .map(|cs| {
            cs.iter()
                .filter(|c| c["component"].as_str().is_some_and(|n| n.ends_with(&own)))
                .filter_map(|c| c["cs"]["cv_error_um"].as_f64())
                .fold(f64::NAN, f64::max)
        })
        .filter(|v| v.is_finite());
    // Unidirectional repeatability (max of R↑, R↓): the bidirectional R contains the reversal,
    // which the compensation corrects per direction.
    let m = &summary["iso230"][a]["measured"];
    let r = [m["r_up_um"].as_f64(), m["r_down_um"].as_f64()]
        .into_iter()
        .flatten()
        .reduce(f64::max);
    let m = ax.and_then(|x| x["components"].as_array()).and_then(|cs| {
        cs.iter()
            .filter(|c| c["component"].as_str().is_some_and(|n| n.ends_with(&own)))
            .filter_map(|c| c["cs"]["m"].as_u64())
            .max()
    });
    Prior {
        cv_error_um: cv,
        repeatability_um: r,
        m,
        grid_points: ax.and_then(|x| x["grid_points"].as_u64()),
    }
}

fn approaches(samples: &[SampleRecord], axis: AxisId, keep: &dyn Fn(f64) -> bool) -> Vec<Approach> {
    samples
        .iter()
        .filter(|s| s.target.run.axis == axis && keep(s.target.target_um()))
        .map(|s| Approach {
            target_um: s.target.target_um(),
            forward: s.target.run.direction == Direction::Forward,
            deviation_um: s.error_um(axis),
        })
        .collect()
}

/// RMS of the mean deviation per (target, direction), µm; NaN without approaches.
fn rms_of_means(a: &[Approach]) -> f64 {
    let mut per: BTreeMap<(i64, bool), (f64, usize)> = BTreeMap::new();
    for x in a {
        let e = per
            .entry(((x.target_um * 1e6).round() as i64, x.forward))
            .or_insert((0.0, 0));
        e.0 += x.deviation_um;
        e.1 += 1;
    }
    if per.is_empty() {
        return f64::NAN;
    }
    let ss: f64 = per.values().map(|(s, n)| (s / *n as f64).powi(2)).sum();
    (ss / per.len() as f64).sqrt()
}

fn abs_stats(a: &[Approach]) -> (f64, f64) {
    if a.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let max = a.iter().map(|x| x.deviation_um.abs()).fold(0.0, f64::max);
    let mean = a.iter().map(|x| x.deviation_um.abs()).sum::<f64>() / a.len() as f64;
    (mean, max)
}

/// Why a verification gave no verdict.
#[derive(Debug, Clone, PartialEq)]
pub enum VerifyError {
    /// The request or the compensation cannot be served (nothing moved).
    Refused(String),
    /// Stopped (shutdown, resumable) or aborted by the operator; motion stopped.
    Halted(EndState),
    /// The hardware or the store failed; motion stopped.
    Failed(String),
}

impl std::fmt::Display for VerifyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VerifyError::Refused(m) | VerifyError::Failed(m) => f.write_str(m),
            VerifyError::Halted(EndState::Aborted) => {
                f.write_str("verification aborted; motion stopped")
            }
            VerifyError::Halted(_) => f.write_str("verification stopped; motion stopped"),
        }
    }
}

/// Targets of a verification of `c`'s axes: (before pass, after pass). The after pass's
/// targets are numbered after the before pass's.
pub fn planned(c: &Campaign, opts: &VerifyOptions) -> (u64, u64) {
    let n = plan_of(c, opts, 0).0.total() as u64;
    (n, n)
}

/// Runs the verification of characterisation `id` (campaign `c`, its compensation `comp`) on
/// the campaign's hardware: a pass without, then a pass with the compensation. Every
/// compensated command is computed (and any refused) before the stage moves. Targets in
/// `done` (a resumed verification campaign) are not measured again; their samples count.
#[allow(clippy::too_many_arguments)]
pub async fn run(
    id: i64,
    c: &Campaign,
    comp: Arc<Compensation>,
    prior: &(dyn Fn(AxisId) -> Prior + Sync),
    opts: &VerifyOptions,
    control: watch::Receiver<Control>,
    done: &BTreeMap<u64, SampleRecord>,
    sink: &mut dyn Sink,
) -> Result<Verdict, VerifyError> {
    use VerifyError::{Failed, Refused};
    if opts.cycles == 0 || opts.cycles > MAX_CYCLES {
        return Err(Refused(format!("cycles must be 1..={MAX_CYCLES}")));
    }
    if opts.iso_targets < 2 || opts.iso_targets + opts.unvisited_targets > MAX_TARGETS {
        return Err(Refused(format!(
            "targets: at least 2 on the grid, at most {MAX_TARGETS} in all"
        )));
    }
    comp.check_stage(&c.spec().campaign.stage)
        .map_err(|e| Refused(e.to_string()))?;
    for ax in c.axes() {
        comp.check_covers(ax.axis, ax.grid.start_um, ax.grid.end_um())
            .map_err(|e| Refused(e.to_string()))?;
    }
    let (before_plan, sets) = plan_of(c, opts, 0);
    let (after_plan, _) = plan_of(c, opts, before_plan.total() as u64);
    let mut rig = rig::build(c)
        .await
        .map_err(|e| Failed(format!("hardware: {e}")))?;
    // Every compensated command before anything moves; the time of the computation per move.
    let mut compute_us_max: f64 = 0.0;
    for t in after_plan.batches.iter().flat_map(|b| &b.targets) {
        let limits = rig.axis(t.run.axis).soft_limits_um();
        let t0 = std::time::Instant::now();
        let r = comp.command(t.run.axis, t.run.direction, t.target_um(), limits);
        compute_us_max = compute_us_max.max(t0.elapsed().as_secs_f64() * 1e6);
        if let Err(e) = r {
            rig.close().await;
            return Err(Refused(format!("compensation: {e}")));
        }
    }
    let (passes, acquisition_s) = run_passes(
        c,
        rig,
        &comp,
        [&before_plan, &after_plan],
        control,
        done,
        sink,
    )
    .await?;
    let [before, after] = &passes;
    let mut axes = Vec::new();
    for (axis, iso, un, ext) in &sets {
        let on = |list: &Vec<f64>| {
            let list = list.clone();
            move |p: f64| list.iter().any(|q| (q - p).abs() < 1e-9)
        };
        let (is_iso, is_un, is_ext) = (on(iso), on(un), on(ext));
        let measured = |p: f64| !is_ext(p);
        let tol = 1e-6;
        let fig = |s: &[SampleRecord]| {
            evaluate(&approaches(s, *axis, &is_iso), tol)
                .ok_or_else(|| Failed(format!("axis {axis}: no samples at the ISO targets")))
        };
        let (fb, fa) = (fig(before)?, fig(after)?);
        let (mean_b, max_b) = abs_stats(&approaches(before, *axis, &measured));
        let (mean_a, max_a) = abs_stats(&approaches(after, *axis, &measured));
        let rms_a = rms_of_means(&approaches(after, *axis, &measured));
        let (_, max_b_ext) = abs_stats(&approaches(before, *axis, &is_ext));
        let (_, max_a_ext) = abs_stats(&approaches(after, *axis, &is_ext));
        let (_, max_b_un) = abs_stats(&approaches(before, *axis, &is_un));
        let (_, max_a_un) = abs_stats(&approaches(after, *axis, &is_un));
        let p = prior(*axis);
        // Without a measured repeatability from the characterisation, the verification's own
        // uncompensated pass gives it (same targets, same cycles).
        let own = [fb.r_up_um, fb.r_down_um]
            .into_iter()
            .flatten()
            .reduce(f64::max);
        let repeat = p.repeatability_um.or(own);
        // The expected residual: given; else at each target 3 u + R from the table's pointwise
        // uncertainty (wider across the characterisation's gaps, where its curve interpolates);
        // else one figure for the axis, 3 × CV error + R.
        let band = comp
            .table(*axis)
            .filter(|t| t.u_forward_um.is_some() || t.u_backward_um.is_some());
        let mut worst_target_um = None;
        let (expected, passed, expected_from) = match (opts.expected_um, band) {
            (Some(e), _) => (e, e.is_finite() && max_a <= e, "given"),
            (None, Some(t)) => {
                let mut worst: Option<(f64, f64, f64)> = None; // (margin, expected, target)
                for x in approaches(after, *axis, &measured) {
                    let d = if x.forward {
                        Direction::Forward
                    } else {
                        Direction::Backward
                    };
                    let e =
                        3.0 * t.u_at(d, x.target_um).unwrap_or(f64::NAN) + repeat.unwrap_or(0.0);
                    let margin = e - x.deviation_um.abs();
                    // A target without u (NaN) is the worst: it fails the verdict.
                    if worst.is_none_or(|w| !w.0.is_nan() && (margin.is_nan() || margin < w.0)) {
                        worst = Some((margin, e, x.target_um));
                    }
                }
                match worst {
                    Some((margin, e, target)) => {
                        worst_target_um = Some(target);
                        (e, margin >= 0.0, "band")
                    }
                    None => (f64::NAN, false, "band"),
                }
            }
            (None, None) => {
                let e = 3.0 * p.cv_error_um.unwrap_or(f64::NAN) + repeat.unwrap_or(0.0);
                (e, e.is_finite() && max_a <= e, "cv")
            }
        };
        // Each target's pass line, as the verdict above checks it.
        let expected_at = |d: Direction, x: f64| match (opts.expected_um, band) {
            (Some(e), _) => e,
            (None, Some(t)) => 3.0 * t.u_at(d, x).unwrap_or(f64::NAN) + repeat.unwrap_or(0.0),
            (None, None) => expected,
        };
        let kind_of = |x: f64| {
            if is_iso(x) {
                Some("iso")
            } else if is_un(x) {
                Some("unvisited")
            } else {
                None
            }
        };
        let per_target =
            crate::report::verification::per_target(before, after, *axis, &kind_of, &expected_at);
        let u_mean_um = band.map(|t| {
            let u: Vec<f64> = [&t.u_forward_um, &t.u_backward_um]
                .into_iter()
                .flatten()
                .flatten()
                .copied()
                .collect();
            u.iter().sum::<f64>() / u.len().max(1) as f64
        });
        axes.push(AxisVerdict {
            axis: axis.as_str().into(),
            before: Figures::from(&fb),
            after: Figures::from(&fa),
            max_abs_after_um: max_a,
            expected_um: expected,
            expected_from,
            worst_target_um,
            u_mean_um,
            passed,
            max_abs_before_um: max_b,
            mean_abs_before_um: mean_b,
            mean_abs_after_um: mean_a,
            max_abs_after_unvisited_um: max_a_un,
            max_abs_before_unvisited_um: max_b_un,
            e_reduction: fb.e_um / fa.e_um,
            cv_error_um: p.cv_error_um,
            repeatability_um: repeat,
            iso_targets_um: iso.clone(),
            unvisited_targets_um: un.clone(),
            measured_span_um: opts.measured_span_um[*axis as usize],
            rms_after_um: rms_a,
            characterisation_m: p.m,
            grid_points: p.grid_points,
            extrapolated_targets_um: ext.clone(),
            max_abs_before_extrapolated_um: (!ext.is_empty()).then_some(max_b_ext),
            max_abs_after_extrapolated_um: (!ext.is_empty()).then_some(max_a_ext),
            cycles: opts.cycles,
            per_target,
        });
    }
    let raw = before
        .iter()
        .map(|s| (false, *s))
        .chain(after.iter().map(|s| (true, *s)))
        .collect();
    Ok(Verdict {
        campaign: id,
        passed: !axes.is_empty() && axes.iter().all(|a| a.passed),
        axes,
        stage: c.spec().campaign.stage.clone(),
        compensation: comp.source.clone(),
        acquisition_s,
        samples: [before.len(), after.len()],
        command_compute_us_max: compute_us_max,
        raw,
    })
}

/// The two passes of a verification on `rig`: plain moves (`plans[0]`), then compensated
/// (`plans[1]`, numbered after the first). Targets in `done` are not measured again; their
/// samples count. Returns each pass's samples and the acquisition and positioning time; motion
/// is stopped on failure and the rig closed in every case.
pub(super) async fn run_passes(
    c: &Campaign,
    mut rig: Rig,
    comp: &Arc<Compensation>,
    plans: [&Plan; 2],
    control: watch::Receiver<Control>,
    done: &BTreeMap<u64, SampleRecord>,
    sink: &mut dyn Sink,
) -> Result<([Vec<SampleRecord>; 2], f64), VerifyError> {
    use VerifyError::{Failed, Halted};
    let mut acquisition_s = 0.0;
    let mut passes: [Vec<SampleRecord>; 2] = Default::default();
    let split = plans[0].total() as u64;
    for (k, plan) in plans.into_iter().enumerate() {
        let pass = ["before", "after"][k];
        sink.event("pass", &json!({"pass": pass, "targets": plan.total()}));
        let stored: BTreeMap<u64, SampleRecord> = done
            .iter()
            .filter(|(&seq, _)| (seq < split) == (k == 0))
            .map(|(&seq, s)| (seq, *s))
            .collect();
        let mut rec = Collect {
            samples: stored.values().copied().collect(),
            sink: &mut *sink,
        };
        let r = {
            let mut e = Engine::new(c, &mut rig, &mut rec, control.clone(), stored);
            if k == 1 {
                e.compensation = Some(comp.clone());
            }
            e.run(plan).await
        };
        let out = match r {
            Ok(o) => o,
            Err(e) => {
                rig.stop_all().await;
                rig.close().await;
                return Err(Failed(format!("stopped: {e}")));
            }
        };
        if out.end != EndState::Done {
            rig.close().await;
            return Err(Halted(out.end));
        }
        acquisition_s += out
            .stats
            .values()
            .map(|s| s.acquisition_s + s.positioning_s)
            .sum::<f64>();
        passes[k] = rec.samples;
    }
    rig.close().await;
    Ok((passes, acquisition_s))
}

fn opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.3}"))
}

/// What an axis's expected residual is made of, in words.
fn basis(a: &AxisVerdict) -> String {
    match a.expected_from {
        "band" => format!(
            "expected 3 u + unidirectional R {} at each target, tightest at {} µm: {:.3} µm (mean u {})",
            opt(a.repeatability_um),
            opt(a.worst_target_um),
            a.expected_um,
            opt(a.u_mean_um)
        ),
        "given" => format!("expected {:.3} µm (given)", a.expected_um),
        _ => format!(
            "expected {:.3} µm (3 x CV error {} + unidirectional R {})",
            a.expected_um,
            opt(a.cv_error_um),
            opt(a.repeatability_um)
        ),
    }
}

/// The side-by-side table (`summary.txt` of the verification).
pub fn table(v: &Verdict) -> String {
    let mut s = format!(
        "verification of campaign {} on stage {} (compensation: {})\n",
        v.campaign, v.stage, v.compensation
    );
    s.push_str(&format!(
        "{:<5} {:<7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>10} {:>10}\n",
        "axis", "", "A µm", "B µm", "E µm", "M µm", "R µm", "mean|e| µm", "max|e| µm"
    ));
    for a in &v.axes {
        for (name, f, mean, max) in [
            (
                "before",
                &a.before,
                a.mean_abs_before_um,
                a.max_abs_before_um,
            ),
            ("after", &a.after, a.mean_abs_after_um, a.max_abs_after_um),
        ] {
            s.push_str(&format!(
                "{:<5} {:<7} {:>8.3} {:>8} {:>8.3} {:>8} {:>8} {:>10.3} {:>10.3}\n",
                a.axis.to_uppercase(),
                name,
                f.a_um,
                opt(f.b_um),
                f.e_um,
                opt(f.m_um),
                opt(f.r_um),
                mean,
                max
            ));
        }
        let basis = basis(a);
        s.push_str(&format!(
            "{:<5} E reduced {:.1}x; max |after| {:.3} µm ({:.3} µm at never-visited targets) vs {}: {}\n",
            a.axis.to_uppercase(),
            a.e_reduction,
            a.max_abs_after_um,
            a.max_abs_after_unvisited_um,
            basis,
            if a.passed { "passed" } else { "FAILED" }
        ));
        let m = match (a.characterisation_m, a.grid_points) {
            (Some(m), Some(n)) if n > 0 => format!(
                "characterised with m = {m} of {n} grid points per run ({:.1} %); ",
                100.0 * m as f64 / n as f64
            ),
            _ => String::new(),
        };
        if let Some(cv) = a.cv_error_um.filter(|v| *v > 0.0) {
            s.push_str(&format!(
                "{:<5} {m}rms of the mean residual {:.3} µm vs its CV error estimate {cv:.3} µm ({:+.0} %)\n",
                a.axis.to_uppercase(),
                a.rms_after_um,
                100.0 * (a.rms_after_um / cv - 1.0)
            ));
        }
        if let (Some((lo, hi)), Some(after), Some(before)) = (
            a.measured_span_um,
            a.max_abs_after_extrapolated_um,
            a.max_abs_before_extrapolated_um,
        ) {
            s.push_str(&format!(
                "{:<5} grid ends outside the characterised span [{lo}, {hi}] µm ({}): max |error| {before:.3} before, {after:.3} µm after (extrapolated table, not in the figures or the verdict)\n",
                a.axis.to_uppercase(),
                a.extrapolated_targets_um
                    .iter()
                    .map(|p| format!("{p}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
    }
    s.push_str(&format!(
        "{}\n",
        if v.passed {
            "verification passed"
        } else {
            "verification FAILED"
        }
    ));
    s
}

/// The one JSON object of `csmetro verify --json` (and `verify.json`).
pub fn json(v: &Verdict) -> Value {
    serde_json::to_value(v).unwrap_or(Value::Null)
}

/// Raw samples of both passes as CSV, in the layout of every samples file
/// ([`crate::samples::LAYOUT`]; `pass` before | after).
pub fn samples_csv(v: &Verdict) -> String {
    let mut s = crate::samples::layout_header();
    for (after, r) in &v.raw {
        s.push_str(&crate::samples::layout_row(r, Some(*after)));
    }
    s
}

/// The compensated approaches of an axis the verdict checks: (target, deviation), µm.
fn after_samples(v: &Verdict, a: &AxisVerdict) -> Vec<(f64, f64)> {
    v.raw
        .iter()
        .filter(|(after, r)| {
            *after
                && r.target.run.axis.as_str() == a.axis
                && !a
                    .extrapolated_targets_um
                    .iter()
                    .any(|q| (q - r.target.target_um()).abs() < 1e-9)
        })
        .map(|(_, r)| (r.target.target_um(), r.error_um(r.target.run.axis)))
        .collect()
}

/// Size of the verification charts.
const CHART: crate::report::PlotOptions = crate::report::PlotOptions {
    width: 1200,
    height: 700,
};

fn chart<T>(
    v: &Verdict,
    axis: &str,
    draw: impl FnOnce(&crate::report::verification::VerifyChart<'_>) -> Result<T, String>,
) -> Result<T, String> {
    let a = v
        .axes
        .iter()
        .find(|a| a.axis == axis)
        .ok_or_else(|| format!("no axis {axis}"))?;
    let samples = after_samples(v, a);
    draw(&crate::report::verification::VerifyChart {
        axis,
        checks: &a.per_target,
        after_samples: &samples,
        passed: a.passed,
    })
}

/// One axis before / after (mean deviation per target and direction, every compensated
/// approach, the pass line ±expected) as SVG.
pub fn plot_svg(v: &Verdict, axis: &str) -> Result<String, String> {
    chart(v, axis, |c| {
        crate::report::verification::verify_chart_svg(c, &CHART)
    })
}

/// [`plot_svg`] as PNG.
pub fn plot_png(v: &Verdict, axis: &str) -> Result<Vec<u8>, String> {
    chart(v, axis, |c| {
        crate::report::verification::verify_chart_png(c, &CHART)
    })
}

/// `verify/report.html`: the before/after tables and charts (`pngs`: per axis).
pub fn page_html(v: &Verdict, pngs: &[(String, Vec<u8>)]) -> String {
    use crate::report::verification::{verify_html, AxisPage};
    let axes: Vec<AxisPage<'_>> = v
        .axes
        .iter()
        .map(|a| AxisPage {
            axis: &a.axis,
            e_before_um: a.before.e_um,
            e_after_um: a.after.e_um,
            mean_abs_before_um: a.mean_abs_before_um,
            mean_abs_after_um: a.mean_abs_after_um,
            max_abs_after_um: a.max_abs_after_um,
            expected_um: a.expected_um,
            expected_basis: basis(a),
            passed: a.passed,
            checks: &a.per_target,
            png: pngs
                .iter()
                .find(|(n, _)| *n == a.axis)
                .map(|(_, b)| b.as_slice()),
            svg_name: Some(format!("verify_{}.svg", a.axis)),
        })
        .collect();
    verify_html(
        &format!(
            "Verification of campaign {} on stage {}",
            v.campaign, v.stage
        ),
        &format!("Compensation: {}.", v.compensation),
        v.passed,
        &axes,
        &table(v),
    )
}

/// The stored verdict (the JSON of `csmetro verify --json`), among a campaign's results.
pub const VERDICT_FILE: &str = "verify/verify.json";

/// `report.html` of a verification campaign: verdict, the side-by-side table, the plots of both
/// curves (embedded), the campaign file.
pub fn report_html(v: &Verdict, id: i64, name: &str, text: &str, origin: &str) -> String {
    use crate::report::html::esc;
    use base64::Engine as _;
    let title = format!(
        "csmetro campaign {id} — {name}: verification of campaign {}",
        v.campaign
    );
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\
         <style>body{{font-family:sans-serif;max-width:1250px;margin:1em auto}}pre{{background:#f4f4f4;padding:.5em;overflow-x:auto}}\
         img{{max-width:100%}}.bad{{color:#b00020}}</style></head><body>\n<h1>{t}</h1>\n",
        t = esc(&title)
    );
    h.push_str(&format!(
        "<p>Verdict: <b{}>{}</b>. Stage {}, compensation {}. Units: µm (error = measured − wanted position).</p>\n",
        if v.passed { "" } else { " class=\"bad\"" },
        if v.passed { "passed" } else { "FAILED" },
        esc(&v.stage),
        esc(&v.compensation)
    ));
    h.push_str(&format!(
        "<h2>Before / after (ISO 230-2)</h2>\n<p><a href=\"{REPORT_FILE}\">Each target against its pass line</a>.</p>\n<pre>{}</pre>\n",
        esc(&table(v))
    ));
    for a in &v.axes {
        if let Ok(svg) = plot_svg(v, &a.axis) {
            h.push_str(&format!(
                "<figure><img alt=\"axis {ax}\" src=\"data:image/svg+xml;base64,{}\"></figure>\n",
                base64::engine::general_purpose::STANDARD.encode(svg),
                ax = esc(&a.axis)
            ));
        }
    }
    h.push_str(&format!(
        "<h2>Campaign file</h2>\n<p>{}</p>\n<pre>{}</pre>\n</body></html>\n",
        esc(origin),
        esc(text)
    ));
    h
}

/// The verification's result files (name relative to the characterisation's results, content
/// type, bytes).
pub fn files(v: &Verdict) -> Vec<(String, String, Vec<u8>)> {
    let mut f = vec![
        (
            "verify/summary.txt".to_string(),
            "text/plain".to_string(),
            table(v).into_bytes(),
        ),
        (
            VERDICT_FILE.into(),
            "application/json".into(),
            serde_json::to_vec_pretty(&json(v)).unwrap_or_default(),
        ),
        (
            "verify/samples.csv".into(),
            "text/csv".into(),
            samples_csv(v).into_bytes(),
        ),
    ];
    let mut pngs = Vec::new();
    for a in &v.axes {
        if let Ok(svg) = plot_svg(v, &a.axis) {
            f.push((
                format!("verify/verify_{}.svg", a.axis),
                "image/svg+xml".into(),
                svg.into_bytes(),
            ));
        }
        if let Ok(png) = plot_png(v, &a.axis) {
            f.push((
                format!("verify/verify_{}.png", a.axis),
                "image/png".into(),
                png.clone(),
            ));
            pngs.push((a.axis.clone(), png));
        }
    }
    f.push((
        REPORT_FILE.into(),
        "text/html; charset=utf-8".into(),
        page_html(v, &pngs).into_bytes(),
    ));
    f
}

/// The verification's page among the characterisation's results (linked from its report.html).
pub const REPORT_FILE: &str = "verify/report.html";

#[cfg(test)]
mod tests;

pub mod map;
