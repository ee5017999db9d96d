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

/// A validated campaign: the spec plus what it resolves to.
#[derive(Debug, Clone)]
pub struct Campaign {
    pub spec: CampaignSpec,
    /// The file text as given (stored with the campaign, so a resume runs the same plan).
    pub text: String,
    pub origin: String,
    /// Directory of the campaign file (relative paths in it resolve from here).
    pub base_dir: PathBuf,
    pub axes: Vec<AxisPlan>,
    pub method: Method,
    pub solver: Solver,
    /// `[map]`, resolved.
    pub map: Option<MapPlan>,
    /// The simulator's stage model as validated (`[hardware.sim] model`), with the text it was
    /// read from: the rig runs this one, and the store keeps the text with the campaign.
    pub model: Option<Arc<LoadedModel>>,
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
}

type Validated = (
    Vec<AxisPlan>,
    Method,
    Solver,
    Option<MapPlan>,
    Option<LoadedModel>,
);

/// A campaign or stage name: it becomes part of file names, so a short plain word.
fn check_name(v: &str) -> Result<(), String> {
    if v.trim().is_empty() {
        return Err("must not be empty".into());
    }
    if v.len() > MAX_NAME_LEN {
        return Err(format!("must be at most {MAX_NAME_LEN} characters"));
    }
    let plain = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    if !v.starts_with(|c: char| c.is_ascii_alphanumeric()) || !v.chars().all(plain) {
        return Err(
            "may hold only letters, digits, `-`, `_` and `.`, and starts with a letter or digit"
                .into(),
        );
    }
    Ok(())
}

