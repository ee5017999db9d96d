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

fn key(v: f64) -> i64 {
    super::design::key_um(v)
}

fn build_tables(
    samples: &[Sample],
    model: &StageModel,
    motor_period_um: f64,
) -> (Vec<Table>, Vec<String>) {
    use std::collections::BTreeMap;
    let mut groups: BTreeMap<(AxisId, i64), Vec<&Sample>> = BTreeMap::new();
    for s in samples {
        if s.meas(s.moving).is_finite() {
            groups
                .entry((s.moving, key(s.target(s.moving.other()))))
                .or_default()
                .push(s);
        }
    }
    let mut out = Vec::new();
    let mut skipped = Vec::new();
    for ((axis, _), ss) in groups {
        let static_um = ss[0].target(axis.other());
        let mut targets: Vec<(i64, f64)> = ss
            .iter()
            .map(|s| (key(s.target(axis)), s.target(axis)))
            .collect();
        targets.sort_by_key(|a| a.0);
        targets.dedup_by_key(|a| a.0);
        let mut cycles: Vec<i64> = ss.iter().map(|s| s.run).collect();
        cycles.sort_unstable();
        cycles.dedup();
        if cycles.len() < 3 || targets.len() < 2 {
            skipped.push(format!(
                "{axis} axis at {} = {static_um:.0} µm: {} cycles, {} targets (at least 3 cycles and 2 targets are needed)",
                axis.other(),
                cycles.len(),
                targets.len()
            ));
            continue;
        }
        let mut cells: Vec<(usize, bool)> = Vec::new();
        let mut obs = Vec::new();
        let mut tsum = vec![0.0; cycles.len()];
        let mut tn = vec![0usize; cycles.len()];
        for s in &ss {
            let ti = targets
                .binary_search_by_key(&key(s.target(axis)), |a| a.0)
                .unwrap_or(0);
            let fwd = s.direction > 0.0;
            let cell = match cells.iter().position(|&c| c == (ti, fwd)) {
                Some(c) => c,
                None => {
                    cells.push((ti, fwd));
                    cells.len() - 1
                }
            };
            let ci = cycles.binary_search(&s.run).unwrap_or(0);
            let (px, py) = model.predict(&s.context());
            let pred = if axis == AxisId::X { px } else { py };
            tsum[ci] += s.time_s;
            tn[ci] += 1;
            obs.push(Obs {
                y: s.meas(axis) - pred,
                cell,
                cycle: ci,
                t: s.time_s,
                pos: s.target(axis),
                dir: s.direction,
            });
        }
        let cycle_time: Vec<f64> = tsum
            .iter()
            .zip(&tn)
            .map(|(s, &n)| s / n.max(1) as f64)
            .collect();
        let t0 = obs.iter().map(|o| o.t).fold(f64::INFINITY, f64::min);
        let xs: Vec<f64> = targets.iter().map(|a| a.1).collect();
        let max_gap = xs.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
        let span = xs[xs.len() - 1] - xs[0];
        let mut periods: Vec<(&'static str, f64)> = Vec::new();
        for e in model.effects.iter().filter(|e| e.axis == axis) {
            match &e.kind {
                EffectKind::LeadscrewCyclic { period_um, .. } => {
                    periods.push(("leadscrew_cyclic", *period_um))
                }
                EffectKind::MotorCyclic { period_um, .. } => {
                    periods.push(("motor_cyclic", *period_um))
                }
                _ => {}
            }
        }
        if !periods.iter().any(|p| p.0 == "leadscrew_cyclic") {
            periods.push(("leadscrew_cyclic", 400.0));
        }
        if !periods.iter().any(|p| p.0 == "motor_cyclic") && motor_period_um > 0.0 {
            periods.push(("motor_cyclic", motor_period_um));
        }
        // Resolved: sampled above Nyquist everywhere, within the span, 8 targets at least (a
        // line and one harmonic leave 4 df of lack of fit).
        periods.retain(|p| p.1.is_finite() && p.1 > 2.0 * max_gap && p.1 <= span && xs.len() >= 8);
        periods.truncate(32);
        out.push(Table {
            periods,
            axis,
            static_um,
            travel: model.travel(axis),
            obs,
            targets: targets.into_iter().map(|a| a.1).collect(),
            cells,
            cycles,
            cycle_time,
            t0,
        });
    }
    (out, skipped)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Slope and intercept of y on x, with Σ(x − x̄)² and the residual sum of squares.
fn line(x: &[f64], y: &[f64]) -> Option<(f64, f64, f64, f64)> {
    let (mx, my) = (mean(x), mean(y));
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    if x.len() < 2 || sxx <= 0.0 {
        return None;
    }
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let k = sxy / sxx;
    let c = my - k * mx;
    let rss = x.iter().zip(y).map(|(a, b)| (b - c - k * a).powi(2)).sum();
    Some((k, c, sxx, rss))
}

impl Table {
    fn h(&self, o: &Obs, shape: Shape, timing: Timing) -> f64 {
        let t = match timing {
            Timing::Continuous => o.t,
            Timing::PerCycle => self.cycle_time[o.cycle],
        };
        match shape {
            Shape::Linear => (t - self.t0) / 3600.0,
            Shape::Settling(tau) => (-(t - self.t0) / tau).exp(),
        }
    }

    fn s(&self, x: f64) -> f64 {
        map_to_unit(x, self.travel)
    }

    /// Cell sums over the kept cycles.
    fn cell_means(&self, keep: &dyn Fn(usize) -> bool, hcol: Option<&[f64]>) -> CellSums {
        let nc = self.cells.len();
        let mut c = CellSums {
            n: vec![0; nc],
            y: vec![0.0; nc],
            h: vec![0.0; nc],
        };
        for (k, o) in self.obs.iter().enumerate() {
            if keep(o.cycle) {
                c.n[o.cell] += 1;
                c.y[o.cell] += o.y;
                if let Some(h) = hcol {
                    c.h[o.cell] += h[k];
                }
            }
        }
        for i in 0..nc {
            if c.n[i] > 0 {
                c.y[i] /= c.n[i] as f64;
                c.h[i] /= c.n[i] as f64;
            }
        }
        c
    }

    fn hcol(&self, d: Option<(Shape, Timing)>) -> Option<Vec<f64>> {
        d.map(|(s, t)| self.obs.iter().map(|o| self.h(o, s, t)).collect())
    }

    fn fit(&self, keep: &dyn Fn(usize) -> bool, drift: Option<(Shape, Timing)>) -> Fit {
        let hcol = self.hcol(drift);
        let cs = self.cell_means(keep, hcol.as_deref());
        let mut beta = 0.0;
        if let Some(h) = &hcol {
            let (mut sxy, mut sxx) = (0.0, 0.0);
            for (k, o) in self.obs.iter().enumerate() {
                if keep(o.cycle) {
                    let hc = h[k] - cs.h[o.cell];
                    sxy += hc * (o.y - cs.y[o.cell]);
                    sxx += hc * hc;
                }
            }
            if sxx > 1e-300 {
                beta = sxy / sxx;
            }
        }
        let mu: Vec<f64> = (0..self.cells.len())
            .map(|c| {
                if cs.n[c] > 0 {
                    cs.y[c] - beta * cs.h[c]
                } else {
                    f64::NAN
                }
            })
            .collect();
        let cell_of = |ti: usize, fwd: bool| {
            self.cells
                .iter()
                .position(|&c| c == (ti, fwd))
                .filter(|&c| cs.n[c] > 0)
        };
        let mut b_i = Vec::new();
        let mut m = Vec::new();
        for ti in 0..self.targets.len() {
            let (u, d) = (cell_of(ti, true), cell_of(ti, false));
            if let (Some(u), Some(d)) = (u, d) {
                b_i.push((ti, mu[u] - mu[d]));
                m.push((self.targets[ti], 0.5 * (mu[u] + mu[d])));
            } else if let Some(c) = u.or(d) {
                m.push((self.targets[ti], mu[c]));
            }
        }
        let b_mean = if b_i.is_empty() {
            f64::NAN
        } else {
            b_i.iter().map(|b| b.1).sum::<f64>() / b_i.len() as f64
        };
        let hyst = if b_i.len() >= 3 {
            let x: Vec<f64> = b_i.iter().map(|b| self.s(self.targets[b.0])).collect();
            let y: Vec<f64> = b_i.iter().map(|b| b.1).collect();
            line(&x, &y).map(|(k, c, _, _)| (c, k))
        } else {
            None
        };
        let scale = if m.len() >= 3 {
            let x: Vec<f64> = m.iter().map(|v| v.0).collect();
            let y: Vec<f64> = m.iter().map(|v| v.1).collect();
            line(&x, &y).map(|v| v.0)
        } else {
            None
        };
        let cyc = self
            .periods
            .iter()
            .map(|&(_, p)| cyclic_fit(&m, p).map(|c| (c.0, c.1)))
            .collect();
        Fit {
            beta,
            mu,
            n: cs.n,
            b_i,
            b_mean,
            hyst,
            scale,
            cyc,
        }
    }

    fn terms(&self, f: &Fit, named: &Named, o: &Obs, h: Option<f64>) -> f64 {
        let mut v = 0.0;
        if named.hyst {
            if let Some((b0, b1)) = f.hyst {
                v += (b0 + b1 * self.s(o.pos)) / 2.0 * o.dir;
            }
        } else if named.backlash && f.b_mean.is_finite() {
            v += f.b_mean / 2.0 * o.dir;
        }
        if named.scale {
            if let Some(k) = f.scale {
                v += k * o.pos;
            }
        }
        for (j, c) in f.cyc.iter().enumerate() {
            if named.cyclic & (1 << j) != 0 {
                if let Some((a, b)) = c {
                    let w = std::f64::consts::TAU * o.pos / self.periods[j].1;
                    v += a * w.cos() + b * w.sin();
                }
            }
        }
        if let Some(h) = h {
            v += f.beta * h;
        }
        v
    }

    /// Leave-one-cycle-out: fit on the other cycles (one zero for the table), predict the
    /// held-out cycle. Sum of squares and count.
    fn loco(&self, named: &Named) -> (f64, usize) {
        let hcol = self.hcol(named.drift);
        let h = |k: usize| hcol.as_ref().map(|h| h[k]);
        let (mut sse, mut n) = (0.0, 0usize);
        for c in 0..self.cycles.len() {
            let keep = |k: usize| k != c;
            let f = self.fit(&keep, named.drift);
            let (mut so, mut no) = (0.0, 0usize);
            for (k, o) in self.obs.iter().enumerate() {
                if o.cycle != c {
                    so += o.y - self.terms(&f, named, o, h(k));
                    no += 1;
                }
            }
            if no == 0 {
                continue;
            }
            let off = so / no as f64;
            for (k, o) in self.obs.iter().enumerate() {
                if o.cycle == c {
                    let e = o.y - off - self.terms(&f, named, o, h(k));
                    if e.is_finite() {
                        sse += e * e;
                        n += 1;
                    }
                }
            }
        }
        (sse, n)
    }

    fn loco_rms(&self, named: &Named) -> f64 {
        let (s, n) = self.loco(named);
        (s / n.max(1) as f64).sqrt()
    }

    /// Residual sum of squares and degrees of freedom of the saturated model with free cycle
    /// offsets (the pure error), and the sum of squares the free offsets explain.
    fn pure_error(&self) -> (f64, f64, f64) {
        let all = |_: usize| true;
        let cs = self.cell_means(&all, None);
        let nc = self.cycles.len();
        let p = nc - 1;
        // Within-cell demeaned cycle dummies (cycle 0 is the reference).
        let mut frac = vec![vec![0.0; p]; self.cells.len()];
        for o in &self.obs {
            if o.cycle > 0 {
                frac[o.cell][o.cycle - 1] += 1.0 / cs.n[o.cell] as f64;
            }
        }
        let mut g = DMatrix::<f64>::zeros(p, p);
        let mut b = DVector::<f64>::zeros(p);
        let mut ss0 = 0.0;
        let mut row = vec![0.0; p];
        for o in &self.obs {
            let r = o.y - cs.y[o.cell];
            ss0 += r * r;
            for (j, v) in row.iter_mut().enumerate() {
                *v = f64::from(u8::from(o.cycle == j + 1)) - frac[o.cell][j];
            }
            for a in 0..p {
                b[a] += row[a] * r;
                for c in 0..p {
                    g[(a, c)] += row[a] * row[c];
                }
            }
        }
        let svd = g.svd(true, true);
        let smax = svd.singular_values.max();
        let eps = smax * 1e-10;
        let rank = svd.singular_values.iter().filter(|&&s| s > eps).count();
        let ss_free = match svd.solve(&b, eps) {
            Ok(x) => b.dot(&x).max(0.0),
            Err(_) => 0.0,
        };
        let used_cells = cs.n.iter().filter(|&&n| n > 0).count();
        let df = self.obs.len() as f64 - used_cells as f64 - rank as f64;
        ((ss0 - ss_free).max(0.0), df, ss_free)
    }

    /// Sum of squares one drift column explains within cells, and Σ hc².
    fn drift_ss(&self, shape: Shape, timing: Timing) -> (f64, f64) {
        let all = |_: usize| true;
        let hcol = self.hcol(Some((shape, timing))).unwrap_or_default();
        let cs = self.cell_means(&all, Some(&hcol));
        let (mut sxy, mut sxx) = (0.0, 0.0);
        for (k, o) in self.obs.iter().enumerate() {
            let hc = hcol[k] - cs.h[o.cell];
            sxy += hc * (o.y - cs.y[o.cell]);
            sxx += hc * hc;
        }
        if sxx <= 1e-300 {
            (0.0, 0.0)
        } else {
            (sxy * sxy / sxx, sxx)
        }
    }

    fn iso_r(&self, f: Option<(&Fit, Shape, Timing)>) -> Option<f64> {
        let ap: Vec<crate::iso230::Approach> = self
            .obs
            .iter()
            .map(|o| {
                let corr = f.map_or(0.0, |(f, s, t)| f.beta * self.h(o, s, t));
                crate::iso230::Approach {
                    target_um: o.pos,
                    forward: o.dir > 0.0,
                    deviation_um: o.y - corr,
                }
            })
            .collect();
        crate::iso230::evaluate(&ap, 0.01).and_then(|s| s.r_um)
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

/// Backlash, hysteresis and scale tests of one fit (`corrected`: with the drift removed).
#[allow(clippy::too_many_arguments)]
fn push_reversal_scale(
    pending: &mut Vec<Pending>,
    ti: usize,
    tb: &Table,
    f: &Fit,
    raw_b: f64,
    s2: f64,
    df_pe: f64,
    corrected: bool,
) {
    let tag = |mut x: serde_json::Map<String, Json>| {
        x.insert("drift_corrected".into(), json!(corrected));
        x
    };
    let cell_of = |ti: usize, fwd: bool| tb.cells.iter().position(|&c| c == (ti, fwd));
    let var_b: Vec<f64> = f
        .b_i
        .iter()
        .map(|&(t, _)| {
            let nu = cell_of(t, true).map_or(1, |c| f.n[c].max(1)) as f64;
            let nd = cell_of(t, false).map_or(1, |c| f.n[c].max(1)) as f64;
            s2 * (1.0 / nu + 1.0 / nd)
        })
        .collect();
    let nt = f.b_i.len();
    if nt >= 1 {
        let b: Vec<f64> = f.b_i.iter().map(|v| v.1).collect();
        let bm = f.b_mean;
        let se_pe = var_b.iter().sum::<f64>().sqrt() / nt as f64;
        let p_pe = t_two_sided(bm / se_pe, df_pe);
        let (mut p, mut se) = (p_pe, se_pe);
        let mut extra = serde_json::Map::new();
        let mut p_var = 1.0;
        if nt >= 2 {
            let q: f64 = b
                .iter()
                .zip(&var_b)
                .map(|(v, w)| (v - bm).powi(2) / w)
                .sum();
            p_var = f_sf(q / (nt - 1) as f64, (nt - 1) as f64, df_pe);
            let sd = (b.iter().map(|v| (v - bm).powi(2)).sum::<f64>() / (nt - 1) as f64).sqrt();
            let se_t = sd / (nt as f64).sqrt();
            if p_var < ALPHA_VARIES {
                p = p.max(t_two_sided(bm / se_t.max(1e-300), (nt - 1) as f64));
                se = se.max(se_t);
            }
            extra.insert("se_over_targets_um".into(), json!(se_t));
        }
        extra.insert("se_pure_error_um".into(), json!(se_pe));
        extra.insert("iso_reversal_um".into(), json!(raw_b));
        extra.insert("drift_correction_um".into(), json!(bm - raw_b));
        extra.insert("reversal_varies_p".into(), json!(p_var));
        extra.insert(
            "per_target_reversal_um".into(),
            json!(f
                .b_i
                .iter()
                .map(|&(t, v)| json!({"target_um": tb.targets[t], "reversal_um": v}))
                .collect::<Vec<_>>()),
        );
        extra.insert(
            "reversal_range_um".into(),
            json!([
                b.iter().copied().fold(f64::INFINITY, f64::min),
                b.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            ]),
        );
        pending.push(Pending {
            table: ti,
            order: 0,
            finding: Finding {
                kind: "backlash",
                what: "backlash (reversal x̄↑ − x̄↓, constant over the targets)".into(),
                axis: tb.axis,
                static_um: tb.static_um,
                value: bm,
                se,
                unit: "um",
                t: bm / se,
                p,
                extra: tag(extra),
                ..Finding::undecided()
            },
        });
        // Linear change of the reversal over the travel (hysteresis), against the pure error
        // and against the reversals' own scatter about the line.
        if nt >= 4 {
            let x: Vec<f64> = f.b_i.iter().map(|&(t, _)| tb.s(tb.targets[t])).collect();
            if let Some((k, c, sxx, rss)) = line(&x, &b) {
                let se_pe = (mean(&var_b) / sxx).sqrt();
                let se_lof = (rss / (nt - 2) as f64 / sxx).sqrt();
                let p = t_two_sided(k / se_pe, df_pe)
                    .max(t_two_sided(k / se_lof.max(1e-300), (nt - 2) as f64));
                let se = se_pe.max(se_lof);
                let mut extra = serde_json::Map::new();
                extra.insert("b0_um".into(), json!(c));
                extra.insert("b1_um".into(), json!(k));
                pending.push(Pending {
                    table: ti,
                    order: 2,
                    finding: Finding {
                        kind: "hysteresis",
                        what: "reversal changing linearly over the travel (hysteresis b1, µm per half travel)".into(),
                        axis: tb.axis,
                        static_um: tb.static_um,
                        value: k,
                        se,
                        unit: "um",
                        t: k / se,
                        p,
                        extra: tag(extra),
                        ..Finding::undecided()
                    },
                });
            }
        }
    }
    // Linear scale of the bidirectional means.
    let mut x = Vec::new();
    let mut y = Vec::new();
    let mut w = Vec::new();
    for t in 0..tb.targets.len() {
        let cells: Vec<usize> = [true, false]
            .iter()
            .filter_map(|&d| cell_of(t, d))
            .filter(|&c| f.n[c] > 0)
            .collect();
        if cells.is_empty() {
            continue;
        }
        x.push(tb.targets[t]);
        y.push(cells.iter().map(|&c| f.mu[c]).sum::<f64>() / cells.len() as f64);
        let k = cells.len() as f64;
        w.push(s2 * cells.iter().map(|&c| 1.0 / f.n[c] as f64).sum::<f64>() / (k * k));
    }
    if x.len() >= 4 {
        if let Some((k, _, sxx, rss)) = line(&x, &y) {
            let n = x.len();
            let se_pe = (mean(&w) / sxx).sqrt();
            let se_lof = (rss / (n - 2) as f64 / sxx).sqrt();
            let p = t_two_sided(k / se_pe, df_pe)
                .max(t_two_sided(k / se_lof.max(1e-300), (n - 2) as f64));
            let se = se_pe.max(se_lof);
            let span = x.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                - x.iter().copied().fold(f64::INFINITY, f64::min);
            let mut extra = serde_json::Map::new();
            extra.insert("ppm".into(), json!(k * 1e6));
            let my = mean(&y);
            let sst: f64 = y.iter().map(|v| (v - my).powi(2)).sum();
            extra.insert(
                "line_share".into(),
                json!(if sst > 0.0 { 1.0 - rss / sst } else { 0.0 }),
            );
            extra.insert("se_ppm".into(), json!(se * 1e6));
            extra.insert("over_targets_um".into(), json!(k * span));
            pending.push(Pending {
                table: ti,
                order: 3,
                finding: Finding {
                    kind: "scale",
                    what: "linear scale error of the bidirectional means".into(),
                    axis: tb.axis,
                    static_um: tb.static_um,
                    value: k * 1e6,
                    se: se * 1e6,
                    unit: "ppm",
                    t: k / se,
                    p,
                    extra: tag(extra),
                    ..Finding::undecided()
                },
            });
        }
    }
    // Cyclic errors of the library's periods, only where the targets resolve them: the two
    // terms beside a line, against the pure error and against the lack of fit left.
    let m: Vec<(f64, f64)> = x.iter().copied().zip(y.iter().copied()).collect();
    for (pj, &(kind, period)) in tb.periods.iter().enumerate() {
        let Some((a, b, ss, rss, df_lof)) = cyclic_fit(&m, period) else {
            continue;
        };
        let n = m.len() as f64;
        let f_pe = ss / 2.0 / mean(&w).max(1e-300);
        let f_lof = ss / 2.0 / (rss / df_lof).max(1e-300);
        let p = f_sf(f_pe, 2.0, df_pe).max(f_sf(f_lof, 2.0, df_lof));
        let amp = a.hypot(b);
        let se = (2.0 * mean(&w).max(rss / df_lof) / n).sqrt();
        let mut extra = serde_json::Map::new();
        extra.insert("period_um".into(), json!(period));
        extra.insert("period_index".into(), json!(pj));
        extra.insert("cos_um".into(), json!(a));
        extra.insert("sin_um".into(), json!(b));
        pending.push(Pending {
            table: ti,
            order: 4 + pj,
            finding: Finding {
                kind,
                what: format!("cyclic error of period {period:.1} µm (amplitude)"),
                axis: tb.axis,
                static_um: tb.static_um,
                value: amp,
                se,
                unit: "um",
                t: amp / se.max(1e-300),
                p,
                extra: tag(extra),
                ..Finding::undecided()
            },
        });
    }
}

/// Cosine and sine of one period fitted beside a smooth curve (Chebyshev polynomial of degree
/// 1–6, by the number of targets) to the bidirectional means: (a, b, the sum of squares the two
/// terms add, residual sum of squares, its degrees of freedom). A smooth position error of
/// longer periods is then not taken for the cyclic one.
fn cyclic_fit(m: &[(f64, f64)], period: f64) -> Option<(f64, f64, f64, f64, f64)> {
    let n = m.len();
    if n < 8 {
        return None;
    }
    let deg = ((n - 6) / 4).clamp(1, 6);
    let lo = m.iter().map(|v| v.0).fold(f64::INFINITY, f64::min);
    let hi = m.iter().map(|v| v.0).fold(f64::NEG_INFINITY, f64::max);
    if hi <= lo {
        return None;
    }
    let u = |x: f64| 2.0 * (x - lo) / (hi - lo) - 1.0;
    let w = |x: f64| std::f64::consts::TAU * x / period;
    let fit = |with: bool| {
        let k = deg + 1 + if with { 2 } else { 0 };
        let a = DMatrix::from_fn(n, k, |i, j| {
            let x = m[i].0;
            if j <= deg {
                (j as f64 * u(x).clamp(-1.0, 1.0).acos()).cos()
            } else if j == deg + 1 {
                w(x).cos()
            } else {
                w(x).sin()
            }
        });
        let y = DVector::from_fn(n, |i, _| m[i].1);
        let beta = a.clone().svd(true, true).solve(&y, 1e-10).ok()?;
        let r = &y - &a * &beta;
        Some((beta, r.dot(&r)))
    };
    let (b4, rss4) = fit(true)?;
    let (_, rss2) = fit(false)?;
    let df = n as f64 - (deg + 3) as f64;
    Some((b4[deg + 1], b4[deg + 2], (rss2 - rss4).max(0.0), rss4, df))
}

type TableModel = Option<(f64, f64, f64, (Shape, f64, f64), Timing)>;

fn finalise(
    tables: Vec<Table>,
    per_table: Vec<TableModel>,
    pending: Vec<Pending>,
    skipped: Vec<String>,
    model: &StageModel,
    timed: bool,
) -> Option<IsoAnalysis> {
    // The drift decision comes first (it decides which reversal/scale variant stands): Holm
    // counts one test per effect and table (the two variants are one test, of which one is
    // kept).
    let n_tests = pending
        .iter()
        .filter(|p| p.finding.kind == "thermal_drift" || !corrected(&p.finding))
        .count();
    // Holm on the drift-free variants first to decide the drift, then the reversal and scale
    // tests of the variant that matches the drift decision (the family is the same size).
    let holm = |ps: &mut [(usize, f64)]| -> Vec<(usize, f64, bool)> {
        ps.sort_by(|a, b| a.1.total_cmp(&b.1));
        let m = ps.len();
        let mut out = Vec::new();
        let mut go = true;
        for (r, &(i, p)) in ps.iter().enumerate() {
            let a = ALPHA_FAMILY / (m - r) as f64;
            let ok = go && p <= a;
            go = ok;
            out.push((i, a, ok));
        }
        out
    };
    // Pass 1: decide drift with the uncorrected variants in the family.
    let mut ps: Vec<(usize, f64)> = pending
        .iter()
        .enumerate()
        .filter(|(_, p)| p.finding.kind == "thermal_drift" || !corrected(&p.finding))
        .map(|(i, p)| (i, p.finding.p))
        .collect();
    let pass1 = holm(&mut ps);
    let drift_sig: Vec<bool> = (0..tables.len())
        .map(|ti| {
            pass1.iter().any(|&(i, _, ok)| {
                ok && pending[i].table == ti && pending[i].finding.kind == "thermal_drift"
            })
        })
        .collect();
    // Drift named only when it also predicts held-out cycles better.
    // The shape that predicts held-out cycles: the fitted one, or a straight line when a
    // settling fitted to four cycles cannot be extrapolated to the fifth (its first cycles
    // carry most of the settling).
    let loco_drift: Vec<Option<(Shape, Timing)>> = (0..tables.len())
        .map(|ti| {
            let (_, _, _, shape, timing) = per_table[ti]?;
            if !drift_sig[ti] {
                return None;
            }
            let none = tables[ti].loco_rms(&Named::default());
            let mut tries = vec![shape.0];
            if shape.0 != Shape::Linear {
                tries.push(Shape::Linear);
            }
            tries.into_iter().map(|sh| (sh, timing)).find(|&d| {
                let with = Named {
                    drift: Some(d),
                    ..Default::default()
                };
                tables[ti].loco_rms(&with) < none
            })
        })
        .collect();
    let drift_named: Vec<bool> = loco_drift.iter().map(Option::is_some).collect();
    // Pass 2: the variants that match the drift decision.
    let keep: Vec<bool> = pending
        .iter()
        .map(|p| p.finding.kind == "thermal_drift" || corrected(&p.finding) == drift_named[p.table])
        .collect();
    let mut ps: Vec<(usize, f64)> = pending
        .iter()
        .enumerate()
        .filter(|(i, _)| keep[*i])
        .map(|(i, p)| (i, p.finding.p))
        .collect();
    let pass2 = holm(&mut ps);
    let mut sig = vec![false; pending.len()];
    let mut alpha = vec![f64::NAN; pending.len()];
    for (i, a, ok) in pass2 {
        sig[i] = ok;
        alpha[i] = a;
    }
    let mut out_tables = Vec::new();
    let (mut sse_b, mut sse_a, mut n_all) = (0.0, 0.0, 0usize);
    let mut s2_pool = (0.0, 0.0);
    let mut pending: Vec<Option<Pending>> = pending.into_iter().map(Some).collect();
    for (ti, tb) in tables.iter().enumerate() {
        let Some((s2, df_pe, ss_free, shape, timing)) = per_table[ti] else {
            continue;
        };
        s2_pool.0 += s2 * df_pe;
        s2_pool.1 += df_pe;
        let mut fs: Vec<(usize, bool, f64, Finding)> = Vec::new();
        for (i, p) in pending.iter_mut().enumerate() {
            if !keep[i] {
                continue;
            }
            if let Some(p) = p.take_if(|p| p.table == ti) {
                let mut f = p.finding;
                f.significant = sig[i];
                f.alpha = alpha[i];
                fs.push((p.order, sig[i], f.p, f));
            }
        }
        fs.sort_by_key(|a| a.0);
        let drift = loco_drift[ti].or(Some((shape.0, timing)));
        let mut named = Named::default();
        let before = tb.loco(&named);
        let mut cur = before;
        for (_, s, _, f) in fs.iter_mut() {
            let mut alone = Named::default();
            set(&mut alone, f, drift);
            let a = tb.loco(&alone);
            f.heldout_alone_um = (a.0 / a.1.max(1) as f64).sqrt();
            if !*s {
                continue;
            }
            let share = f.extra.get("line_share").and_then(Json::as_f64);
            if let Some(sh) = share.filter(|&sh| f.kind == "scale" && sh < SCALE_LINE_SHARE) {
                f.refused = Some(format!(
                    "the line is only {:.0} % of the position-dependent error: part of that error, not a scale error",
                    100.0 * sh
                ));
                continue;
            }
            if f.kind == "thermal_drift" && !drift_named[ti] {
                f.refused = Some("leave-one-cycle-out prediction does not improve".into());
                continue;
            }
            let mut trial = named;
            set(&mut trial, f, drift);
            let t = tb.loco(&trial);
            if t.0 < cur.0 {
                f.named = true;
                f.heldout_before_um = Some((cur.0 / cur.1.max(1) as f64).sqrt());
                f.heldout_after_um = Some((t.0 / t.1.max(1) as f64).sqrt());
                named = trial;
                cur = t;
            } else {
                f.refused = Some("leave-one-cycle-out prediction does not improve".into());
            }
        }
        // Final fit with everything named: effects for the model, ISO R with and without drift.
        let all = |_: usize| true;
        let est = named.drift.map(|_| (shape.0, timing));
        let ff = tb.fit(&all, est);
        let r_before = tb.iso_r(None);
        let r_after = est.and_then(|(s, t)| tb.iso_r(Some((&ff, s, t))));
        let before_rms = (before.0 / before.1.max(1) as f64).sqrt();
        for (_, _, _, f) in fs.iter_mut() {
            // Alone: from this baseline (one zero per table, nothing named) to
            // `heldout_rms_alone_um`.
            f.extra
                .insert("heldout_rms_baseline_um".into(), json!(before_rms));
            if !f.named {
                continue;
            }
            f.effect = effect_of(f, tb, &ff, shape.0);
            if f.kind == "thermal_drift" {
                if let Some((Shape::Linear, _)) = named.drift.filter(|_| shape.0 != Shape::Linear) {
                    f.extra.insert(
                        "heldout_shape".into(),
                        json!("linear (the settling fitted to the other cycles does not extrapolate to a held-out end cycle)"),
                    );
                }
                f.extra.insert("r_before_um".into(), json!(r_before));
                f.extra.insert("r_after_um".into(), json!(r_after));
                if let (Some(a), Some(b)) = (r_before, r_after) {
                    if a > 0.0 {
                        f.extra.insert("share_of_r".into(), json!(1.0 - b / a));
                    }
                }
                let d = before_rms.powi(2) - s2;
                if d > 0.0 {
                    f.extra.insert(
                        "share_of_heldout_gap".into(),
                        json!(
                            ((before_rms.powi(2) - f.heldout_alone_um.powi(2)) / d).clamp(0.0, 1.0)
                        ),
                    );
                }
            }
        }
        let findings: Vec<Finding> = fs.into_iter().map(|x| x.3).collect();
        let iso_reversal = tb.fit(&all, None).b_mean;
        let (cannot, cj, un_rms, un_z, left) =
            cannot_see(tb, &ff, &named, s2, df_pe, ss_free, shape, &findings, model);
        sse_b += before.0;
        sse_a += cur.0;
        n_all += before.1;
        out_tables.push(IsoTable {
            axis: tb.axis,
            static_um: tb.static_um,
            targets: tb.targets.len(),
            cycles: tb.cycles.len(),
            samples: tb.obs.len(),
            sigma_pe_um: s2.sqrt(),
            df_pe,
            iso_reversal_um: iso_reversal,
            findings,
            heldout_before_um: before_rms,
            heldout_after_um: (cur.0 / cur.1.max(1) as f64).sqrt(),
            cannot_see: cannot,
            cannot_see_json: cj,
            unexplained_rms_um: un_rms,
            unexplained_z: un_z,
            structure_left: left,
        });
    }
    let _ = timed;
    let mut skipped = skipped;
    for (ti, tb) in tables.iter().enumerate() {
        if per_table[ti].is_none() {
            skipped.push(format!(
                "{} axis at {} = {:.0} µm: too few repeats for a pure error (< 3 degrees of freedom)",
                tb.axis,
                tb.axis.other(),
                tb.static_um
            ));
        }
    }
    if out_tables.is_empty() {
        return None;
    }
    let n = n_all.max(1) as f64;
    Some(IsoAnalysis {
        tables: out_tables,
        heldout_before_um: (sse_b / n).sqrt(),
        heldout_after_um: (sse_a / n).sqrt(),
        sigma_um: (s2_pool.0 / s2_pool.1.max(1.0)).sqrt(),
        alpha_family: ALPHA_FAMILY,
        tests: n_tests,
        skipped,
    })
}

fn corrected(f: &Finding) -> bool {
    f.extra
        .get("drift_corrected")
        .and_then(Json::as_bool)
        .unwrap_or(false)
}

fn set(n: &mut Named, f: &Finding, drift: Option<(Shape, Timing)>) {
    match f.kind {
        "backlash" => n.backlash = true,
        "hysteresis" => n.hyst = true,
        "scale" => n.scale = true,
        "thermal_drift" => n.drift = drift,
        "leadscrew_cyclic" | "motor_cyclic" => {
            if let Some(j) = f.extra.get("period_index").and_then(Json::as_u64) {
                n.cyclic |= 1u32 << (j.min(31) as u32);
            }
        }
        _ => {}
    }
}

fn effect_of(fnd: &Finding, tb: &Table, f: &Fit, shape: Shape) -> Option<Effect> {
    let kind = fnd.kind;
    let k = match kind {
        "backlash" => EffectKind::Backlash {
            reversal_um: f.b_mean,
        },
        "hysteresis" => {
            let (b0, b1) = f.hyst?;
            EffectKind::Hysteresis {
                b0_um: b0,
                b1_um: b1,
            }
        }
        "scale" => EffectKind::Scale {
            ppm: f.scale? * 1e6,
            ref_um: 0.0,
        },
        "leadscrew_cyclic" | "motor_cyclic" => {
            let j = fnd.extra.get("period_index").and_then(Json::as_u64)? as usize;
            let (a, b) = (*f.cyc.get(j)?)?;
            let period_um = tb.periods.get(j)?.1;
            if kind == "motor_cyclic" {
                EffectKind::MotorCyclic {
                    period_um,
                    cos_um: vec![a],
                    sin_um: vec![b],
                }
            } else {
                EffectKind::LeadscrewCyclic {
                    period_um,
                    cos_um: vec![a],
                    sin_um: vec![b],
                }
            }
        }
        "thermal_drift" => match shape {
            Shape::Linear => EffectKind::ThermalDrift {
                component: tb.axis,
                amp_um: 0.0,
                tau_s: 1.0,
                rate_um_per_h: f.beta,
            },
            Shape::Settling(tau) => {
                // β·exp(-(t - t0)/τ) = -β·e^(t0/τ)·(1 - e^(-t/τ)) + const.
                let amp = -f.beta * (tb.t0 / tau).exp();
                if !amp.is_finite() {
                    return None;
                }
                EffectKind::ThermalDrift {
                    component: tb.axis,
                    amp_um: amp,
                    tau_s: tau,
                    rate_um_per_h: 0.0,
                }
            }
        },
        _ => return None,
    };
    Some(Effect::new(tb.axis, k))
}

/// What the table cannot resolve: the repeatable position structure left, reversals that vary
/// irregularly, cycle offsets off the trend; with the limits of this layout and what to measure.
#[allow(clippy::too_many_arguments)]
fn cannot_see(
    tb: &Table,
    f: &Fit,
    named: &Named,
    s2: f64,
    df_pe: f64,
    ss_free: f64,
    shape: (Shape, f64, f64),
    findings: &[Finding],
    model: &StageModel,
) -> (Vec<String>, Json, f64, f64, bool) {
    let mut text = Vec::new();
    let mut left = false;
    let mut j = serde_json::Map::new();
    let nt = tb.targets.len();
    let mut xs = tb.targets.clone();
    xs.sort_by(f64::total_cmp);
    let gaps: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
    let max_gap = gaps.iter().copied().fold(0.0, f64::max);
    let span = xs[nt - 1] - xs[0];
    let min_period = 2.0 * max_gap;
    // Position structure: bidirectional cell means minus the named effects.
    let cell_of = |t: usize, fwd: bool| tb.cells.iter().position(|&c| c == (t, fwd));
    let mut res = Vec::new();
    let mut var = Vec::new();
    for t in 0..nt {
        let cs: Vec<usize> = [true, false]
            .iter()
            .filter_map(|&d| cell_of(t, d))
            .filter(|&c| f.n[c] > 0)
            .collect();
        if cs.is_empty() {
            continue;
        }
        let k = cs.len() as f64;
        let mut v = 0.0;
        for &c in &cs {
            let o = Obs {
                y: 0.0,
                cell: c,
                cycle: 0,
                t: 0.0,
                pos: tb.targets[t],
                dir: if tb.cells[c].1 { 1.0 } else { -1.0 },
            };
            let no_drift = Named {
                drift: None,
                ..*named
            };
            v += f.mu[c] - tb.terms(f, &no_drift, &o, None);
        }
        res.push((tb.targets[t], v / k));
        var.push(s2 * cs.iter().map(|&c| 1.0 / f.n[c] as f64).sum::<f64>() / (k * k));
    }
    let m = mean(&res.iter().map(|r| r.1).collect::<Vec<_>>());
    let ss: f64 = res.iter().map(|r| (r.1 - m).powi(2)).sum();
    let chi: f64 = res
        .iter()
        .zip(&var)
        .map(|(r, w)| (r.1 - m).powi(2) / w)
        .sum();
    let dfp = (res.len() as f64 - 1.0 - f64::from(u8::from(named.scale))).max(1.0);
    let z = chi2_z(chi, dfp);
    let rms = ((ss / res.len().max(1) as f64) - mean(&var))
        .max(0.0)
        .sqrt();
    let worst = res
        .iter()
        .max_by(|a, b| (a.1 - m).abs().total_cmp(&(b.1 - m).abs()))
        .map(|r| (r.0, r.1 - m))
        .unwrap_or((f64::NAN, 0.0));
    // Library periods this layout cannot see.
    let mut periods: Vec<(String, f64)> = model
        .effects
        .iter()
        .filter(|e| e.axis == tb.axis)
        .filter_map(|e| match &e.kind {
            EffectKind::LeadscrewCyclic { period_um, .. } => {
                Some(("leadscrew".to_string(), *period_um))
            }
            EffectKind::MotorCyclic { period_um, .. } => Some(("motor".to_string(), *period_um)),
            _ => None,
        })
        .collect();
    if !periods.iter().any(|p| p.0 == "leadscrew") {
        periods.push(("leadscrew (catalogue pitch)".into(), 400.0));
    }
    let need = |p: f64| ((span / (0.5 * p)).ceil() as usize + 1).max(nt);
    let unresolved: Vec<String> = periods
        .iter()
        .filter(|p| p.1 < min_period)
        .map(|(n, p)| {
            format!(
                "the {n} period {p:.0} µm needs targets ≤ {:.0} µm apart (≥ {} targets over these {:.1} mm, irregular offsets as ISO 230-2 asks)",
                0.5 * p,
                need(*p),
                span / 1000.0
            )
        })
        .collect();
    if z > 3.5 && rms > 0.0 {
        left = true;
        let mut s = format!(
            "a repeatable position-dependent error of {rms:.2} µm RMS (largest {:.2} µm at {:.0} µm; χ² z {z:.1} against the pure error) is left unexplained: {nt} targets {:.0} µm apart resolve no period below {min_period:.0} µm, so it cannot be told apart from a cyclic error, a sensor nonlinearity or any shorter-period error",
            worst.1, worst.0, max_gap
        );
        if !unresolved.is_empty() {
            s += &format!("; to resolve it: {}", unresolved.join("; "));
        }
        s += "; the cell means in the ISO 230-2 table are its measured values at the targets";
        text.push(s);
    }
    j.insert(
        "position_error".into(),
        json!({
            "rms_um": rms,
            "z": z,
            "significant": z > 3.5,
            "largest_um": worst.1,
            "at_um": worst.0,
            "target_spacing_um": max_gap,
            "shortest_resolvable_period_um": min_period,
            "span_um": span,
            "targets": nt,
            "to_resolve": unresolved,
        }),
    );
    // Reversals that vary irregularly beyond what is named.
    if f.b_i.len() >= 3 {
        let pred = |t: usize| -> f64 {
            if named.hyst {
                f.hyst
                    .map_or(f.b_mean, |(b0, b1)| b0 + b1 * tb.s(tb.targets[t]))
            } else if named.backlash {
                f.b_mean
            } else {
                0.0
            }
        };
        let mut chi = 0.0;
        let mut ssr = 0.0;
        let mut wsum = 0.0;
        for &(t, b) in &f.b_i {
            let nu = cell_of(t, true).map_or(1, |c| f.n[c].max(1)) as f64;
            let nd = cell_of(t, false).map_or(1, |c| f.n[c].max(1)) as f64;
            let w = s2 * (1.0 / nu + 1.0 / nd);
            let r = b - pred(t);
            chi += r * r / w;
            ssr += r * r;
            wsum += w;
        }
        let k = f.b_i.len() as f64;
        let dfr = (k
            - f64::from(u8::from(named.backlash || named.hyst))
            - f64::from(u8::from(named.hyst)))
        .max(1.0);
        let zr = chi2_z(chi, dfr);
        let rr = (ssr / k - wsum / k).max(0.0).sqrt();
        if zr > 3.5 {
            left = true;
            let lo = f.b_i.iter().map(|b| b.1).fold(f64::INFINITY, f64::min);
            let hi = f.b_i.iter().map(|b| b.1).fold(f64::NEG_INFINITY, f64::max);
            text.push(format!(
                "the reversal varies from target to target ({lo:.2} … {hi:.2} µm; {rr:.2} µm RMS around what is named, χ² z {zr:.1}) in a way no backlash or linear hysteresis describes: more targets (and both approach speeds) are needed to see its shape"
            ));
        }
        j.insert(
            "reversal_irregular".into(),
            json!({"rms_um": rr, "z": zr, "significant": zr > 3.5}),
        );
    }
    // Cycle offsets beyond the trend (or beyond none).
    let nc = tb.cycles.len() as f64;
    let explained = if named.drift.is_some() { shape.1 } else { 0.0 };
    let dfc = nc - 1.0 - f64::from(u8::from(named.drift.is_some()));
    if dfc >= 1.0 {
        let ss_c = (ss_free - explained).max(0.0);
        let zc = chi2_z(ss_c / s2, dfc);
        let per_cycle = (ss_c / (tb.obs.len() as f64 / nc) / nc).sqrt();
        if zc > 3.5 {
            left = true;
            text.push(format!(
                "the cycle offsets scatter {per_cycle:.2} µm RMS beyond {} (χ² z {zc:.1}): a zero that wanders or a drift of another shape; give `time_s` and measure more cycles (or a reference at a fixed target between cycles) to resolve it",
                if named.drift.is_some() { "the named drift" } else { "a constant zero" }
            ));
        }
        j.insert(
            "cycle_offsets".into(),
            json!({"rms_um": per_cycle, "z": zc, "significant": zc > 3.5, "df": dfc}),
        );
    }
    // Detection limits of this layout (what a null result means).
    let se_b = findings.iter().find(|f| f.kind == "backlash").map(|f| f.se);
    let se_d = findings
        .iter()
        .find(|f| f.kind == "thermal_drift")
        .and_then(|f| f.extra.get("rate_se_um_per_cycle").and_then(Json::as_f64));
    let z_lim = 4.0;
    let mut lim = serde_json::Map::new();
    if let Some(se) = se_b {
        lim.insert("reversal_um".into(), json!(z_lim * se));
    }
    if let Some(se) = se_d {
        lim.insert("drift_um_per_cycle".into(), json!(z_lim * se));
    }
    let unnamed: Vec<&str> = findings
        .iter()
        .filter(|f| !f.named && (f.kind == "backlash" || f.kind == "thermal_drift"))
        .map(|f| f.kind)
        .collect();
    if !unnamed.is_empty() {
        let parts: Vec<String> = unnamed
            .iter()
            .filter_map(|k| match *k {
                "backlash" => se_b.map(|s| format!("a reversal below ≈ {:.2} µm", z_lim * s)),
                _ => se_d.map(|s| format!("a drift below ≈ {:.3} µm per cycle", z_lim * s)),
            })
            .collect();
        if !parts.is_empty() {
            text.push(format!(
                "with {} cycles × {nt} targets (pure error σ {:.3} µm, {df_pe} df) this table cannot show {}; more cycles shrink these limits as 1/√cycles",
                tb.cycles.len(),
                s2.sqrt(),
                parts.join(" or ")
            ));
        }
    }
    j.insert("detection_limits".into(), Json::Object(lim));
    j.insert("text".into(), json!(text));
    (text, Json::Object(j), rms, z, left)
}
