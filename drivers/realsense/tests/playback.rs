//! Real librealsense playback through [`RealsenseSource`]: a `.bag` written in the test by
//! pyrealsense2's software device (`record_software_device.py`: depth Z16 + colour RGB8 with
//! known pixels, intrinsics and depth units) comes back exactly, upright-rotated on request.
//!
//! Needs the project venv with pyrealsense2 (`./scripts/setup-python.sh`) and the librealsense
//! sysroot (`./scripts/setup-realsense.sh`); `scripts/test.sh` sets both up. Without the venv
//! the tests fail naming the script.
#![cfg(feature = "librealsense")]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::source::{FrameSource, SourceError, SourceStatus};
use op3dsg_realsense::RealsenseConfig;
use op3dsg_realsense::RealsenseSource;
use op3dsg_realsense::rotate::Rotation;

const W: u32 = 80;
const H: u32 = 60;
const FRAMES: usize = 10;

struct Recording {
    _dir: tempfile::TempDir,
    bag: PathBuf,
    stamps_ms: Vec<f64>,
    intrinsics: Intrinsics,
}

fn python() -> PathBuf {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    assert!(venv.exists(), "{} missing: run ./scripts/setup-python.sh (it installs pyrealsense2)", venv.display());
    venv
}

fn record(frames: usize) -> Recording {
    let dir = tempfile::tempdir().expect("tempdir");
    let bag = dir.path().join("software.bag");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/record_software_device.py");
    let out = Command::new(python())
        .arg(&script)
        .arg(&bag)
        .args(["--frames", &frames.to_string(), "--width", &W.to_string(), "--height", &H.to_string()])
        .output()
        .expect("run the recorder");
    assert!(out.status.success(), "recorder failed: {}", String::from_utf8_lossy(&out.stderr));
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).expect("recorder prints JSON");
    let f = |k: &str| info[k].as_f64().expect("number") as f32;
    Recording {
        _dir: dir,
        bag,
        stamps_ms: info["stamps_ms"].as_array().expect("stamps").iter().map(|v| v.as_f64().expect("stamp")).collect(),
        intrinsics: Intrinsics { width: W, height: H, fx: f("fx"), fy: f("fy"), cx: f("ppx"), cy: f("ppy") },
    }
}

fn config(rec: &Recording, real_time: bool, rotate: Rotation) -> RealsenseConfig {
    RealsenseConfig {
        bag: rec.bag.display().to_string(),
        bag_real_time: real_time,
        rotate,
        ..RealsenseConfig::default()
    }
}

/// Plays the whole file: the frames as delivered.
fn play(source: &mut RealsenseSource) -> Vec<Frame> {
    let mut frames = Vec::new();
    let mut frame = Frame::new(source.intrinsics());
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(Instant::now() < deadline, "playback did not end");
        match source.next_frame(&mut frame).expect("next_frame") {
            SourceStatus::Frame => frames.push(frame.clone()),
            SourceStatus::Pending => {}
            SourceStatus::EndOfStream => return frames,
        }
    }
}

fn depth_at(recorded: usize, u: u32, v: u32) -> u16 {
    (500 + 7 * u + 13 * v) as u16 + recorded as u16
}

fn colour_at(recorded: usize, u: u32, v: u32) -> [u8; 3] {
    [(u % 256) as u8, (v % 256) as u8, ((11 * recorded) % 256) as u8]
}

/// The recorded index of a delivered frame: librealsense's pipeline never delivers the first
/// depth frame of a recording with both streams on, so delivered frame k is recorded k + 1.
const FIRST_DELIVERED: usize = 1;

#[test]
fn playback_delivers_the_recorded_frames_exactly() {
    let rec = record(FRAMES);
    let mut source = RealsenseSource::open(&config(&rec, true, Rotation::None), None).expect("open the bag");
    assert_eq!(source.intrinsics(), rec.intrinsics, "intrinsics from the recording");
    assert!(!source.has_poses());
    let frames = play(&mut source);
    assert_eq!(
        frames.len(),
        FRAMES - FIRST_DELIVERED,
        "frames delivered (repeated sets passed over: {})",
        source.repeated_sets()
    );
    for (k, frame) in frames.iter().enumerate() {
        let i = k + FIRST_DELIVERED;
        assert_eq!(frame.seq, k as u64);
        let want_ns = rec.stamps_ms[i] * 1e6;
        // Recorded stamps come back with float noise (microsecond precision in the file).
        assert!(
            (frame.stamp_ns as f64 - want_ns).abs() <= 1_000.0,
            "frame {k}: stamp {} ns, recorded {want_ns}",
            frame.stamp_ns
        );
        assert_eq!(frame.intrinsics, rec.intrinsics);
        assert_eq!(frame.depth_units_per_m, 4000.0, "1 / depth_units 0.00025 m");
        for v in 0..H {
            for u in 0..W {
                let p = (v * W + u) as usize;
                assert_eq!(frame.depth[p], depth_at(i, u, v), "frame {k} depth at ({u}, {v})");
                assert_eq!(frame.rgb[p * 3..p * 3 + 3], colour_at(i, u, v), "frame {k} colour at ({u}, {v})");
            }
        }
    }
    // Stamps strictly increase.
    assert!(frames.windows(2).all(|w| w[0].stamp_ns < w[1].stamp_ns));
}

