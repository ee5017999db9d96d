//! csmetro: compressive-sensing characterization of micropositioning stages.
pub mod cli;
pub mod grid;
pub mod recon;
pub mod samples;
pub mod sampling;
pub mod synth;
