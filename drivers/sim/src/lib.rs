#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]
// Modules are private; the curated list below is the crate's API.
mod camera;
mod controller;
mod reference;
mod stage;

pub use camera::{PositionSource, SimCamera};
pub use controller::soak::{soak_gcs, BindingCheck, SoakOptions, SoakReport};
pub use controller::{
    remove_stale_links, Controller, ControllerConfig, Endpoint, Exchange, Fault, FaultCounts,
    FaultSpec, Outcome, RandomFaults, SimController, AXIS, GARBAGE, MAX_RANDOM_FAULT_MS, TRACE_ENV,
};
// The stage model is its own crate (csmetro-effects, shared with `csmetro gap`); re-exported.
pub use csmetro_effects::{
    legendre, map_to_unit, AxisId, Component, Deviation, Direction, Effect, EffectKind, ModelError,
    SampleContext, StageModel, LIBRARY_KINDS, MAX_EFFECTS, MAX_TERMS, MAX_TRAVEL_UM,
    SIM_ONLY_KINDS,
};
pub use reference::{error_curve, paper_like_model, ReferenceCurveParams};
pub use stage::{
    check_time_scale, AxisState, Motion, MotionKind, Profile, SimClock, SimStage, MAX_TIME_SCALE,
    MIN_TIME_SCALE,
};
