#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]
pub mod camera;
pub mod controller;
pub mod model;
pub mod reference;
pub mod stage;

pub use model::{AxisId, Deviation, Effect, EffectKind, SampleContext, StageModel};
