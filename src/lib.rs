//! csmetro: compressive-sensing characterization of micropositioning stages.
pub mod api;
pub mod campaign;
pub mod cli;
pub mod compensation;
pub mod export;
pub mod gap;
pub mod grid;
pub mod iso230;
pub mod recon;
pub mod recon2d;
pub mod report;
pub mod samples;
pub mod sampling;
pub mod sampling2d;
pub mod store;
pub mod synth;
mod tomlpos;
pub mod types;
