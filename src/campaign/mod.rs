//! Campaigns: plans as data (a TOML file), the acquisition engine that runs them on any
//! hardware behind the `csmetro-hal` traits, and the reconstruction worker.
pub mod types;

pub use types::*;
