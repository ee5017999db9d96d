use super::*;

const GOOD: &str = r#"
[campaign]
name = "t"

[hardware]
kind = "sim"

[axes.x]
range_um = [0.0, 9500.0]
step_um = 5.0
other_at_um = 2100.0

[sampling]
m = 300
"#;

fn line(t: &str, needle: &str) -> usize {
    t.lines().position(|l| l.contains(needle)).unwrap() + 1
}

fn parse(t: &str) -> Result<Campaign, SpecError> {
    Campaign::parse(t, "c.toml", Path::new("."))
}

#[test]
fn a_minimal_campaign_resolves_grid_and_defaults() {
    let c = parse(GOOD).unwrap();
    assert_eq!(c.axes.len(), 1);
    assert_eq!(c.axes[0].grid.n, 1901);
    assert_eq!(c.axes[0].m, 300);
    assert_eq!(c.spec.acquisition.directions.len(), 2);
    assert_eq!(c.method, Method::Auto);
}

/// The issue-40 rule: nothing assumes the simulator's 400 µm pitch; a configured one is a hint
/// handed to the reconstruction, and must be a length.
#[test]
fn the_pitch_is_a_hint_only_when_configured() {
    let c = parse(GOOD).unwrap();
    assert_eq!(crate::campaign::worker::settings(&c).pitch_um, None);
    let t = format!("{GOOD}\n[reconstruction]\npitch_um = 250.0\n");
    let c = parse(&t).unwrap();
    assert_eq!(crate::campaign::worker::settings(&c).pitch_um, Some(250.0));
    let t = format!("{GOOD}\n[reconstruction]\npitch_um = -1.0\n");
    let e = parse(&t).unwrap_err().to_string();
    assert!(e.contains("reconstruction.pitch_um"), "{e}");
}

#[test]
fn unknown_key_names_file_line_and_key() {
    let t = GOOD.replace("step_um = 5.0", "step_um = 5.0\nstpe = 3");
    let e = parse(&t).unwrap_err();
    let l = line(&t, "stpe");
    assert_eq!(e.line, l, "{e}");
    assert!(
        e.to_string()
            .starts_with(&format!("c.toml:{l}: axes.x.stpe:")),
        "{e}"
    );
    assert!(e.message.contains("stpe"), "{e}");
}

#[test]
fn wrong_type_names_the_key() {
    let t = GOOD.replace("m = 300", "m = \"many\"");
    let e = parse(&t).unwrap_err();
    assert_eq!(e.key, "sampling.m", "{e}");
    assert_eq!(e.line, line(&t, "many"), "{e}");
}

#[test]
fn semantic_errors_point_at_the_key() {
    let t = GOOD.replace("m = 300", "m = 5000");
    let e = parse(&t).unwrap_err();
    assert_eq!(
        (e.key.as_str(), e.line),
        ("sampling.m", line(&t, "m = 5000")),
        "{e}"
    );

    let t = GOOD.replace("range_um = [0.0, 9500.0]", "range_um = [0.0, 13500.0]");
    let e = parse(&t).unwrap_err();
    assert_eq!(
        (e.key.as_str(), e.line),
        ("axes.x.range_um", line(&t, "13500")),
        "{e}"
    );
    assert!(e.message.contains("soft limits"), "{e}");

    let t = GOOD.replace("range_um = [0.0, 9500.0]", "range_um = [0.0, 9502.0]");
    let e = parse(&t).unwrap_err();
    assert_eq!(e.key, "axes.x.range_um", "{e}");

    let t = format!("{GOOD}\n[reconstruction]\nmethod = \"magic\"\n");
    let e = parse(&t).unwrap_err();
    assert_eq!(e.key, "reconstruction.method", "{e}");
    assert!(e.message.contains("unknown method"), "{e}");

    let t = GOOD.replace("name = \"t\"", "name = \"\"");
    assert_eq!(parse(&t).unwrap_err().key, "campaign.name");

    let t = GOOD.replace("kind = \"sim\"", "kind = \"real\"");
    assert_eq!(parse(&t).unwrap_err().key, "hardware.controllers");
}

