//! End to end through the real Aravis client: a fake GigE Vision camera on 127.0.0.1 whose
//! frames our code draws, opened and grabbed by `AravisCamera` like a hardware camera.
//!
//! Only one fake GV camera can serve 127.0.0.1, so every test takes the one shared fixture
//! through a mutex (tests run one at a time) and sets its own frame source.
#![cfg(feature = "aravis")]

use std::net::Ipv4Addr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};
use std::time::{Duration, Instant};

use csmetro_camera::{
    AravisCamera, CameraConfig, CameraId, FakeGvCamera, FrameSource, PixelFormat, Roi,
};
use csmetro_hal::{Camera, CameraError, Frame, Pixels};

static FIXTURE: OnceLock<Mutex<Option<FakeGvCamera>>> = OnceLock::new();

/// The shared fake camera, started on first use (or after a test stopped it).
fn fixture() -> MutexGuard<'static, Option<FakeGvCamera>> {
    let mut guard = FIXTURE
        .get_or_init(|| Mutex::new(None))
        .lock()
        // A failed test must not take the others down with it.
        .unwrap_or_else(|e| e.into_inner());
    match guard.as_ref() {
        None => *guard = Some(FakeGvCamera::start(blank_source()).expect("start fake GV camera")),
        // The fake keeps drawing after a test's camera is gone: a source the last test left
        // (Mono16's asserts two bytes per pixel) would fail on the next test's frames and count
        // as a source panic there.
        Some(fake) => fake.set_source(blank_source()),
    }
    guard
}

fn blank_source() -> FrameSource {
    Arc::new(|buf: &mut [u8], _w: usize, _h: usize| buf.fill(0))
}

/// Frame `k` of the counter pattern: k (u64 LE) in the first 8 bytes, then a ramp shifted by k.
fn counter_frame(k: u64, w: usize, h: usize) -> Vec<u8> {
    let mut buf = vec![0u8; w * h];
    draw_counter(&mut buf, w, k);
    buf
}

fn draw_counter(buf: &mut [u8], w: usize, k: u64) {
    for (i, p) in buf.iter_mut().enumerate() {
        *p = ((i % w) as u64 + 7 * (i / w) as u64 + 13 * k) as u8;
    }
    buf[..8].copy_from_slice(&k.to_le_bytes());
}

/// A source drawing the counter pattern; the counter holds the number of frames drawn.
fn counter_source(counter: Arc<AtomicU64>) -> FrameSource {
    Arc::new(move |buf: &mut [u8], w: usize, _h: usize| {
        draw_counter(buf, w, counter.fetch_add(1, Ordering::SeqCst))
    })
}

fn mono8(frame: &Frame) -> &[u8] {
    match &frame.pixels {
        Pixels::Mono8(p) => p,
        other => panic!("expected Mono8, got {other:?}"),
    }
}

/// Panics with the first differing pixel (never dumps whole frames).
fn assert_pixels(got: &[u8], want: &[u8], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    if let Some(i) = got.iter().zip(want).position(|(a, b)| a != b) {
        let bad = got.iter().zip(want).filter(|(a, b)| a != b).count();
        panic!(
            "{what}: {bad} of {} bytes differ, first at {i}: got {}, want {}",
            got.len(),
            got[i],
            want[i]
        );
    }
}

/// Asserts the frame is exactly counter frame `k` (k read from the frame) and returns k.
fn assert_counter_frame(frame: &Frame) -> u64 {
    let k = counter_of(frame);
    assert_pixels(
        mono8(frame),
        &counter_frame(k, frame.width, frame.height),
        &format!("counter frame {k}"),
    );
    k
}

fn counter_of(frame: &Frame) -> u64 {
    u64::from_le_bytes(mono8(frame)[..8].try_into().unwrap())
}

fn open(fake: &FakeGvCamera) -> AravisCamera {
    AravisCamera::open(fake.camera_config(1000.0)).expect("open fake camera by IP")
}

const GRAB: Duration = Duration::from_secs(2);

