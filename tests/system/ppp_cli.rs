//! `csmetro ppp render` → `csmetro ppp decode` through the binary: JSON fields, exit codes.
use std::path::Path;
use std::process::{Command, Output};

fn csmetro(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args(args)
        .output()
        .expect("run csmetro")
}

fn render(dir: &Path, name: &str, extra: &[&str]) -> String {
    let out = dir.join(name).display().to_string();
    let mut args = vec!["ppp", "render", "--out", &out];
    args.extend_from_slice(extra);
    let o = csmetro(&args);
    assert!(
        o.status.success(),
        "render failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

fn decode_json(path: &str) -> (Option<i32>, serde_json::Value) {
    let o = csmetro(&["ppp", "decode", path, "--json"]);
    let text = String::from_utf8_lossy(&o.stdout);
    let v: serde_json::Value =
        serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"));
    (o.status.code(), v)
}

#[test]
fn render_then_decode_round_trip_gives_the_pose() {
    let dir = tempfile::tempdir().unwrap();
    let f = render(
        dir.path(),
        "a.png",
        &[
            "--x-um",
            "1234.567",
            "--y-um",
            "3210.123",
            "--theta-mrad",
            "-12.5",
        ],
    );
    let (code, v) = decode_json(&f);
    assert_eq!(code, Some(0), "{v}");
    assert_eq!(v["ok"], true);
    let num = |k: &str| {
        v[k].as_f64()
            .unwrap_or_else(|| panic!("field {k} missing or not a number: {v}"))
    };
    // 1 px PSF and 1 % noise by default: a few nm.
    assert!((num("x_um") - 1234.567).abs() < 0.005, "{v}");
    assert!((num("y_um") - 3210.123).abs() < 0.005, "{v}");
    assert!((num("theta_mrad") + 12.5).abs() < 0.01, "{v}");
    assert!(num("decode_ms") > 0.0);
    assert!((num("period_px") - 4.0 / 0.465).abs() < 1e-3);
    for k in [
        "peak_snr",
        "modulation",
        "phase_rms_rad",
        "bits_x",
        "bits_y",
        "bit_errors_x",
        "margin_x",
        "margin_y",
    ] {
        num(k);
    }
    assert!(num("bits_x") >= 14.0 && num("bits_y") >= 14.0);
}

#[test]
fn range_edge_and_12_bit_frame_decode() {
    let dir = tempfile::tempdir().unwrap();
    let f = render(
        dir.path(),
        "edge.png",
        &[
            "--x-um",
            "9500",
            "--y-um",
            "0",
            "--theta-mrad",
            "20",
            "--bit-depth",
            "12",
        ],
    );
    let (code, v) = decode_json(&f);
    assert_eq!(code, Some(0), "{v}");
    assert!(
        (v["x_um"].as_f64().unwrap() - 9500.0).abs() < 0.005
            && v["y_um"].as_f64().unwrap().abs() < 0.005,
        "{v}"
    );
}

#[test]
fn undecodable_frame_is_rejected_with_reason_and_nonzero_exit() {
    let dir = tempfile::tempdir().unwrap();
    let f = render(
        dir.path(),
        "blur.png",
        &["--x-um", "100", "--y-um", "200", "--blur-px", "6"],
    );
    let (code, v) = decode_json(&f);
    assert_eq!(code, Some(3), "{v}");
    assert_eq!(v["ok"], false);
    assert!(v["reason"].as_str().is_some_and(|r| !r.is_empty()), "{v}");
    assert!(
        v["x_um"].is_null() && v["y_um"].is_null(),
        "a rejected frame has no position: {v}"
    );
    assert!(v["decode_ms"].as_f64().is_some());
}

#[test]
fn bad_input_exits_2_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.png").display().to_string();
    let o = csmetro(&["ppp", "decode", &missing]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");

    let not_png = dir.path().join("x.png");
    std::fs::write(&not_png, b"not a png").unwrap();
    assert_eq!(
        csmetro(&["ppp", "decode", not_png.to_str().unwrap()])
            .status
            .code(),
        Some(2)
    );

    let out = dir.path().join("o.png").display().to_string();
    let o = csmetro(&[
        "ppp",
        "render",
        "--x-um",
        "1",
        "--y-um",
        "1",
        "--bit-depth",
        "10",
        "--out",
        &out,
    ]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let o = csmetro(&[
        "ppp", "render", "--x-um", "1", "--y-um", "1", "--noise", "-1", "--out", &out,
    ]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn a_huge_png_is_refused_from_its_header_and_rejections_name_the_frame() {
    let dir = tempfile::tempdir().unwrap();
    // A header claiming 20000 x 20000 px (the decoder would need 400 MB for it) and no pixels.
    let huge = dir.path().join("huge.png");
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, 20_000, 20_000);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().unwrap();
        w.write_chunk(png::chunk::IDAT, &[0x78, 0x9c, 0x03, 0x00])
            .unwrap();
    }
    std::fs::write(&huge, bytes).unwrap();
    // Refused from the header (the error gives its size), before any decoding.
    let o = csmetro(&["ppp", "decode", huge.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("huge.png") && err.contains("20000 x 20000"),
        "{err}"
    );

    // A frame the decoder rejects: the text and the JSON name it.
    let f = render(
        dir.path(),
        "blurred.png",
        &["--x-um", "100", "--y-um", "200", "--blur-px", "6"],
    );
    let o = csmetro(&["ppp", "decode", &f]);
    assert_eq!(o.status.code(), Some(3));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.starts_with("rejected: ") && out.contains("blurred.png"),
        "{out}"
    );
    let (_, v) = decode_json(&f);
    assert_eq!(v["frame"], f.as_str(), "{v}");
}

#[test]
fn decode_refuses_a_fifo_instead_of_blocking() {
    // Opening a fifo blocks until a writer comes: the frame must be refused before that, as
    // every other input file is (exit 2, the file named).
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("frame.png");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let mut child = Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args(["ppp", "decode"])
        .arg(&fifo)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > std::time::Duration::from_secs(10) {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("`csmetro ppp decode FIFO` still blocked after 10 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("frame.png: not a regular file"), "{err}");
}
