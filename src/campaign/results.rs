//! Results of a finished campaign: curves, the JSON summary (the paper's Table III as a
//! report: measurements, physical acquisition time, processing time, recovery error), the
//! summary table `csmetro run` prints, and the files written to the output directory.
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde_json::{json, Value};

use super::engine::{stats_key, PhaseStats};
use super::plan::Plan;
use super::rig::Rig;
use super::spec::Campaign;
use super::worker::Curve;
use crate::report::{iso_chart_files, iso_text, report_files, ComponentCurve, ReportOptions};
use crate::store::EventRow;
use crate::types::{AxisId, Component, Phase, RunKey, SampleRecord};

/// The figures of a campaign as the store holds them: every count and physical time comes from
/// the stored samples and events, so a campaign interrupted, restarted or resumed any number of
/// times reports what one uninterrupted run of the same plan reports (wall times and the
/// physical time of the re-approaches aside).
#[derive(Debug, Clone, Default)]
pub struct Tally {
    /// Per `stats_key(phase, axis)`.
    pub stats: BTreeMap<String, PhaseStats>,
    /// Physical time re-approaching after pauses and restarts, per `stats_key`, s.
    pub repositioning_s: BTreeMap<String, f64>,
    /// Planned targets that never got a sample (rejected beyond the retries).
    pub failed_points: u64,
    /// Adaptive runs: the last stop decision of each, by run label (the `adaptive` event).
    pub adaptive: BTreeMap<String, Value>,
}

impl Tally {
    /// Stats of one (phase, axis), zero when absent.
    pub fn stat(&self, phase: Phase, axis: AxisId) -> PhaseStats {
        self.stats
            .get(&stats_key(phase, axis))
            .cloned()
            .unwrap_or_default()
    }
}

fn run_of_event(e: &EventRow, by_seq: &BTreeMap<u64, RunKey>) -> Option<String> {
    if let (Some(p), Some(a)) = (e.data["phase"].as_str(), e.data["axis"].as_str()) {
        return Some(format!("{p}-{a}"));
    }
    let run = by_seq.get(&e.data["seq"].as_u64()?)?;
    Some(stats_key(run.phase, run.axis))
}

/// Counts and times of a campaign from its stored samples and events. Meant for a campaign
/// whose last attempt went through the whole plan: every planned target then has a sample,
/// was skipped by the adaptive mode, or failed.
pub fn tally(plan: &Plan, samples: &[SampleRecord], events: &[EventRow]) -> Tally {
    let mut t = Tally::default();
    let by_seq: BTreeMap<u64, RunKey> = plan
        .batches
        .iter()
        .flat_map(|b| b.targets.iter().map(|x| (x.seq, x.run)))
        .collect();
    let stored: BTreeSet<u64> = samples.iter().map(|s| s.target.seq).collect();
    for s in samples {
        let st = t
            .stats
            .entry(stats_key(s.target.run.phase, s.target.run.axis))
            .or_default();
        st.measurements += 1;
        st.acquisition_s += s.point_s;
        st.frames += s.frames as u64;
    }
    // The last adaptive decision of each run, and the last approach to its start.
    let mut adaptive: BTreeMap<String, (u64, bool)> = BTreeMap::new();
    let mut run_start: BTreeMap<String, (String, f64)> = BTreeMap::new();
    let mut failed_s: BTreeMap<u64, (String, f64)> = BTreeMap::new();
    for e in events {
        let d = &e.data;
        match e.kind.as_str() {
            "frame_rejected" => {
                if let Some(k) = run_of_event(e, &by_seq) {
                    let st = t.stats.entry(k).or_default();
                    st.rejected_frames += 1;
                    st.frames += d["frames"].as_u64().unwrap_or(0);
                }
            }
            "point_failed" => {
                if let (Some(k), Some(seq)) = (run_of_event(e, &by_seq), d["seq"].as_u64()) {
                    failed_s.insert(seq, (k, d["physical_s"].as_f64().unwrap_or(0.0)));
                }
            }
            "positioned" => {
                let (Some(k), Some(run), Some(phys)) = (
                    run_of_event(e, &by_seq),
                    d["run"].as_str(),
                    d["physical_s"].as_f64(),
                ) else {
                    continue;
                };
                if d["run_start"].as_bool() == Some(true) {
                    run_start.insert(run.to_string(), (k, phys));
                } else {
                    *t.repositioning_s.entry(k).or_default() += phys;
                }
            }
            "adaptive" => {
                if let (Some(run), Some(b)) = (d["run"].as_str(), d["batch"].as_u64()) {
                    adaptive.insert(run.to_string(), (b, d["stop"].as_bool() == Some(true)));
                    t.adaptive.insert(run.to_string(), d.clone());
                }
            }
            "attempt" => {
                if let Some(m) = d["decode_s"].as_object() {
                    for (k, v) in m {
                        t.stats.entry(k.clone()).or_default().decode_s += v.as_f64().unwrap_or(0.0);
                    }
                }
            }
            _ => {}
        }
    }
    for (k, phys) in run_start.into_values() {
        t.stats.entry(k).or_default().positioning_s += phys;
    }
    // A point that failed and was measured by a later attempt is not a failed point.
    for (seq, (k, phys)) in &failed_s {
        if !stored.contains(seq) {
            t.stats.entry(k.clone()).or_default().acquisition_s += phys;
        }
    }
    for b in &plan.batches {
        let key = stats_key(b.run.phase, b.run.axis);
        let skipped = adaptive
            .get(&b.run.label())
            .is_some_and(|&(last, stop)| stop && (b.index as u64) > last);
        let missing = b
            .targets
            .iter()
            .filter(|x| !stored.contains(&x.seq))
            .count() as u64;
        let st = t.stats.entry(key).or_default();
        if skipped {
            st.saved_by_adaptive += missing;
        } else {
            st.failed_points += missing;
            t.failed_points += missing;
        }
    }
    t
}

