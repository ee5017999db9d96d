//! csmetro: compressive-sensing characterization of micropositioning stages.
// The mathematics is its own crate (no runtime, store or drivers); its modules keep their
// `csmetro::` paths. `recon2d` and `samples` add the file readers and writers here.
pub use csmetro_metrology::{grid, iso230, iso_uncertainty, recon, sampling, sampling2d};

pub mod api;
pub mod campaign;
pub mod cli;
pub mod compensation;
pub mod export;
pub mod gap;
pub mod noise;
pub mod recon2d;
pub mod report;
pub mod samples;
pub mod store;
pub mod synth;
mod tomlpos;
/// Why a bounded file read failed (samples, tables, TOML files).
pub use tomlpos::ReadError;
pub mod types;
