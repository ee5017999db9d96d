//! `csmetro camera list|snap` as a user runs them: the simulated camera in every build, the
//! refusal of a backend the build lacks, and (with `--features aravis`) a GigE Vision camera on
//! 127.0.0.1 found, grabbed and decoded through the real Aravis client path.
mod common;

use std::process::Output;

use common::bin;

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("run csmetro")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// (x_um, y_um) from the decode line `x_um X y_um Y ...`.
fn decoded(stdout: &str) -> (f64, f64) {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("x_um "))
        .unwrap_or_else(|| panic!("no decode line in {stdout}"));
    let w: Vec<&str> = line.split_whitespace().collect();
    (w[1].parse().unwrap(), w[3].parse().unwrap())
}

#[test]
fn snap_of_the_simulated_camera_writes_the_frame_and_decodes_where_it_looks() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("frame.png");
    let o = run(&[
        "camera",
        "snap",
        "--id",
        "sim",
        "--sim-x-um",
        "3210.5",
        "--sim-y-um",
        "1234.25",
        "--out",
        png.to_str().unwrap(),
        "--decode",
    ]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}{err}");
    assert!(out.contains("frame: 1024x768 Mono8"), "{out}");
    let (x, y) = decoded(&out);
    assert!(
        (x - 3210.5).abs() < 0.5 && (y - 1234.25).abs() < 0.5,
        "{out}"
    );
    // The PNG is the frame: `csmetro ppp decode` reads the same position from it.
    let o = run(&["ppp", "decode", png.to_str().unwrap()]);
    let (out2, err2) = text(&o);
    assert!(o.status.success(), "{out2}{err2}");
    let (x2, y2) = decoded(&out2);
    assert!((x2 - x).abs() < 1e-3 && (y2 - y).abs() < 1e-3, "{out2}");
}

#[test]
fn bad_ids_and_backends_this_build_lacks_exit_2_naming_the_feature() {
    for bad in ["ip:999.1.1.1", "guid:0xnothex"] {
        let o = run(&["camera", "snap", "--id", bad]);
        let (out, err) = text(&o);
        assert_eq!(o.status.code(), Some(2), "{bad}: {out}{err}");
        assert!(err.contains(bad) && err.lines().count() == 1, "{err}");
    }
    let o = run(&["camera", "snap", "--id", "guid:0x000a47010e0a1b2c"]);
    let (out, err) = text(&o);
    if cfg!(feature = "firewire") {
        // The real library, no IEEE 1394 bus here: a clean error, not a crash.
        assert_eq!(o.status.code(), Some(1), "{out}{err}");
        assert!(err.contains("no IIDC camera found"), "{err}");
    } else {
        assert_eq!(o.status.code(), Some(2), "{out}{err}");
        assert!(err.contains("--features firewire"), "{err}");
    }
    if !cfg!(feature = "aravis") {
        let o = run(&["camera", "snap", "--id", "ip:192.168.1.20"]);
        let (out, err) = text(&o);
        assert_eq!(o.status.code(), Some(2), "{out}{err}");
        assert!(err.contains("--features aravis"), "{err}");
        // The campaign's camera: refused by the campaign's validation, with file and line.
        let lab = common::repo("config/campaigns/lab-xy-real.toml");
        let o = run(&["camera", "snap", "--campaign", lab.to_str().unwrap()]);
        let (out, err) = text(&o);
        assert_eq!(o.status.code(), Some(2), "{out}{err}");
        assert!(
            err.contains("lab-xy-real.toml:")
                && err.contains("hardware.camera.backend = \"aravis\" needs a csmetro built with --features aravis"),
            "{err}"
        );
    }
}

/// Without the aravis feature no camera can be on any backend of this machine (no 1394 bus).
#[cfg(not(feature = "aravis"))]
#[test]
fn with_no_camera_list_and_snap_say_so_and_fail() {
    let o = run(&["camera", "list"]);
    let (out, err) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{out}{err}");
    assert!(
        out.contains("aravis: not in this build (rebuild with --features aravis)"),
        "{out}"
    );
    assert!(err.contains("no camera found"), "{err}");
    let o = run(&["camera", "snap", "--decode"]);
    let (out, err) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{out}{err}");
    assert!(err.contains("no camera found"), "{err}");
}

#[cfg(feature = "aravis")]
mod gige {
    use std::sync::Arc;

    use csmetro_camera::{FakeGvCamera, FrameSource};
    use csmetro_hal::Pixels;
    use csmetro_ppp::render;
    use csmetro_ppp::{Optics, Pattern, PatternConfig, Pose};

    use super::*;

    #[test]
    fn list_and_snap_find_grab_and_decode_the_fake_gige_camera() {
        let (x, y) = (2718.3, 1414.2);
        let pattern = Pattern::new(PatternConfig::default()).unwrap();
        let source: FrameSource = Arc::new(move |buf: &mut [u8], w: usize, h: usize| {
            let optics = Optics {
                width: w,
                height: h,
                ..Optics::default()
            };
            if let Pixels::Mono8(p) = render(&pattern, &optics, Pose::new(x, y, 0.0), 3).pixels {
                buf[..p.len()].copy_from_slice(&p);
            }
        });
        let fake = FakeGvCamera::start(source).expect("fake GV camera on 127.0.0.1");

        let o = run(&["camera", "list"]);
        let (out, err) = text(&o);
        assert!(o.status.success(), "{out}{err}");
        let line = out
            .lines()
            .find(|l| l.contains(fake.serial()))
            .unwrap_or_else(|| panic!("fake camera not listed: {out}"));
        assert!(
            line.starts_with("aravis: ") && line.contains("backend = \"aravis\", id = { device_id"),
            "{line}"
        );

        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("gv.png");
        for id in [Some("ip:127.0.0.1"), None] {
            let mut args = vec!["camera", "snap", "--out", png.to_str().unwrap(), "--decode"];
            if let Some(id) = id {
                args.extend(["--id", id]);
            }
            let o = run(&args);
            let (out, err) = text(&o);
            assert!(o.status.success(), "{id:?}: {out}{err}");
            assert!(out.contains(fake.serial()), "camera line names it: {out}");
            let (dx, dy) = decoded(&out);
            assert!(
                (dx - x).abs() < 0.5 && (dy - y).abs() < 0.5,
                "{id:?}: {out}"
            );
            assert!(png.is_file());
        }
    }
}
