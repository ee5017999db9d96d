//! A `csmetro sim rig` process for the tests: started from a rig file, the devices' addresses
//! read from its first stdout lines, stopped with SIGTERM, and what its controllers were asked.
#![allow(dead_code, unreachable_pub)]
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard};

/// One fake GigE Vision camera per address (GVCP port 3956): rigs of one test binary take
/// turns.
static CAMERA_PORT: Mutex<()> = Mutex::new(());

pub fn camera_turn() -> MutexGuard<'static, ()> {
    CAMERA_PORT.lock().unwrap_or_else(|e| e.into_inner())
}

/// A rig file: two controllers on TCP port 0, travel [-1, 14] mm, carriage at (`x_mm`,
/// `y_mm`), and (when `camera`) a 640 x 640 camera, serial CSMTEST01.
pub fn rig_file(dir: &Path, model: Option<&Path>, x_mm: f64, y_mm: f64, camera: bool) -> PathBuf {
    let mut t = String::from("time_scale = 1000\n");
    if let Some(m) = model {
        t.push_str(&format!("model = {:?}\n", m.display().to_string()));
    }
    for (a, start) in [("x", x_mm), ("y", y_mm)] {
        t.push_str(&format!(
            "[{a}]\ntcp = \"127.0.0.1:0\"\n[{a}.controller]\ntravel_mm = [-1.0, 14.0]\n\
             start_mm = {start:?}\nreference_switch_mm = 6.5\n"
        ));
    }
    if camera {
        t.push_str("[camera]\nserial = \"CSMTEST01\"\nwidth = 640\nheight = 640\nseed = 5\n");
    }
    let p = dir.join(format!("rig-{x_mm}-{y_mm}.toml"));
    std::fs::write(&p, t).unwrap();
    p
}

/// The rig camera's `id` in a campaign file.
pub const CAMERA: &str = r#"{ serial = "CSMTEST01" }"#;

pub struct Rig {
    child: Child,
    pub x: String,
    pub y: String,
    pub camera: String,
    log: PathBuf,
}

impl Rig {
    pub fn start(bin: &Path, config: &Path) -> Rig {
        let log = config.with_extension("commands");
        let mut child = Command::new(bin)
            .args(["sim", "rig", "--config"])
            .arg(config)
            .arg("--command-log")
            .arg(&log)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let (mut x, mut y, mut camera) = (String::new(), String::new(), String::new());
        loop {
            let mut line = String::new();
            assert!(out.read_line(&mut line).unwrap() > 0, "the rig ended early");
            let line = line.trim();
            if line == "ready" {
                break;
            }
            let (k, v) = line.split_once(": ").unwrap();
            let addr = |v: &str| v.strip_prefix("tcp ").unwrap().to_string();
            match k {
                "x" => x = addr(v),
                "y" => y = addr(v),
                "camera" => camera = v.to_string(),
                _ => panic!("unexpected rig line {line:?}"),
            }
        }
        Rig {
            child,
            x,
            y,
            camera,
            log,
        }
    }

    /// Stops the rig (SIGTERM) and returns every command its controllers received, as
    /// `(axis, command)`.
    pub fn stop(mut self) -> Vec<(String, String)> {
        let st = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .unwrap();
        assert!(st.success());
        let st = self.child.wait().unwrap();
        assert!(st.success(), "rig exit {st:?}");
        std::fs::read_to_string(&self.log)
            .unwrap()
            .lines()
            .map(|l| {
                let (a, c) = l.split_once('\t').unwrap();
                (a.to_string(), c.to_string())
            })
            .collect()
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The `[hardware]` of a `kind = "real"` campaign on a rig's controllers at `x` and `y` (soft
/// limits in µm), its camera given as a TOML `id` value (`{ serial = "CSMTEST01" }` for the
/// rig's own), the decoder's optics the rig camera's full 640 × 640 frame.
pub fn real_hardware(
    x: &str,
    y: &str,
    x_lim_um: [f64; 2],
    y_lim_um: [f64; 2],
    camera: &str,
) -> String {
    let [x0, x1] = x_lim_um;
    let [y0, y1] = y_lim_um;
    format!(
        r#"
[hardware]
kind = "real"
optics = {{ width = 640, height = 640 }}

[hardware.controllers.x]
transport = {{ kind = "tcp", address = "{x}" }}
soft_limits_um = [{x0:?}, {x1:?}]
poll_interval_ms = 2

[hardware.controllers.y]
transport = {{ kind = "tcp", address = "{y}" }}
soft_limits_um = [{y0:?}, {y1:?}]
poll_interval_ms = 2

[hardware.camera]
id = {camera}
exposure_us = 1000.0
"#
    )
}