#[test]
fn opens_by_ip_serial_and_device_id_and_refuses_unknown_serial() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    for id in [
        CameraId::Ip(Ipv4Addr::LOCALHOST),
        CameraId::Serial(fake.serial().to_string()),
        CameraId::DeviceId(fake.device_id()),
    ] {
        let mut cam = AravisCamera::open(CameraConfig::new(id.clone(), 1000.0))
            .unwrap_or_else(|e| panic!("open by {id}: {e}"));
        assert_eq!(cam.serial(), fake.serial(), "opened by {id}");
        assert!(cam.describe().contains(fake.serial()), "{}", cam.describe());
        let (w, h) = (fake.options().sensor_width, fake.options().sensor_height);
        assert_eq!(
            (cam.limits().sensor_width, cam.limits().sensor_height),
            (w, h),
            "sensor size set by the fixture"
        );
        let f = cam
            .grab(GRAB)
            .unwrap_or_else(|e| panic!("grab by {id}: {e}"));
        assert_eq!(
            (f.width, f.height, f.bit_depth),
            (w as usize, h as usize, 8)
        );
    }
    let err = AravisCamera::open(CameraConfig::new(
        CameraId::Serial("NOSUCHCAM".into()),
        1000.0,
    ))
    .err()
    .expect("unknown serial must not open");
    assert!(
        matches!(&err, CameraError::Disconnected(m) if m.contains("no camera with serial NOSUCHCAM")),
        "{err}"
    );
}

#[test]
fn mono8_frames_are_byte_exact_and_each_grab_is_a_new_exposure() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    let counter = Arc::new(AtomicU64::new(0));
    fake.set_source(counter_source(counter.clone()));
    let mut cam = open(fake);
    let mut last = None;
    for _ in 0..10 {
        let f = cam.grab(GRAB).expect("grab");
        let k = assert_counter_frame(&f);
        if let Some(prev) = last {
            assert_eq!(k, prev + 1, "one trigger must give exactly one new frame");
        }
        assert_eq!(
            k + 1,
            counter.load(Ordering::SeqCst),
            "grab returned the newest frame"
        );
        last = Some(k);
    }
}

#[test]
fn hundred_triggered_frames_none_incomplete_with_latency_figures() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    // A precomputed image stamped with a frame counter: a memcpy per frame, so the figures
    // measure the trigger/transport path rather than drawing in an unoptimised test build.
    let (w, h) = (
        fake.options().sensor_width as usize,
        fake.options().sensor_height as usize,
    );
    let base = Arc::new(counter_frame(0, w, h));
    let counter = Arc::new(AtomicU64::new(1));
    let (b, c) = (base.clone(), counter.clone());
    fake.set_source(Arc::new(move |buf: &mut [u8], _w: usize, _h: usize| {
        buf.copy_from_slice(&b);
        buf[..8].copy_from_slice(&c.fetch_add(1, Ordering::SeqCst).to_le_bytes());
    }));
    let mut cam = open(fake);
    let (_, failures_before, _) = cam.stream_statistics().unwrap();
    // CSMETRO_CAMERA_FRAMES=1000 for a longer measurement.
    let n_frames: usize = std::env::var("CSMETRO_CAMERA_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100);
    let mut latencies = Vec::with_capacity(n_frames);
    let mut errors = Vec::new();
    for _ in 0..n_frames {
        let t = Instant::now();
        match cam.grab(GRAB) {
            Ok(f) => {
                latencies.push(t.elapsed());
                let k = counter_of(&f);
                assert_eq!(k + 1, counter.load(Ordering::SeqCst), "stale frame {k}");
                assert_pixels(&mono8(&f)[8..], &base[8..], &format!("frame {k}"));
            }
            Err(e) => errors.push(e.to_string()),
        }
    }
    let (completed, failures, underruns) = cam.stream_statistics().unwrap();
    latencies.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let n = latencies.len().max(1);
    println!(
        "1024x768 Mono8 via Aravis: {} frames, {} errors, trigger->frame median {:.1} ms, p99 {:.1} ms, max {:.1} ms; stream completed {completed}, failures {failures}, underruns {underruns}",
        latencies.len(),
        errors.len(),
        ms(latencies[n / 2]),
        ms(latencies[(n * 99 / 100).min(n - 1)]),
        ms(*latencies.last().unwrap()),
    );
    assert!(
        errors.is_empty(),
        "{} failed grabs: {errors:?}",
        errors.len()
    );
    assert_eq!(failures, failures_before, "stream reported failed frames");
}

