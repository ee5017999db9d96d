//! The reconstruction worker: its own thread, fed samples as they are committed; when a run's
//! data are complete it reconstructs both components the run measures (e.g. ef_xx and ef_xy
//! for x forward), off the acquisition path.
use std::collections::BTreeMap;
use std::sync::mpsc;
use std::thread::JoinHandle;

use serde::Serialize;

use super::spec::Campaign;
use crate::grid::Grid;
use crate::recon::{reconstruct, Method, ReconSettings};
use crate::samples::GridSamples;
use crate::types::{Component, Phase, RunKey, SampleRecord};

/// A reconstructed (CS) or measured (full scan) curve of one component of one run.
#[derive(Debug, Clone, Serialize)]
pub struct Curve {
    pub run: RunKey,
    pub component: Component,
    pub positions_um: Vec<f64>,
    pub values_um: Vec<f64>,
    pub method: String,
    pub cv_error_um: Option<f64>,
    pub solve_ms: f64,
    /// The measured samples (position, error), µm.
    pub samples: Vec<(f64, f64)>,
}

impl Curve {
    pub fn csv(&self) -> String {
        let mut s = String::from("position_um,error_um\n");
        for (p, v) in self.positions_um.iter().zip(&self.values_um) {
            s.push_str(&format!("{p},{v:.6}\n"));
        }
        s
    }
}

enum Msg {
    Sample(SampleRecord),
    RunDone(RunKey),
}

/// Reconstructs the components of `run` from its samples.
pub fn reconstruct_run(
    grid: &Grid,
    settings: &ReconSettings,
    run: RunKey,
    samples: &[SampleRecord],
) -> Vec<Result<Curve, String>> {
    let mut by_idx: BTreeMap<usize, &SampleRecord> = BTreeMap::new();
    for s in samples.iter().filter(|s| s.target.run == run) {
        by_idx.insert(s.target.grid_index, s);
    }
    run.components()
        .into_iter()
        .map(|component| {
            let gs = GridSamples {
                idx: by_idx.keys().copied().collect(),
                values: by_idx
                    .values()
                    .map(|s| s.error_um(component.measured))
                    .collect(),
            };
            let mut st = settings.clone();
            if run.phase == Phase::Full {
                // The full scan is the curve; failed points (if any) are bridged linearly.
                st.method = Method::Linear;
            }
            let r = reconstruct(grid, &gs, &st)
                .map_err(|e| format!("{} of {}: {e}", component.name(), run.label()))?;
            Ok(Curve {
                run,
                component,
                positions_um: grid.positions(),
                values_um: r.values,
                method: r.method,
                cv_error_um: r.cv_error_um,
                solve_ms: r.solve_ms,
                samples: gs
                    .idx
                    .iter()
                    .zip(&gs.values)
                    .map(|(&i, &v)| (grid.position(i), v))
                    .collect(),
            })
        })
        .collect()
}

pub fn settings(c: &Campaign) -> ReconSettings {
    let r = &c.spec.reconstruction;
    ReconSettings {
        method: c.method,
        solver: c.solver,
        noise_um: r.noise_um,
        pitch_um: Some(r.pitch_um),
        ..ReconSettings::default()
    }
}

/// The maps the worker reconstructed (`[map]` runs), filled as each map run completes.
pub type Maps = std::sync::Arc<std::sync::Mutex<Vec<Result<super::map::MapResult, String>>>>;

/// Handle of the worker thread.
pub struct Worker {
    tx: mpsc::Sender<Msg>,
    handle: JoinHandle<Vec<Curve>>,
    maps: Maps,
}

impl Worker {
    /// Starts the worker; `on_curve` is called (on the worker thread) for each finished curve
    /// or failed reconstruction.
    pub fn start(
        c: &Campaign,
        mut on_curve: impl FnMut(Result<&Curve, String>) + Send + 'static,
    ) -> Worker {
        let grids: BTreeMap<_, Grid> = c.axes.iter().map(|a| (a.axis, a.grid)).collect();
        let settings = settings(c);
        let map_plan = c.map.clone();
        let maps = Maps::default();
        let maps2 = maps.clone();
        let (tx, rx) = mpsc::channel::<Msg>();
        let handle = std::thread::Builder::new()
            .name("csmetro-recon".into())
            .spawn(move || {
                let mut samples: Vec<SampleRecord> = Vec::new();
                let mut curves = Vec::new();
                let mut done = std::collections::BTreeSet::new();
                while let Ok(m) = rx.recv() {
                    match m {
                        Msg::Sample(s) => samples.push(s),
                        Msg::RunDone(run) => {
                            if !done.insert(run) {
                                continue;
                            }
                            if let (Phase::Map, Some(mp)) = (run.phase, &map_plan) {
                                let r = super::map::reconstruct_run(mp, run, &samples);
                                maps2.lock().unwrap_or_else(|p| p.into_inner()).push(r);
                                continue;
                            }
                            let Some(grid) = grids.get(&run.axis) else {
                                continue;
                            };
                            for r in reconstruct_run(grid, &settings, run, &samples) {
                                match r {
                                    Ok(c) => {
                                        on_curve(Ok(&c));
                                        curves.push(c);
                                    }
                                    Err(e) => on_curve(Err(e)),
                                }
                            }
                        }
                    }
                }
                curves
            })
            .expect("spawn the reconstruction worker");
        Worker { tx, handle, maps }
    }

    /// The maps reconstructed so far (all of them once [`Worker::finish`] returned).
    pub fn maps(&self) -> Maps {
        self.maps.clone()
    }

    pub fn sample(&self, s: &SampleRecord) {
        let _ = self.tx.send(Msg::Sample(*s));
    }

    pub fn run_done(&self, run: RunKey) {
        let _ = self.tx.send(Msg::RunDone(run));
    }

    /// Waits for the queued work and returns every curve.
    pub fn finish(self) -> Vec<Curve> {
        drop(self.tx);
        self.handle.join().unwrap_or_default()
    }
}
