//! The map campaign's (`[map]`) results: the estimate of a full grid scan's time and its result
//! files (map CSV, heat maps, a 2D compensation table, ISO 230-1 figures). Its plan batches are
//! [`super::plan::map`], the worker's 2D reconstruction of each map run [`super::worker::map`].
//!
//! A map run visits the design's points (see [`crate::sampling2d`]) with both axes moving; the
//! engine ends every move on each axis in the run's direction (forward: +x and +y) by at least
//! `[acquisition] approach_um`, pre-positioning where the path goes the other way, so every
//! point has a known backlash state. The samples' errors (measured − target on x and y, θ) are
//! reconstructed over the whole grid by [`crate::recon2d::reconstruct`].
use serde_json::{json, Value};

use super::results::{diff_stats, Report, Tally, TruthSource};
use super::rig::trapezoid_s;
use super::spec::{Campaign, MapPlan};
pub use super::worker::map::MapResult;
use crate::recon2d::{write_map, Grid2, Map};
use crate::report::heatmap::{heatmap_png, heatmap_svg, HeatMap};
use crate::report::iso230_1::{iso230_1, iso230_1_text, Iso2301};
use crate::report::{format_hms, PlotOptions};
use crate::types::{AxisId, Phase};

/// Physical time of a full scan of the map's rectangle at `full_scan_step_um` under the same
/// motion model and per-point times as the campaign (s): a raster of rows in +x, each row
/// entered from `approach_um` before its first point (the return from the previous row's end
/// and the approach), one step in +y between rows; per point the move, the controller's
/// settling, `settle_s + dwell_s` and the frames.
pub fn full_scan_estimate_s(c: &Campaign, mp: &MapPlan, motion_settle_s: f64) -> (u64, f64) {
    let h = &c.spec().hardware.sim;
    let a = &c.spec().acquisition;
    let step = mp.full_scan_step_um;
    let (wx, wy) = (
        mp.grid.x.end_um() - mp.grid.x.start_um,
        mp.grid.y.end_um() - mp.grid.y.start_um,
    );
    let (nx, ny) = (
        (wx / step + 1e-9).floor() as u64 + 1,
        (wy / step + 1e-9).floor() as u64 + 1,
    );
    let mv = |d_um: f64| {
        trapezoid_s(d_um / 1000.0, h.velocity_mm_s, h.acceleration_mm_s2) + motion_settle_s
    };
    let point = a.settle_s + a.dwell_s + h.frame_time_s * a.frames_per_point as f64;
    let pre = a.approach_um;
    let row = mv(wx + pre) + mv(pre) + (nx - 1) as f64 * mv(step);
    let total = ny as f64 * row + (ny - 1) as f64 * mv(step) + (nx * ny) as f64 * point;
    (nx * ny, total)
}