pub struct Report {
    pub summary: Value,
    pub table: String,
    /// ISO 230-2 figures per moving axis (also in `iso230.json`).
    pub iso: Vec<crate::report::AxisIso230>,
    /// (file name, content type, bytes)
    pub files: Vec<(String, String, Vec<u8>)>,
}

/// The file that says whose results a results folder holds: the store's identity and the
/// campaign's id. A folder marked by another campaign is never written into.
pub const MARKER: &str = ".csmetro-results.json";

/// Where campaign `id` of store `store_id` writes its results, and marks the folder as its
/// own: `dir` itself when it is new, holds no results, or is already this campaign's; else,
/// when `dir` holds another campaign's results (marked by another store with the same `{id}`,
/// by this store under a template without `{id}`, or unmarked, from an older csmetro), `dir`
/// with the store's identity and the campaign id in its name (`it-1.store-<id>-c1`). Refused
/// (the results stay in the store) when that folder is taken too or cannot be marked.
pub fn claim_out_dir(
    dir: &Path,
    store_id: &str,
    id: i64,
    name: &str,
) -> Result<PathBuf, ResultsError> {
    let mine = json!({"store_id": store_id, "campaign": id});
    let fallback = {
        let base = dir.file_name().map_or_else(
            || "results".to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        dir.with_file_name(format!("{base}.store-{store_id}-c{id}"))
    };
    for d in [dir, fallback.as_path()] {
        match owner(d) {
            Owner::Free => {
                std::fs::create_dir_all(d).map_err(|e| ResultsError::Create(e.kind()))?;
                let marker = json!({"store_id": store_id, "campaign": id, "name": name});
                // create_new: two processes claiming one folder at once, one wins.
                let created = std::fs::OpenOptions::new()
                    .write(true)
                    .create_new(true)
                    .open(d.join(MARKER))
                    .and_then(|mut f| {
                        std::io::Write::write_all(&mut f, marker.to_string().as_bytes())
                    });
                match created {
                    Ok(()) => return Ok(d.to_path_buf()),
                    Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                        if owner(d) == Owner::Marked(mine.clone()) {
                            return Ok(d.to_path_buf());
                        }
                    }
                    Err(e) => return Err(ResultsError::Mark(e.kind())),
                }
            }
            Owner::Marked(m) if m == mine => return Ok(d.to_path_buf()),
            Owner::Marked(_) | Owner::Unmarked => {}
        }
    }
    Err(ResultsError::Taken)
}

/// Why a campaign's result files are not in its output directory (they are in the store).
#[derive(Debug, thiserror::Error)]
pub enum ResultsError {
    #[error("results not written to the output directory (cannot create it: {0}); they are in the store")]
    Create(std::io::ErrorKind),
    #[error(
        "results not written to the output directory (cannot mark it: {0}); they are in the store"
    )]
    Mark(std::io::ErrorKind),
    #[error("results not written to the output directory (it and its fallback hold other campaigns' results); they are in the store")]
    Taken,
    /// The first file that could not be written, relative to the directory.
    #[error("results not written to the output directory ({name}: {kind}); they are in the store")]
    Write {
        name: String,
        kind: std::io::ErrorKind,
    },
}

