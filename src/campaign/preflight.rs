//! Pre-flight: whether a campaign can run on its rig, checked without moving anything and
//! without recording anything. `csmetro check` prints it; `run`, `resume` and the service run
//! it before a campaign is recorded or started.
//!
//! Only queries go to the controllers (`*IDN?`, `SAI?`, `CST?`, `TMN?`, `TMX?`, `FRF?`,
//! `SVO?`, `POS?`): no `MOV`, no reference move, no servo change. The camera takes one
//! software-triggered frame, which the campaign's decoder must read as its pattern at the
//! position the encoders report.
use std::path::Path;
use std::time::Duration;

use csmetro_gcs::C863;
use csmetro_gcs::{AxisQuery, Command};
use csmetro_hal::{AxisError, CameraError};
use serde::Serialize;
use serde_json::{json, Value};

use super::rig::{self, Devices, RigError};
use super::spec::{Campaign, HardwareKind};
use crate::types::AxisId;

/// Most distance between the decoded position and the encoders' before the frame is taken as
/// not showing the campaign's pattern (a wrong `origin_um`, another pattern), µm. Stage errors
/// are micrometres; a mount offset this large means the decoded positions are not the stage's.
pub const PATTERN_TOLERANCE_UM: f64 = 500.0;
/// Port opening attempts after the first, for a controller that is not there.
const RECONNECT_ATTEMPTS: u32 = 1;
/// Longest wait for the one frame when the campaign names no camera timeout.
const FRAME_TIMEOUT: Duration = Duration::from_secs(5);

/// Outcome of one check.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Ok,
    Fail,
    /// Not checked because an earlier check failed (not a pass).
    Skip,
}

/// What a failure asks to fix: the campaign file (exit 2, HTTP 409) or the rig (exit 1, 503).
/// `View`: the frame came but shows no pattern where the stage is parked now; `check` fails
/// on it, while `run` and the service only warn, since the campaign moves the stage before its
/// first frame and rejects frames point by point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Class {
    Config,
    Device,
    View,
}

#[derive(Debug, Clone, Serialize)]
pub struct Check {
    pub name: String,
    pub status: Status,
    pub class: Class,
    pub detail: String,
}

/// Every check, in order.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Report {
    pub checks: Vec<Check>,
}

