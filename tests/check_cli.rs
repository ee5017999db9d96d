//! `csmetro check CAMPAIGN.toml`: the pre-flight without motion. A table (or JSON) of checks,
//! exit 0 only if all pass; each fault of a rig on its own failed line; nothing moves and
//! nothing is recorded. The rig faults run against `csmetro sim rig` (feature `aravis` for its
//! GigE Vision camera): `cargo test --features aravis --test check_cli`.
mod common;
mod rig;

use std::path::Path;

use common::bin;
use serde_json::Value;

/// `check --json`: (exit code, the checks as (name, status, detail)).
fn check(campaign: &Path, db: &Path) -> (i32, Vec<(String, String, String)>) {
    let o = bin()
        .args(["check", "--json", "--db"])
        .arg(db)
        .arg(campaign)
        .output()
        .unwrap();
    let j: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
        panic!(
            "{e}: {} / {}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        )
    });
    let checks = j["checks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["name"].as_str().unwrap().to_string(),
                c["status"].as_str().unwrap().to_string(),
                c["detail"].as_str().unwrap().to_string(),
            )
        })
        .collect::<Vec<_>>();
    let code = o.status.code().unwrap();
    assert_eq!(j["passed"], code == 0, "{j}");
    if code != 0 {
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("pre-flight check `"), "{err}");
    }
    (code, checks)
}

fn failed(checks: &[(String, String, String)]) -> Vec<&str> {
    checks
        .iter()
        .filter(|c| c.1 == "fail")
        .map(|c| c.0.as_str())
        .collect()
}

#[test]
fn a_simulated_campaign_passes_every_check_and_records_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::repo("config/sim/ideal.toml");
    let text = common::campaign("chk", "chk-stage", 4, 1000.0).replace(
        "model = \"ideal.toml\"",
        &format!("model = {:?}", model.display().to_string()),
    );
    let file = dir.path().join("chk.toml");
    std::fs::write(&file, text).unwrap();
    let db = dir.path().join("store").join("csmetro.db");
    let (code, checks) = check(&file, &db);
    assert_eq!(code, 0, "{checks:?}");
    let names: Vec<&str> = checks.iter().map(|c| c.0.as_str()).collect();
    for n in [
        "config",
        "outputs",
        "stage",
        "store",
        "x: controller",
        "x: axis",
        "x: limits",
        "x: referenced",
        "y: controller",
        "camera",
        "pattern",
    ] {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    assert!(checks.iter().all(|c| c.1 == "ok"), "{checks:?}");
    // The table form says the same.
    let o = bin()
        .arg("check")
        .arg("--db")
        .arg(&db)
        .arg(&file)
        .output()
        .unwrap();
    assert!(o.status.success());
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(
        table
            .lines()
            .any(|l| l.starts_with("x: limits") && l.contains(" ok ")),
        "{table}"
    );
    // Nothing recorded: the store was not even created.
    assert!(!db.exists() && !db.parent().unwrap().exists());
}

#[test]
fn an_invalid_file_fails_the_config_line_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, "[campaign]\nname = \"x\"\n[hardware]\nkind = \"sim\"\n[axes.x]\nrange_um = [0.0, 10.0]\nstep_um = 0.0\nother_at_um = 0.0\nm = 2\n").unwrap();
    let (code, checks) = check(&file, &dir.path().join("s.db"));
    assert_eq!(code, 2);
    assert_eq!(failed(&checks), ["config"], "{checks:?}");
    assert!(checks[0].2.contains("bad.toml:"), "{checks:?}");
}

/// A `kind = "real"` campaign of x over [lo, hi] µm on the rig's controllers and camera.
fn real_campaign(dir: &Path, name: &str, x: &str, y: &str, extra: &Edits) -> std::path::PathBuf {
    let t = format!(
        r#"[campaign]
name = "{name}"
stage = "chk-rig"

[hardware]
kind = "real"
optics = {{ width = 640, height = 640 }}

[hardware.controllers.x]
transport = {{ kind = "tcp", address = "{x}" }}
soft_limits_um = [{xlim}]
axis = "{axis}"
reply_timeout_ms = 300
poll_interval_ms = 2

[hardware.controllers.y]
transport = {{ kind = "tcp", address = "{y}" }}
soft_limits_um = [500.0, 4000.0]
reply_timeout_ms = 300
poll_interval_ms = 2

[hardware.camera]
id = {camera}
exposure_us = 1000.0

[axes.x]
range_um = [{range}]
step_um = 10.0
other_at_um = 2100.0
m = 6

[sampling]
design = "random"
seed = 4

[acquisition]
settle_s = 0.0
approach_um = 20.0

[reconstruction]
method = "pchip"

[outputs]
dir = "{out}/{{name}}-{{id}}"
"#,
        xlim = extra.soft_limits,
        axis = extra.axis,
        camera = extra.camera,
        range = extra.range,
        out = dir.display(),
    );
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(&p, t).unwrap();
    p
}

