//! ISO 230-2 decomposition of repeated bidirectional tables (one measured component, the same
//! targets approached in every cycle, forward and backward): effects are tested against the
//! pure error of the saturated model ISO 230-2 itself uses (one mean per target and direction,
//! plus a free offset per cycle), not against whatever else stays unexplained. A large
//! repeatable position-dependent error sits in the cell means, so it neither inflates the pure
//! error nor hides a backlash or a drift.
//!
//! Nested tests, each with its value ± standard error: the reversal x̄↑ − x̄↓ constant over the
//! targets (backlash) vs none, its linear change over the travel (hysteresis) vs constant; the
//! cycle offsets trending in time (drift: linear or settling) vs none, free cycle offsets vs the
//! trend; a linear scale of the bidirectional means. Family-wise error over all tests tried:
//! Holm at [`ALPHA_FAMILY`]. An effect is named when it is significant **and** leave-one-cycle-out
//! prediction improves (held-out cycle predicted with one zero per table, as ISO 230-2 sets it
//! once, so a drift between cycles counts). What is left (position structure the targets cannot
//! resolve, irregular reversals, cycle offsets off the trend) is said plainly, with what to
//! measure to resolve it.
use csmetro_effects::{map_to_unit, AxisId, Effect, EffectKind, StageModel};
use nalgebra::{DMatrix, DVector};
use serde_json::{json, Value as Json};

use super::localise::chi2_z;
use super::stats::{f_sf, t_two_sided};
use super::Sample;

mod finalise;
mod reversal;
mod tables;
#[allow(clippy::wildcard_imports)]
use finalise::*;
#[allow(clippy::wildcard_imports)]
use reversal::*;
#[allow(clippy::wildcard_imports)]
use tables::*;

/// Family-wise false-alarm rate over all tests of all tables of one data set.
pub const ALPHA_FAMILY: f64 = 0.01;
/// Reversal variation beyond the pure error at which the backlash is judged against the
/// spread of the per-target reversals (its standard error over targets) as well.
const ALPHA_VARIES: f64 = 0.05;
/// χ² (1 df) by which correcting the reversals for a continuous drift must make them more
/// constant before the drift is taken as continuous in time.
const TIMING_EVIDENCE: f64 = 0.0;
/// Share of the bidirectional means' variance a line must explain to be named a scale error
/// (else it is the linear part of a position-dependent error of another shape).
const SCALE_LINE_SHARE: f64 = 0.9;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    Linear,
    /// a·exp(-(t - t0)/τ).
    Settling(f64),
}

/// Whether the drift acts on every sample at its own time (a continuous drift: the backward
/// pass of a cycle sees more of it than the forward pass) or steps once per cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Timing {
    Continuous,
    PerCycle,
}

struct Obs {
    y: f64,
    cell: usize,
    cycle: usize,
    t: f64,
    pos: f64,
    dir: f64,
}

