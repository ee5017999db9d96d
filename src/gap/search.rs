//! The search: greedy forward selection of candidate groups scored by leave-one-run-out
//! cross-validation, gated by position cross-validation and a paired t-test, with ties.
use std::collections::HashMap;

use csmetro_sim::{AxisId, Effect, StageModel};
use nalgebra::{DMatrix, DVector};

use super::candidates::{candidate_groups, generalises, merge_into, Group};
use super::design::{build_columns, paired_t, solve, union, Cv, Design, Rows};
use super::localise::{cell_stats, chi2_z, frequency_map, other_axis_map, where_maps};
use super::report::{Added, Diagnosis, Tie, Unexplained};
use super::{GapError, Options, Sample};

/// Diagnoses the gap between `samples` and `model`.
pub fn diagnose(
    model: &StageModel,
    samples: &[Sample],
    opts: &Options,
) -> Result<Diagnosis, GapError> {
    if let Some(ks) = &opts.kinds {
        for k in ks {
            if k == "noise" || !csmetro_sim::LIBRARY_KINDS.contains(&k.as_str()) {
                return Err(GapError(format!(
                    "unknown candidate kind `{k}` (library: {})",
                    csmetro_sim::LIBRARY_KINDS
                        .iter()
                        .filter(|k| **k != "noise")
                        .copied()
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
        }
    }
    let mut runs: Vec<i64> = samples.iter().map(|s| s.run).collect();
    runs.sort_unstable();
    runs.dedup();
    if runs.len() < 2 {
        return Err(GapError(format!(
            "the data hold a single run ({}): nothing can be held out; at least 2 repeated runs are needed",
            runs.first().copied().unwrap_or(0)
        )));
    }
    let rows = Rows::build(samples, model);
    let mut have: Vec<AxisId> = samples.iter().map(|s| s.moving).collect();
    have.sort();
    have.dedup();
    let mut groups = candidate_groups(model, &have, opts);
    let (cols, scale) = build_columns(samples, model, &rows, &mut groups);
    groups.retain(|g| g.cols.iter().any(Option::is_some));
    let design = Design::new(&rows, cols, scale);

    // σ from repeats on the baseline residual, refined on the final residual below.
    let cs0 = cell_stats(&rows, &rows.y, 0);
    let mut current: Vec<usize> = Vec::new();
    let base_cv = design.cv(&rows, &current);
    let mut cur_cv = base_cv.clone();
    let mut chosen: Vec<usize> = Vec::new();
    let mut steps: Vec<(f64, f64, Vec<Tie>)> = Vec::new();
    let mut used_families: Vec<String> = Vec::new();
    for _ in 0..opts.max_steps {
        let cur_block = design.block_cv(&current);
        let mut evals: Vec<(usize, Vec<usize>, Cv, f64)> = Vec::new();
        let mut gated: Vec<(usize, Cv, f64)> = Vec::new();
        for (gi, g) in groups.iter().enumerate() {
            if chosen.contains(&gi) || used_families.contains(&g.family()) {
                continue;
            }
            let s = union(&current, &g.col_set());
            if s.len() == current.len() {
                continue;
            }
            let cv = design.cv(&rows, &s);
            let t = paired_t(&cur_cv, &cv);
            // Gate: the group must also predict parts of the travel it was not fitted on.
            if t > opts.t_accept && paired_t(&cur_block, &design.block_cv(&s)) <= opts.t_block {
                gated.push((gi, cv, t));
                continue;
            }
            evals.push((gi, s, cv, t));
        }
        let sig: Vec<&(usize, Vec<usize>, Cv, f64)> =
            evals.iter().filter(|e| e.3 > opts.t_accept).collect();
        let Some(best) = sig.iter().min_by(|a, b| a.2.rms.total_cmp(&b.2.rms)) else {
            // Two effects on the same lines can each fail the position gate alone (neither
            // extrapolates without the other): try pairs of the best gated candidates jointly.
            gated.sort_by(|a, b| a.1.rms.total_cmp(&b.1.rms));
            gated.truncate(6);
            let mut best_pair: Option<(usize, usize, Vec<usize>, Cv, f64)> = None;
            for (x, (ga, _, _)) in gated.iter().enumerate() {
                for (gb, _, _) in &gated[x + 1..] {
                    if groups[*ga].family() == groups[*gb].family() {
                        continue;
                    }
                    let s2 = union(
                        &union(&current, &groups[*ga].col_set()),
                        &groups[*gb].col_set(),
                    );
                    let cv = design.cv(&rows, &s2);
                    let t = paired_t(&cur_cv, &cv);
                    if t > opts.t_accept
                        && paired_t(&cur_block, &design.block_cv(&s2)) > opts.t_block
                        && best_pair.as_ref().is_none_or(|b| cv.rms < b.3.rms)
                    {
                        best_pair = Some((*ga, *gb, s2, cv, t));
                    }
                }
            }
            let Some((ga, gb, s2, cv, t)) = best_pair else {
                break;
            };
            let first = gated.iter().find(|g| g.0 == ga).expect("from gated");
            steps.push((first.1.rms, first.2, Vec::new()));
            steps.push((cv.rms, t, Vec::new()));
            for g in [ga, gb] {
                used_families.push(groups[g].family());
                chosen.push(g);
            }
            current = s2;
            cur_cv = cv;
            continue;
        };
        // Parsimony among the candidates the held-out data cannot tell from the best.
        let near: Vec<&&(usize, Vec<usize>, Cv, f64)> = sig
            .iter()
            .filter(|e| e.0 == best.0 || paired_t(&e.2, &best.2) < opts.t_tie)
            .collect();
        let pick = *near
            .iter()
            .min_by(|a, b| {
                (a.1.len(), a.2.rms)
                    .partial_cmp(&(b.1.len(), b.2.rms))
                    .unwrap_or(std::cmp::Ordering::Equal)
            })
            .expect("best is near itself");
        let pg = &groups[pick.0];
        let mut ties: Vec<Tie> = near
            .iter()
            .filter(|e| e.0 != pick.0)
            .filter(|e| {
                let g = &groups[e.0];
                !generalises(g, pg) && !generalises(pg, g) && g.family() != pg.family()
            })
            .map(|e| Tie {
                members: vec![(groups[e.0].kind().into(), groups[e.0].axis_label())],
                heldout_rms_um: Some(e.2.rms),
                reason: "score",
            })
            .collect();
        ties.sort_by_key(|a| a.label());
        ties.dedup_by(|a, b| a.label() == b.label());
        // Span ties: a group or pair of groups that reproduces the pick's fitted deviation.
        let beta = design.fit(&pick.1);
        let pcols = pg.col_set();
        let bvec: Vec<(usize, f64)> = pick
            .1
            .iter()
            .enumerate()
            .filter(|(_, j)| pcols.contains(j) && !current.contains(j))
            .map(|(k, &j)| (j, beta[k]))
            .collect();
        let p = design.p;
        let ff: f64 = bvec
            .iter()
            .flat_map(|&(i, bi)| bvec.iter().map(move |&(j, bj)| (i, j, bi * bj)))
            .map(|(i, j, w)| w * design.gt[i * p + j])
            .sum();
        let reproduces = |extra: &[usize]| -> bool {
            let s = union(&current, extra);
            if ff <= 0.0 || s.is_empty() {
                return false;
            }
            let a = DMatrix::from_fn(s.len(), s.len(), |i, j| design.gt[s[i] * p + s[j]]);
            let c = DVector::from_fn(s.len(), |i, _| {
                bvec.iter()
                    .map(|&(j, bj)| bj * design.gt[s[i] * p + j])
                    .sum()
            });
            let x = solve(a, c.clone());
            let resid = (ff - c.dot(&x)).max(0.0);
            (resid / ff).sqrt() < opts.span_tie
        };
        let others: Vec<usize> = (0..groups.len())
            .filter(|&gi| {
                gi != pick.0
                    && !chosen.contains(&gi)
                    && groups[gi].family() != pg.family()
                    && !generalises(&groups[gi], pg)
                    && !generalises(pg, &groups[gi])
                    && !groups[gi].col_set().iter().all(|j| current.contains(j))
            })
            .collect();
        let mut single_ties = Vec::new();
        for &gi in &others {
            if reproduces(&groups[gi].col_set()) {
                single_ties.push(gi);
            }
        }
        let label_of = |gi: usize| (groups[gi].kind().to_string(), groups[gi].axis_label());
        for &gi in &single_ties {
            let m = vec![label_of(gi)];
            if !ties.iter().any(|t| t.members == m) {
                ties.push(Tie {
                    members: m,
                    heldout_rms_um: None,
                    reason: "span",
                });
            }
        }
        for (x, &gi) in others.iter().enumerate() {
            for &gj in &others[x + 1..] {
                if single_ties.contains(&gi)
                    || single_ties.contains(&gj)
                    || groups[gi].family() == groups[gj].family()
                {
                    continue;
                }
                if reproduces(&union(&groups[gi].col_set(), &groups[gj].col_set())) {
                    ties.push(Tie {
                        members: vec![label_of(gi), label_of(gj)],
                        heldout_rms_um: None,
                        reason: "span",
                    });
                }
            }
        }
        used_families.push(pg.family());
        chosen.push(pick.0);
        current = pick.1.clone();
        cur_cv = pick.2.clone();
        steps.push((pick.2.rms, pick.3, ties));
    }

    // Final joint fit, residual, repeatability and lack of fit.
    let beta = design.fit(&current);
    let e = design.residual(&rows, &current, &beta);
    let cs = cell_stats(&rows, &e, current.len());
    let (sigma2, from_repeats) = if cs.df_pe >= 5.0 && cs.ss_pe > 0.0 {
        (cs.ss_pe / cs.df_pe, true)
    } else {
        (cur_cv.rms.powi(2).max(1e-18), false)
    };
    let sigma = sigma2.sqrt();
    let lof_before_z = chi2_z(cs0.ss_lof / sigma2, cs0.df_lof);
    let lof_z = chi2_z(cs.ss_lof / sigma2, cs.df_lof);
    let (where_before, _) = where_maps(samples, model, &rows, &rows.y, &cs0, sigma2, opts);
    let (where_after, time_z) = where_maps(samples, model, &rows, &e, &cs, sigma2, opts);
    let unexpl_rms = ((cs.ss_lof - cs.df_lof.max(0.0) * sigma2).max(0.0) / rows.n as f64).sqrt();
    let significant = lof_z > opts.z_unexplained || time_z > opts.z_unexplained;

    // Parameters: each column belongs to the first chosen group that has it.
    let mut owner: HashMap<usize, usize> = HashMap::new();
    for &gi in &chosen {
        for j in groups[gi].col_set() {
            owner.entry(j).or_insert(gi);
        }
    }
    let coef_of = |j: usize| -> f64 {
        current
            .iter()
            .position(|&c| c == j)
            .map(|k| beta[k] / design.scale[j])
            .unwrap_or(0.0)
    };
    let before = base_cv.rms;
    let mut updated = model.clone();
    let mut added = Vec::new();
    for (step, &gi) in chosen.iter().enumerate() {
        let g = &groups[gi];
        let c: Vec<f64> = g
            .cols
            .iter()
            .map(|cj| match cj {
                Some(j) if owner.get(j) == Some(&gi) => coef_of(*j),
                _ => 0.0,
            })
            .collect();
        let mut eff = Effect::new(g.axis, g.spec.kind(&c));
        eff.travel_um = g.travel_um;
        merge_into(&mut updated, &eff);
        let (rms, t, ties) = steps[step].clone();
        let denom = before * before - sigma2;
        let gap_closed = if denom > 1e-12 * before * before && denom > 0.0 {
            Some(((before * before - rms * rms) / denom).clamp(0.0, 1.0))
        } else {
            None
        };
        added.push(Added {
            kind: g.kind().into(),
            axis: g.axis_label(),
            effect: eff,
            heldout_rms_um: rms,
            gap_closed,
            t_stat: t,
            ties,
        });
    }
    Ok(Diagnosis {
        n_samples: samples.len(),
        n_runs: rows.n_runs,
        n_lines: rows.n_lines,
        sigma_um: sigma,
        sigma_from_repeats: from_repeats,
        heldout_rms_before_um: before,
        heldout_rms_after_um: cur_cv.rms,
        lack_of_fit_before_z: lof_before_z,
        added,
        where_: where_before,
        frequency: frequency_map(samples, model, &rows, &cs0, sigma2),
        other_axis: other_axis_map(samples, &rows, &cs0, sigma2),
        unexplained: Unexplained {
            significant,
            rms_um: if significant { unexpl_rms } else { 0.0 },
            lack_of_fit_z: lof_z,
            time_z,
            where_: if significant { where_after } else { Vec::new() },
            frequency: if significant {
                frequency_map(samples, model, &rows, &cs, sigma2)
            } else {
                Vec::new()
            },
        },
        model: updated,
        candidates: groups.iter().map(Group::label).collect::<Vec<_>>(),
    })
}
