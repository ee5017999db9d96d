//! PI's own Python client (pipython) drives `csmetro sim controller` over TCP and over a pty.
//! Skipped with a SKIP line when pipython is not installed, unless CSMETRO_REQUIRE_PIPYTHON=1
//! (CI), where a missing pipython fails.
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_csmetro");
const SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/pipython/scenarios.py");

fn pipython_or_skip(test: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import pipython"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        if std::env::var("CSMETRO_REQUIRE_PIPYTHON").as_deref() == Ok("1") {
            panic!("CSMETRO_REQUIRE_PIPYTHON=1 but `python3 -c 'import pipython'` fails; pip install pipython==2.11.0.6");
        }
        println!("SKIP {test}: pipython not installed (pip install pipython==2.11.0.6)");
    }
    ok
}

/// A `csmetro sim controller` child: SIGTERM on drop (so it removes its pty link), then
/// SIGKILL if it has not exited within 5 s.
struct Sim(Child);

impl Drop for Sim {
    fn drop(&mut self) {
        if let Ok(Some(_)) = self.0.try_wait() {
            return;
        }
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .stderr(Stdio::null())
            .status();
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts the simulator and returns it with its first stdout line (address or tty path).
fn start(args: &[&str]) -> (Sim, String) {
    let mut child = Command::new(BIN)
        .args(["sim", "controller"])
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn csmetro");
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = BufReader::new(stdout).read_line(&mut line);
        let _ = tx.send(line);
    });
    let sim = Sim(child);
    let line = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("no first line from the simulator");
    (sim, line.trim().to_string())
}

/// Runs the pipython scenarios, at most 120 s.
fn run_scenarios(kind: &str, where_: &str) {
    let mut child = Command::new("python3")
        .args([SCRIPT, kind, where_])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn python3");
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("pipython scenarios over {kind} did not finish in 120 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    assert!(
        status.success(),
        "pipython over {kind} failed:\n{stdout}\n{stderr}"
    );
    assert_eq!(
        stdout.lines().last(),
        Some(format!("PASS {kind}").as_str()),
        "{stdout}"
    );
}

#[test]
fn pipython_drives_the_simulated_c863_over_tcp() {
    if !pipython_or_skip("pipython_drives_the_simulated_c863_over_tcp") {
        return;
    }
    let (_sim, addr) = start(&["--tcp", "127.0.0.1:0", "--time-scale", "20"]);
    assert!(addr.starts_with("127.0.0.1:"), "{addr}");
    run_scenarios("tcp", &addr);
}

#[test]
fn pipython_drives_the_simulated_c863_over_a_pty() {
    if !pipython_or_skip("pipython_drives_the_simulated_c863_over_a_pty") {
        return;
    }
    let (_sim, path) = start(&["--pty", "--time-scale", "20"]);
    assert!(
        std::fs::canonicalize(&path)
            .unwrap()
            .starts_with("/dev/pts"),
        "{path}"
    );
    run_scenarios("pty", &path);
}

#[test]
fn sim_controller_stops_on_sigterm_and_removes_its_pty_link() {
    let (mut sim, path) = start(&["--pty"]);
    assert!(std::path::Path::new(&path).exists());
    let pid = sim.0.id().to_string();
    assert!(Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap()
        .success());
    let t = Instant::now();
    let status = loop {
        if let Some(s) = sim.0.try_wait().unwrap() {
            break s;
        }
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "still running after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(10));
    };
    assert!(status.success(), "{status:?}");
    assert!(
        !std::path::Path::new(&path).exists(),
        "pty link left behind"
    );
}

#[test]
fn sim_controller_refuses_bad_input_with_exit_2() {
    let out = Command::new(BIN)
        .args(["sim", "controller", "--tcp", "127.0.0.1:0", "--axis", "z"])
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(&cfg, "[controller]\nspeed = 3\n").unwrap();
    let out = Command::new(BIN)
        .args(["sim", "controller", "--pty", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("speed"),
        "names the bad key"
    );
}

#[test]
fn sim_controller_applies_settings_and_faults_from_its_config() {
    use std::io::{Read, Write};
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(
        &cfg,
        "time_scale = 100\n[controller]\nstage = \"M-111.2DG\"\n\
         [[controller.faults]]\nkind = \"garbage\"\nafter_commands = 1\n",
    )
    .unwrap();
    let (_sim, addr) = start(&["--tcp", "127.0.0.1:0", "--config", cfg.to_str().unwrap()]);
    let mut s = std::net::TcpStream::connect(&addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut ask = |cmd: &str| {
        s.write_all(cmd.as_bytes()).unwrap();
        let mut got = Vec::new();
        let mut b = [0u8; 1];
        while got.last() != Some(&b'\n') {
            s.read_exact(&mut b).unwrap();
            got.push(b[0]);
        }
        got
    };
    assert_eq!(ask("CST? 1\n"), b"1=M-111.2DG\n", "first command answered");
    assert_ne!(ask("CST? 1\n"), b"1=M-111.2DG\n", "second reply garbled");
    assert_eq!(ask("CST? 1\n"), b"1=M-111.2DG\n");
}