/// One ISO table: a moving axis at one static position, its measured component.
struct Table {
    axis: AxisId,
    static_um: f64,
    travel: [f64; 2],
    obs: Vec<Obs>,
    targets: Vec<f64>,
    /// (target index, forward).
    cells: Vec<(usize, bool)>,
    cycles: Vec<i64>,
    cycle_time: Vec<f64>,
    t0: f64,
    /// Library cyclic errors the targets resolve: (kind, period µm).
    periods: Vec<(&'static str, f64)>,
}

#[derive(Debug, Clone, Copy, Default)]
struct Named {
    backlash: bool,
    hyst: bool,
    scale: bool,
    drift: Option<(Shape, Timing)>,
    /// Cyclic terms named, one bit per entry of `Table::periods`.
    cyclic: u32,
}

struct Fit {
    beta: f64,
    mu: Vec<f64>,
    n: Vec<usize>,
    /// (target index, reversal).
    b_i: Vec<(usize, f64)>,
    b_mean: f64,
    hyst: Option<(f64, f64)>,
    /// Scale, µm per µm.
    scale: Option<f64>,
    /// Cosine and sine amplitude of each resolvable period (fitted with a line beside it).
    cyc: Vec<Option<(f64, f64)>>,
}

/// One effect the decomposition tested.
#[derive(Debug, Clone)]
pub struct Finding {
    /// Library kind (`backlash`, `hysteresis`, `thermal_drift`, `scale`).
    pub kind: &'static str,
    /// What it is, in words.
    pub what: String,
    pub axis: AxisId,
    pub static_um: f64,
    pub value: f64,
    pub se: f64,
    pub unit: &'static str,
    pub t: f64,
    pub p: f64,
    /// Holm threshold the p was held to (NaN when not reached).
    pub alpha: f64,
    pub significant: bool,
    pub named: bool,
    /// Why a significant effect was not named.
    pub refused: Option<String>,
    /// Held-out RMS with this effect alone, µm.
    pub heldout_alone_um: f64,
    /// Cumulative held-out RMS before and after it (named effects, in naming order), µm.
    pub heldout_before_um: Option<f64>,
    pub heldout_after_um: Option<f64>,
    /// Kind-specific fields (rate, shape, ppm, ...).
    pub extra: serde_json::Map<String, Json>,
    pub effect: Option<Effect>,
}

impl Finding {
    /// A finding as its test leaves it: not yet held to Holm's threshold nor to the held-out
    /// check, no effect attached. Every test overrides what it measured (kind, what, axis,
    /// value, se, unit, t, p, extra) with struct update syntax.
    fn undecided() -> Finding {
        Finding {
            kind: "",
            what: String::new(),
            axis: AxisId::X,
            static_um: 0.0,
            value: f64::NAN,
            se: f64::NAN,
            unit: "um",
            t: f64::NAN,
            p: f64::NAN,
            alpha: f64::NAN,
            significant: false,
            named: false,
            refused: None,
            heldout_alone_um: f64::NAN,
            heldout_before_um: None,
            heldout_after_um: None,
            extra: serde_json::Map::new(),
            effect: None,
        }
    }

    pub fn to_json(&self) -> Json {
        let f = |v: f64| if v.is_finite() { json!(v) } else { Json::Null };
        let mut j = json!({
            "kind": self.kind,
            "what": self.what,
            "axis": self.axis.as_str(),
            "static_um": self.static_um,
            "named": self.named,
            "value_um": if self.unit == "um" { f(self.value) } else { Json::Null },
            "se_um": if self.unit == "um" { f(self.se) } else { Json::Null },
            "value": f(self.value),
            "se": f(self.se),
            "unit": self.unit,
            "t": f(self.t),
            "p": f(self.p),
            "alpha_holm": f(self.alpha),
            "significant": self.significant,
            "refused": self.refused,
            "heldout_rms_alone_um": f(self.heldout_alone_um),
            "heldout_rms_before_um": self.heldout_before_um.map(f),
            "heldout_rms_after_um": self.heldout_after_um.map(f),
        });
        if let Some(o) = j.as_object_mut() {
            for (k, v) in &self.extra {
                o.insert(k.clone(), v.clone());
            }
        }
        j
    }