/// The results folder campaign `id` of store `store_id` claimed from the template's `dir`
/// ([`claim_out_dir`]: `dir` or its fallback), when it exists and is marked as its own; nothing
/// is created.
pub fn owned_out_dir(dir: &Path, store_id: &str, id: i64) -> Option<PathBuf> {
    let mine = json!({"store_id": store_id, "campaign": id});
    let base = dir.file_name()?.to_string_lossy().into_owned();
    let fallback = dir.with_file_name(format!("{base}.store-{store_id}-c{id}"));
    [dir.to_path_buf(), fallback]
        .into_iter()
        .find(|d| matches!(owner(d), Owner::Marked(m) if m == mine))
}

#[derive(Debug, PartialEq)]
enum Owner {
    /// Missing, or holds no results and no marker.
    Free,
    /// The marker's `store_id` and `campaign`.
    Marked(Value),
    /// Results (a `summary.json` file) without a marker.
    Unmarked,
}

fn owner(d: &Path) -> Owner {
    match std::fs::read(d.join(MARKER)) {
        Ok(b) => {
            let v: Value = serde_json::from_slice(&b).unwrap_or(Value::Null);
            Owner::Marked(json!({"store_id": v["store_id"], "campaign": v["campaign"]}))
        }
        Err(_) if d.join("summary.json").is_file() => Owner::Unmarked,
        Err(_) => Owner::Free,
    }
}

/// The output template of a campaign the service runs: always below the service's
/// `results_dir`. A relative template is joined to it; an absolute one (a foreground campaign
/// the service took over) keeps its part from the first `{id}`/`{name}` on, or its last
/// component, below `results_dir`.
pub fn service_outputs(results_dir: &Path, template: &str) -> String {
    let t = Path::new(template);
    if t.is_relative() {
        return results_dir.join(t).display().to_string();
    }
    let parts: Vec<_> = t
        .components()
        .filter(|c| matches!(c, std::path::Component::Normal(_)))
        .collect();
    let first = parts
        .iter()
        .position(|c| c.as_os_str().to_string_lossy().contains('{'))
        .unwrap_or(parts.len().saturating_sub(1));
    let mut out = results_dir.to_path_buf();
    for c in &parts[first..] {
        out.push(c.as_os_str());
    }
    out.display().to_string()
}

pub fn out_dir(c: &Campaign, id: i64) -> PathBuf {
    PathBuf::from(
        c.spec()
            .outputs
            .dir
            .replace("{id}", &id.to_string())
            .replace("{name}", &c.spec().campaign.name),
    )
}

/// mean |a - b|, max |a - b|, std of (a - b), µm.
pub fn diff_stats(a: &[f64], b: &[f64]) -> Value {
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let n = d.len().max(1) as f64;
    let mean_abs = d.iter().map(|v| v.abs()).sum::<f64>() / n;
    let max_abs = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mean = d.iter().sum::<f64>() / n;
    let std = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    json!({"mean_abs_um": mean_abs, "max_abs_um": max_abs, "std_um": std})
}

fn hms(s: f64) -> String {
    let t = s.round() as u64;
    format!("{}:{:02}:{:02}", t / 3600, (t / 60) % 60, t % 60)
}

/// What went wrong in a campaign that measured to its end: failed points, failed
/// reconstructions. Empty: it is done.
pub fn problems(t: &Tally, reconstruction_failures: &[String]) -> Vec<String> {
    let mut v = Vec::new();
    if t.failed_points > 0 {
        v.push(format!(
            "{} planned point(s) failed (every frame rejected)",
            t.failed_points
        ));
    }
    for e in reconstruction_failures {
        v.push(format!("reconstruction failed: {e}"));
    }
    v
}