struct Edits {
    soft_limits: &'static str,
    axis: &'static str,
    camera: &'static str,
    range: &'static str,
}

const GOOD: Edits = Edits {
    soft_limits: "500.0, 3000.0",
    axis: "1",
    camera: "{ ip = \"127.0.0.1\" }",
    range: "1000.0, 1200.0",
};

#[cfg(not(feature = "aravis"))]
#[test]
fn without_the_aravis_feature_the_camera_line_names_it_and_exit_is_2() {
    let dir = tempfile::tempdir().unwrap();
    // Nothing listens on port 9 (discard) of the loopback here.
    let c = real_campaign(dir.path(), "noaravis", "127.0.0.1:9", "127.0.0.1:9", &GOOD);
    let (code, checks) = check(&c, &dir.path().join("s.db"));
    assert_eq!(code, 2, "{checks:?}");
    // The file asks for a camera backend this build lacks: refused as configuration, naming
    // the feature to build with, before any device is opened.
    let cfg = checks.iter().find(|c| c.0 == "config").unwrap();
    assert!(
        cfg.1 == "fail" && cfg.2.contains("--features aravis"),
        "{cfg:?}"
    );
    assert!(
        checks
            .iter()
            .filter(|c| c.0.ends_with(": controller"))
            .all(|c| c.1 != "ok"),
        "{checks:?}"
    );
}

#[cfg(feature = "aravis")]
#[test]
fn each_rig_fault_fails_its_own_line_nothing_moves_nothing_is_recorded() {
    use csmetro::store::Store;

    let _turn = rig::camera_turn();
    let dir = tempfile::tempdir().unwrap();
    let exe = Path::new(env!("CARGO_BIN_EXE_csmetro"));
    let r = rig::Rig::start(exe, &rig::rig_file(dir.path(), None, 1.0, 2.0, true));
    assert!(r.camera.contains("serial CSMTEST01"), "{}", r.camera);

    // An existing store: every check must leave it as it was.
    let db = dir.path().join("chk.db");
    drop(Store::open(&db).unwrap());
    let campaigns = || Store::open(&db).unwrap().campaigns().unwrap().len();

    let good = real_campaign(dir.path(), "good", &r.x, &r.y, &GOOD);
    let (code, checks) = check(&good, &db);
    assert_eq!(code, 0, "{checks:?}");
    let pattern = &checks.iter().find(|c| c.0 == "pattern").unwrap().2;
    assert!(
        pattern.contains("encoders (1000.000, 2000.000)"),
        "{pattern}"
    );

    // A port nothing listens on (the rig's own, closed again).
    let closed = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().to_string()
    };
    let faults: [(&str, String, Edits, &str, i32); 4] = [
        ("port", closed, GOOD, "x: controller", 1),
        (
            "axis",
            r.x.clone(),
            Edits { axis: "2", ..GOOD },
            "x: axis",
            2,
        ),
        (
            "limits",
            r.x.clone(),
            Edits {
                soft_limits: "500.0, 15000.0",
                range: "13800.0, 14000.0",
                ..GOOD
            },
            "x: limits",
            2,
        ),
        (
            "camera",
            r.x.clone(),
            Edits {
                camera: "{ serial = \"NOSUCHCAM1\" }",
                ..GOOD
            },
            "camera",
            1,
        ),
    ];
    for (name, x, edits, line, want) in faults {
        let c = real_campaign(dir.path(), name, &x, &r.y, &edits);
        let (code, checks) = check(&c, &db);
        assert_eq!(failed(&checks), [line], "{name}: {checks:?}");
        assert_eq!(code, want, "{name}: {checks:?}");
    }
    let limits = {
        let c = real_campaign(
            dir.path(),
            "limits2",
            &r.x,
            &r.y,
            &Edits {
                soft_limits: "500.0, 15000.0",
                range: "13800.0, 14000.0",
                ..GOOD
            },
        );
        check(&c, &db).1
    };
    let l = &limits.iter().find(|c| c.0 == "x: limits").unwrap().2;
    assert!(
        l.contains("[13780, 14020] µm") && l.contains("[-1000, 14000] µm"),
        "{l}"
    );

    // A store that cannot be written: read-only for a user, immutable for root.
    let ro = dir.path().join("ro.db");
    drop(Store::open(&ro).unwrap());
    let root = Command::new("id").arg("-u").output().unwrap().stdout == b"0\n";
    let locked = if root {
        Command::new("chattr")
            .arg("+i")
            .arg(&ro)
            .status()
            .is_ok_and(|s| s.success())
    } else {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o444)).is_ok()
    };
    if locked {
        let (code, checks) = check(&good, &ro);
        if root {
            let _ = Command::new("chattr").arg("-i").arg(&ro).status();
        }
        assert_eq!(failed(&checks), ["store"], "{checks:?}");
        assert_eq!(code, 1);
    } else {
        eprintln!("store fault not checked: cannot make a file read-only here");
    }

    // Nothing moved: the rig's controllers were only asked questions, and the carriage is
    // where it started.
    let (code, checks) = check(&good, &db);
    assert_eq!(code, 0, "{checks:?}");
    let x = &checks.iter().find(|c| c.0 == "x: referenced").unwrap().2;
    assert!(
        x.contains("encoder at 1000.000 µm") && x.starts_with("no "),
        "{x}"
    );
    let log = r.stop();
    assert!(log.len() > 20, "{log:?}");
    for (axis, cmd) in &log {
        assert!(cmd.contains('?'), "{axis} was sent {cmd:?}: not a query");
    }
    assert_eq!(campaigns(), 0, "nothing recorded");

    // The pattern out of view: the carriage parked beyond the coded area (12.4 mm).
    let r = rig::Rig::start(exe, &rig::rig_file(dir.path(), None, 12.9, 2.0, true));
    let good = real_campaign(dir.path(), "offpattern", &r.x, &r.y, &GOOD);
    let (code, checks) = check(&good, &db);
    assert_eq!(failed(&checks), ["pattern"], "{checks:?}");
    assert_eq!(code, 1);
    let log = r.stop();
    assert!(log.iter().all(|(_, c)| c.contains('?')), "{log:?}");
    assert_eq!(campaigns(), 0, "nothing recorded");
}

