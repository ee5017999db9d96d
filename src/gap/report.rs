//! What the diagnosis reports: accepted effects with their ties, where the gap lies, and the
//! JSON and text forms of the result.
use csmetro_effects::{Effect, StageModel};
use serde_json::{json, Value as Json};

pub use super::findings::{OtherAxis, Peak, Where};

/// One tie: a candidate (or set) the data cannot tell apart from the pick.
#[derive(Debug, Clone)]
pub struct Tie {
    pub members: Vec<(String, String)>,
    pub heldout_rms_um: Option<f64>,
    /// "score" (held-out score within noise) or "span" (reproduces the pick's fitted deviation).
    pub reason: &'static str,
}

impl Tie {
    pub fn label(&self) -> String {
        self.members
            .iter()
            .map(|(k, a)| {
                if a == "-" {
                    k.clone()
                } else {
                    format!("{k} {a}")
                }
            })
            .collect::<Vec<_>>()
            .join(" + ")
    }
}

/// One accepted effect group.
#[derive(Debug, Clone)]
pub struct Added {
    pub kind: String,
    /// x, y, or "-" for camera kinds (thermal drift: its component).
    pub axis: String,
    /// The fitted effect (what the data say the missing effect is), final joint fit.
    pub effect: Effect,
    pub heldout_rms_um: f64,
    pub gap_closed: Option<f64>,
    pub t_stat: f64,
    pub ties: Vec<Tie>,
}

#[derive(Debug, Clone)]
pub struct Unexplained {
    pub significant: bool,
    pub rms_um: f64,
    pub lack_of_fit_z: f64,
    pub time_z: f64,
    pub where_: Vec<Where>,
    pub frequency: Vec<Peak>,
}

#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub n_samples: usize,
    pub n_runs: usize,
    pub n_lines: usize,
    pub sigma_um: f64,
    pub sigma_from_repeats: bool,
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
    pub lack_of_fit_before_z: f64,
    pub added: Vec<Added>,
    pub where_: Vec<Where>,
    pub frequency: Vec<Peak>,
    pub other_axis: Vec<OtherAxis>,
    pub unexplained: Unexplained,
    pub model: StageModel,
    pub candidates: Vec<String>,
    /// What the data cannot tell: too few runs, unresolvable periods, ties, unmeasured components.
    pub notes: Vec<String>,
    /// Drift in time against the noise left once it is removed.
    pub drift: super::drift::Drift,
    /// ISO 230-2 decomposition (tables of repeated bidirectional cycles): what is named there
    /// is what `added` holds.
    pub iso: Option<super::saturated::IsoAnalysis>,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

pub(super) fn toml_to_json(v: &toml::Value) -> Json {
    match v {
        toml::Value::Float(f) => json!(f),
        toml::Value::Integer(i) => json!(i),
        toml::Value::String(s) => json!(s),
        toml::Value::Boolean(b) => json!(b),
        toml::Value::Array(a) => Json::Array(a.iter().map(toml_to_json).collect()),
        other => json!(other.to_string()),
    }
}

impl Diagnosis {
    pub fn to_json(&self) -> Json {
        let added: Vec<Json> = self
            .added
            .iter()
            .map(|a| {
                let params: serde_json::Map<String, Json> = a
                    .effect
                    .params()
                    .iter()
                    .map(|(k, v)| (k.clone(), toml_to_json(v)))
                    .collect();
                json!({
                    "kind": a.kind,
                    "axis": a.axis,
                    "params": params,
                    "heldout_rms_um": a.heldout_rms_um,
                    "gap_closed": a.gap_closed,
                    "t_stat": if a.t_stat.is_finite() { a.t_stat } else { 1e9 },
                    "ties": a.ties.iter().map(|t| json!({
                        "label": t.label(),
                        "members": t.members.iter().map(|(k, ax)| json!({"kind": k, "axis": ax})).collect::<Vec<_>>(),
                        "heldout_rms_um": t.heldout_rms_um,
                        "reason": t.reason,
                    })).collect::<Vec<_>>(),
                })
            })
            .collect();
        json!({
            "n_samples": self.n_samples,
            "n_runs": self.n_runs,
            "n_lines": self.n_lines,
            "sigma_um": self.sigma_um,
            "sigma_from_repeats": self.sigma_from_repeats,
            "heldout_rms_before_um": self.heldout_rms_before_um,
            "heldout_rms_after_um": self.heldout_rms_after_um,
            "lack_of_fit_before_z": self.lack_of_fit_before_z,
            "added": added,
            "where": self.where_.iter().map(Where::to_json).collect::<Vec<_>>(),
            "frequency": self.frequency.iter().map(Peak::to_json).collect::<Vec<_>>(),
            "other_axis": self.other_axis.iter().map(OtherAxis::to_json).collect::<Vec<_>>(),
            "unexplained": {
                "significant": self.unexplained.significant,
                "rms_um": self.unexplained.rms_um,
                "lack_of_fit_z": self.unexplained.lack_of_fit_z,
                "time_z": self.unexplained.time_z,
                "where": self.unexplained.where_.iter().map(Where::to_json).collect::<Vec<_>>(),
                "frequency": self.unexplained.frequency.iter().map(Peak::to_json).collect::<Vec<_>>(),
            },
            "candidates": self.candidates,
            "notes": self.notes,
            "findings": self.iso.as_ref().map_or_else(Vec::new, |i| i.findings().map(|f| f.to_json()).collect::<Vec<_>>()),
            "cannot_see": self.iso.as_ref().map_or_else(Vec::new, |i| i.tables.iter().flat_map(|t| t.cannot_see.iter().cloned()).collect::<Vec<_>>()),
            "iso_decomposition": self.iso.as_ref().map(|i| i.to_json()),
            "drift": {
                "significant": self.drift.significant,
                "z": self.drift.z,
                "rate_um_per_h": {
                    "x": finite(self.drift.rate_mid_um_per_h[0]),
                    "y": finite(self.drift.rate_mid_um_per_h[1]),
                },
                "rate_at_travel_ends_um_per_h": {
                    "x": self.drift.rate_ends_um_per_h[0].map(finite),
                    "y": self.drift.rate_ends_um_per_h[1].map(finite),
                },
                "line_offset_rate_um_per_h": finite(self.drift.offset_rate_um_per_h),
                "line_offset_z": finite(self.drift.offset_z),
                "between_cycles": self.iso.as_ref().map(|i| i.findings().filter(|f| f.kind == "thermal_drift").map(|f| {
                    let g = |k: &str| f.extra.get(k).cloned().unwrap_or(Json::Null);
                    json!({
                        "axis": f.axis.as_str(),
                        "named": f.named,
                        "rate_um_per_cycle": g("rate_um_per_cycle"),
                        "rate_se_um_per_cycle": g("rate_se_um_per_cycle"),
                        "rate_um_per_h": g("rate_um_per_h"),
                        "shape": g("shape"),
                        "p": f.p,
                    })
                }).collect::<Vec<_>>()),
            },
        })
    }