    pub fn describe(&self) -> String {
        let v = match self.unit {
            "um" => format!("{:.2} ± {:.2} µm", self.value, self.se),
            u => format!("{:.3} ± {:.3} {u}", self.value, self.se),
        };
        let extra = match self.kind {
            "thermal_drift" => {
                let g = |k: &str| self.extra.get(k).and_then(Json::as_f64);
                let mut s = format!(
                    "; {:.2} ± {:.2} µm per cycle",
                    g("rate_um_per_cycle").unwrap_or(f64::NAN),
                    g("rate_se_um_per_cycle").unwrap_or(f64::NAN)
                );
                if let Some(h) = g("rate_um_per_h") {
                    s += &format!(" ({h:.2} µm/h)");
                }
                if let Some(sh) = self.extra.get("shape").and_then(Json::as_str) {
                    s += &format!(", {sh}");
                }
                if let (Some(a), Some(b)) = (g("r_before_um"), g("r_after_um")) {
                    s += &format!(", ISO R {a:.2} → {b:.2} µm without it");
                }
                s
            }
            "backlash" => {
                let g = |k: &str| self.extra.get(k).and_then(Json::as_f64);
                match (g("iso_reversal_um"), g("drift_correction_um")) {
                    (Some(raw), Some(c)) if c.abs() > 1e-9 => format!(
                        " (x̄↑ − x̄↓ as measured {raw:.2} µm; {c:+.2} µm of it is the drift between the two passes)"
                    ),
                    _ => String::new(),
                }
            }
            "scale" => format!(
                " ({:.1} ppm)",
                self.extra
                    .get("ppm")
                    .and_then(Json::as_f64)
                    .unwrap_or(f64::NAN)
            ),
            _ => String::new(),
        };
        let status = if self.named {
            format!(
                "named; held-out RMS {:.2} → {:.2} µm (alone {:.2})",
                self.heldout_before_um.unwrap_or(f64::NAN),
                self.heldout_after_um.unwrap_or(f64::NAN),
                self.heldout_alone_um
            )
        } else if let Some(r) = &self.refused {
            format!("not named: {r}")
        } else {
            format!("not significant (p {:.2e})", self.p)
        };
        format!(
            "{} {}: {}{extra} (t {:.1}, p {:.1e}); {status}",
            self.what, self.axis, v, self.t, self.p
        )
    }
}

/// The decomposition of one table.
#[derive(Debug, Clone)]
pub struct IsoTable {
    pub axis: AxisId,
    pub static_um: f64,
    pub targets: usize,
    pub cycles: usize,
    pub samples: usize,
    pub sigma_pe_um: f64,
    pub df_pe: f64,
    /// x̄↑ − x̄↓ averaged over the targets, as ISO 230-2 reports it (no drift correction), µm.
    pub iso_reversal_um: f64,
    pub findings: Vec<Finding>,
    pub heldout_before_um: f64,
    pub heldout_after_um: f64,
    /// What the table cannot resolve, in words (also in the diagnosis' notes).
    pub cannot_see: Vec<String>,
    pub cannot_see_json: Json,
    /// RMS and z of the repeatable position structure left once the named effects are removed.
    pub unexplained_rms_um: f64,
    pub unexplained_z: f64,
    /// Structure left beyond the pure error (position error, irregular reversals or cycle
    /// offsets off the trend); detection limits alone do not count.
    pub structure_left: bool,
}

impl IsoTable {
    pub fn to_json(&self) -> Json {
        json!({
            "axis": self.axis.as_str(),
            "static_um": self.static_um,
            "targets": self.targets,
            "cycles": self.cycles,
            "samples": self.samples,
            "sigma_pe_um": self.sigma_pe_um,
            "df_pe": self.df_pe,
            "iso_reversal_um": if self.iso_reversal_um.is_finite() { json!(self.iso_reversal_um) } else { Json::Null },
            "heldout_rms_before_um": self.heldout_before_um,
            "heldout_rms_after_um": self.heldout_after_um,
            "findings": self.findings.iter().map(Finding::to_json).collect::<Vec<_>>(),
            "cannot_see": self.cannot_see_json,
            "unexplained_rms_um": self.unexplained_rms_um,
            "unexplained_z": self.unexplained_z,
            "structure_left": self.structure_left,
        })
    }
}

/// The decomposition of all tables of a data set.
#[derive(Debug, Clone)]
pub struct IsoAnalysis {
    pub tables: Vec<IsoTable>,
    /// Leave-one-cycle-out RMS over all tables (one zero per table), before and after the
    /// named effects, µm.
    pub heldout_before_um: f64,
    pub heldout_after_um: f64,
    /// Pooled pure-error σ, µm.
    pub sigma_um: f64,
    pub alpha_family: f64,
    pub tests: usize,
    /// Why some line groups were not decomposed.
    pub skipped: Vec<String>,
}

impl IsoAnalysis {
    pub fn findings(&self) -> impl Iterator<Item = &Finding> {
        self.tables.iter().flat_map(|t| t.findings.iter())
    }

    pub fn to_json(&self) -> Json {
        json!({
            "method": "saturated model (one mean per target and direction, free cycle offsets) as pure-error reference; Holm over all tests; named only when leave-one-cycle-out prediction improves",
            "alpha_family": self.alpha_family,
            "tests": self.tests,
            "sigma_pe_um": self.sigma_um,
            "heldout_rms_before_um": self.heldout_before_um,
            "heldout_rms_after_um": self.heldout_after_um,
            "tables": self.tables.iter().map(IsoTable::to_json).collect::<Vec<_>>(),
            "skipped": self.skipped,
        })
    }

    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        for t in &self.tables {
            let _ = writeln!(
                s,
                "ISO 230-2 decomposition, {} axis at {} = {:.0} µm ({} targets × {} cycles; pure error σ {:.3} µm, {} df; family-wise α {}):",
                t.axis,
                t.axis.other(),
                t.static_um,
                t.targets,
                t.cycles,
                t.sigma_pe_um,
                t.df_pe,
                self.alpha_family
            );
            let _ = writeln!(
                s,
                "  held-out RMS (leave one cycle out, one zero per table): {:.3} → {:.3} µm",
                t.heldout_before_um, t.heldout_after_um
            );
            for f in &t.findings {
                let _ = writeln!(s, "  {}", f.describe());
            }
            for c in &t.cannot_see {
                let _ = writeln!(s, "  cannot see: {c}");
            }
        }
        for k in &self.skipped {
            let _ = writeln!(s, "ISO 230-2 decomposition: {k}");
        }
        s
    }
}