#[allow(clippy::too_many_arguments)]
pub fn build(
    c: &Campaign,
    id: i64,
    tally: &Tally,
    wall_s: f64,
    problems: &[String],
    curves: &[Curve],
    samples: &[SampleRecord],
    truth: &TruthSource,
) -> Report {
    // The plan is a pure function of the campaign: the adaptive runs' batches.
    let plan = super::plan::plan(c);
    let mut files = Vec::new();
    let mut axes_json = Vec::new();
    let mut table = String::new();
    table.push_str(&format!(
        "{:<6} {:<10} {:>7} {:>12} {:>11} {:>12} {:>13} {:>13}\n",
        "axis",
        "method",
        "meas.",
        "acquisition",
        "processing",
        "saved",
        "err vs full",
        "err vs truth"
    ));
    table.push_str(&format!(
        "{:<6} {:<10} {:>7} {:>12} {:>11} {:>12} {:>13} {:>13}\n",
        "", "", "", "h:mm:ss", "s", "acq. %", "mean/max µm", "mean/max µm"
    ));
    let mut tot = [[0.0f64; 3]; 2]; // [phase][meas, acq_s, proc_s]
    let mut report_curves: Vec<ComponentCurve> = Vec::new();
    for ax in c.axes() {
        let a = ax.axis;
        let mut comps = Vec::new();
        let mut proc_s = [0.0f64; 2];
        let curve = |phase: Phase, comp: &Component, cycle: u32| {
            curves
                .iter()
                .find(|k| k.run.phase == phase && k.component == *comp && k.run.cycle == cycle)
        };
        for k in curves.iter().filter(|k| k.run.axis == a) {
            proc_s[(k.run.phase == Phase::Full) as usize] += k.solve_ms / 1000.0;
        }
        for comp in Component::all().into_iter().filter(|k| k.moving == a) {
            let cs = curve(Phase::Cs, &comp, 0);
            let full = curve(Phase::Full, &comp, 0);
            let Some(main) = cs.or(full) else { continue };
            let t = truth.curve(main, ax.other_at_um);
            let mut j = json!({"component": comp.name()});
            if let Some(k) = cs {
                j["cs"] = json!({"method": k.method, "m": k.samples.len(), "cv_error_um": k.cv_error_um, "solve_ms": k.solve_ms,
                                "pooled_with": k.pooled_with, "difference_degree": k.difference_degree,
                                // σ used, told, and as the frames showed it (several per point).
                                "noise_um": k.noise.used_um, "noise_told_um": k.noise.told_um,
                                "frame_noise_um": k.noise.measured_um, "frame_noise_dof": k.noise.dof});
                if let Some(f) = full {
                    j["cs_vs_full"] = diff_stats(&k.values_um, &f.values_um);
                }
                if let Some(t) = &t {
                    j["cs_vs_truth"] = diff_stats(&k.values_um, t);
                }
                if k.u_um.len() == k.values_um.len() && !k.u_um.is_empty() {
                    let n = k.u_um.len() as f64;
                    j["cs"]["u_mean_um"] = json!(k.u_um.iter().sum::<f64>() / n);
                    j["cs"]["u_max_um"] = json!(k.u_um.iter().copied().fold(0.0, f64::max));
                    // Share of the grid where the truth lies within ±2u (simulated campaigns).
                    if let Some(t) = t.as_ref().filter(|t| t.len() == k.u_um.len()) {
                        let inside = k
                            .values_um
                            .iter()
                            .zip(t)
                            .zip(&k.u_um)
                            .filter(|((v, t), u)| (*v - *t).abs() <= 2.0 * *u)
                            .count();
                        j["cs_band_coverage"] = json!(inside as f64 / n);
                    }
                }
            }
            if let (Some(f), Some(t)) = (full, &t) {
                j["full_vs_truth"] = diff_stats(&f.values_um, t);
            }
            comps.push(j);
            // The report's view: CS against the full scan and the truth where they exist.
            let reference = cs.and(full).map(|f| f.values_um.clone());
            report_curves.push(ComponentCurve {
                component: comp.name().to_string(),
                grid_um: main.positions_um.clone(),
                reconstructed_um: main.values_um.clone(),
                method: if cs.is_some() {
                    main.method.clone()
                } else {
                    format!("full scan ({})", main.method)
                },
                cv_error_um: main.cv_error_um,
                // Every cycle's samples of that phase: repeated approaches give ISO 230-2 its
                // measured figures (R, s); the curve itself is cycle 0's reconstruction.
                samples: curves
                    .iter()
                    .filter(|k| k.run.phase == main.run.phase && k.component == comp)
                    .flat_map(|k| k.samples.iter().copied())
                    .collect(),
                full_scan_um: reference,
                // ISO 230-2 figures come from these measurements when there are any.
                full_scan_samples: curves
                    .iter()
                    .filter(|k| k.run.phase == Phase::Full && k.component == comp)
                    .flat_map(|k| k.samples.iter().copied())
                    .collect(),
                truth_um: t.clone(),
                u_um: main.u_um.clone(),
            });
            // Curve file with every available column.
            let mut csv = String::from("position_um");
            let mut cols: Vec<&[f64]> = Vec::new();
            if let Some(k) = cs {
                csv.push_str(",cs_um");
                cols.push(&k.values_um);
            }
            if let Some(f) = full {
                csv.push_str(",full_scan_um");
                cols.push(&f.values_um);
            }
            if let Some(t) = &t {
                csv.push_str(",truth_um");
                cols.push(t);
            }
            // Last, so readers of the older columns by position are not disturbed.
            if let Some(k) = cs.filter(|k| k.u_um.len() == k.values_um.len()) {
                csv.push_str(",cs_u_um");
                cols.push(&k.u_um);
            }
            csv.push('\n');
            for (i, p) in main.positions_um.iter().enumerate() {
                csv.push_str(&p.to_string());
                for col in &cols {
                    csv.push_str(&format!(",{:.6}", col[i]));
                }
                csv.push('\n');
            }
            files.push((
                format!("{}.csv", comp.name()),
                "text/csv".into(),
                csv.into_bytes(),
            ));
        }
        let full_st = tally.stat(Phase::Full, a);
        let cs_st = tally.stat(Phase::Cs, a);
        let mut phase_json = serde_json::Map::new();
        for (pi, (phase, st)) in [(Phase::Cs, &cs_st), (Phase::Full, &full_st)]
            .into_iter()
            .enumerate()
        {
            if st.measurements == 0 && st.acquisition_s == 0.0 {
                continue;
            }
            let processing = st.decode_s + proc_s[pi];
            tot[pi][0] += st.measurements as f64;
            tot[pi][1] += st.acquisition_s;
            tot[pi][2] += processing;
            phase_json.insert(
                phase.as_str().into(),
                json!({"measurements": st.measurements, "acquisition_s": st.acquisition_s, "positioning_s": st.positioning_s,
                       "repositioning_s": tally.repositioning_s.get(&stats_key(phase, a)).copied().unwrap_or(0.0),
                       "processing_s": processing,
                       "decode_s": st.decode_s, "reconstruction_s": proc_s[pi], "frames": st.frames,
                       "rejected_frames": st.rejected_frames, "failed_points": st.failed_points,
                       "saved_by_adaptive": st.saved_by_adaptive}),
            );
        }
        let saved = (full_st.acquisition_s > 0.0 && cs_st.acquisition_s > 0.0)
            .then(|| 100.0 * (1.0 - cs_st.acquisition_s / full_st.acquisition_s));
        let drive = |key: &str| -> String {
            comps
                .iter()
                .find(|j| {
                    j["component"]
                        .as_str()
                        .is_some_and(|n| n.ends_with(&format!("_{a}{a}")))
                        && j.get(key).is_some()
                })
                .map(|j| {
                    format!(
                        "{:.3}/{:.3}",
                        j[key]["mean_abs_um"].as_f64().unwrap_or(f64::NAN),
                        j[key]["max_abs_um"].as_f64().unwrap_or(f64::NAN)
                    )
                })
                .unwrap_or_else(|| "-".into())
        };
        let method = comps
            .iter()
            .find_map(|j| j["cs"]["method"].as_str().map(str::to_string))
            .unwrap_or_else(|| "-".into());
        if full_st.measurements > 0 {
            table.push_str(&format!(
                "{:<6} {:<10} {:>7} {:>12} {:>11.2} {:>12} {:>13} {:>13}\n",
                a.as_str().to_uppercase(),
                "full scan",
                full_st.measurements,
                hms(full_st.acquisition_s),
                full_st.decode_s + proc_s[1],
                "",
                "",
                drive_truth_full(&comps, a)
            ));
        }
        if cs_st.measurements > 0 {
            table.push_str(&format!(
                "{:<6} {:<10} {:>7} {:>12} {:>11.2} {:>12} {:>13} {:>13}\n",
                a.as_str().to_uppercase(),
                format!("CS {method}"),
                cs_st.measurements,
                hms(cs_st.acquisition_s),
                cs_st.decode_s + proc_s[0],
                saved.map_or("-".into(), |s| format!("{s:.2}")),
                drive("cs_vs_full"),
                drive("cs_vs_truth"),
            ));
        }
        // Adaptive runs: where each stopped, on what estimate, and how many targets that saved.
        let mut adaptive = Vec::new();
        for b in plan
            .batches
            .iter()
            .filter(|b| b.run.axis == a && b.index == 0)
        {
            let Some(d) = tally.adaptive.get(&b.run.label()) else {
                continue;
            };
            let planned: usize = plan.run_batches(b.run).map(|b| b.targets.len()).sum();
            let stop = d["stop"].as_bool() == Some(true);
            let m = if stop {
                d["m"].as_u64()
            } else {
                Some(planned as u64)
            };
            let saved_targets = m.map(|m| planned as u64 - m.min(planned as u64));
            table.push_str(&format!(
                "adaptive {}: {} at m = {} of {planned} (band {} µm, estimate {} µm, target {} µm), {} targets saved\n",
                b.run.label(),
                if stop { "stopped" } else { "whole design" },
                m.map_or("-".into(), |m| m.to_string()),
                d["band_error_um"].as_f64().map_or("-".into(), |e| format!("{e:.4}")),
                d["error_estimate_um"].as_f64().map_or("-".into(), |e| format!("{e:.4}")),
                d["target_error_um"].as_f64().map_or("-".into(), |e| format!("{e}")),
                saved_targets.map_or("-".into(), |n| n.to_string()),
            ));
            adaptive.push(
                json!({"run": b.run.label(), "direction": b.run.direction.as_str(),
                "cycle": b.run.cycle, "planned": planned, "stopped": stop, "m": m,
                "saved_targets": saved_targets, "target_error_um": d["target_error_um"],
                "error_estimate_um": d["error_estimate_um"], "scatter_um": d["scatter_um"],
                "cv_error_um": d["cv_error_um"], "band_error_um": d["band_error_um"],
                "u_mean_um": d["u_mean_um"], "true_error_um": d["true_error_um"]}),
            );
        }
        // `other_at_um`: where the line's static axis stood; a two-axis compensation needs it
        // to take that axis's own error back out of the line's curves.
        let mut axis_json = json!({"axis": a.as_str(), "grid_points": ax.grid.n, "phases": phase_json,
                              "acquisition_saved_pct": saved, "components": comps,
                              "other_at_um": ax.other_at_um});
        if !adaptive.is_empty() {
            axis_json["adaptive"] = Value::Array(adaptive);
        }
        axes_json.push(axis_json);
    }
    let total_saved =
        (tot[1][1] > 0.0 && tot[0][1] > 0.0).then(|| 100.0 * (1.0 - tot[0][1] / tot[1][1]));
    let total_saved_all = (tot[1][1] > 0.0 && tot[0][1] > 0.0)
        .then(|| 100.0 * (1.0 - (tot[0][1] + tot[0][2]) / (tot[1][1] + tot[1][2])));
    if let Some(s) = total_saved {
        table.push_str(&format!(
            "total: CS {} measurements in {} vs full scan {} in {}: acquisition time saved {s:.2} % (measurements saved {:.2} %)\n",
            tot[0][0],
            hms(tot[0][1]),
            tot[1][0],
            hms(tot[1][1]),
            100.0 * (1.0 - tot[0][0] / tot[1][0].max(1.0))
        ));
    }
    // The σ each curve used, where the frames measured one (several frames a point) or the
    // held-out residuals lowered the told one.
    for k in curves.iter().filter(|k| k.run.phase == Phase::Cs) {
        let n = &k.noise;
        if n.measured_um.is_none() && !n.changed() {
            continue;
        }
        let frames = n.measured_um.map_or(String::new(), |f| {
            format!(", frames show {f:.4} µm ({} degrees of freedom)", n.dof)
        });
        table.push_str(&format!(
            "noise {} {}: told {} µm{frames}: {}\n",
            k.component.name(),
            k.run.label(),
            n.told_um,
            if n.changed() {
                format!("reconstructed with {:.4} µm", n.used_um)
            } else {
                "the told σ kept".into()
            }
        ));
    }
    // Plots, compensation tables and ISO 230-2 figures; a report failure leaves the rest intact.
    let mut iso = Value::Null;
    let mut report_error = None;
    // Checked at validation; a stored campaign of an older csmetro has the defaults.
    let mut budget = c.spec().uncertainty.inputs().unwrap_or_default();
    // The sensor's repeatability (what a measured row's one approach is worth) told below what
    // the measured runs' frames show is raised to it, as a curve's σ is (`crate::noise`).
    let told_sensor = budget.sensor_u_um;
    for k in curves
        .iter()
        .filter(|k| k.run.phase == Phase::Full && k.component.measured == k.run.axis)
    {
        let run = samples.iter().filter(|s| s.target.run == k.run);
        let f = crate::noise::noise_floor(told_sensor, run, k.component.measured);
        budget.sensor_u_um = budget.sensor_u_um.max(f.used_um);
    }
    if budget.sensor_u_um > told_sensor {
        table.push_str(&format!(
            "sensor repeatability (ISO 230-2 budget): told {told_sensor} µm, the full scan's frames \
             show {:.4} µm: used\n",
            budget.sensor_u_um
        ));
    }
    let opts = ReportOptions {
        budget,
        ..ReportOptions::default()
    };
    let mut iso_figures = Vec::new();
    match report_files(&report_curves, &opts) {
        Ok((rf, figures)) => {
            for f in rf {
                if f.name == "iso230.json" {
                    iso = serde_json::from_slice(&f.bytes).unwrap_or(Value::Null);
                }
                files.push((f.name, f.content_type.to_string(), f.bytes));
            }
            iso_figures = figures;
        }
        Err(e) => report_error = Some(e.to_string()),
    }
    match iso_chart_files(&iso_figures, &opts.plot) {
        Ok(charts) => files.extend(
            charts
                .into_iter()
                .map(|f| (f.name, f.content_type.to_string(), f.bytes)),
        ),
        Err(e) => report_error = Some(e.to_string()),
    }
    table.push_str(&iso_text(&iso_figures));
    for p in problems {
        table.push_str(&format!("error: {p}\n"));
    }
    let summary = json!({
        "id": id,
        "name": &c.spec().campaign.name,
        "stage": c.spec().campaign.stage,
        "state": if problems.is_empty() { "done" } else { "failed" },
        "errors": problems,
        "wall_s": wall_s,
        "samples": samples.len(),
        "axes": axes_json,
        "total": {
            "cs": {"measurements": tot[0][0] as u64, "acquisition_s": tot[0][1], "processing_s": tot[0][2]},
            "full": {"measurements": tot[1][0] as u64, "acquisition_s": tot[1][1], "processing_s": tot[1][2]},
            "acquisition_saved_pct": total_saved,
            // What the counts alone would save: the rest of the gap is the CS moves' longer travel.
            "measurements_saved_pct": (tot[1][0] > 0.0 && tot[0][0] > 0.0).then(|| 100.0 * (1.0 - tot[0][0] / tot[1][0])),
            "acquisition_and_processing_saved_pct": total_saved_all,
        },
        "iso230": iso,
        "report_error": report_error,
        "units": {"position": "µm", "error": "µm (measured - target)", "time": "s"},
    });
    files.push((
        "summary.json".into(),
        "application/json".into(),
        serde_json::to_vec_pretty(&summary).unwrap_or_default(),
    ));
    files.push((
        "summary.txt".into(),
        "text/plain".into(),
        table.clone().into_bytes(),
    ));
    // One layout for every samples file (crate::samples::LAYOUT): any command reads it.
    let mut sc = crate::samples::layout_header();
    for s in samples {
        sc.push_str(&crate::samples::layout_row(s, None));
    }
    files.push(("samples.csv".into(), "text/csv".into(), sc.into_bytes()));
    Report {
        summary,
        table,
        iso: iso_figures,
        files,
    }
}