#[test]
fn a_missing_model_file_is_refused_before_anything_runs() {
    let t = GOOD.replace(
        "kind = \"sim\"",
        "kind = \"sim\"\n[hardware.sim]\nmodel = \"nope.toml\"",
    );
    let e = parse(&t).unwrap_err();
    assert_eq!(e.key, "hardware.sim.model", "{e}");
    assert!(e.message.contains("nope.toml"), "{e}");
}

#[test]
fn range_um_takes_exactly_two_numbers() {
    let t = GOOD.replace("[0.0, 9500.0]", "[0.0, 500.0, 1000.0]");
    let e = parse(&t).unwrap_err();
    assert_eq!(
        (e.key.as_str(), e.line),
        ("axes.x.range_um", line(&t, "1000.0")),
        "{e}"
    );
    assert!(e.message.contains("exactly 2"), "{e}");
    let t = GOOD.replace("[0.0, 9500.0]", "[0.0]");
    assert_eq!(parse(&t).unwrap_err().key, "axes.x.range_um");
}

#[test]
fn grids_too_large_for_the_method_are_refused() {
    let t = GOOD.replace("step_um = 5.0", "step_um = 0.1") + "[reconstruction]\nmethod = \"bp\"\n";
    let e = parse(&t).unwrap_err();
    assert_eq!(e.key, "axes.x.range_um", "{e}");
    assert!(e.message.contains("at most 65536"), "{e}");
    parse(&t.replace("\"bp\"", "\"pchip\"")).unwrap();
}

#[test]
fn a_huge_grid_is_refused_before_allocating() {
    let t = GOOD.replace("step_um = 5.0", "step_um = 1e-7");
    let e = parse(&t).unwrap_err();
    assert_eq!(e.key, "axes.x.range_um", "{e}");
    assert!(e.message.contains("more than"), "{e}");
}

#[test]
fn names_are_bounded_and_plain() {
    for (find, bad, key) in [
        (
            "name = \"t\"",
            format!("name = \"{}\"", "n".repeat(65)),
            "campaign.name",
        ),
        ("name = \"t\"", "name = \"..\"".into(), "campaign.name"),
        ("name = \"t\"", "name = \"a/b\"".into(), "campaign.name"),
        (
            "name = \"t\"",
            format!("name = \"t\"\nstage = \"{}\"", "s".repeat(300)),
            "campaign.stage",
        ),
        (
            "name = \"t\"",
            "name = \"t\"\nstage = \"a b\"".into(),
            "campaign.stage",
        ),
    ] {
        let t = GOOD.replace(find, &bad);
        assert_eq!(parse(&t).unwrap_err().key, key, "{bad}");
    }
    let t = GOOD.replace(
        "name = \"t\"",
        "name = \"demo-sim_2.b\"\nstage = \"sim-xy\"",
    );
    parse(&t).unwrap();
}

#[test]
fn a_campaign_planning_billions_of_points_is_refused() {
    let t = GOOD.replace("step_um = 5.0", "step_um = 0.01")
        + "full_scan = true\n[acquisition]\ncycles = 1000\n\
           [reconstruction]\nmethod = \"pchip\"\n";
    let e = parse(&t).unwrap_err();
    assert!(e.message.contains("would plan more than"), "{e}");
}

#[test]
fn model_files_are_regular_and_bounded() {
    for dev in ["/dev/zero", "/proc/self/environ", "/"] {
        let t = GOOD.replace(
            "kind = \"sim\"",
            &format!("kind = \"sim\"\n[hardware.sim]\nmodel = \"{dev}\""),
        );
        let e = parse(&t).unwrap_err();
        assert_eq!(e.key, "hardware.sim.model", "{e}");
        assert!(e.message.contains("not a regular file"), "{dev}: {e}");
    }
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("big.toml"), vec![b'#'; 2 << 20]).unwrap();
    let t = GOOD.replace(
        "kind = \"sim\"",
        "kind = \"sim\"\n[hardware.sim]\nmodel = \"big.toml\"",
    );
    let e = Campaign::parse(&t, "c.toml", dir.path()).unwrap_err();
    assert!(e.message.contains("larger than"), "{e}");
}

fn policy(dir: &Path) -> SubmitPolicy {
    SubmitPolicy {
        base_dir: dir.join("campaigns"),
        read_roots: vec![dir.join("campaigns"), dir.join("sim")],
        results_dir: dir.join("results"),
        serial_ports: vec![],
        tcp_endpoints: vec!["127.0.0.1:50863".into()],
    }
}