struct CellSums {
    n: Vec<usize>,
    y: Vec<f64>,
    h: Vec<f64>,
}

/// A test before the Holm step.
struct Pending {
    table: usize,
    finding: Finding,
    order: usize,
}

/// Decomposes every ISO table of `samples` (residuals against `model`). None when no line group
/// has the shape (≥ 3 cycles over repeated targets).
pub fn analyse(
    samples: &[Sample],
    model: &StageModel,
    timed: bool,
    motor_period_um: f64,
) -> Option<IsoAnalysis> {
    let (tables, skipped) = build_tables(samples, model, motor_period_um);
    if tables.is_empty() {
        return None;
    }
    let mut pending: Vec<Pending> = Vec::new();
    let mut per_table = Vec::new();
    for (ti, tb) in tables.iter().enumerate() {
        let (ss_pe, df_pe, ss_free) = tb.pure_error();
        if df_pe < 3.0 {
            per_table.push(None);
            continue;
        }
        // A floor far below any real repeatability keeps quantised or noise-free data finite.
        let ymax = tb.obs.iter().map(|o| o.y.abs()).fold(0.0, f64::max);
        let s2 = (ss_pe / df_pe).max(1e-24 * (1.0 + ymax * ymax));
        let span_t = tb.obs.iter().map(|o| o.t).fold(f64::NEG_INFINITY, f64::max) - tb.t0;
        // Drift: linear or settling (τ a fraction of the test's duration), one df each.
        let mut shapes = vec![Shape::Linear];
        if span_t > 0.0 {
            for fr in [0.125, 0.25, 0.5, 1.0] {
                shapes.push(Shape::Settling(fr * span_t));
            }
        }
        let ss: Vec<(Shape, f64, f64)> = shapes
            .iter()
            .map(|&s| {
                let (v, sxx) = tb.drift_ss(s, Timing::Continuous);
                (s, v, sxx)
            })
            .collect();
        let best = ss
            .iter()
            .copied()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((Shape::Linear, 0.0, 0.0));
        let lin = ss[0];
        // Settling only when its curvature is evidenced against the straight line.
        let shape =
            if matches!(best.0, Shape::Settling(_)) && (best.1 - lin.1) / s2 > 3.84 && best.2 > 0.0
            {
                best
            } else {
                lin
            };
        let n_shapes = ss.iter().filter(|s| s.2 > 0.0).count().max(1) as f64;
        let p_drift = (f_sf(best.1 / s2, 1.0, df_pe) * n_shapes).min(1.0);
        // Timing: the one that leaves the reversal most constant over the targets (a
        // continuous drift biases x̄↑ − x̄↓ by what it does between the two passes).
        let all = |_: usize| true;
        // Timing: ISO 230-2 reads x̄↑ − x̄↓ as measured (a drift that steps between cycles
        // leaves it alone). A drift continuous in time also acts between the forward and the
        // backward pass, most at the targets visited first and last: it tilts the per-target
        // reversals. Continuous only when correcting for it makes the reversals significantly
        // more constant (1 df against the pure error of a reversal).
        let timing = {
            let spread = |t: Timing| {
                let f = tb.fit(&all, Some((shape.0, t)));
                let var: Vec<f64> = f
                    .b_i
                    .iter()
                    .map(|&(ti, _)| {
                        let n = |fwd: bool| {
                            tb.cells
                                .iter()
                                .position(|&c| c == (ti, fwd))
                                .map_or(1, |c| f.n[c].max(1)) as f64
                        };
                        s2 * (1.0 / n(true) + 1.0 / n(false))
                    })
                    .collect();
                let ss = f.b_i.iter().map(|b| (b.1 - f.b_mean).powi(2)).sum::<f64>();
                (ss, mean(&var), f.b_i.len())
            };
            let (pc, var, nb) = spread(Timing::PerCycle);
            let (co, _, _) = spread(Timing::Continuous);
            if nb >= 3 && (pc - co) / var.max(1e-300) > TIMING_EVIDENCE {
                Timing::Continuous
            } else {
                Timing::PerCycle
            }
        };
        per_table.push(Some((s2, df_pe, ss_free, shape, timing)));
        let (_, sxx_shape) = tb.drift_ss(shape.0, timing);
        let fd = tb.fit(&all, Some((shape.0, timing)));
        let se_beta = (s2 / sxx_shape.max(1e-300)).sqrt();
        let nc = tb.cycles.len();
        let cyc_dur = (tb.cycle_time[nc - 1] - tb.cycle_time[0]) / (nc - 1) as f64;
        let g_at = |t: f64| match shape.0 {
            Shape::Linear => (t - tb.t0) / 3600.0,
            Shape::Settling(tau) => (-(t - tb.t0) / tau).exp(),
        };
        let dh = (g_at(tb.cycle_time[nc - 1]) - g_at(tb.cycle_time[0])) / (nc - 1) as f64;
        let rate_cycle = fd.beta * dh;
        let rate_cycle_se = se_beta * dh.abs();
        let total = rate_cycle * (nc - 1) as f64;
        let mut extra = serde_json::Map::new();
        extra.insert("rate_um_per_cycle".into(), json!(rate_cycle));
        extra.insert("rate_se_um_per_cycle".into(), json!(rate_cycle_se));
        extra.insert(
            "rate_um_per_h".into(),
            if timed && cyc_dur > 0.0 {
                json!(rate_cycle / cyc_dur * 3600.0)
            } else {
                Json::Null
            },
        );
        extra.insert("cycle_duration_s".into(), json!(cyc_dur));
        extra.insert(
            "shape".into(),
            json!(match shape.0 {
                Shape::Linear => "linear",
                Shape::Settling(_) => "settling",
            }),
        );
        extra.insert(
            "tau_s".into(),
            match shape.0 {
                Shape::Settling(t) => json!(t),
                Shape::Linear => Json::Null,
            },
        );
        extra.insert(
            "timing".into(),
            json!(match timing {
                Timing::Continuous => "continuous in time",
                Timing::PerCycle => "steps between cycles",
            }),
        );
        extra.insert("time_from_column".into(), json!(timed));
        // Free cycle offsets beyond the trend.
        let lof_df = (nc as f64 - 2.0).max(0.0);
        let p_lof = if lof_df > 0.0 {
            f_sf(((ss_free - shape.1).max(0.0) / lof_df) / s2, lof_df, df_pe)
        } else {
            1.0
        };
        extra.insert("cycle_offsets_beyond_trend_p".into(), json!(p_lof));
        let cycle_means: Vec<f64> = (0..nc)
            .map(|c| {
                let keep_all = |_: usize| true;
                let cs = tb.cell_means(&keep_all, None);
                let v: Vec<f64> = tb
                    .obs
                    .iter()
                    .filter(|o| o.cycle == c)
                    .map(|o| o.y - cs.y[o.cell])
                    .collect();
                mean(&v)
            })
            .collect();
        extra.insert("cycle_means_um".into(), json!(cycle_means));
        pending.push(Pending {
            table: ti,
            order: 1,
            finding: Finding {
                kind: "thermal_drift",
                what: "drift between cycles (cycle means trending)".into(),
                axis: tb.axis,
                static_um: tb.static_um,
                value: total,
                se: rate_cycle_se * (nc - 1) as f64,
                unit: "um",
                t: if rate_cycle_se > 0.0 {
                    rate_cycle / rate_cycle_se
                } else {
                    0.0
                },
                p: p_drift,
                extra,
                ..Finding::undecided()
            },
        });
        // Reversal and scale tests on the cell means, as measured and with the drift removed:
        // `finalise` keeps the variant that matches whether the drift is named.
        let raw_b = tb.fit(&all, None).b_mean;
        for variant in [None, Some((shape.0, timing))] {
            let f = tb.fit(&all, variant);
            push_reversal_scale(
                &mut pending,
                ti,
                tb,
                &f,
                raw_b,
                s2,
                df_pe,
                variant.is_some(),
            );
        }
    }
    finalise(tables, per_table, pending, skipped, model, timed)
}
