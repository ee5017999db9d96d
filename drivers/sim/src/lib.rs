#![doc = include_str!("../README.md")]
pub mod camera;
pub mod controller;
pub mod model;
pub mod reference;
pub mod stage;

pub use model::{AxisId, Deviation, Effect, EffectKind, SampleContext, StageModel};
