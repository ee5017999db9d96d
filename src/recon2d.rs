//! The XY error map (`csmetro_metrology::recon2d`) and its files: the mathematics lives in the
//! pure crate, reading and writing files stays here in the service.
use std::path::Path;

pub use csmetro_metrology::recon2d::*;

/// Largest samples file read: a few % of a full map is a few MB; 4 M rows of ~60 bytes fit.
pub const MAX_MAP_SAMPLES_BYTES: u64 = 256 << 20;

/// Reads `x_um,y_um,ex_um,ey_um[,theta_urad]`; every error is one line naming file and line.
pub fn read_map_samples_csv(
    path: &Path,
    g: &Grid2,
) -> Result<MapSamples, crate::samples::SamplesFileError> {
    use crate::samples::SamplesFileError;
    let text = crate::tomlpos::read_bounded(path, MAX_MAP_SAMPLES_BYTES)
        .map_err(SamplesFileError::read(path))?;
    parse_map_samples_csv(&text, g).map_err(SamplesFileError::line(path))
}

/// Writes the map with the samples' header at every grid point, x fastest.
pub fn write_map_csv(path: &Path, g: &Grid2, map: &Map) -> std::io::Result<()> {
    use std::io::Write;
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    write_map(&mut w, g, map)?;
    w.flush()
}