#[cfg(feature = "aravis")]
use std::process::Command;

#[test]
fn run_and_the_service_refuse_a_campaign_whose_rig_fails_the_preflight() {
    use csmetro::store::Store;

    let dir = tempfile::tempdir().unwrap();
    let closed = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().to_string()
    };
    let c = real_campaign(dir.path(), "refused", &closed, &closed, &GOOD);
    // With the aravis feature the controllers fail (the rig's business, exit 1); without it the
    // file is refused at validation: its camera backend is not built in (exit 2).
    let want = if cfg!(feature = "aravis") { 1 } else { 2 };

    let db = dir.path().join("run.db");
    let o = bin()
        .args(["run", "--quiet", "--db"])
        .arg(&db)
        .arg(&c)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(want), "{err}");
    let last = err.lines().last().unwrap_or_default();
    if want == 1 {
        assert!(
            last.starts_with("error: pre-flight check `") && last.contains("nothing was recorded"),
            "{err}"
        );
    } else {
        assert!(last.contains("--features aravis"), "{err}");
    }
    if want == 1 {
        assert!(
            last.contains("`x: controller` failed") && last.contains(&closed),
            "{last}"
        );
    }
    assert!(Store::open(&db).unwrap().campaigns().unwrap().is_empty());

    // The service: refused before it is recorded, 503 (the rig) or 409 (the file or build).
    let sdir = dir.path().join("svc");
    std::fs::create_dir_all(&sdir).unwrap();
    // The service lets submitted campaigns connect only where its configuration says.
    let cfg = common::write_config(&sdir, "127.0.0.1:0", None);
    let mut t = std::fs::read_to_string(&cfg).unwrap();
    t.push_str(&format!("\n[hardware]\ntcp_endpoints = [\"{closed}\"]\n"));
    std::fs::write(&cfg, t).unwrap();
    let server = common::Server::start(&sdir, None);
    let text = std::fs::read_to_string(&c)
        .unwrap()
        .replace(&format!("dir = \"{}/", dir.path().display()), "dir = \"");
    // An endpoint the configuration does not list: refused at validation, not tried.
    let unlisted = text.replace(&closed, "127.0.0.1:1");
    let (status, body) = server.post("/campaigns", Some(("application/toml", &unlisted)));
    assert_eq!(status, 400, "{body}");
    let msg = body["error"].as_str().unwrap_or_default();
    assert!(
        msg.contains(".transport:") && !msg.contains("127.0.0.1:1"),
        "{msg}"
    );

    let (status, body) = server.post("/campaigns", Some(("application/toml", &text)));
    let msg = body["error"].as_str().unwrap_or_default();
    if want == 1 {
        assert_eq!(status, 503, "{body}");
        assert!(msg.starts_with("pre-flight check `"), "{msg}");
        // One generic answer for an unreachable device: no "connection refused" oracle.
        assert!(
            msg.contains("unreachable or did not answer")
                && !msg.to_lowercase().contains("refused")
                && !msg.contains(&closed),
            "{msg}"
        );
    } else {
        assert_eq!(status, 400, "{body}");
        assert!(msg.contains("--features aravis"), "{msg}");
    }
    assert!(
        !msg.contains(&dir.path().display().to_string()),
        "a server path: {msg}"
    );
    let (s, list) = server.get("/campaigns");
    assert_eq!(s, 200);
    assert_eq!(list.as_array().map(Vec::len), Some(0), "{list}");
}
