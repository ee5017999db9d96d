//! Synthetic problems from the simulator's stage model: a paper-like truth and noisy samples.
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use csmetro_sim::{error_curve, paper_like_model, ReferenceCurveParams};
use csmetro_sim::{AxisId, StageModel};

use crate::grid::Grid;
use crate::samples::GridSamples;
use crate::sampling::Design;

/// A generated X-forward error curve with its model and a sampled, noisy subset.
pub struct SynthProblem {
    pub model: StageModel,
    /// Noise-free error at every grid point, µm.
    pub truth: Vec<f64>,
    pub samples: GridSamples,
}

/// Why a synthetic problem could not be built.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// The design's own reason (the metrology crate reports it in text).
    #[error("{0}")]
    Design(String),
    #[error(transparent)]
    Noise(#[from] rand_distr::NormalError),
}

/// Builds the truth from `curve_seed`, samples it with `design` and adds N(0, noise_um²).
pub fn problem(
    grid: &Grid,
    curve_seed: u64,
    params: &ReferenceCurveParams,
    design: &Design,
    noise_um: f64,
) -> Result<SynthProblem, SynthError> {
    let model = paper_like_model(curve_seed, params);
    let truth = error_curve(&model, AxisId::X, &grid.positions(), 0.0);
    let idx = design.indices(grid.n).map_err(SynthError::Design)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(design.seed ^ 0x05ee_d0f0_015e);
    let noise = Normal::new(0.0, noise_um.max(0.0))?;
    let values = idx
        .iter()
        .map(|&i| truth[i] + noise.sample(&mut rng))
        .collect();
    Ok(SynthProblem {
        model,
        truth,
        samples: GridSamples { idx, values },
    })
}

/// Recovery error statistics of g against f (µm): mean |g-f|, max |g-f|, std of g-f.
pub fn error_stats(g: &[f64], f: &[f64]) -> (f64, f64, f64) {
    let n = f.len() as f64;
    let d: Vec<f64> = g.iter().zip(f).map(|(a, b)| a - b).collect();
    let mean_abs = d.iter().map(|v| v.abs()).sum::<f64>() / n;
    let max_abs = d.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let mean = d.iter().sum::<f64>() / n;
    let std = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    (mean_abs, max_abs, std)
}