impl Report {
    // Stays a text result: pass or fail, the detail is the report's text (shown and
    // serialized as it is), not an error anyone branches on.
    pub fn push(&mut self, name: impl Into<String>, class: Class, r: Result<String, String>) {
        let (status, detail) = match r {
            Ok(d) => (Status::Ok, d),
            Err(d) => (Status::Fail, d),
        };
        self.checks.push(Check {
            name: name.into(),
            status,
            class,
            detail,
        });
    }
    pub fn skip(&mut self, name: impl Into<String>, class: Class, why: impl Into<String>) {
        self.checks.push(Check {
            name: name.into(),
            status: Status::Skip,
            class,
            detail: why.into(),
        });
    }
    /// Whether every check passed.
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|c| c.status == Status::Ok)
    }
    /// Whether a failure keeps a campaign from being recorded or started (all but `View`).
    pub fn blocks(&self) -> bool {
        self.checks
            .iter()
            .any(|c| c.status != Status::Ok && c.class != Class::View)
    }
    /// The failures that do not block, as warnings (one line each).
    pub fn warnings(&self) -> Vec<String> {
        self.checks
            .iter()
            .filter(|c| c.status == Status::Fail && c.class == Class::View)
            .map(|c| format!("pre-flight check `{}`: {}", c.name, c.detail))
            .collect()
    }
    /// The first failed check.
    pub fn failure(&self) -> Option<&Check> {
        self.checks.iter().find(|c| c.status == Status::Fail)
    }
    /// 0 when all passed; 2 when a failure is the campaign file's, else 1.
    pub fn exit_code(&self) -> u8 {
        if self.passed() {
            0
        } else if self
            .checks
            .iter()
            .any(|c| c.status == Status::Fail && c.class == Class::Config)
        {
            2
        } else {
            1
        }
    }
    /// One line naming the failed check that decides the exit code (and how many others
    /// failed), for `run` and the service.
    pub fn error_message(&self) -> String {
        let failed: Vec<&Check> = self
            .checks
            .iter()
            .filter(|c| c.status == Status::Fail)
            .collect();
        let class = self.failure_class();
        let Some(c) = failed.iter().find(|c| c.class == class).or(failed.first()) else {
            return "pre-flight checks not all passed".into();
        };
        let more = match failed.len() - 1 {
            0 => String::new(),
            n => format!(
                " (and {n} more failed check{})",
                if n > 1 { "s" } else { "" }
            ),
        };
        format!("pre-flight check `{}` failed: {}{more}", c.name, c.detail)
    }
    /// [`Report::error_message`] for a client of the service: a device failure says only
    /// which check failed, not why (a refused connection, a timeout and a wrong reply would
    /// otherwise tell a client what answers where on the service's network). The full message
    /// goes to the service's log.
    pub fn client_message(&self) -> String {
        if self.failure_class() == Class::Config {
            return self.error_message();
        }
        match self.checks.iter().find(|c| c.status == Status::Fail) {
            Some(c) => format!(
                "pre-flight check `{}` failed: the device is unreachable or did not answer as \
                 expected (the service's log has the details)",
                c.name
            ),
            None => "pre-flight checks not all passed".into(),
        }
    }
    /// The class of the first failure.
    pub fn failure_class(&self) -> Class {
        if self.exit_code() == 2 {
            Class::Config
        } else {
            Class::Device
        }
    }
    pub fn table(&self) -> String {
        let w = self.checks.iter().map(|c| c.name.len()).max().unwrap_or(5);
        let mut s = String::new();
        for c in &self.checks {
            let st = match c.status {
                Status::Ok => "ok",
                Status::Fail => "FAIL",
                Status::Skip => "skip",
            };
            s.push_str(&format!("{:<w$}  {:<4}  {}\n", c.name, st, c.detail));
        }
        s
    }
    pub fn json(&self) -> Value {
        json!({"passed": self.passed(), "checks": self.checks})
    }
}

/// What else to check besides the devices.
#[derive(Debug, Clone, Copy, Default)]
pub struct Options<'a> {
    /// The SQLite store the campaign will be recorded in (checked writable, left untouched).
    pub store: Option<&'a Path>,
}

/// Runs the device checks of a validated campaign (and the store's, if given) and appends
/// them to `report`. Nothing moves and nothing is recorded.
pub async fn check_devices(c: &Campaign, opts: Options<'_>, report: &mut Report) {
    if let Some(db) = opts.store {
        report.push(
            "store",
            Class::Device,
            store_writable(db).map_err(|e| e.to_string()),
        );
    }
    let mut devices = match rig::open_devices(c, RECONNECT_ATTEMPTS).await {
        Ok(d) => d,
        Err(e) => {
            report.push("rig", Class::Device, Err(e.to_string()));
            return;
        }
    };
    let mut encoders: [Option<f64>; 2] = [None, None];
    for a in [AxisId::X, AxisId::Y] {
        let drv = match a {
            AxisId::X => &mut devices.x,
            AxisId::Y => &mut devices.y,
        };
        encoders[a as usize] = check_axis(c, a, drv, report).await;
    }
    check_camera(c, &mut devices, encoders, report).await;
    devices.close().await;
}

fn axis_err(e: AxisError) -> String {
    e.to_string()
}

