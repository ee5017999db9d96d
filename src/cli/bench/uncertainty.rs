//! `bench uncertainty`: do the ISO 230-2 figures' expanded uncertainties U (k = 2) cover the
//! simulator's truth? Over `seeds` simulated characterisations of the paper-like X axis (the
//! simulator's model, a backlash of 0.5–3 µm added so B and M mean something):
//! - `cs`: the campaign's path — a random design of m targets per direction, noise σ, `auto`
//!   with its band, ISO 230-2 estimated from the reconstruction (A = E there), against the
//!   figures of the noise-free curves on the same grid;
//! - `cycles`: an ISO 230-2 test — 11 targets with random offsets, 5 approaches per direction,
//!   noise σ (repeatability), against the figures of the noise-free deviations at those targets
//!   (A with the true σ: max(x + 2σ) − min(x − 2σ)).
//!
//! The budget's systematic lines (pitch, misalignment) are set to 0 here: the simulated camera
//! has neither, so only the data's own u is judged.
use std::time::Instant;

use csmetro_sim::{paper_like_model, Effect, EffectKind, ReferenceCurveParams, SampleContext};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::grid::Grid;
use crate::iso230::{evaluate, Approach};
use crate::iso_uncertainty::{iso_uncertainty, measured_row_u, BudgetInputs};
use crate::recon::{self, ReconSettings};
use crate::report::{iso230_axis_with, ComponentCurve};
use crate::samples::GridSamples;
use crate::sampling::{Design, DesignKind};
use crate::types::{AxisId, Component, Direction};

