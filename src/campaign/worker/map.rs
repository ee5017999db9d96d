//! The worker's job for a map run: the samples' errors (measured − target on x and y, θ)
//! reconstructed over the whole grid by [`crate::recon2d::reconstruct`].
use crate::campaign::spec::MapPlan;
use crate::recon2d::{reconstruct, Grid2, Map, MapSamples, Report2};
use crate::types::{AxisId, RunKey, SampleRecord};

/// A reconstructed map of one run.
#[derive(Debug, Clone)]
pub struct MapResult {
    pub run: RunKey,
    pub map: Map,
    pub report: Report2,
    pub samples: MapSamples,
}

/// The samples of map run `run` (the last one stored per grid point): errors in µm, θ in µrad.
pub fn map_samples(g: &Grid2, run: RunKey, samples: &[SampleRecord]) -> MapSamples {
    let mut by_idx = std::collections::BTreeMap::new();
    for s in samples.iter().filter(|s| s.target.run == run) {
        by_idx.insert(s.target.grid_index, s);
    }
    let nx = g.x.n;
    let mut m = MapSamples {
        theta: Some(Vec::new()),
        ..MapSamples::default()
    };
    for (&k, s) in &by_idx {
        m.ix.push(k % nx);
        m.iy.push(k / nx);
        m.ex.push(s.error_um(AxisId::X));
        m.ey.push(s.error_um(AxisId::Y));
        if let Some(t) = m.theta.as_mut() {
            t.push(s.theta_mrad * 1000.0);
        }
    }
    m
}

/// The worker's job when a map run is complete.
pub fn reconstruct_run(
    mp: &MapPlan,
    run: RunKey,
    samples: &[SampleRecord],
) -> Result<MapResult, super::ReconError> {
    let s = map_samples(&mp.grid, run, samples);
    let (map, report) =
        reconstruct(&mp.grid, &s, mp.method).map_err(|reason| super::ReconError::Map {
            direction: run.direction.as_str(),
            reason,
        })?;
    Ok(MapResult {
        run,
        map,
        report,
        samples: s,
    })
}