#[test]
fn rotation_puts_a_known_pixel_where_it_belongs() {
    let rec = record(3);
    let mut source = RealsenseSource::open(&config(&rec, true, Rotation::Cw90), None).expect("open the bag");
    let upright = Rotation::Cw90.intrinsics(&rec.intrinsics);
    assert_eq!(source.intrinsics(), upright);
    assert_eq!((upright.width, upright.height), (H, W));
    assert_eq!(source.camera_intrinsics(), rec.intrinsics);
    let frames = play(&mut source);
    assert_eq!(frames.len(), 3 - FIRST_DELIVERED);
    let frame = &frames[0];
    // Pixel (10, 5) of the camera image (its top-left area) is at (H - 1 - 5, 10) upright:
    // top-right area, as a 90° clockwise turn puts it.
    let (u, v) = (10, 5);
    let at = |x: u32, y: u32| (y * upright.width + x) as usize;
    assert_eq!(frame.depth[at(H - 1 - v, u)], depth_at(1, u, v));
    assert_eq!(frame.rgb[at(H - 1 - v, u) * 3..at(H - 1 - v, u) * 3 + 3], colour_at(1, u, v));
    // And every other pixel likewise.
    for v in 0..H {
        for u in 0..W {
            let (x, y) = Rotation::Cw90.map_pixel(u, v, W, H);
            assert_eq!(frame.depth[at(x, y)], depth_at(1, u, v), "({u}, {v}) -> ({x}, {y})");
        }
    }
    // Back-projected, the upright pixel and the camera pixel are the same point.
    let depth_m = frame.depth_m(at(H - 1 - v, u));
    let in_upright = upright.point_in_camera((H - 1 - v) as f32, u as f32, depth_m).as_dvec3();
    let in_camera = rec.intrinsics.point_in_camera(u as f32, v as f32, depth_m).as_dvec3();
    assert!((Rotation::Cw90.camera_from_upright().transform_point(in_upright) - in_camera).length() < 1e-6);
}

#[test]
fn real_time_playback_keeps_the_recorded_pace() {
    let rec = record(FRAMES);
    let mut source = RealsenseSource::open(&config(&rec, true, Rotation::None), None).expect("open the bag");
    let started = Instant::now();
    let frames = play(&mut source);
    let elapsed = started.elapsed();
    assert!(frames.len() >= FRAMES / 2, "most frames come in real time: {}", frames.len());
    // A lower bound only: real time cannot be faster than the recording's span.
    let span_ms = rec.stamps_ms[FRAMES - 1] - rec.stamps_ms[FIRST_DELIVERED];
    assert!(
        elapsed.as_secs_f64() * 1000.0 >= span_ms * 0.8,
        "played {FRAMES} frames in {elapsed:?}, span {span_ms} ms"
    );
}

#[test]
fn bad_files_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("nope.bag");
    let cfg = RealsenseConfig { bag: missing.display().to_string(), ..RealsenseConfig::default() };
    let err = RealsenseSource::open(&cfg, None).expect_err("missing file");
    assert!(matches!(err, SourceError::File { .. }) && err.to_string().contains("nope.bag"), "{err}");

    let garbage = dir.path().join("garbage.bag");
    std::fs::write(&garbage, b"not a rosbag at all").expect("write");
    let cfg = RealsenseConfig { bag: "garbage.bag".to_owned(), ..RealsenseConfig::default() };
    // Relative to the profile's folder.
    let err = RealsenseSource::open(&cfg, Some(dir.path())).expect_err("garbage file");
    assert!(err.to_string().contains(&garbage.display().to_string()), "{err}");
}
