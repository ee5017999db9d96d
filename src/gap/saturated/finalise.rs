//! A table's decomposition decided: effects named (Holm, then the held-out check), their
//! stage-model effects, and what the table cannot resolve.
#[allow(clippy::wildcard_imports)]
use super::*;

pub(super) type TableModel = Option<(f64, f64, f64, (Shape, f64, f64), Timing)>;

pub(super) fn finalise(
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

pub(super) fn corrected(f: &Finding) -> bool {
    f.extra
        .get("drift_corrected")
        .and_then(Json::as_bool)
        .unwrap_or(false)
}

pub(super) fn set(n: &mut Named, f: &Finding, drift: Option<(Shape, Timing)>) {
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

pub(super) fn effect_of(fnd: &Finding, tb: &Table, f: &Fit, shape: Shape) -> Option<Effect> {
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
pub(super) fn cannot_see(
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
