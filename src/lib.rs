//! csmetro: compressive-sensing characterization of micropositioning stages.
pub mod cli;
pub mod grid;
pub mod recon;
pub mod sampling;
pub mod samples;
