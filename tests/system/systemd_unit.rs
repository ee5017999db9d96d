//! The shipped systemd unit: the directives the service relies on (notify + watchdog, restart,
//! hardening, serial and camera devices only) and that the configuration it names is a valid one.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use csmetro::api::ServiceConfig;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// section -> key -> every value given (a key may repeat, e.g. DeviceAllow).
fn parse_unit(text: &str) -> BTreeMap<String, BTreeMap<String, Vec<String>>> {
    let mut out: BTreeMap<String, BTreeMap<String, Vec<String>>> = BTreeMap::new();
    let mut section = String::new();
    for l in text.lines().map(str::trim) {
        if l.is_empty() || l.starts_with('#') || l.starts_with(';') {
            continue;
        }
        if let Some(s) = l.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            section = s.to_string();
            continue;
        }
        let (k, v) = l.split_once('=').expect("key=value line");
        out.entry(section.clone())
            .or_default()
            .entry(k.trim().to_string())
            .or_default()
            .push(v.trim().to_string());
    }
    out
}

fn one<'a>(u: &'a BTreeMap<String, BTreeMap<String, Vec<String>>>, key: &str) -> &'a str {
    let v = u["Service"]
        .get(key)
        .unwrap_or_else(|| panic!("[Service] has no {key}"));
    assert_eq!(v.len(), 1, "{key} given more than once: {v:?}");
    &v[0]
}

#[test]
fn unit_has_notify_watchdog_restart_and_hardening() {
    let text = std::fs::read_to_string(repo("systemd/csmetro.service")).unwrap();
    let u = parse_unit(&text);
    assert_eq!(one(&u, "Type"), "notify");
    let wd: u64 = one(&u, "WatchdogSec").parse().expect("WatchdogSec in s");
    assert!((5..=120).contains(&wd), "WatchdogSec={wd}");
    assert_eq!(one(&u, "Restart"), "on-failure");
    assert_eq!(one(&u, "ProtectSystem"), "strict");
    assert_eq!(one(&u, "ProtectHome"), "yes");
    assert_eq!(one(&u, "PrivateTmp"), "yes");
    assert_eq!(one(&u, "NoNewPrivileges"), "yes");
    assert_eq!(one(&u, "User"), "csmetro");
    assert_eq!(one(&u, "StateDirectory"), "csmetro");
    assert!(u["Service"].get("DynamicUser").is_none_or(|v| v == &["no"]));
    assert!(one(&u, "SupplementaryGroups").contains("dialout"));
    // Devices: closed policy, and only serial lines (plus pseudo-terminals for the simulator)
    // and the cameras' USB (USB3 Vision) and FireWire (IIDC) nodes.
    assert_eq!(one(&u, "DevicePolicy"), "closed");
    let allowed = &u["Service"]["DeviceAllow"];
    for want in [
        "char-ttyS rw",
        "char-ttyUSB rw",
        "char-ttyACM rw",
        "char-usb_device rw",
        "char-firewire rw",
    ] {
        assert!(
            allowed.iter().any(|a| a == want),
            "DeviceAllow={want} missing: {allowed:?}"
        );
    }
    for a in allowed {
        let dev = a.split_whitespace().next().unwrap();
        assert!(
            [
                "char-ttyS",
                "char-ttyUSB",
                "char-ttyACM",
                "char-pts",
                "/dev/ptmx",
                "char-usb_device",
                "char-firewire",
            ]
            .contains(&dev),
            "unexpected device access {a:?}"
        );
    }
    // Stopping must leave time for the service's own 10 s grace.
    let stop: u64 = one(&u, "TimeoutStopSec").parse().unwrap();
    assert!(
        stop > csmetro::api::SHUTDOWN_GRACE.as_secs(),
        "TimeoutStopSec={stop}"
    );
    assert_eq!(u["Install"]["WantedBy"], ["multi-user.target"]);
}

#[test]
fn unit_config_parses_and_keeps_state_in_the_state_directory() {
    let text = std::fs::read_to_string(repo("systemd/csmetro.service")).unwrap();
    let u = parse_unit(&text);
    let exec = one(&u, "ExecStart");
    let args: Vec<&str> = exec.split_whitespace().collect();
    assert_eq!(args[..2], ["/usr/local/bin/csmetro", "serve"]);
    let i = args
        .iter()
        .position(|a| *a == "--config")
        .expect("--config");
    assert_eq!(args[i + 1], "/etc/csmetro/csmetro.toml");

    // The file installed there is systemd/csmetro.toml.
    let cfg_text = std::fs::read_to_string(repo("systemd/csmetro.toml")).unwrap();
    let cfg = ServiceConfig::parse(&cfg_text, args[i + 1], Path::new("/etc/csmetro"))
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(cfg.bind.ip().is_loopback(), "{}", cfg.bind);
    assert!(
        cfg.db.starts_with("/var/lib/csmetro"),
        "{}",
        cfg.db.display()
    );
    assert!(cfg.results_dir.starts_with("/var/lib/csmetro"));
    assert!(cfg.token.is_none());
    // The shipped campaigns name their models as ../sim/...: submitting them must work.
    assert_eq!(
        cfg.models_dir.as_deref(),
        Some(Path::new("/etc/csmetro/sim"))
    );
    // Stage locks are shared with local `csmetro run` processes through /run/lock.
    assert!(
        u["Service"]["ReadWritePaths"]
            .iter()
            .any(|p| p == "/run/lock"),
        "ReadWritePaths {:?}",
        u["Service"]["ReadWritePaths"]
    );
}

#[test]
fn repository_config_parses() {
    let cfg = ServiceConfig::load(&repo("config/csmetro.toml")).unwrap_or_else(|e| panic!("{e}"));
    assert!(cfg.bind.ip().is_loopback());
    assert!(cfg.campaigns_dir.join("demo-sim.toml").is_file());
}

/// `systemd-analyze verify` where it exists (it needs the binary at the ExecStart path, so
/// only the unit's syntax is checked: unknown directives are reported on stderr).
#[test]
fn systemd_analyze_knows_every_directive_when_available() {
    let Ok(out) = std::process::Command::new("systemd-analyze")
        .arg("verify")
        .arg(repo("systemd/csmetro.service"))
        .output()
    else {
        return;
    };
    let err = String::from_utf8_lossy(&out.stderr);
    for l in err.lines() {
        assert!(
            !l.contains("Unknown key") && !l.contains("Unknown section"),
            "systemd-analyze: {l}"
        );
    }
}

/// The unit documents the udev rules that give the service's group the camera nodes the
/// DeviceAllow classes let through.
#[test]
fn camera_udev_rules_for_the_allowed_device_classes_are_documented() {
    let text = std::fs::read_to_string(repo("systemd/csmetro.service")).unwrap();
    // The rules a lab copies: group csmetro, mode 0660, one for USB, one for FireWire.
    let rules: Vec<&str> = text
        .lines()
        .filter_map(|l| l.trim_start_matches('#').trim().split("   #").next())
        .filter(|l| l.starts_with("SUBSYSTEM=="))
        .collect();
    for subsystem in ["usb", "firewire"] {
        let r = rules
            .iter()
            .find(|r| r.starts_with(&format!("SUBSYSTEM==\"{subsystem}\"")))
            .unwrap_or_else(|| panic!("no udev rule for {subsystem} in the unit: {rules:?}"));
        assert!(
            r.contains("GROUP=\"csmetro\"") && r.contains("MODE=\"0660\""),
            "{r}"
        );
    }
}
