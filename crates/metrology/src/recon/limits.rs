//! Sizes a reconstruction is asked to solve, bounded so that a mistyped grid is refused at once
//! instead of running for hours or exhausting memory.
use super::{Method, ReconError, Solver};

/// Largest grid basis pursuit (`bp`, `bpdn`) is asked to solve: n = 65 536 at 10 % sampling
/// takes < 1 s (BENCHMARKS.md), a grid of millions of points would take hours.
pub const MAX_BP_POINTS: usize = 65_536;
/// Largest grid the physics model (`physics`, `auto`) fits; its design matrix has a row per
/// grid point.
pub const MAX_PHYSICS_POINTS: usize = 262_144;
/// Largest n·m given to the interior-point solver (`clarabel`): its constraint matrix holds
/// every entry of the sampled basis (n = 1901, m = 600 is 1.1 million).
pub const MAX_CLARABEL_ENTRIES: usize = 4_000_000;

/// Whether `method` (with `solver`) may reconstruct `m` samples on an `n`-point grid in bounded
/// time and memory; the error says which limit and how to get below it.
pub fn check_solve_size(
    method: Method,
    solver: Solver,
    n: usize,
    m: usize,
) -> Result<(), ReconError> {
    match method {
        Method::Bp | Method::Bpdn if n > MAX_BP_POINTS => Err(ReconError::GridTooLarge {
            method: method.as_str(),
            n,
            limit: MAX_BP_POINTS,
        }),
        Method::Bp | Method::Bpdn
            if solver == Solver::Clarabel && n.saturating_mul(m) > MAX_CLARABEL_ENTRIES =>
        {
            Err(ReconError::SolverTooLarge {
                n,
                m,
                limit: MAX_CLARABEL_ENTRIES,
            })
        }
        Method::Physics | Method::Auto if n > MAX_PHYSICS_POINTS => Err(ReconError::GridTooLarge {
            method: method.as_str(),
            n,
            limit: MAX_PHYSICS_POINTS,
        }),
        _ => Ok(()),
    }
}