/// Where the campaign needs axis `a`: its grid with the approach travel, and where it stands
/// while the other axis is characterized, µm.
pub fn needed_span_um(c: &Campaign, a: AxisId) -> Option<(f64, f64)> {
    let approach = c.spec().acquisition.approach_um;
    let mut span: Option<(f64, f64)> = None;
    let mut add = |lo: f64, hi: f64| {
        span = Some(span.map_or((lo, hi), |(l, h)| (l.min(lo), h.max(hi))));
    };
    for p in c.axes() {
        if p.axis == a {
            add(p.grid.start_um - approach, p.grid.end_um() + approach);
        } else {
            add(p.other_at_um, p.other_at_um);
        }
    }
    // A map moves both axes over its grid, with the approach travel on either side.
    if let Some(m) = c.map() {
        let g = if a == AxisId::X { m.grid.x } else { m.grid.y };
        add(g.start_um - approach, g.end_um() + approach);
    }
    span
}

/// The checks of one controller; returns its encoder position, µm, when it answered.
async fn check_axis(
    c: &Campaign,
    a: AxisId,
    slot: &mut Result<C863, RigError>,
    report: &mut Report,
) -> Option<f64> {
    let names = ["controller", "axis", "limits", "referenced"].map(|n| format!("{a}: {n}"));
    let drv = match slot {
        Ok(d) => d,
        Err(e) => {
            report.push(&names[0], Class::Device, Err(e.to_string()));
            for n in &names[1..] {
                report.skip(n, Class::Device, format!("controller {a} did not answer"));
            }
            return None;
        }
    };
    let idn = drv
        .query(&Command::Idn)
        .await
        .map_err(axis_err)
        .and_then(|r| r.single().map(|l| l.trim().to_string()));
    let at = describe_port(c, drv);
    match idn {
        Ok(l) => report.push(&names[0], Class::Device, Ok(format!("{l} ({at})"))),
        Err(e) => {
            // The driver's resync probe names the configured axis, and a controller without
            // that axis never answers it: ask as axis "1" (every C-863 has it) to tell a
            // wrong axis from a silent controller.
            let cfg = drv.config().clone();
            let found = if cfg.axis != C863_AXIS {
                // The port is free again only once this driver is gone.
                *slot = Err(RigError::Taken);
                axes_as_default(cfg.clone()).await
            } else {
                None
            };
            match found {
                Some((idn, axes)) => {
                    report.push(&names[0], Class::Device, Ok(format!("{idn} ({at})")));
                    report.push(
                        &names[1],
                        Class::Config,
                        Err(format!(
                            "the controller has no axis {:?} (SAI? lists {axes:?}); fix \
                             [hardware.controllers.{a}] axis",
                            cfg.axis
                        )),
                    );
                    for n in &names[2..] {
                        report.skip(
                            n,
                            Class::Device,
                            format!("no usable axis on controller {a}"),
                        );
                    }
                }
                None => {
                    report.push(&names[0], Class::Device, Err(format!("{at}: {e}")));
                    for n in &names[1..] {
                        report.skip(n, Class::Device, format!("controller {a} did not answer"));
                    }
                }
            }
            return None;
        }
    }
    let gcs_axis = drv.config().axis.clone();
    let axes = drv
        .query(&Command::Sai { all: false })
        .await
        .map_err(axis_err);
    let axis_ok = match axes {
        Ok(r) if r.lines.iter().any(|l| l.trim() == gcs_axis) => {
            let stage = drv
                .query(&Command::Query {
                    query: AxisQuery::Cst,
                    axes: vec![gcs_axis.clone()],
                })
                .await
                .map_err(axis_err)
                .and_then(|r| r.axis_value(&gcs_axis).map(str::to_string));
            match stage {
                Ok(s) => {
                    report.push(
                        &names[1],
                        Class::Config,
                        Ok(format!("axis {gcs_axis:?}, stage {s}")),
                    );
                    true
                }
                Err(e) => {
                    report.push(&names[1], Class::Device, Err(format!("CST?: {e}")));
                    false
                }
            }
        }
        Ok(r) => {
            let have: Vec<&str> = r.lines.iter().map(|l| l.trim()).collect();
            report.push(
                &names[1],
                Class::Config,
                Err(format!(
                    "the controller has no axis {gcs_axis:?} (SAI? lists {have:?}); fix \
                     [hardware.controllers.{a}] axis"
                )),
            );
            false
        }
        Err(e) => {
            report.push(&names[1], Class::Device, Err(format!("SAI?: {e}")));
            false
        }
    };
    if !axis_ok {
        for n in &names[2..] {
            report.skip(
                n,
                Class::Device,
                format!("no usable axis on controller {a}"),
            );
        }
        return None;
    }
    let travel = match (
        axis_f64(drv, AxisQuery::Tmn).await,
        axis_f64(drv, AxisQuery::Tmx).await,
    ) {
        (Ok(lo), Ok(hi)) => Ok((lo * 1000.0, hi * 1000.0)),
        (Err(e), _) | (_, Err(e)) => Err(format!("TMN?/TMX?: {e}")),
    };
    let soft = drv.config().soft_limits_um;
    match travel {
        Ok((tlo, thi)) => {
            let r = limits_verdict(c, a, soft, (tlo, thi)).map_err(|e| e.to_string());
            report.push(&names[2], Class::Config, r);
        }
        Err(e) => report.push(&names[2], Class::Device, Err(e)),
    }
    let referenced = drv
        .query(&axis_query(drv, AxisQuery::Frf))
        .await
        .map_err(axis_err)
        .and_then(|r| r.axis_bool(&gcs_axis));
    let pos = axis_f64(drv, AxisQuery::Pos).await.map(|mm| mm * 1000.0);
    match (referenced, &pos) {
        (Ok(r), Ok(p)) => {
            let how = match c.spec().hardware.kind {
                HardwareKind::Real => format!("{:?}", drv.config().reference).to_uppercase(),
                HardwareKind::Sim => "FRF".into(),
            };
            report.push(
                &names[3],
                Class::Device,
                Ok(if r {
                    format!("yes; encoder at {p:.3} µm")
                } else {
                    format!("no (the campaign references it first, {how}); encoder at {p:.3} µm")
                }),
            );
        }
        (Err(e), _) => report.push(&names[3], Class::Device, Err(format!("FRF?: {e}"))),
        (_, Err(e)) => report.push(&names[3], Class::Device, Err(format!("POS?: {e}"))),
    }
    pos.ok()
}

