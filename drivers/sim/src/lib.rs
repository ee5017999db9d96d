//! The simulator: one stage model (effect library) and the simulated devices built on it.
pub mod camera;
pub mod controller;
pub mod model;
pub mod reference;
pub mod stage;

pub use model::{AxisId, Deviation, Effect, EffectKind, SampleContext, StageModel};
