//! A campaign file (TOML): hardware, axes, sampling, acquisition, reconstruction, outputs.
//! Parsed and validated completely before anything moves; every error names the file, the
//! line and the key.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use csmetro_camera::CameraConfig;
use csmetro_gcs::C863Config;
use csmetro_ppp::{Optics, PatternConfig};
use serde::{Deserialize, Serialize};

use crate::grid::Grid;
use crate::recon::{Method, Solver};
use crate::sampling::DesignKind;
pub use crate::tomlpos::TomlError;
use crate::tomlpos::{io_reason, line_of, read_bounded, span_of, MAX_TOML_BYTES};
use crate::types::{AxisId, Direction};

/// A campaign file as written.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignSpec {
    pub campaign: Meta,
    pub hardware: Hardware,
    /// `[axes.x]`, `[axes.y]`: the axes to characterize, in that order (none for a `[map]`). A
    /// verification (`[campaign] verify = ID`) has none: it measures the characterisation's.
    #[serde(default)]
    pub axes: BTreeMap<String, AxisSpec>,
    #[serde(default)]
    pub sampling: Sampling,
    #[serde(default)]
    pub acquisition: Acquisition,
    #[serde(default)]
    pub reconstruction: Reconstruction,
    #[serde(default)]
    pub outputs: Outputs,
    /// `[compensation]`: run the whole campaign compensated (see [`crate::compensation`]).
    #[serde(default)]
    pub compensation: Option<CompensationSpec>,
    /// `[map]`: an XY workspace map (see [`map`]).
    #[serde(default)]
    pub map: Option<MapSpec>,
    /// `[uncertainty]`: the ISO 230-2 uncertainty budget's inputs.
    #[serde(default)]
    pub uncertainty: UncertaintySpec,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Meta {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// The stage this campaign runs on; one campaign runs per stage at a time.
    #[serde(default = "default_stage")]
    pub stage: String,
    /// `verify = ID`: this campaign verifies stored characterisation ID with its compensation
    /// (see [`crate::campaign::verification`]); its axes are the characterisation's.
    #[serde(default)]
    pub verify: Option<i64>,
}