fn axis_query(drv: &C863, query: AxisQuery) -> Command {
    Command::Query {
        query,
        axes: vec![drv.config().axis.clone()],
    }
}

/// A number the controller reports for its axis (GCS units: mm, mm/s).
async fn axis_f64(drv: &mut C863, query: AxisQuery) -> Result<f64, ProbeError> {
    let axis = drv.config().axis.clone();
    let reply = drv.query(&axis_query(drv, query)).await?;
    reply.axis_f64(&axis).map_err(ProbeError::Reply)
}

/// A controller query of the pre-flight that failed.
#[derive(Debug, thiserror::Error)]
enum ProbeError {
    #[error(transparent)]
    Axis(#[from] AxisError),
    /// A reply that does not parse (the GCS driver's reply parsers say why in text).
    #[error("{0}")]
    Reply(String),
}

/// Where the controller is, as the campaign file names it (a simulated campaign's pty is the
/// simulator's business).
fn describe_port(c: &Campaign, drv: &C863) -> String {
    match (&drv.config().transport, c.spec().hardware.kind) {
        (_, HardwareKind::Sim) => "simulated".into(),
        (csmetro_gcs::Transport::Tcp { address }, _) => format!("tcp {address}"),
        (csmetro_gcs::Transport::Serial { port, .. }, _) => format!("serial {port}"),
    }
}

/// The one axis of a C-863 (GCS axis identifier).
const C863_AXIS: &str = "1";

/// `*IDN?` and the axes (`SAI?`) of the controller `cfg` reaches, asked as axis
/// [`C863_AXIS`]; None if it does not answer that way either.
async fn axes_as_default(mut cfg: csmetro_gcs::C863Config) -> Option<(String, Vec<String>)> {
    cfg.axis = C863_AXIS.into();
    cfg.reconnect_attempts = cfg.reconnect_attempts.min(RECONNECT_ATTEMPTS);
    cfg.retries = cfg.retries.min(RECONNECT_ATTEMPTS);
    let mut d = C863::connect(cfg).await.ok()?;
    let idn = d
        .query(&Command::Idn)
        .await
        .ok()?
        .single()
        .ok()?
        .trim()
        .to_string();
    let axes = d.query(&Command::Sai { all: false }).await.ok()?;
    Some((
        idn,
        axes.lines.iter().map(|l| l.trim().to_string()).collect(),
    ))
}

/// Whether the campaign's positions of axis `a` lie inside its soft limits and inside the
/// travel the controller accepts (`TMN?`, `TMX?`), µm.
fn limits_verdict(
    c: &Campaign,
    a: AxisId,
    soft: (f64, f64),
    travel: (f64, f64),
) -> Result<String, LimitsError> {
    let shown = |(lo, hi): (f64, f64)| format!("[{lo}, {hi}] µm");
    let limits = format!(
        "soft limits {}, controller travel {}",
        shown(soft),
        shown(travel)
    );
    let Some(need) = needed_span_um(c, a) else {
        return Ok(format!("not used by the campaign; {limits}"));
    };
    let inside = |(lo, hi): (f64, f64)| need.0 >= lo - 1e-9 && need.1 <= hi + 1e-9;
    let what = format!(
        "campaign needs {} (range ± {} µm approach, other-axis positions)",
        shown(need),
        c.spec().acquisition.approach_um
    );
    if !inside(soft) {
        Err(LimitsError::Soft { what, limits })
    } else if !inside(travel) {
        Err(LimitsError::Travel {
            what,
            travel: shown(travel),
            soft: shown(soft),
        })
    } else {
        Ok(format!("{what}; {limits}"))
    }
}

/// Where a campaign's positions fall outside an axis' limits; `what` says what the campaign
/// needs, the limits are written out (µm).
#[derive(Debug, thiserror::Error)]
enum LimitsError {
    #[error("{what}, beyond the {limits}")]
    Soft { what: String, limits: String },
    #[error("{what}, beyond the controller travel {travel} (soft limits {soft})")]
    Travel {
        what: String,
        travel: String,
        soft: String,
    },
}

async fn check_camera(
    c: &Campaign,
    devices: &mut Devices,
    encoders: [Option<f64>; 2],
    report: &mut Report,
) {
    let cam = match std::mem::replace(&mut devices.camera, Err(RigError::Taken)) {
        Ok(cam) => {
            report.push("camera", Class::Device, Ok(cam.describe()));
            cam
        }
        Err(e) => {
            // A build without the camera's backend is the configuration's problem.
            report.push("camera", camera_class(&e), Err(e.to_string()));
            report.skip("pattern", Class::Device, "no camera");
            return;
        }
    };
    let timeout = c
        .spec()
        .hardware
        .camera
        .as_ref()
        .filter(|_| c.spec().hardware.kind == HardwareKind::Real)
        .map_or(FRAME_TIMEOUT, |k| k.frame_timeout());
    let decoder = devices.decoder.clone();
    let r = tokio::task::spawn_blocking(move || {
        let mut cam = cam;
        let frame = cam.grab(timeout);
        drop(cam);
        frame.map(|f| decoder.decode(&f))
    })
    .await;
    let (class, verdict) = match r {
        Err(e) => (Class::Device, Err(format!("no frame: camera task: {e}"))),
        Ok(Err(e)) => (Class::Device, Err(format!("no frame: {e}"))),
        Ok(Ok(d)) if !d.ok => (
            Class::View,
            Err(format!(
                "the frame does not show the campaign's pattern ({}); is the pattern in view and \
             [hardware.pattern] right?",
                d.reason.unwrap_or_else(|| "not decoded".into())
            )),
        ),
        Ok(Ok(d)) => (
            Class::Config,
            match encoders {
                [Some(ex), Some(ey)] => {
                    let off = ((d.x_um - ex).powi(2) + (d.y_um - ey).powi(2)).sqrt();
                    let text = format!(
                    "decoded ({:.3}, {:.3}) µm, encoders ({ex:.3}, {ey:.3}) µm, {off:.1} µm apart",
                    d.x_um, d.y_um
                );
                    if off <= PATTERN_TOLERANCE_UM {
                        Ok(text)
                    } else {
                        Err(format!(
                        "{text}: more than {PATTERN_TOLERANCE_UM} µm, not the campaign's pattern \
                         ([hardware.pattern] origin_um?)"
                    ))
                    }
                }
                _ => Ok(format!(
                    "decoded ({:.3}, {:.3}) µm (no encoder to compare)",
                    d.x_um, d.y_um
                )),
            },
        ),
    };
    report.push("pattern", class, verdict);
}

/// Who must act on a camera that did not open: the configuration when this build lacks its
/// backend, else the device.
fn camera_class(e: &RigError) -> Class {
    match e {
        RigError::Camera(CameraError::NotCompiled(_)) => Class::Config,
        _ => Class::Device,
    }
}

/// Whether the store at `db` can take writes, without writing to it: an existing database is
/// opened read-write and a write transaction begun and rolled back; its directory (journal
/// files) must take a new file. A store that does not exist yet needs a writable directory.
pub fn store_writable(db: &Path) -> Result<String, StoreCheckError> {
    use rusqlite::{Connection, OpenFlags};
    let shown = db.display();
    let sqlite = |source| StoreCheckError::Sqlite {
        store: shown.to_string(),
        source,
    };
    if db.exists() {
        let conn =
            Connection::open_with_flags(db, OpenFlags::SQLITE_OPEN_READ_WRITE).map_err(sqlite)?;
        if conn.is_readonly("main").unwrap_or(true) {
            return Err(StoreCheckError::ReadOnly(shown.to_string()));
        }
        conn.execute_batch("BEGIN IMMEDIATE; ROLLBACK;")
            .map_err(sqlite)?;
        let dir = db.parent().filter(|d| !d.as_os_str().is_empty());
        probe_dir(dir.unwrap_or(Path::new(".")))?;
        Ok(format!("{shown}: writable"))
    } else {
        let mut d = db.parent().unwrap_or(Path::new("."));
        while !d.as_os_str().is_empty() && !d.exists() {
            d = d.parent().unwrap_or(Path::new(""));
        }
        let d = if d.as_os_str().is_empty() {
            Path::new(".")
        } else {
            d
        };
        probe_dir(d)?;
        Ok(format!("{shown}: new store (directory writable)"))
    }
}

/// Why the store would not take writes.
#[derive(Debug, thiserror::Error)]
pub enum StoreCheckError {
    #[error("{store}: {source}")]
    Sqlite {
        store: String,
        source: rusqlite::Error,
    },
    #[error("{0}: read-only")]
    ReadOnly(String),
    #[error("{dir}: not writable ({})", crate::tomlpos::io_reason(.source))]
    NotWritable { dir: String, source: std::io::Error },
}

/// Creates and removes a probe file in `dir`.
fn probe_dir(dir: &Path) -> Result<(), StoreCheckError> {
    let probe = dir.join(format!(".csmetro-check-{}", std::process::id()));
    let r = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .and_then(|mut f| std::io::Write::write_all(&mut f, b"probe"));
    let _ = std::fs::remove_file(&probe);
    r.map_err(|source| StoreCheckError::NotWritable {
        dir: dir.display().to_string(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn campaign(approach_um: f64) -> Campaign {
        let text = format!(
            r#"[campaign]
name = "pf"
[hardware]
kind = "sim"
[axes.x]
range_um = [1000.0, 2000.0]
step_um = 10.0
other_at_um = 3000.0
m = 10
[axes.y]
range_um = [500.0, 900.0]
step_um = 10.0
other_at_um = 4000.0
m = 10
[acquisition]
approach_um = {approach_um}
"#
        );
        Campaign::parse(&text, "pf.toml", Path::new(".")).unwrap()
    }

    #[test]
    fn the_span_an_axis_needs_is_its_range_with_approach_and_where_it_waits() {
        let c = campaign(25.0);
        // x: its grid ± 25 µm, and 4000 µm while y is characterized.
        assert_eq!(needed_span_um(&c, AxisId::X), Some((975.0, 4000.0)));
        assert_eq!(needed_span_um(&c, AxisId::Y), Some((475.0, 3000.0)));
    }

    #[test]
    fn a_map_needs_its_grid_with_the_approach_on_both_axes() {
        let text = "[campaign]\nname = \"pf\"\n[hardware]\nkind = \"sim\"\n[map]\n\
            x_range_um = [1000.0, 2000.0]\ny_range_um = [500.0, 900.0]\nstep_um = [50.0, 50.0]\n\
            m = 20\n[acquisition]\napproach_um = 30.0\n";
        let c = Campaign::parse(text, "pf.toml", Path::new(".")).unwrap();
        assert_eq!(needed_span_um(&c, AxisId::X), Some((970.0, 2030.0)));
        assert_eq!(needed_span_um(&c, AxisId::Y), Some((470.0, 930.0)));
        let e = limits_verdict(&c, AxisId::Y, (0.0, 920.0), (-1000.0, 14_000.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("[470, 930] µm"), "{e}");
    }

    #[test]
    fn limits_fail_beyond_the_soft_limits_or_the_controller_travel() {
        let c = campaign(25.0);
        assert!(limits_verdict(&c, AxisId::X, (0.0, 5000.0), (-1000.0, 14_000.0)).is_ok());
        // Soft limits cut the approach travel by 1 µm.
        let e = limits_verdict(&c, AxisId::X, (976.0, 5000.0), (-1000.0, 14_000.0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[975, 4000] µm") && e.contains("soft limits"),
            "{e}"
        );
        // The controller accepts less than the soft limits allow.
        let e = limits_verdict(&c, AxisId::X, (0.0, 5000.0), (0.0, 3999.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("controller travel [0, 3999] µm"), "{e}");
    }

    #[test]
    fn a_store_not_there_yet_is_probed_without_being_created() {
        let d = tempfile::tempdir().unwrap();
        let db = d.path().join("a").join("b.db");
        assert!(store_writable(&db).is_ok());
        assert!(!d.path().join("a").exists());
        let file = d.path().join("f");
        std::fs::write(&file, "x").unwrap();
        // A path below a regular file can never hold a store.
        assert!(store_writable(&file.join("s.db")).is_err());
    }

    #[test]
    fn a_camera_backend_this_build_lacks_is_the_configuration_s_problem() {
        let lacking = RigError::Camera(CameraError::NotCompiled("aravis"));
        assert_eq!(camera_class(&lacking), Class::Config);
        assert!(
            lacking
                .to_string()
                .contains("built without the `aravis` camera backend"),
            "{lacking}"
        );
        let lost = RigError::Camera(CameraError::Disconnected("built without".into()));
        assert_eq!(camera_class(&lost), Class::Device);
    }

    #[test]
    fn the_exit_code_and_message_follow_the_failure_that_decides() {
        let mut r = Report::default();
        r.push("x: controller", Class::Device, Err("refused".into()));
        r.push("camera", Class::Config, Err("built without aravis".into()));
        assert_eq!(r.exit_code(), 2);
        assert!(r.blocks());
        let m = r.error_message();
        assert!(
            m.starts_with("pre-flight check `camera` failed") && m.contains("1 more"),
            "{m}"
        );
        let mut v = Report::default();
        v.push("pattern", Class::View, Err("no pattern".into()));
        assert_eq!(
            (v.exit_code(), v.blocks(), v.warnings().len()),
            (1, false, 1)
        );
    }
}