#[test]
fn frame_timeout_is_an_error_and_the_late_frame_is_not_returned_later() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    let counter = Arc::new(AtomicU64::new(0));
    let slow = Arc::new(AtomicBool::new(false));
    let (c, s) = (counter.clone(), slow.clone());
    fake.set_source(Arc::new(move |buf: &mut [u8], w: usize, _h: usize| {
        let k = c.fetch_add(1, Ordering::SeqCst);
        if s.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(300));
        }
        draw_counter(buf, w, k);
    }));
    let mut cam = open(fake);
    cam.grab(GRAB).expect("warm-up grab");

    slow.store(true, Ordering::SeqCst);
    // Exposures from here on are at least this number; the timed-out one is the first of them.
    let first_slow = counter.load(Ordering::SeqCst);
    let r = cam.grab(Duration::from_millis(100));
    slow.store(false, Ordering::SeqCst);
    assert!(
        matches!(r, Err(CameraError::Timeout(d)) if d == Duration::from_millis(100)),
        "expected a timeout, got {r:?}"
    );
    assert_eq!(cam.reconnects(), 0, "a slow frame is not a dropped camera");

    // The late frame arrives meanwhile; the next grab must return a newer exposure, never the
    // timed-out one. (The fake camera may render more exposures than are delivered, so the
    // counter is only an upper bound.)
    let f = cam.grab(GRAB).expect("grab after a timeout");
    let k = assert_counter_frame(&f);
    assert!(
        k > first_slow && k < counter.load(Ordering::SeqCst),
        "got frame {k}: the timed-out exposure was {first_slow}"
    );
}

#[test]
fn reconnects_after_the_camera_restarts_and_reports_when_it_stays_away() {
    let mut guard = fixture();
    let counter = Arc::new(AtomicU64::new(0));
    guard
        .as_ref()
        .unwrap()
        .set_source(counter_source(counter.clone()));
    let mut cfg = guard.as_ref().unwrap().camera_config(1000.0);
    cfg.reconnect_attempts = 3;
    cfg.reconnect_backoff_ms = 200;
    let mut cam = AravisCamera::open(cfg).expect("open");
    cam.grab(GRAB).expect("grab before the drop");

    // Camera power-cycles: it comes back at once, with none of our settings.
    *guard = None;
    *guard = Some(FakeGvCamera::start(counter_source(counter.clone())).expect("restart"));
    let t = Instant::now();
    let f = cam
        .grab(GRAB)
        .expect("grab after the restart reconnects transparently");
    println!("restart -> first frame {:.2} s", t.elapsed().as_secs_f64());
    assert_eq!(cam.reconnects(), 1);
    assert_counter_frame(&f);

    // Camera gone for good: a bounded number of attempts, then Disconnected.
    *guard = None;
    let t = Instant::now();
    let r = cam.grab(Duration::from_millis(500));
    let took = t.elapsed();
    println!(
        "camera away -> error after {:.2} s: {r:?}",
        took.as_secs_f64()
    );
    // Bounded by the attempts (3, 200 ms back-off): a typed error, the time only printed.
    assert!(matches!(r, Err(CameraError::Disconnected(_))), "got {r:?}");

    // Back again: the next grab reconnects.
    *guard = Some(FakeGvCamera::start(counter_source(counter.clone())).expect("restart"));
    let f = cam.grab(GRAB).expect("grab once the camera is back");
    assert_eq!(cam.reconnects(), 2);
    assert_counter_frame(&f);
}

