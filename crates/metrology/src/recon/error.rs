//! Why a curve could not be reconstructed: a bad sample set, a problem too large to solve in
//! bounded time, or a model that does not fit. Callers map these to their exit codes and HTTP
//! statuses; the text is for people, not for decisions.
use thiserror::Error;

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ReconError {
    #[error("need at least 2 samples, got {m}")]
    TooFewSamples { m: usize },
    #[error("more samples ({m}) than grid points ({n})")]
    MoreSamplesThanPoints { m: usize, n: usize },
    #[error("sample indices must be distinct, ascending and on the grid")]
    BadIndices,
    #[error("{method} on {n} grid points: at most {limit} (use a coarser grid, or pchip/linear)")]
    GridTooLarge {
        method: &'static str,
        n: usize,
        limit: usize,
    },
    #[error(
        "the clarabel solver on {n} grid points x {m} samples: at most {limit} (use --solver fast)"
    )]
    SolverTooLarge { n: usize, m: usize, limit: usize },
    #[error("physics model fit failed (singular system)")]
    PhysicsSingular,
}