/// Adds the map results to a campaign's report: files, summary.json `map`, summary.txt lines.
/// Returns the problems (missing or failed maps).
pub fn add_to_report(
    c: &Campaign,
    maps: &[Result<MapResult, super::worker::ReconError>],
    tally: &Tally,
    truth: &TruthSource,
    motion_settle_s: f64,
    rep: &mut Report,
) -> Vec<String> {
    let Some(mp) = c.map() else {
        return Vec::new();
    };
    let mut problems = Vec::new();
    let mut text = String::new();
    let g = &mp.grid;
    let st = tally.stat(Phase::Map, AxisId::X);
    let (full_n, full_s) = full_scan_estimate_s(c, mp, motion_settle_s);
    let map_s = st.acquisition_s + st.positioning_s;
    let saved = 100.0 * (1.0 - map_s / full_s);
    text.push_str(&format!(
        "map {} x {} ({} x {} µm steps): {} measurements in {} (positioning {}) vs full {} µm grid scan {} points in {} (estimated, same motion model): acquisition time saved {saved:.2} %\n",
        g.x.n, g.y.n, g.x.step_um, g.y.step_um, st.measurements, format_hms(map_s),
        format_hms(st.positioning_s), mp.full_scan_step_um, full_n, format_hms(full_s)
    ));
    let mut runs_json = Vec::new();
    let opts = PlotOptions::default();
    for r in maps {
        let r = match r {
            Ok(r) => r,
            Err(e) => {
                problems.push(format!("map reconstruction failed: {e}"));
                continue;
            }
        };
        let dir = r.run.direction.as_str();
        let mut csv = Vec::new();
        if let Err(e) = write_map(&mut csv, g, &r.map) {
            problems.push(format!("map {dir}: {e}"));
        }
        rep.files
            .push((format!("map_{dir}.csv"), "text/csv".into(), csv));
        rep.files.push((
            format!("compensation_map_{dir}.csv"),
            "text/csv".into(),
            compensation_map_csv(g, &r.map).into_bytes(),
        ));
        let iso = iso230_1(g, &r.map.ex, &r.map.ey);
        text.push_str(&format!(
            "map {dir}: {} ({} samples, cv {:.4} µm, {:.0} ms)\n",
            r.report.method, r.report.m, r.report.cv_error_um, r.report.solve_ms
        ));
        text.push_str(&iso230_1_text(&format!("map {dir}"), &iso));
        let sample_pos: Vec<(f64, f64)> = r
            .samples
            .ix
            .iter()
            .zip(&r.samples.iy)
            .map(|(&i, &j)| (g.x.position(i), g.y.position(j)))
            .collect();
        let mut fields: Vec<(String, String, Vec<f64>)> = vec![
            ("ex".into(), "e_x / µm".into(), r.map.ex.clone()),
            ("ey".into(), "e_y / µm".into(), r.map.ey.clone()),
        ];
        if let Some(t) = &r.map.theta {
            fields.push(("theta".into(), "θ / µrad".into(), t.clone()));
        }
        let mut j = json!({"direction": dir, "method": r.report.method, "m": r.report.m,
            "cv_error_um": r.report.cv_error_um, "solve_ms": r.report.solve_ms,
            "knot_um": r.report.knot_um, "iso230_1": iso_json(&iso),
            "u_ex_mean_um": r.report.u_ex_mean_um, "u_ex_max_um": r.report.u_ex_max_um,
            "u_ey_mean_um": r.report.u_ey_mean_um, "u_ey_max_um": r.report.u_ey_max_um});
        if let Some([tx, ty, tt]) = truth.map_truth(g, r.run.direction) {
            j["vs_truth"] =
                json!({"ex": diff_stats(&r.map.ex, &tx), "ey": diff_stats(&r.map.ey, &ty)});
            // Share of the grid inside ±2u of the truth, per component.
            let cover = |v: &[f64], u: &[f64], t: &[f64]| {
                (u.len() == v.len() && !v.is_empty()).then(|| {
                    let inside = v
                        .iter()
                        .zip(u)
                        .zip(t)
                        .filter(|((v, u), t)| (*v - *t).abs() <= 2.0 * *u)
                        .count();
                    inside as f64 / v.len() as f64
                })
            };
            j["vs_truth"]["ex"]["band_coverage"] = json!(cover(&r.map.ex, &r.map.u_ex, &tx));
            j["vs_truth"]["ey"]["band_coverage"] = json!(cover(&r.map.ey, &r.map.u_ey, &ty));
            j["truth_iso230_1"] = iso_json(&iso230_1(g, &tx, &ty));
            let res = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p - q).collect();
            // The baseline side by side: linear interpolation on a triangulation of the same
            // samples.
            let (lin_x, lin_y) = if r.report.method == "linear" {
                (r.map.ex.clone(), r.map.ey.clone())
            } else {
                let l = crate::recon2d::linear::interpolate(g, &r.samples);
                (l.ex, l.ey)
            };
            j["linear_vs_truth"] =
                json!({"ex": diff_stats(&lin_x, &tx), "ey": diff_stats(&lin_y, &ty)});
            let mm = |v: &Value| {
                format!(
                    "{:.4}/{:.4}",
                    v["mean_abs_um"].as_f64().unwrap_or(f64::NAN),
                    v["max_abs_um"].as_f64().unwrap_or(f64::NAN)
                )
            };
            text.push_str(&format!(
                "map {dir} vs truth (mean/max |error| µm): e_x {}, e_y {}; linear interpolation of the same samples: e_x {}, e_y {}\n",
                mm(&j["vs_truth"]["ex"]),
                mm(&j["vs_truth"]["ey"]),
                mm(&j["linear_vs_truth"]["ex"]),
                mm(&j["linear_vs_truth"]["ey"])
            ));
            fields.push((
                "residual_ex".into(),
                "e_x − truth / µm".into(),
                res(&r.map.ex, &tx),
            ));
            fields.push((
                "residual_ey".into(),
                "e_y − truth / µm".into(),
                res(&r.map.ey, &ty),
            ));
            // θ: the simulated camera renders the carriage's yaw (plus its fixed angle, 0).
            if let Some(t) = &r.map.theta {
                j["vs_truth"]["theta_urad"] = diff_stats(t, &tt);
                text.push_str(&format!(
                    "map {dir} θ vs truth (mean/max |error| µrad): {}\n",
                    mm(&j["vs_truth"]["theta_urad"])
                ));
                fields.push((
                    "residual_theta".into(),
                    "θ − truth / µrad".into(),
                    res(t, &tt),
                ));
            }
        }
        for (name, unit, values) in &fields {
            let h = HeatMap {
                title: format!(
                    "{} ({dir}, {})",
                    unit.split(" / ").next().unwrap_or(name),
                    r.report.method
                ),
                unit: unit.clone(),
                grid: g,
                values,
                samples: &sample_pos,
            };
            let file = format!("plots/map_{dir}_{name}");
            match (heatmap_svg(&h, &opts), heatmap_png(&h, &opts)) {
                (Ok(svg), Ok(png)) => {
                    rep.files.push((
                        format!("{file}.svg"),
                        "image/svg+xml".into(),
                        svg.into_bytes(),
                    ));
                    rep.files
                        .push((format!("{file}.png"), "image/png".into(), png));
                }
                (Err(e), _) | (_, Err(e)) => problems.push(format!("{file}: {e}")),
            }
        }
        runs_json.push(j);
    }
    for d in &mp.directions {
        if !maps
            .iter()
            .any(|r| r.as_ref().is_ok_and(|r| r.run.direction == *d))
            && !maps.iter().any(|r| r.is_err())
        {
            problems.push(format!("map {}: no reconstruction", d.as_str()));
        }
    }
    rep.summary["map"] = json!({
        "nx": g.x.n, "ny": g.y.n, "step_um": [g.x.step_um, g.y.step_um],
        "measurements": st.measurements, "acquisition_s": st.acquisition_s,
        "positioning_s": st.positioning_s, "failed_points": st.failed_points,
        "full_scan_estimate": {"step_um": mp.full_scan_step_um, "points": full_n, "acquisition_s": full_s},
        "acquisition_saved_pct": saved,
        "runs": runs_json,
    });
    if c.axes().is_empty() {
        // No line runs: the line table's two header lines head nothing.
        rep.table = rep
            .table
            .lines()
            .skip(2)
            .map(|l| format!("{l}\n"))
            .collect();
    }
    rep.table.push_str(&text);
    for (name, _, bytes) in rep.files.iter_mut() {
        if name == "summary.json" {
            *bytes = serde_json::to_vec_pretty(&rep.summary).unwrap_or_default();
        } else if name == "summary.txt" {
            *bytes = rep.table.clone().into_bytes();
        }
    }
    problems
}

fn iso_json(f: &Iso2301) -> Value {
    serde_json::to_value(f).unwrap_or(Value::Null)
}

/// The 2D compensation table: `x_um,y_um,corr_x_um,corr_y_um` at every grid point (x fastest),
/// corr = −error: commanding (x + corr_x, y + corr_y) reaches (x, y) to first order, for the
/// map's approach direction.
pub fn compensation_map_csv(g: &Grid2, map: &Map) -> String {
    let mut s = String::from("x_um,y_um,corr_x_um,corr_y_um\n");
    for j in 0..g.y.n {
        for i in 0..g.x.n {
            let k = j * g.x.n + i;
            s.push_str(&format!(
                "{},{},{:.6},{:.6}\n",
                g.x.position(i),
                g.y.position(j),
                -map.ex[k],
                -map.ey[k]
            ));
        }
    }
    s
}