#[test]
fn settings_outside_the_camera_bounds_are_refused_and_valid_ones_applied() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    let counter = Arc::new(AtomicU64::new(0));
    fake.set_source(counter_source(counter.clone()));
    let (sw, sh) = (fake.options().sensor_width, fake.options().sensor_height);
    let setting_err = |cfg: CameraConfig, what: &str| match AravisCamera::open(cfg) {
        Err(CameraError::Setting(m)) => assert!(m.contains(what), "{m}"),
        Err(e) => panic!("expected a setting error about {what}, got {e}"),
        Ok(_) => panic!("opened despite bad {what}"),
    };
    let mut c = fake.camera_config(1000.0);
    c.roi = Some(Roi {
        x: 0,
        y: 0,
        width: sw + 8,
        height: 64,
    });
    setting_err(c.clone(), "roi width");
    c.roi = Some(Roi {
        x: sw - 64,
        y: 0,
        width: 128,
        height: 64,
    });
    setting_err(c.clone(), "does not fit");
    let mut c = fake.camera_config(5.0); // the fake camera's minimum is 10 µs
    setting_err(c.clone(), "exposure_us");
    c.exposure_us = 2e7;
    setting_err(c, "exposure_us");
    let mut c = fake.camera_config(1000.0);
    c.pixel_format = PixelFormat::Mono12; // the fake camera offers Mono8 and Mono16 only
    setting_err(c, "Mono12 is not offered");

    let mut c = fake.camera_config(1000.0);
    let roi = Roi {
        x: 16,
        y: 8,
        width: 320,
        height: 240,
    };
    c.roi = Some(roi);
    let mut cam = AravisCamera::open(c).expect("valid ROI");
    let f = cam.grab(GRAB).expect("ROI grab");
    assert_eq!((f.width, f.height), (320, 240));
    assert_counter_frame(&f);

    let err = cam.set_exposure_us(5.0).unwrap_err();
    assert!(matches!(err, CameraError::Setting(_)), "{err}");
    let applied = cam.set_exposure_us(2500.0).expect("valid exposure");
    assert!(
        (applied - 2500.0).abs() <= 1.0,
        "camera reports {applied} µs"
    );
    assert!(cam
        .set_roi(Some(Roi {
            x: 0,
            y: 0,
            width: 0,
            height: 4
        }))
        .is_err());
    cam.set_roi(None).expect("full sensor");
    let f = cam.grab(GRAB).expect("grab after ROI change");
    assert_eq!((f.width, f.height), (sw as usize, sh as usize));
    assert_counter_frame(&f);
}

#[test]
fn mono16_frames_arrive_as_sixteen_bit_words() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    let panics_before = fake.source_panics();
    fake.set_source(Arc::new(|buf: &mut [u8], w: usize, h: usize| {
        assert_eq!(buf.len(), 2 * w * h, "two bytes per Mono16 pixel");
        for (i, px) in buf.chunks_exact_mut(2).enumerate() {
            px.copy_from_slice(&((i * 37) as u16).to_le_bytes());
        }
    }));
    let mut c = fake.camera_config(1000.0);
    c.pixel_format = PixelFormat::Mono16;
    c.roi = Some(Roi {
        x: 0,
        y: 0,
        width: 256,
        height: 128,
    });
    let mut cam = AravisCamera::open(c).expect("open Mono16");
    let f = cam.grab(GRAB).expect("Mono16 grab");
    assert_eq!(f.bit_depth, 16);
    let Pixels::Mono16(p) = &f.pixels else {
        panic!("expected Mono16 pixels")
    };
    assert_eq!(p.len(), 256 * 128);
    if let Some(i) = p
        .iter()
        .enumerate()
        .position(|(i, &v)| v != (i * 37) as u16)
    {
        panic!("Mono16 pixel {i} is {}, want {}", p[i], (i * 37) as u16);
    }
    assert_eq!(
        fake.source_panics(),
        panics_before,
        "source saw a wrong buffer size"
    );
}

#[test]
fn frames_with_missing_packets_are_incomplete_errors_never_frames() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    let counter = Arc::new(AtomicU64::new(0));
    fake.set_source(counter_source(counter));
    // An 8 KiB receive buffer cannot hold a 768 KiB burst: packets get dropped on loopback,
    // and Aravis 0.8.26's fake camera does not answer resend requests.
    let mut c = fake.camera_config(1000.0);
    c.socket_buffer_bytes = Some(8192);
    let mut cam = AravisCamera::open(c).expect("open");
    let (mut incomplete, mut timeouts, mut good) = (0, 0, 0);
    for _ in 0..5 {
        match cam.grab(GRAB) {
            Ok(f) => {
                assert_counter_frame(&f); // any frame handed out must be exact
                good += 1;
            }
            Err(CameraError::Incomplete(m)) => {
                assert!(m.contains("MissingPackets") || m.contains("Timeout"), "{m}");
                incomplete += 1;
            }
            Err(CameraError::Timeout(_)) => timeouts += 1,
            Err(e) => panic!("unexpected error: {e}"),
        }
    }
    println!("8 KiB socket buffer: {good} good, {incomplete} incomplete, {timeouts} timeouts");
    assert!(
        incomplete > 0,
        "lost packets were never reported as Incomplete"
    );
    let (_, failures, _) = cam.stream_statistics().unwrap();
    assert!(failures > 0, "Aravis counted no failed buffer");
}