fn default_stage() -> String {
    "xy".into()
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HardwareKind {
    /// Simulated C-863s (over a pty or TCP) and a simulated camera: no hardware needed.
    Sim,
    /// PI C-863 controllers on serial ports (or terminal servers) and a camera through Aravis
    /// (GigE / USB3 Vision) or libdc1394 (FireWire IIDC), `[hardware.camera] backend`.
    Real,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hardware {
    pub kind: HardwareKind,
    /// The PPP pattern on the stage.
    #[serde(default)]
    pub pattern: PatternConfig,
    /// Optics of the camera as the decoder sees them (pixel pitch, magnification, frame size).
    #[serde(default)]
    pub optics: Optics,
    /// Settings of the simulation (`kind = "sim"`).
    #[serde(default)]
    pub sim: SimHardware,
    /// Controllers of the real axes (`kind = "real"`), `[hardware.controllers.x]`.
    #[serde(default)]
    pub controllers: BTreeMap<String, C863Config>,
    /// The real camera (`kind = "real"`; its `backend`'s cargo feature must be built in).
    #[serde(default)]
    pub camera: Option<CameraConfig>,
    /// Longest reference move, s.
    #[serde(default = "default_reference_timeout_s")]
    pub reference_timeout_s: f64,
    /// Longest wait for on-target after a move, s.
    #[serde(default = "default_move_timeout_s")]
    pub move_timeout_s: f64,
}

fn default_reference_timeout_s() -> f64 {
    60.0
}
fn default_move_timeout_s() -> f64 {
    20.0
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SimTransport {
    /// A pseudo-terminal the driver opens like a serial device.
    Pty,
    /// TCP on 127.0.0.1.
    Tcp,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimHardware {
    /// Stage model TOML (relative to the campaign file); the simulator's ground truth.
    pub model: Option<String>,
    /// Simulated time runs this many times faster than wall time.
    pub time_scale: f64,
    pub transport: SimTransport,
    /// Physical time one frame takes (exposure + readout + transfer), s.
    pub frame_time_s: f64,
    /// Optics the simulated camera renders with; defaults to `[hardware.optics]`.
    pub render_optics: Option<Optics>,
    /// Seed of the camera noise and of the model's white measurement noise.
    pub seed: u64,
    /// Travel of the simulated controllers (`TMN?`, `TMX?`), mm. A C-863 can place its zero
    /// anywhere in the 15 mm of an M-111.1DG; `[-1, 14]` leaves room to approach 0 from below.
    pub travel_mm: [f64; 2],
    /// Soft limits of the simulated axes, µm (x, y).
    pub soft_limits_x_um: [f64; 2],
    pub soft_limits_y_um: [f64; 2],
    /// Controller velocity, mm/s (GCS units) and acceleration, mm/s². The M-111.1DG datasheet
    /// gives 1.5 mm/s; its acceleration is not published. The default (50 mm/s², 1.5 mm/s
    /// reached in 30 ms) is calibrated on the rig's one timing record, the paper's Table III: it
    /// spent the same time per point (3.00 s, ±1 % from the rounding of the hours) on 600 random
    /// targets ~32 µm apart as on 3801 targets 5 µm apart, which the simulated rig reproduces
    /// from ~50 mm/s² on (CS/full time per point 1.031 at 5, 1.013 at 30, 1.010 at 50 mm/s²;
    /// BENCHMARKS.md).
    pub velocity_mm_s: f64,
    pub acceleration_mm_s2: f64,
    /// `[hardware.sim.faults]`: random faults of both simulated controllers (soaks); each axis
    /// draws from its own seed, derived from `seed` here.
    pub faults: Option<csmetro_sim::RandomFaults>,
}

impl Default for SimHardware {
    fn default() -> Self {
        Self {
            model: None,
            time_scale: 1000.0,
            transport: SimTransport::Pty,
            frame_time_s: 0.1,
            render_optics: None,
            seed: 1,
            travel_mm: [-1.0, 14.0],
            soft_limits_x_um: [-500.0, 13_500.0],
            soft_limits_y_um: [-500.0, 13_500.0],
            velocity_mm_s: 1.5,
            acceleration_mm_s2: 50.0,
            faults: None,
        }
    }
}

/// One axis to characterize.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisSpec {
    /// Grid `[start, end]`, µm, and its step, µm.
    #[serde(deserialize_with = "exactly_two")]
    pub range_um: [f64; 2],
    pub step_um: f64,
    /// Where the other axis stands while this one is characterized, µm.
    pub other_at_um: f64,
    /// Overrides of `[sampling]` for this axis.
    #[serde(default)]
    pub m: Option<usize>,
    #[serde(default)]
    pub fraction: Option<f64>,
    #[serde(default)]
    pub target_error_um: Option<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Sampling {
    /// random | jittered | full
    pub design: DesignKind,
    /// Measurements per run (one direction of one cycle), or a fraction of the grid.
    pub m: Option<usize>,
    pub fraction: Option<f64>,
    pub seed: u64,
    /// Adaptive mode: measure in batches until the cross-validated error estimate is at most
    /// this (µm); `m` (or `fraction`) is then the budget.
    pub target_error_um: Option<f64>,
    /// Adaptive batch size (first batch: `batch`, then `batch` more each time).
    pub batch: usize,
    /// Also measure the full scan (every grid point) to compare against.
    pub full_scan: bool,
}

impl Default for Sampling {
    fn default() -> Self {
        Self {
            design: DesignKind::Random,
            m: None,
            fraction: None,
            seed: 1,
            target_error_um: None,
            batch: 50,
            full_scan: false,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Acquisition {
    pub directions: Vec<Direction>,
    pub cycles: u32,
    /// Wait after on-target before the frame, s.
    pub settle_s: f64,
    /// Extra dwell per point (e.g. thermal), s.
    pub dwell_s: f64,
    /// Frames decoded and averaged per point.
    pub frames_per_point: u32,
    /// Attempts at a rejected frame before the point fails.
    pub max_retries: u32,
    /// Pre-travel before each run so every target is approached from its run's direction, µm.
    pub approach_um: f64,
}

impl Default for Acquisition {
    fn default() -> Self {
        Self {
            directions: vec![Direction::Forward, Direction::Backward],
            cycles: 1,
            settle_s: 0.5,
            dwell_s: 0.0,
            frames_per_point: 1,
            max_retries: 3,
            approach_um: 50.0,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Reconstruction {
    pub method: String,
    pub solver: String,
    /// Sensor noise σ, µm.
    pub noise_um: f64,
    /// Leadscrew pitch, µm, if known: a hint the physics model weighs against the periods it
    /// finds in the samples (none by default: nothing assumes the simulator's 400 µm).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pitch_um: Option<f64>,
}

impl Default for Reconstruction {
    fn default() -> Self {
        Self {
            method: "auto".into(),
            solver: "fast".into(),
            noise_um: 0.01,
            pitch_um: None,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Outputs {
    /// Where result files go (relative to the working directory); `{id}` and `{name}` expand.
    pub dir: String,
    pub plots: bool,
    /// Also write the campaign as a NeXus file (`<name>-<id>.nxs`) with the results; needs a
    /// build with `--features nexus`.
    pub nexus: bool,
}

impl Default for Outputs {
    fn default() -> Self {
        Self {
            dir: "csmetro-results/{name}-{id}".into(),
            plots: true,
            nexus: false,
        }
    }
}

/// `[start, end]` and nothing else: a third number is a mistake, not something to drop.
fn exactly_two<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
    let v: Vec<f64> = Vec::deserialize(d)?;
    <[f64; 2]>::try_from(v.as_slice())
        .map_err(|_| serde::de::Error::invalid_length(v.len(), &"exactly 2 numbers [start, end]"))
}

/// A validation error pointing into the campaign file (`file:line: key: message`).
pub type SpecError = TomlError;

/// Longest campaign or stage name; both end up in file names (outputs, stage locks).
pub const MAX_NAME_LEN: usize = 64;
/// Longest description.
pub const MAX_DESCRIPTION_LEN: usize = 4096;
/// Most measurements one campaign may plan (all axes, directions, cycles, full scans).
pub const MAX_PLANNED: u64 = 10_000_000;
/// Longest path written in a campaign file.
const MAX_PATH_LEN: usize = 1024;

/// Who wrote a campaign file, and so what it may name.
#[derive(Debug, Clone)]
pub enum Trust {
    /// `csmetro run FILE`: the operator's own file. Paths are local, relative ones resolve from
    /// `base_dir` (the file's directory); files are still size-limited and regular-only.
    Local { base_dir: PathBuf },
    /// Sent to the service by a client: it names files only inside the directories the service
    /// allows and writes only below its results directory; errors show neither server paths
    /// nor file contents.
    Submitted(SubmitPolicy),
    /// Read back from the store to run or resume: validated when it was recorded, its stage
    /// model is the text snapshot taken then (`model_toml`), never the file again (a file
    /// swapped in meanwhile changes nothing). Stores from before snapshots (`None`) read the
    /// file as [`Trust::Local`] does.
    Stored {
        base_dir: PathBuf,
        model_toml: Option<String>,
    },
}

/// What a submitted campaign may read and write (from the service configuration).
#[derive(Debug, Clone)]
pub struct SubmitPolicy {
    /// Where relative paths in submitted files resolve (`[campaigns] base_dir`).
    pub base_dir: PathBuf,
    /// Directories a resolved path must stay inside (`base_dir`, `[campaigns] models_dir`).
    pub read_roots: Vec<PathBuf>,
    /// `[storage] results_dir`: every output directory is below it.
    pub results_dir: PathBuf,
    /// `[hardware] serial_ports`: the only serial devices a submitted campaign may open.
    pub serial_ports: Vec<String>,
    /// `[hardware] tcp_endpoints`: the only `host:port` a submitted campaign may connect to.
    pub tcp_endpoints: Vec<String>,
}

impl Trust {
    fn base_dir(&self) -> &Path {
        match self {
            Trust::Local { base_dir } | Trust::Stored { base_dir, .. } => base_dir,
            Trust::Submitted(p) => &p.base_dir,
        }
    }
}

/// A validated campaign: the spec plus what it resolves to. Immutable: built only by its
/// constructors (which validate), read through its accessors.
#[derive(Debug, Clone)]
pub struct Campaign {
    spec: CampaignSpec,
    /// The file text as given (stored with the campaign, so a resume runs the same plan).
    text: String,
    origin: String,
    /// Directory of the campaign file (relative paths in it resolve from here).
    base_dir: PathBuf,
    axes: Vec<AxisPlan>,
    method: Method,
    solver: Solver,
    /// `[map]`, resolved.
    map: Option<MapPlan>,
    /// The simulator's stage model as validated (`[hardware.sim] model`), with the text it was
    /// read from: the rig runs this one, and the store keeps the text with the campaign.
    model: Option<Arc<LoadedModel>>,
}

/// A stage model read and checked at validation.
#[derive(Debug)]
pub struct LoadedModel {
    pub model: csmetro_sim::StageModel,
    /// The TOML it was parsed from (stored with the campaign: a resume runs the same truth).
    pub text: String,
}

/// One axis, resolved.
#[derive(Debug, Clone)]
pub struct AxisPlan {
    pub axis: AxisId,
    pub grid: Grid,
    pub other_at_um: f64,
    /// Measurements per CS run.
    pub m: usize,
    pub target_error_um: Option<f64>,
}

impl Campaign {
    /// Reads and validates a campaign file of the local operator (`csmetro run FILE`): at most
    /// 1 MiB, a regular file; its output directory must be writable (checked by creating it and
    /// writing a probe file, both removed again).
    pub fn load(path: &Path) -> Result<Campaign, SpecError> {
        let origin = path.display().to_string();
        let text = read_bounded(path, MAX_TOML_BYTES).map_err(|e| SpecError {
            origin: origin.clone(),
            line: 0,
            key: "-".into(),
            message: format!("cannot read: {e}"),
        })?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let c = Campaign::parse(&text, &origin, &base)?;
        let fail = |k: &str, m: String| c.error_at(k, m);
        probe_outputs(&c.spec.outputs.dir, None, &fail)?;
        Ok(c)
    }

    /// Parses and validates campaign text of the local operator; `origin` names it in errors,
    /// relative paths resolve from `base_dir`.
    pub fn parse(text: &str, origin: &str, base_dir: &Path) -> Result<Campaign, SpecError> {
        Campaign::parse_with(
            text,
            origin,
            &Trust::Local {
                base_dir: base_dir.to_path_buf(),
            },
        )
    }

    /// Validates a campaign a client submitted to the service: files only by name inside the
    /// policy's directories, outputs below its results directory (created and probed).
    pub fn parse_submitted(
        text: &str,
        origin: &str,
        policy: &SubmitPolicy,
    ) -> Result<Campaign, SpecError> {
        let trust = Trust::Submitted(policy.clone());
        let c = Campaign::parse_with(text, origin, &trust)?;
        let fail = |k: &str, m: String| c.error_at(k, m);
        probe_outputs(&c.spec.outputs.dir, Some(&policy.results_dir), &fail)?;
        Ok(c)
    }

    /// Parses and validates campaign text in a trust context.
    pub fn parse_with(text: &str, origin: &str, trust: &Trust) -> Result<Campaign, SpecError> {
        let c = Campaign::parse_inner(text, origin, trust)?;
        c.check_camera_backend_compiled()?;
        Ok(c)
    }

    /// A campaign read back from the store: `model_toml` is the stage model's snapshot taken
    /// when it was recorded (None: a store from before snapshots; the file is read).
    pub fn parse_stored(
        text: &str,
        origin: &str,
        base_dir: &Path,
        model_toml: Option<String>,
    ) -> Result<Campaign, SpecError> {
        Campaign::parse_with(
            text,
            origin,
            &Trust::Stored {
                base_dir: base_dir.to_path_buf(),
                model_toml,
            },
        )
    }

    /// Validates a local campaign file as a build with every camera backend would: to check a
    /// lab's file on a machine without the camera libraries. The run paths (`load`, `parse`,
    /// `parse_submitted`) also refuse a camera backend this build lacks.
    pub fn parse_any_build(
        text: &str,
        origin: &str,
        base_dir: &Path,
    ) -> Result<Campaign, SpecError> {
        Campaign::parse_inner(
            text,
            origin,
            &Trust::Local {
                base_dir: base_dir.to_path_buf(),
            },
        )
    }

    /// A `kind = "real"` campaign whose camera backend is not compiled in is refused here,
    /// before anything opens or is stored, naming the cargo feature that builds it.
    fn check_camera_backend_compiled(&self) -> Result<(), SpecError> {
        let h = &self.spec.hardware;
        let (HardwareKind::Real, Some(cam)) = (h.kind, &h.camera) else {
            return Ok(());
        };
        if cam.backend.compiled() {
            return Ok(());
        }
        // Point at the backend key, or at the camera table when the default applies.
        let key = if span_of(&self.text, "hardware.camera.backend").is_some() {
            "hardware.camera.backend"
        } else {
            "hardware.camera"
        };
        Err(self.error_at(
            key,
            format!(
                "hardware.camera.backend = \"{b}\" needs a csmetro built with --features {b}",
                b = cam.backend.name()
            ),
        ))
    }

    fn parse_inner(text: &str, origin: &str, trust: &Trust) -> Result<Campaign, SpecError> {
        if text.len() as u64 > MAX_TOML_BYTES {
            return Err(SpecError {
                origin: origin.into(),
                line: 0,
                key: "-".into(),
                message: format!("larger than {MAX_TOML_BYTES} bytes"),
            });
        }
        let spec: CampaignSpec =
            toml::from_str(text).map_err(|e| TomlError::from_toml(text, origin, &e))?;
        let fail = |path: &str, message: String| SpecError {
            origin: origin.into(),
            line: span_of(text, path)
                .map(|s| line_of(text, s.start))
                .unwrap_or(0),
            key: path.to_string(),
            message,
        };
        let c =
            validate(&spec, trust, &fail).map(|(axes, method, solver, map, model)| Campaign {
                spec,
                text: text.to_string(),
                origin: origin.into(),
                base_dir: trust.base_dir().to_path_buf(),
                axes,
                method,
                solver,
                map,
                model: model.map(Arc::new),
            })?;
        check_compensation(&c, matches!(trust, Trust::Submitted(_)))
            .map_err(|(k, m)| fail(k, m))?;
        Ok(c)
    }

    /// An error at `key` of this campaign's text.
    fn error_at(&self, key: &str, message: String) -> SpecError {
        SpecError {
            origin: self.origin.clone(),
            line: span_of(&self.text, key)
                .map(|s| line_of(&self.text, s.start))
                .unwrap_or(0),
            key: key.into(),
            message,
        }
    }

    /// Resolves a path written in the campaign file.
    pub fn resolve(&self, p: &str) -> PathBuf {
        let p = Path::new(p);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.base_dir.join(p)
        }
    }

    pub fn axis(&self, a: AxisId) -> Option<&AxisPlan> {
        self.axes.iter().find(|p| p.axis == a)
    }

    /// The file as written (with a verification's axes resolved).
    pub fn spec(&self) -> &CampaignSpec {
        &self.spec
    }

    /// The file text as given (stored with the campaign, so a resume runs the same plan).
    pub fn text(&self) -> &str {
        &self.text
    }

    /// Where the file came from (a path; errors name it).
    pub fn origin(&self) -> &str {
        &self.origin
    }

    /// Directory of the campaign file (relative paths in it resolve from here).
    pub fn base_dir(&self) -> &Path {
        &self.base_dir
    }

    /// The axes, resolved.
    pub fn axes(&self) -> &[AxisPlan] {
        &self.axes
    }

    pub fn method(&self) -> Method {
        self.method
    }

    pub fn solver(&self) -> Solver {
        self.solver
    }

    /// `[map]`, resolved.
    pub fn map(&self) -> Option<&MapPlan> {
        self.map.as_ref()
    }

    /// The simulator's stage model as validated, with the text it was read from.
    pub fn model(&self) -> Option<&Arc<LoadedModel>> {
        self.model.as_ref()
    }

    /// This verification campaign (`verify = ID`, no axes of its own) measuring the axes of
    /// characterisation `ch`, validated with it: a new campaign, this one is not changed.
    pub fn measuring_axes_of(self, ch: Campaign) -> Campaign {
        let mut spec = self.spec;
        spec.axes = ch.spec.axes;
        Campaign {
            spec,
            axes: ch.axes,
            ..self
        }
    }

    /// This campaign writing its results under `dir` (the service keeps every campaign's
    /// results below its own results directory).
    pub fn with_outputs_dir(self, dir: String) -> Campaign {
        let mut spec = self.spec;
        spec.outputs.dir = dir;
        Campaign { spec, ..self }
    }

    /// This campaign under the name it is stored by (a submitted file's path in the service's
    /// campaigns directory: a resume resolves its relative paths from there).
    pub fn stored_as(self, origin: String) -> Campaign {
        Campaign { origin, ..self }
    }
}

mod compensation;
mod validate;
pub use compensation::{check_spec as check_compensation, fits, CompensationSpec, Misfit};
use validate::validate;
pub mod map;
pub use map::{MapPlan, MapSpec};
mod verification;
pub use verification::{check_verification, DEFAULT_VERIFY_CYCLES, MAX_VERIFY_CYCLES};
mod paths;
mod uncertainty;
use paths::{check_submitted_outputs, load_model, probe_outputs};
pub use uncertainty::UncertaintySpec;

#[cfg(test)]
mod tests;
