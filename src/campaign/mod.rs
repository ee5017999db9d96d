//! Campaigns: plans as data (a TOML file), the acquisition engine that runs them on any
//! hardware behind the `csmetro-hal` traits, and the reconstruction worker.
pub mod attempt;
pub mod compensate;
pub mod engine;
pub mod error;
pub mod events;
pub mod map;
pub mod motion;
pub mod plan;
pub mod preflight;
pub mod results;
pub mod rig;
pub mod session;
pub mod spec;
pub mod stagelock;
pub mod verification;
pub mod verify;
pub mod worker;

// The campaign vocabulary lives below campaign, store and report (`crate::types`).
pub use crate::types::*;