#[test]
fn a_panicking_frame_source_costs_a_frame_not_the_process() {
    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    fake.set_source(counter_source(Arc::new(AtomicU64::new(1))));
    let mut cam = open(fake);
    let before = cam.grab(GRAB).expect("grab before the panic");
    assert!(mono8(&before).iter().any(|&p| p != 0));

    let panics_before = fake.source_panics();
    fake.set_source(Arc::new(|_b: &mut [u8], _w: usize, _h: usize| {
        panic!("renderer bug (expected by this test)")
    }));
    // The camera still sends that frame: black, not a stale copy of the previous one.
    let f = cam.grab(GRAB).expect("grab while the source panics");
    assert!(
        mono8(&f).iter().all(|&p| p == 0),
        "a failed draw must not look like a frame"
    );
    assert_eq!(fake.source_panics(), panics_before + 1);

    fake.set_source(counter_source(Arc::new(AtomicU64::new(0))));
    assert_counter_frame(&cam.grab(GRAB).expect("grab after the panic"));
}

/// The end-to-end case: the fake GV camera's frames are drawn by the PPP renderer at
/// the simulated stage position current when the trigger arrives; the frame that comes back
/// through Aravis decodes to that position.
#[test]
fn a_ppp_frame_through_aravis_decodes_to_the_stage_position() {
    use csmetro_ppp::render;
    use csmetro_ppp::{Pose, PppConfig};

    let guard = fixture();
    let fake = guard.as_ref().unwrap();
    let ppp = PppConfig::default();
    let pattern = ppp.pattern().expect("default pattern");
    let decoder = ppp.decoder().expect("default decoder");
    let optics = ppp.optics.clone();
    assert_eq!(
        (optics.width as u32, optics.height as u32, optics.bit_depth),
        (fake.options().sensor_width, fake.options().sensor_height, 8),
        "renderer and fake sensor must agree"
    );

    // The simulated stage: the source reads its true position at trigger time.
    let stage = Arc::new(Mutex::new(Pose::new(0.0, 0.0, 0.0)));
    let renders = Arc::new(AtomicU64::new(0));
    let (st, n) = (stage.clone(), renders.clone());
    fake.set_source(Arc::new(move |buf: &mut [u8], w: usize, h: usize| {
        let pose = *st.lock().unwrap_or_else(|e| e.into_inner());
        let seed = n.fetch_add(1, Ordering::SeqCst);
        let frame = render(&pattern, &optics, pose, seed);
        match &frame.pixels {
            Pixels::Mono8(p) if (frame.width, frame.height) == (w, h) => buf.copy_from_slice(p),
            _ => buf.fill(0), // decodes to a rejection, never to a position
        }
    }));
    let mut cam = open(fake);
    for (x_um, y_um) in [(3210.7, 1234.3), (812.345, 3987.65), (9001.05, 150.5)] {
        *stage.lock().unwrap() = Pose::new(x_um, y_um, 0.0);
        let frame = cam.grab(GRAB).expect("grab");
        let r = decoder.decode(&frame);
        assert!(r.ok, "({x_um}, {y_um}) rejected: {:?}", r.reason);
        let (ex, ey) = (r.x_um - x_um, r.y_um - y_um);
        println!(
            "PPP via Aravis at ({x_um}, {y_um}) µm: error ({:.4}, {:.4}) µm, decode {:.0} ms",
            ex, ey, r.decode_ms
        );
        assert!(
            ex.abs() < 0.05 && ey.abs() < 0.05,
            "decoded ({}, {}) for ({x_um}, {y_um})",
            r.x_um,
            r.y_um
        );
    }
}

#[test]
fn a_second_fake_camera_on_the_same_ip_is_refused() {
    let guard = fixture();
    assert!(guard.as_ref().unwrap().is_running());
    let second = FakeGvCamera::start(blank_source());
    assert!(
        matches!(&second, Err(CameraError::Other(m)) if m.contains("3956")),
        "second fake camera: {:?}",
        second.as_ref().map(|c| c.serial().to_string())
    );
}