#[test]
fn submitted_models_resolve_inside_the_roots_only() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for sub in ["campaigns", "sim", "other"] {
        std::fs::create_dir(d.join(sub)).unwrap();
        std::fs::copy(
            concat!(env!("CARGO_MANIFEST_DIR"), "/config/sim/ideal.toml"),
            d.join(sub).join("m.toml"),
        )
        .unwrap();
    }
    let with = |m: &str| {
        GOOD.replace(
            "kind = \"sim\"",
            &format!("kind = \"sim\"\n[hardware.sim]\nmodel = {m:?}"),
        )
    };
    let p = policy(d);
    for ok in ["m.toml", "../sim/m.toml", "./m.toml"] {
        Campaign::parse_submitted(&with(ok), "s.toml", &p).unwrap_or_else(|e| panic!("{ok}: {e}"));
    }
    let abs = d.join("sim/m.toml").display().to_string();
    for bad in ["../other/m.toml", "../../m.toml", abs.as_str(), "m.txt", ""] {
        let e = Campaign::parse_submitted(&with(bad), "s.toml", &p).unwrap_err();
        assert_eq!(e.key, "hardware.sim.model", "{bad}: {e}");
        assert!(!e.to_string().contains(&d.display().to_string()), "{e}");
    }
    // A link out of the directory is refused even though its name is inside.
    std::os::unix::fs::symlink(d.join("other/m.toml"), d.join("campaigns/l.toml")).unwrap();
    let e = Campaign::parse_submitted(&with("l.toml"), "s.toml", &p).unwrap_err();
    assert_eq!(e.key, "hardware.sim.model", "{e}");
    // The local operator's own file may name what it likes.
    Campaign::parse(&with(&abs), "c.toml", d).unwrap();
    // Results were probed below the results directory: the probe file is gone.
    let out = d.join("results/csmetro-results");
    let left: Vec<_> = std::fs::read_dir(&out).unwrap().collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn a_submitted_real_campaign_opens_serial_devices_only() {
    let dir = tempfile::tempdir().unwrap();
    let p = policy(dir.path());
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/campaigns/lab-xy-real.toml"
    ))
    .unwrap();
    let port = "/dev/serial/by-id/usb-PI_C-863_0115500001-if00-port0";
    for bad in [
        "/etc/passwd",
        "/dev/../etc/passwd",
        "/dev/zero/../../etc/passwd",
        // A character device, but not in the service's list.
        "/dev/null",
    ] {
        let t = text.replace(port, bad);
        let e = Campaign::parse_submitted(&t, "r.toml", &p).unwrap_err();
        assert_eq!(e.key, "hardware.controllers.x.transport", "{bad}: {e}");
        assert!(!e.to_string().contains("passwd"), "{e}");
        // The local operator names their own ports (a build without the file's camera backend
        // refuses it for that reason alone: tested in `a_camera_backend_this_build_lacks_...`).
        Campaign::parse_any_build(&t, "r.toml", dir.path()).unwrap();
    }
}

#[test]
fn a_submitted_real_campaign_connects_to_listed_endpoints_only() {
    let dir = tempfile::tempdir().unwrap();
    let p = policy(dir.path());
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/campaigns/lab-xy-rig.toml"
    ))
    .unwrap();
    let listed = "127.0.0.1:50863";
    assert!(text.contains(listed), "the rig file's x controller");
    for bad in ["127.0.0.1:22", "db.internal:5432"] {
        let t = text.replace(listed, bad);
        let e = Campaign::parse_submitted(&t, "r.toml", &p).unwrap_err();
        assert_eq!(e.key, "hardware.controllers.x.transport", "{bad}: {e}");
        assert!(!e.to_string().contains(bad), "{e}");
    }
}

#[test]
fn outputs_must_be_writable_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("c.toml");
    let t = format!("{GOOD}\n[outputs]\ndir = \"/proc/csmetro-{{name}}-{{id}}\"\n");
    std::fs::write(&f, t).unwrap();
    let e = Campaign::load(&f).unwrap_err();
    assert_eq!(e.key, "outputs.dir", "{e}");
    assert!(e.line > 0, "{e}");
    let out = dir.path().join("r");
    let t = format!(
        "{GOOD}\n[outputs]\ndir = \"{}/{{name}}-{{id}}\"\n",
        out.display()
    );
    std::fs::write(&f, t).unwrap();
    Campaign::load(&f).unwrap();
    assert!(!out.exists(), "the probe leaves nothing behind");
}