fn drive_truth_full(comps: &[Value], a: AxisId) -> String {
    comps
        .iter()
        .find(|j| {
            j["component"]
                .as_str()
                .is_some_and(|n| n.ends_with(&format!("_{a}{a}")))
                && j.get("full_vs_truth").is_some()
        })
        .map(|j| {
            format!(
                "{:.3}/{:.3}",
                j["full_vs_truth"]["mean_abs_um"]
                    .as_f64()
                    .unwrap_or(f64::NAN),
                j["full_vs_truth"]["max_abs_um"]
                    .as_f64()
                    .unwrap_or(f64::NAN)
            )
        })
        .unwrap_or_else(|| "-".into())
}

/// Ground truth of a simulated campaign, detached from the rig.
pub struct TruthSource {
    model: Option<Arc<csmetro_sim::StageModel>>,
}

impl TruthSource {
    pub fn new(rig: &Rig, _c: &Campaign) -> Self {
        Self {
            model: rig.truth.clone(),
        }
    }

    /// Noise-free planar truth at every point of a map grid (x fastest), both axes approached
    /// in `direction`: e_x, e_y (µm) and the carriage's rotation θ (µrad).
    pub fn map_truth(
        &self,
        g: &crate::recon2d::Grid2,
        direction: crate::types::Direction,
    ) -> Option<[Vec<f64>; 3]> {
        let m = self.model.as_ref()?;
        let d = direction.sign();
        let mut t = [(); 3].map(|_| Vec::with_capacity(g.len()));
        for j in 0..g.y.n {
            for i in 0..g.x.n {
                let (x, y) = (g.x.position(i), g.y.position(j));
                let v = m.deviation_2d(x, y, d, d, 0.0);
                t[0].push(v.x_um);
                t[1].push(v.y_um);
                t[2].push(m.rotation_urad_2d(x, y));
            }
        }
        Some(t)
    }