/// Coverage of one figure by its U over the seeds.
#[derive(Debug, Clone, Default, Serialize)]
pub(super) struct Cover {
    /// Share of seeds with |estimate − truth| ≤ U.
    pub(super) coverage: f64,
    /// Mean U and mean |estimate − truth|, µm.
    pub(super) mean_expanded_um: f64,
    pub(super) mean_abs_error_um: f64,
    pub(super) n: usize,
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct Report {
    pub(super) seeds: u64,
    pub(super) m: usize,
    pub(super) noise_um: f64,
    pub(super) cs_e: Cover,
    pub(super) cs_a: Cover,
    pub(super) cs_b: Cover,
    pub(super) cs_m: Cover,
    pub(super) cycles_e: Cover,
    pub(super) cycles_a: Cover,
    pub(super) cycles_b: Cover,
    pub(super) cycles_m: Cover,
    pub(super) wall_s: f64,
}

#[derive(Default)]
struct Acc(Vec<(f64, f64)>);

impl Acc {
    fn push(&mut self, est: f64, truth: f64, expanded: f64) {
        if est.is_finite() && truth.is_finite() && expanded.is_finite() {
            self.0.push(((est - truth).abs(), expanded));
        }
    }
    fn cover(&self) -> Cover {
        let n = self.0.len().max(1) as f64;
        Cover {
            coverage: self.0.iter().filter(|(d, u)| d <= u).count() as f64 / n,
            mean_expanded_um: self.0.iter().map(|p| p.1).sum::<f64>() / n,
            mean_abs_error_um: self.0.iter().map(|p| p.0).sum::<f64>() / n,
            n: self.0.len(),
        }
    }
}

fn truth_at(model: &csmetro_sim::StageModel, p: f64, forward: bool) -> f64 {
    let c = SampleContext {
        moving: csmetro_sim::AxisId::X,
        direction: if forward { 1.0 } else { -1.0 },
        target_x_um: p,
        target_y_um: 0.0,
        time_s: 0.0,
    };
    model.deviation(&c).get(csmetro_sim::AxisId::X)
}

pub(super) fn run(
    seeds: u64,
    m: usize,
    noise_um: f64,
    cs: bool,
    cycles: bool,
) -> anyhow::Result<Report> {
    let t0 = Instant::now();
    let inputs = BudgetInputs {
        sensor_u_um: noise_um,
        pitch_u_ppm: 0.0,
        misalignment_mrad: 0.0,
        ..BudgetInputs::default()
    };
    let noise = Normal::new(0.0, noise_um).map_err(anyhow::Error::msg)?;
    let mut c = [(); 4].map(|_| Acc::default());
    let mut y = [(); 4].map(|_| Acc::default());
    for seed in 0..seeds {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x1502 ^ seed);
        let mut model = paper_like_model(seed, &ReferenceCurveParams::default());
        model.push(Effect::new(
            csmetro_sim::AxisId::X,
            EffectKind::Backlash {
                reversal_um: rng.random_range(0.5..3.0),
            },
        ));
        let mut sim = Sim {
            model: &model,
            noise_um,
            noise: &noise,
            rng: &mut rng,
            inputs: &inputs,
        };
        if cs {
            sim.cs_path(seed, m, &mut c)?;
        }
        if cycles {
            sim.cycles_path(&mut y)?;
        }
    }
    let [cs_e, cs_a, cs_b, cs_m] = c.map(|a| a.cover());
    let [cycles_e, cycles_a, cycles_b, cycles_m] = y.map(|a| a.cover());
    Ok(Report {
        seeds,
        m,
        noise_um,
        cs_e,
        cs_a,
        cs_b,
        cs_m,
        cycles_e,
        cycles_a,
        cycles_b,
        cycles_m,
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

/// One simulated stage and what both paths share.
struct Sim<'a> {
    model: &'a csmetro_sim::StageModel,
    noise_um: f64,
    noise: &'a Normal<f64>,
    rng: &'a mut rand_chacha::ChaCha8Rng,
    inputs: &'a BudgetInputs,
}

impl Sim<'_> {
    /// The CS path: one random design per direction, `auto` with its band; E, A, B, M.
    fn cs_path(&mut self, seed: u64, m: usize, acc: &mut [Acc; 4]) -> anyhow::Result<()> {
        let grid: Grid = "0:5:9500".parse().map_err(anyhow::Error::msg)?;
        let positions = grid.positions();
        let mut curves = Vec::new();
        let mut truth_ap = Vec::new();
        for (k, forward) in [true, false].into_iter().enumerate() {
            let truth: Vec<f64> = positions
                .iter()
                .map(|&p| truth_at(self.model, p, forward))
                .collect();
            let design = Design::new(DesignKind::Random, m, 7000 + 2 * seed + k as u64);
            let idx = design.indices(grid.n).map_err(anyhow::Error::msg)?;
            let values = idx
                .iter()
                .map(|&i| truth[i] + self.noise.sample(self.rng))
                .collect();
            let samples = GridSamples { idx, values };
            let measured: Vec<(f64, f64)> = samples
                .idx
                .iter()
                .zip(&samples.values)
                .map(|(&i, &v)| (positions[i], v))
                .collect();
            let s = ReconSettings {
                noise_um: self.noise_um,
                ..Default::default()
            };
            let r = recon::reconstruct(&grid, &samples, &s)?;
            let direction = if forward {
                Direction::Forward
            } else {
                Direction::Backward
            };
            curves.push(ComponentCurve {
                component: Component {
                    moving: AxisId::X,
                    direction,
                    measured: AxisId::X,
                }
                .name(),
                grid_um: positions.clone(),
                reconstructed_um: r.values,
                method: r.method,
                cv_error_um: r.cv_error_um,
                samples: measured,
                full_scan_um: None,
                full_scan_samples: Vec::new(),
                truth_um: None,
                u_um: r.u_um,
            });
            truth_ap.extend(positions.iter().zip(&truth).map(|(&p, &d)| Approach {
                target_um: p,
                forward,
                deviation_um: d,
            }));
        }
        let fig = iso230_axis_with(AxisId::X, &curves, 1e-3, self.inputs)
            .map_err(anyhow::Error::msg)?
            .ok_or_else(|| anyhow::anyhow!("no ISO 230-2 figures"))?;
        let truth = evaluate(&truth_ap, 1e-3).ok_or_else(|| anyhow::anyhow!("no truth figures"))?;
        if let Some(u) = &fig.uncertainty {
            let r = fig.reported();
            acc[0].push(r.e_um, truth.e_um, u.e.expanded_um);
            acc[1].push(r.a_um, truth.a_um, u.a.expanded_um);
            if let (Some(b), Some(tb), Some(ub)) = (r.b_um, truth.b_um, &u.b) {
                acc[2].push(b, tb, ub.expanded_um);
            }
            if let (Some(v), Some(tv), Some(uv)) = (r.m_um, truth.m_um, &u.m) {
                acc[3].push(v, tv, uv.expanded_um);
            }
        }
        Ok(())
    }

    /// ISO 230-2 cycles: 11 targets with random offsets, 5 approaches per direction.
    fn cycles_path(&mut self, acc: &mut [Acc; 4]) -> anyhow::Result<()> {
        let step = 9500.0 / 11.0;
        let targets: Vec<f64> = (0..11)
            .map(|i| (i as f64 * step + self.rng.random_range(0.0..0.3 * step)).round())
            .collect();
        let mut meas = Vec::new();
        let mut exact = Vec::new();
        for &p in &targets {
            for forward in [true, false] {
                let d = truth_at(self.model, p, forward);
                exact.push(Approach {
                    target_um: p,
                    forward,
                    deviation_um: d,
                });
                for _ in 0..5 {
                    meas.push(Approach {
                        target_um: p,
                        forward,
                        deviation_um: d + self.noise.sample(self.rng),
                    });
                }
            }
        }
        let est = evaluate(&meas, 1e-3).ok_or_else(|| anyhow::anyhow!("no figures"))?;
        let t = evaluate(&exact, 1e-3).ok_or_else(|| anyhow::anyhow!("no truth figures"))?;
        let u = iso_uncertainty(
            &est,
            &est.rows,
            &measured_row_u(&est.rows, self.noise_um),
            self.inputs,
        );
        acc[0].push(est.e_um, t.e_um, u.e.expanded_um);
        // The true A of a process with repeatability σ at every target.
        acc[1].push(est.a_um, t.e_um + 4.0 * self.noise_um, u.a.expanded_um);
        if let (Some(b), Some(tb), Some(ub)) = (est.b_um, t.b_um, &u.b) {
            acc[2].push(b, tb, ub.expanded_um);
        }
        if let (Some(v), Some(tv), Some(uv)) = (est.m_um, t.m_um, &u.m) {
            acc[3].push(v, tv, uv.expanded_um);
        }
        Ok(())
    }
}
