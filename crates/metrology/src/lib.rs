#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`).

// The modules stay public: the service and its tests reach into them (`recon::periods`,
// `recon2d::physics`, ...). The names below are the short list a reader starts from.
pub mod grid;
pub mod iso230;
pub mod iso_uncertainty;
pub mod recon;
pub mod recon2d;
pub mod samples;
pub mod sampling;
pub mod sampling2d;

pub use grid::Grid;
pub use iso230::{Approach, Iso230Summary, TargetRow};
pub use iso_uncertainty::{Budget, BudgetInputs, IsoUncertainty};
pub use recon::{reconstruct, Method, ReconSettings, Reconstruction, Solver};
pub use recon2d::{Grid2, Map, MapSamples, Method2, Report2};
pub use samples::GridSamples;
pub use sampling::{Design, DesignKind};
pub use sampling2d::{Design2, Design2Kind};