#[test]
fn syntax_errors_give_a_line() {
    let e = parse("[campaign\nname = 1").unwrap_err();
    assert_eq!(e.line, 1, "{e}");
}

/// The lab template with its camera section replaced by `camera` (a `[hardware.camera]` table).
fn real_with_camera(camera: &str) -> String {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/campaigns/lab-xy-real.toml"
    ))
    .unwrap();
    let start = text.find("[hardware.camera]").unwrap();
    let end = start + text[start..].find("\n[axes.x]").unwrap();
    format!("{}{camera}\n{}", &text[..start], &text[end..])
}

#[test]
fn a_camera_backend_this_build_lacks_is_refused_at_validation_naming_the_feature() {
    let dir = tempfile::tempdir().unwrap();
    let fw = real_with_camera(
        "[hardware.camera]\nbackend = \"firewire\"\nid = { guid = \"0x000a47010e0a1b2c\" }\n\
         exposure_us = 8000.0\n",
    );
    let ar = real_with_camera(
        "[hardware.camera]\nid = { serial = \"50-0536876543\" }\nexposure_us = 8000.0\n",
    );
    for (text, backend, compiled) in [
        (&fw, "firewire", cfg!(feature = "firewire")),
        (&ar, "aravis", cfg!(feature = "aravis")),
    ] {
        // Valid for a build that has the backend.
        Campaign::parse_any_build(text, "r.toml", dir.path()).unwrap();
        let got = Campaign::parse(text, "r.toml", dir.path());
        if compiled {
            got.unwrap();
            continue;
        }
        let e = got.unwrap_err();
        assert!(
            e.message.contains(&format!(
                "hardware.camera.backend = \"{backend}\" needs a csmetro built with --features {backend}"
            )),
            "{e}"
        );
        // Line of the backend key where written, else of the camera table.
        let want = if backend == "firewire" {
            ("hardware.camera.backend", line(text, "backend = "))
        } else {
            ("hardware.camera", line(text, "[hardware.camera]"))
        };
        assert_eq!((e.key.as_str(), e.line), want, "{e}");
        // The service's path refuses it the same way (its ports allowed).
        let mut p = policy(dir.path());
        p.serial_ports = vec!["/dev/null".into()];
        let e = Campaign::parse_submitted(
            &text
                .replace(
                    "/dev/serial/by-id/usb-PI_C-863_0115500001-if00-port0",
                    "/dev/null",
                )
                .replace(
                    "/dev/serial/by-id/usb-PI_C-863_0115500002-if00-port0",
                    "/dev/null",
                ),
            "r.toml",
            &p,
        )
        .unwrap_err();
        assert!(e.message.contains("--features"), "{e}");
    }
}

/// `[uncertainty]`: the budget's inputs are checked at validation (file:line of the key) and a
/// temperature brings the thermal contribution.
#[test]
fn uncertainty_inputs_are_checked_and_reach_the_budget() {
    let c = parse(GOOD).unwrap();
    let d = c.spec.uncertainty.inputs().unwrap();
    assert!(d.thermal.is_none() && d.k == 2.0);

    let t = format!("{GOOD}\n[uncertainty]\ntemperature_c = 22.5\npitch_u_ppm = 5\n");
    let b = parse(&t).unwrap().spec.uncertainty.inputs().unwrap();
    assert_eq!(b.pitch_u_ppm, 5.0);
    assert_eq!(b.thermal.map(|t| t.temperature_c), Some(22.5));

    let t = format!("{GOOD}\n[uncertainty]\nk = 0.5\n");
    let e = parse(&t).unwrap_err();
    assert_eq!(
        (e.key.as_str(), e.line),
        ("uncertainty.k", line(&t, "k = 0.5")),
        "{e}"
    );
    let t = format!("{GOOD}\n[uncertainty]\nsensor_u_um = -1\n");
    assert_eq!(parse(&t).unwrap_err().key, "uncertainty.sensor_u_um");
    let t = format!("{GOOD}\n[uncertainty]\ncoverage = 2\n");
    assert!(parse(&t).is_err(), "unknown keys are refused");
}