    /// Noise-free error of a component at each (target_x, target_y): the stage's planar truth,
    /// the moving axis approached in its run's direction and the static one from below (as
    /// the engine places it), so the static axis's own error at `other_at_um` is in it.
    pub fn curve(&self, curve: &Curve, other_at_um: f64) -> Option<Vec<f64>> {
        self.line(curve.run, curve.component, &curve.positions_um, other_at_um)
    }

    /// [`TruthSource::curve`] of `component` of `run` at `positions_um`.
    pub fn line(
        &self,
        run: RunKey,
        component: Component,
        positions_um: &[f64],
        other_at_um: f64,
    ) -> Option<Vec<f64>> {
        let m = self.model.as_ref()?;
        let d = run.direction.sign();
        Some(
            positions_um
                .iter()
                .map(|&p| {
                    let v = match run.axis {
                        AxisId::X => m.deviation_2d(p, other_at_um, d, 1.0, 0.0),
                        AxisId::Y => m.deviation_2d(other_at_um, p, 1.0, d, 0.0),
                    };
                    match component.measured {
                        AxisId::X => v.x_um,
                        AxisId::Y => v.y_um,
                    }
                })
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn marker(d: &Path) -> Value {
        serde_json::from_slice(&std::fs::read(d.join(MARKER)).unwrap()).unwrap()
    }

    #[test]
    fn a_results_folder_belongs_to_one_campaign_of_one_store() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path().join("it-1");
        // New: claimed and marked.
        assert_eq!(claim_out_dir(&d, "aaaa", 1, "it").unwrap(), d);
        assert_eq!(marker(&d)["store_id"], "aaaa");
        assert_eq!(marker(&d)["campaign"], 1);
        std::fs::write(d.join("summary.json"), "{}").unwrap();
        // The same campaign again (a resume that finishes): its own folder.
        assert_eq!(claim_out_dir(&d, "aaaa", 1, "it").unwrap(), d);
        // Campaign 1 of another store: never this folder; the store is in the other's name.
        let other = claim_out_dir(&d, "bbbb", 1, "it").unwrap();
        assert_eq!(other, tmp.path().join("it-1.store-bbbb-c1"));
        assert_eq!(marker(&other)["store_id"], "bbbb");
        assert_eq!(marker(&d)["store_id"], "aaaa", "first owner's marker kept");
        assert_eq!(claim_out_dir(&d, "bbbb", 1, "it").unwrap(), other);
        // Another campaign of the same store (a template without {id}): its own fallback.
        let c2 = claim_out_dir(&d, "aaaa", 2, "it").unwrap();
        assert_eq!(c2, tmp.path().join("it-1.store-aaaa-c2"));
        // Results nobody marked (an older csmetro's): kept, the new ones go beside them.
        let old = tmp.path().join("old");
        std::fs::create_dir_all(&old).unwrap();
        std::fs::write(old.join("summary.json"), "{}").unwrap();
        let beside = claim_out_dir(&old, "aaaa", 3, "it").unwrap();
        assert_eq!(beside, tmp.path().join("old.store-aaaa-c3"));
        assert!(!old.join(MARKER).exists());
        // Both folders taken by others: refused, the results stay in the store.
        std::fs::write(beside.join(MARKER), r#"{"store_id":"cccc","campaign":3}"#).unwrap();
        let e = claim_out_dir(&old, "aaaa", 3, "it").unwrap_err();
        assert!(e.to_string().contains("results not written"), "{e}");
        // An empty existing folder is free.
        let empty = tmp.path().join("empty");
        std::fs::create_dir_all(&empty).unwrap();
        assert_eq!(claim_out_dir(&empty, "aaaa", 4, "it").unwrap(), empty);
    }

    #[test]
    fn the_service_writes_below_its_results_dir_whatever_the_template() {
        let r = Path::new("/var/lib/csmetro/results");
        assert_eq!(
            service_outputs(r, "{name}-{id}"),
            "/var/lib/csmetro/results/{name}-{id}"
        );
        assert_eq!(
            service_outputs(r, "/home/op/out/{name}/{id}"),
            "/var/lib/csmetro/results/{name}/{id}"
        );
        assert_eq!(
            service_outputs(r, "/home/op/out/fixed"),
            "/var/lib/csmetro/results/fixed"
        );
        assert_eq!(
            service_outputs(r, "/home/op/{name}-{id}/../x"),
            "/var/lib/csmetro/results/{name}-{id}/x"
        );
    }
}