fn validate(
    spec: &CampaignSpec,
    trust: &Trust,
    fail: &dyn Fn(&str, String) -> SpecError,
) -> Result<Validated, SpecError> {
    let pos = |v: f64| v.is_finite() && v > 0.0;
    let nonneg = |v: f64| v.is_finite() && v >= 0.0;
    check_name(&spec.campaign.name).map_err(|e| fail("campaign.name", e))?;
    check_name(&spec.campaign.stage).map_err(|e| fail("campaign.stage", e))?;
    if spec.campaign.description.len() > MAX_DESCRIPTION_LEN {
        return Err(fail(
            "campaign.description",
            format!("must be at most {MAX_DESCRIPTION_LEN} bytes"),
        ));
    }
    if let Some(id) = spec.campaign.verify {
        check_verification(spec, id).map_err(|(k, m)| fail(k, m))?;
    } else if spec.axes.is_empty() && spec.map.is_none() {
        return Err(fail(
            "axes",
            "no axis to characterize: add [axes.x] and/or [axes.y] (or a [map])".into(),
        ));
    }
    let h = &spec.hardware;
    let mut model = None;
    if !pos(h.reference_timeout_s) {
        return Err(fail("hardware.reference_timeout_s", "must be > 0 s".into()));
    }
    if !pos(h.move_timeout_s) {
        return Err(fail("hardware.move_timeout_s", "must be > 0 s".into()));
    }
    h.optics
        .validate()
        .map_err(|e| fail("hardware.optics", e))?;
    csmetro_ppp::Pattern::new(h.pattern.clone())
        .map_err(|e| fail("hardware.pattern", e.to_string()))?;
    let limits_of = |a: AxisId| -> Result<(f64, f64), SpecError> {
        match h.kind {
            HardwareKind::Sim => {
                let l = match a {
                    AxisId::X => h.sim.soft_limits_x_um,
                    AxisId::Y => h.sim.soft_limits_y_um,
                };
                Ok((l[0], l[1]))
            }
            HardwareKind::Real => h
                .controllers
                .get(a.as_str())
                .map(|c| c.soft_limits_um)
                .ok_or_else(|| {
                    fail(
                        "hardware.controllers",
                        format!("no controller for axis {a} ([hardware.controllers.{a}])"),
                    )
                }),
        }
    };
    match h.kind {
        HardwareKind::Sim => {
            let s = &h.sim;
            if let Err(m) = csmetro_sim::check_time_scale(s.time_scale) {
                return Err(fail("hardware.sim.time_scale", m));
            }
            if !nonneg(s.frame_time_s) {
                return Err(fail("hardware.sim.frame_time_s", "must be ≥ 0 s".into()));
            }
            if !(pos(s.velocity_mm_s) && s.velocity_mm_s <= 1.5) {
                return Err(fail(
                    "hardware.sim.velocity_mm_s",
                    "must be in (0, 1.5] mm/s (M-111.1DG)".into(),
                ));
            }
            if !(pos(s.acceleration_mm_s2) && s.acceleration_mm_s2 <= 200.0) {
                return Err(fail(
                    "hardware.sim.acceleration_mm_s2",
                    "must be in (0, 200] mm/s²".into(),
                ));
            }
            if let Some(o) = &s.render_optics {
                o.validate()
                    .map_err(|e| fail("hardware.sim.render_optics", e))?;
            }
            if let Some(f) = &s.faults {
                let rate = |v: f64| (0.0..=1.0).contains(&v);
                let rates = [
                    f.delay_rate,
                    f.drop_rate,
                    f.garbage_rate,
                    f.error_rate,
                    f.vanish_rate,
                ];
                if !rates.into_iter().all(rate) {
                    return Err(fail(
                        "hardware.sim.faults",
                        "every *_rate must be in [0, 1]".into(),
                    ));
                }
                let [lo, hi] = f.delay_ms;
                if !(lo <= hi && hi <= 60_000 && f.vanish_ms <= 60_000) {
                    return Err(fail(
                        "hardware.sim.faults",
                        "delay_ms = [lo, hi] with lo <= hi and vanish_ms at most 60000 ms".into(),
                    ));
                }
            }
            if let Some(m) = &s.model {
                model = Some(load_model(m, trust).map_err(|e| fail("hardware.sim.model", e))?);
            }
            let [tlo, thi] = s.travel_mm;
            if !(tlo.is_finite() && thi.is_finite() && tlo < thi && thi - tlo <= 15.0) {
                return Err(fail(
                    "hardware.sim.travel_mm",
                    "must be [lo, hi] mm with lo < hi and at most 15 mm (M-111.1DG)".into(),
                ));
            }
            for (k, l) in [
                ("hardware.sim.soft_limits_x_um", s.soft_limits_x_um),
                ("hardware.sim.soft_limits_y_um", s.soft_limits_y_um),
            ] {
                let inside = l[0] >= tlo * 1000.0 && l[1] <= thi * 1000.0;
                if !(l[0].is_finite() && l[1].is_finite() && l[0] < l[1] && inside) {
                    return Err(fail(
                        k,
                        format!(
                            "must be [lo, hi] µm with lo < hi inside the travel [{}, {}] µm",
                            tlo * 1000.0,
                            thi * 1000.0
                        ),
                    ));
                }
            }
        }
        HardwareKind::Real => {
            for name in spec.axes.keys() {
                if AxisId::parse(name).is_some() && !h.controllers.contains_key(name) {
                    return Err(fail(
                        "hardware.controllers",
                        format!("no controller for axis {name} ([hardware.controllers.{name}])"),
                    ));
                }
            }
            for (name, c) in &h.controllers {
                if AxisId::parse(name).is_none() {
                    return Err(fail(
                        &format!("hardware.controllers.{name}"),
                        "axis names are x and y".into(),
                    ));
                }
                let (lo, hi) = c.soft_limits_um;
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    return Err(fail(
                        &format!("hardware.controllers.{name}.soft_limits_um"),
                        "must be [lo, hi] with lo < hi (µm)".into(),
                    ));
                }
                if let Trust::Submitted(policy) = trust {
                    // A submitted file opens only what the service's configuration lists; the
                    // value is not repeated (it may be a probe of the server's devices).
                    let allowed = match &c.transport {
                        csmetro_gcs::Transport::Serial { port, .. } => {
                            use std::os::unix::fs::FileTypeExt;
                            policy.serial_ports.iter().any(|p| p == port)
                                && port.starts_with("/dev/")
                                && std::fs::metadata(port)
                                    .is_ok_and(|m| m.file_type().is_char_device())
                        }
                        csmetro_gcs::Transport::Tcp { address, .. } => {
                            policy.tcp_endpoints.iter().any(|a| a == address)
                        }
                    };
                    if !allowed {
                        return Err(fail(
                            &format!("hardware.controllers.{name}.transport"),
                            "the service does not allow this port: submitted campaigns open \
                             only the serial devices and TCP endpoints listed in the service's \
                             [hardware] serial_ports and tcp_endpoints"
                                .into(),
                        ));
                    }
                }
            }
            match &h.camera {
                None => {
                    return Err(fail(
                        "hardware.camera",
                        "a real campaign needs [hardware.camera]".into(),
                    ))
                }
                Some(c) => c
                    .validate()
                    .map_err(|e| fail("hardware.camera", e.to_string()))?,
            }
        }
    }

    let s = &spec.sampling;
    if s.batch < 2 {
        return Err(fail("sampling.batch", "must be ≥ 2".into()));
    }
    if let Some(f) = s.fraction {
        if !(f > 0.0 && f <= 1.0) {
            return Err(fail("sampling.fraction", "must be in (0, 1]".into()));
        }
    }
    if let Some(t) = s.target_error_um {
        if !pos(t) {
            return Err(fail("sampling.target_error_um", "must be > 0 µm".into()));
        }
    }
    let a = &spec.acquisition;
    if a.directions.is_empty() {
        return Err(fail(
            "acquisition.directions",
            "needs forward and/or backward".into(),
        ));
    }
    let mut dirs = a.directions.clone();
    dirs.dedup();
    if dirs.len() != a.directions.len() {
        return Err(fail(
            "acquisition.directions",
            "a direction is listed twice".into(),
        ));
    }
    if !(1..=1000).contains(&a.cycles) {
        return Err(fail("acquisition.cycles", "must be in 1..=1000".into()));
    }
    if !(nonneg(a.settle_s) && a.settle_s <= 600.0) {
        return Err(fail("acquisition.settle_s", "must be in [0, 600] s".into()));
    }
    if !(nonneg(a.dwell_s) && a.dwell_s <= 3600.0) {
        return Err(fail("acquisition.dwell_s", "must be in [0, 3600] s".into()));
    }
    if !(1..=100).contains(&a.frames_per_point) {
        return Err(fail(
            "acquisition.frames_per_point",
            "must be in 1..=100".into(),
        ));
    }
    if a.max_retries > 100 {
        return Err(fail("acquisition.max_retries", "must be ≤ 100".into()));
    }
    if !(nonneg(a.approach_um) && a.approach_um <= 1000.0) {
        return Err(fail(
            "acquisition.approach_um",
            "must be in [0, 1000] µm".into(),
        ));
    }

    let r = &spec.reconstruction;
    let method: Method = r
        .method
        .parse()
        .map_err(|e: String| fail("reconstruction.method", e))?;
    let solver: Solver = r
        .solver
        .parse()
        .map_err(|e: String| fail("reconstruction.solver", e))?;
    if !nonneg(r.noise_um) {
        return Err(fail("reconstruction.noise_um", "must be ≥ 0 µm".into()));
    }
    if r.pitch_um.is_some_and(|p| !pos(p)) {
        return Err(fail("reconstruction.pitch_um", "must be > 0 µm".into()));
    }
    if spec.outputs.nexus && !cfg!(feature = "nexus") {
        return Err(fail(
            "outputs.nexus",
            "writing NeXus files needs a csmetro built with --features nexus (and Debian's \
             libhdf5-dev)"
                .into(),
        ));
    }
    if spec.outputs.dir.trim().is_empty() {
        return Err(fail("outputs.dir", "must not be empty".into()));
    }
    if spec.outputs.dir.len() > MAX_PATH_LEN {
        return Err(fail(
            "outputs.dir",
            format!("must be at most {MAX_PATH_LEN} bytes"),
        ));
    }
    if let Trust::Submitted(_) = trust {
        check_submitted_outputs(&spec.outputs.dir).map_err(|e| fail("outputs.dir", e))?;
    }

    let mut plans = Vec::new();
    let mut planned = 0u64;
    for (name, ax) in &spec.axes {
        let key = |k: &str| format!("axes.{name}.{k}");
        let axis = AxisId::parse(name)
            .ok_or_else(|| fail(&format!("axes.{name}"), "axis names are x and y".into()))?;
        let [start, end] = ax.range_um;
        let grid = Grid::new(start, ax.step_um, end).map_err(|e| fail(&key("range_um"), e))?;
        let (lo, hi) = limits_of(axis)?;
        let pre = a.approach_um;
        if start - pre < lo - 1e-9 || end + pre > hi + 1e-9 {
            return Err(fail(
                &key("range_um"),
                format!(
                    "[{start}, {end}] µm with {pre} µm approach travel leaves the soft limits [{lo}, {hi}] µm"
                ),
            ));
        }
        let (olo, ohi) = limits_of(axis.other())?;
        if !(ax.other_at_um.is_finite() && ax.other_at_um >= olo && ax.other_at_um <= ohi) {
            return Err(fail(
                &key("other_at_um"),
                format!(
                    "{} µm is outside the soft limits [{olo}, {ohi}] µm of axis {}",
                    ax.other_at_um,
                    axis.other()
                ),
            ));
        }
        let n = grid.n;
        let (m, mkey) = match (ax.m.or(s.m), ax.fraction.or(s.fraction)) {
            (Some(m), _) => (
                m,
                if ax.m.is_some() {
                    key("m")
                } else {
                    "sampling.m".into()
                },
            ),
            (None, Some(f)) => (
                ((f * n as f64).round() as usize).max(2),
                if ax.fraction.is_some() {
                    key("fraction")
                } else {
                    "sampling.fraction".into()
                },
            ),
            (None, None) if s.design == DesignKind::Full => (n, "sampling.design".into()),
            (None, None) => {
                return Err(fail(
                    "sampling.m",
                    format!("give m or fraction (axis {name} has {n} grid points)"),
                ))
            }
        };
        if let Some(f) = ax.fraction {
            if !(f > 0.0 && f <= 1.0) {
                return Err(fail(&key("fraction"), "must be in (0, 1]".into()));
            }
        }
        if s.design != DesignKind::Full && !(2..=n).contains(&m) {
            return Err(fail(
                &mkey,
                format!("m = {m} must be in 2..={n} (grid points)"),
            ));
        }
        let target_error_um = ax.target_error_um.or(s.target_error_um);
        if let Some(t) = ax.target_error_um {
            if !pos(t) {
                return Err(fail(&key("target_error_um"), "must be > 0 µm".into()));
            }
        }
        if target_error_um.is_some() && s.design == DesignKind::Full {
            return Err(fail(
                "sampling.target_error_um",
                "adaptive sampling needs a random or jittered design".into(),
            ));
        }
        let m = if s.design == DesignKind::Full { n } else { m };
        crate::recon::limits::check_solve_size(method, solver, n, m)
            .map_err(|e| fail(&key("range_um"), e))?;
        let per_run = m as u64 + if s.full_scan { n as u64 } else { 0 };
        planned += per_run * a.directions.len() as u64 * u64::from(a.cycles);
        if planned > MAX_PLANNED {
            return Err(fail(
                &mkey,
                format!("the campaign would plan more than {MAX_PLANNED} measurements"),
            ));
        }
        plans.push(AxisPlan {
            axis,
            grid,
            other_at_um: ax.other_at_um,
            m,
            target_error_um,
        });
    }
    let map = match &spec.map {
        Some(m) => {
            if spec.compensation.is_some() {
                return Err(fail("map", "a map campaign runs uncompensated".into()));
            }
            // The simulator's truth of a map is planar (both axes' errors at once), a line's is
            // not: lines and a map are separate campaigns.
            if !spec.axes.is_empty() {
                return Err(fail(
                    "map",
                    "a map campaign has no [axes.*]: characterize lines in a campaign of their own"
                        .into(),
                ));
            }
            let p = map::validate_map(m, a.approach_um, &limits_of, fail)?;
            planned += (p.design.m * p.directions.len()) as u64;
            if planned > MAX_PLANNED {
                return Err(fail(
                    "map",
                    format!("the campaign would plan more than {MAX_PLANNED} measurements"),
                ));
            }
            Some(p)
        }
        None => None,
    };
    Ok((plans, method, solver, map, model))
}

mod compensation;
pub use compensation::{check_spec as check_compensation, fits, CompensationSpec};
pub mod map;
pub use map::{MapPlan, MapSpec};
mod verification;
pub use verification::{check_verification, DEFAULT_VERIFY_CYCLES, MAX_VERIFY_CYCLES};
mod paths;
use paths::{check_submitted_outputs, load_model, probe_outputs};

#[cfg(test)]
mod tests;
