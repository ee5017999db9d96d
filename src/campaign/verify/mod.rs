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
use crate::store::StoreError;
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
    fn sample(&mut self, s: &SampleRecord) -> Result<bool, StoreError>;
    fn event(&mut self, kind: &str, data: &Value);
}

/// Progress only: samples are kept in the verdict, events go to a callback.
pub struct Progress<F: FnMut(&str, &Value) + Send>(pub F);

impl<F: FnMut(&str, &Value) + Send> Sink for Progress<F> {
    fn sample(&mut self, _: &SampleRecord) -> Result<bool, StoreError> {
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
    fn sample(&mut self, s: &SampleRecord) -> Result<bool, StoreError> {
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
    let r = crate::compensation::unidirectional_repeatability_um(summary, axis);
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
    let targets = after_plan.batches.iter().flat_map(|b| &b.targets);
    let checked = precheck(&mut rig, targets, |rig, t| {
        let limits = rig.axis(t.run.axis).soft_limits_um();
        comp.command(t.run.axis, t.run.direction, t.target_um(), limits)
            .map(drop)
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

/// Every compensated command of a verification computed before anything moves: the longest
/// computation (µs), or the first refusal (the caller closes the rig).
pub(super) fn precheck<T, E>(
    rig: &mut Rig,
    items: impl IntoIterator<Item = T>,
    mut command: impl FnMut(&mut Rig, T) -> Result<(), E>,
) -> Result<f64, E> {
    let mut compute_us_max: f64 = 0.0;
    for item in items {
        let t0 = std::time::Instant::now();
        let r = command(rig, item);
        compute_us_max = compute_us_max.max(t0.elapsed().as_secs_f64() * 1e6);
        r?;
    }
    Ok(compute_us_max)
}

mod output;
pub use output::{
    files, json, page_html, plot_png, plot_svg, report_html, samples_csv, table, REPORT_FILE,
    VERDICT_FILE,
};

#[cfg(test)]
mod tests;

pub mod map;