    /// Human-readable report.
    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "data: {} samples, {} runs, {} lines; repeatability σ = {:.4} µm{}",
            self.n_samples,
            self.n_runs,
            self.n_lines,
            self.sigma_um,
            if self.sigma_from_repeats {
                " (pure error over repeated runs)"
            } else {
                " (no repeats: from the held-out residual)"
            }
        );
        let _ = writeln!(
            s,
            "held-out RMS gap (leave-one-run-out): before {:.4} µm, after {:.4} µm",
            self.heldout_rms_before_um, self.heldout_rms_after_um
        );
        if let Some(iso) = &self.iso {
            s.push_str(&iso.summary());
        }
        if self.where_.is_empty() {
            let _ = writeln!(
                s,
                "where: no interval significant against the repeatability"
            );
        } else {
            let _ = writeln!(
                s,
                "where (data - model, significant against repeatability):"
            );
            for w in &self.where_ {
                let _ = writeln!(s, "  {}", w.describe());
            }
        }
        for p in &self.frequency {
            let _ = writeln!(s, "  {}", p.describe());
        }
        if self.added.is_empty() {
            let _ = writeln!(
                s,
                "which: no effect improves the held-out fit significantly"
            );
        } else if self.iso.is_some() {
            let _ = writeln!(
                s,
                "which (named by the ISO 230-2 decomposition, held-out RMS cumulative):"
            );
        }
        for (i, a) in self.added.iter().enumerate() {
            let params: Vec<String> = a
                .effect
                .params()
                .iter()
                .map(|(k, v)| format!("{k} = {v}"))
                .collect();
            let _ = writeln!(
                s,
                "{}. {} {}: held-out RMS {:.4} µm, gap closed {} ({})",
                i + 1,
                a.kind,
                a.axis,
                a.heldout_rms_um,
                a.gap_closed
                    .map(|g| format!("{:.0} %", 100.0 * g))
                    .unwrap_or_else(|| "n/a".into()),
                params.join(", ")
            );
            if !a.ties.is_empty() {
                let t: Vec<String> = a
                    .ties
                    .iter()
                    .map(|t| format!("{} ({})", t.label(), t.reason))
                    .collect();
                let _ = writeln!(s, "   tie, the data cannot tell apart: {}", t.join("; "));
            }
        }
        for n in &self.notes {
            let _ = writeln!(s, "note: {n}");
        }
        if self.unexplained.significant {
            let _ = writeln!(
                s,
                "unexplained: structure remains that no library effect explains (RMS {:.4} µm, lack-of-fit z {:.1}, time z {:.1})",
                self.unexplained.rms_um, self.unexplained.lack_of_fit_z, self.unexplained.time_z
            );
            for w in &self.unexplained.where_ {
                let _ = writeln!(s, "  {}", w.describe());
            }
            for p in &self.unexplained.frequency {
                let _ = writeln!(s, "  {}", p.describe());
            }
        } else {
            let _ = writeln!(
                s,
                "unexplained: nothing significant remains (lack-of-fit z {:.1}, time z {:.1})",
                self.unexplained.lack_of_fit_z, self.unexplained.time_z
            );
        }
        s
    }
}
