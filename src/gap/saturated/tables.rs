//! The ISO tables of a data set (a moving axis at one static position, its measured
//! component, repeated bidirectional cycles) and their least-squares fits and sums of squares.
#[allow(clippy::wildcard_imports)]
use super::*;

pub(super) fn key(v: f64) -> i64 {
    super::super::design::key_um(v)
}

pub(super) fn build_tables(
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

pub(super) fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Slope and intercept of y on x, with Σ(x − x̄)² and the residual sum of squares.
pub(super) fn line(x: &[f64], y: &[f64]) -> Option<(f64, f64, f64, f64)> {
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
    pub(super) fn h(&self, o: &Obs, shape: Shape, timing: Timing) -> f64 {
        let t = match timing {
            Timing::Continuous => o.t,
            Timing::PerCycle => self.cycle_time[o.cycle],
        };
        match shape {
            Shape::Linear => (t - self.t0) / 3600.0,
            Shape::Settling(tau) => (-(t - self.t0) / tau).exp(),
        }
    }

    pub(super) fn s(&self, x: f64) -> f64 {
        map_to_unit(x, self.travel)
    }

    /// Cell sums over the kept cycles.
    pub(super) fn cell_means(
        &self,
        keep: &dyn Fn(usize) -> bool,
        hcol: Option<&[f64]>,
    ) -> CellSums {
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

    pub(super) fn hcol(&self, d: Option<(Shape, Timing)>) -> Option<Vec<f64>> {
        d.map(|(s, t)| self.obs.iter().map(|o| self.h(o, s, t)).collect())
    }

    pub(super) fn fit(&self, keep: &dyn Fn(usize) -> bool, drift: Option<(Shape, Timing)>) -> Fit {
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

    pub(super) fn terms(&self, f: &Fit, named: &Named, o: &Obs, h: Option<f64>) -> f64 {
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
    pub(super) fn loco(&self, named: &Named) -> (f64, usize) {
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

    pub(super) fn loco_rms(&self, named: &Named) -> f64 {
        let (s, n) = self.loco(named);
        (s / n.max(1) as f64).sqrt()
    }

    /// Residual sum of squares and degrees of freedom of the saturated model with free cycle
    /// offsets (the pure error), and the sum of squares the free offsets explain.
    pub(super) fn pure_error(&self) -> (f64, f64, f64) {
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
    pub(super) fn drift_ss(&self, shape: Shape, timing: Timing) -> (f64, f64) {
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

    pub(super) fn iso_r(&self, f: Option<(&Fit, Shape, Timing)>) -> Option<f64> {
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
