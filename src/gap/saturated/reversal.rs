//! Backlash, hysteresis, scale and cyclic tests of one table's fit.
#[allow(clippy::wildcard_imports)]
use super::*;

/// Backlash, hysteresis and scale tests of one fit (`corrected`: with the drift removed).
#[allow(clippy::too_many_arguments)]
pub(super) fn push_reversal_scale(
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
pub(super) fn cyclic_fit(m: &[(f64, f64)], period: f64) -> Option<(f64, f64, f64, f64, f64)> {
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
