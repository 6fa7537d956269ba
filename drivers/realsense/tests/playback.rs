//! Real librealsense playback through [`RealsenseSource`]: a `.bag` written in the test by
//! pyrealsense2's software device (`record_software_device.py`: depth Z16 + colour RGB8 with
//! known pixels, intrinsics and depth units) comes back exactly, upright-rotated on request.
//!
//! Needs the project venv with pyrealsense2 (`./scripts/setup-python.sh`) and the librealsense
//! sysroot (`./scripts/setup-realsense.sh`); `scripts/test.sh` sets both up. Without the venv
//! the tests fail naming the script.
#![cfg(feature = "librealsense")]

use std::alloc::System;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::source::{FrameSource, SourceError, SourceStatus};
use op3dsg_realsense::RealsenseConfig;
use op3dsg_realsense::RealsenseSource;
use op3dsg_realsense::config::AlignMode;
use op3dsg_realsense::imu::{ImuSample, MotionKind};
use op3dsg_realsense::rotate::Rotation;
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};

/// Counts the process's allocations (the no-allocation-per-frame test). librealsense's threads
/// allocate through the C++ runtime, not this allocator, and the file's other tests wait on
/// [`PLAYBACK`] meanwhile: what it counts during a `next_frame` is the reading thread's.
#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

const W: u32 = 80;
const H: u32 = 60;
const FRAMES: usize = 10;
/// The recordings' frame rate: 5 Hz leaves the debug-built reader 200 ms per frame set.
/// Real-time playback drops a set the reader has not taken when the next one is due, and at
/// 30 Hz (and 10 Hz, with the distorted lenses' alignment) a loaded CI machine's debug build
/// is late now and then; the content is what these tests check, not the pace.
const FPS: &str = "5";

/// One recording and playback at a time: the tests of this file run in parallel, and each
/// playback thread and reader competes for the same two cores otherwise.
static PLAYBACK: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> MutexGuard<'static, ()> {
    // A test that failed while holding the lock poisons it; the others still run.
    PLAYBACK.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

struct Recording {
    _dir: tempfile::TempDir,
    bag: PathBuf,
    stamps_ms: Vec<f64>,
    intrinsics: Intrinsics,
    /// `--imu`: recorded (stamp ms, x, y, z) per sensor.
    gyro: Vec<[f64; 4]>,
    accel: Vec<[f64; 4]>,
}

fn python() -> PathBuf {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    assert!(venv.exists(), "{} missing: run ./scripts/setup-python.sh (it installs pyrealsense2)", venv.display());
    venv
}

fn record(frames: usize) -> Recording {
    record_with(frames, &["--width", &W.to_string(), "--height", &H.to_string()])
}

/// A recording made with the recorder's options `args` (sizes, calibration, scene).
fn record_with(frames: usize, args: &[&str]) -> Recording {
    let dir = tempfile::tempdir().expect("tempdir");
    let bag = dir.path().join("software.bag");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/record_software_device.py");
    let out = Command::new(python())
        .arg(&script)
        .arg(&bag)
        .args(["--frames", &frames.to_string()])
        .args(if args.contains(&"--fps") { &[][..] } else { &["--fps", FPS][..] })
        .args(args)
        .output()
        .expect("run the recorder");
    assert!(out.status.success(), "recorder failed: {}", String::from_utf8_lossy(&out.stderr));
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).expect("recorder prints JSON");
    let motion = |kind: &str| -> Vec<[f64; 4]> {
        info["imu"][kind]
            .as_array()
            .map(|samples| {
                samples
                    .iter()
                    .map(|s| {
                        let v: Vec<f64> =
                            s.as_array().expect("sample").iter().map(|x| x.as_f64().expect("value")).collect();
                        [v[0], v[1], v[2], v[3]]
                    })
                    .collect()
            })
            .unwrap_or_default()
    };
    let colour = &info["colour"];
    let f = |k: &str| colour[k].as_f64().expect("number") as f32;
    let size = |k: &str| colour[k].as_u64().expect("size") as u32;
    Recording {
        _dir: dir,
        bag,
        stamps_ms: info["stamps_ms"].as_array().expect("stamps").iter().map(|v| v.as_f64().expect("stamp")).collect(),
        intrinsics: Intrinsics {
            width: size("width"),
            height: size("height"),
            fx: f("fx"),
            fy: f("fy"),
            cx: f("ppx"),
            cy: f("ppy"),
        },
        gyro: motion("gyro"),
        accel: motion("accel"),
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

fn config_aligned_by(rec: &Recording, align: AlignMode, rotate: Rotation) -> RealsenseConfig {
    RealsenseConfig { align, ..config(rec, true, rotate) }
}

/// Playbacks tried before a test gives up on getting every frame set of a recording.
const ATTEMPTS: usize = 3;

/// Opens a source with `cfg` and plays the whole file until every frame set librealsense can
/// deliver of `rec` came through (`rec`'s frames less [`FIRST_DELIVERED`]). librealsense's
/// playback drops a frame set whose reader is late (in real time when the next one is due, as
/// fast as possible when the file reader is ahead), and its syncer now and then pairs a depth
/// frame with the previous colour frame (the source passes such sets over), on an idle machine
/// too: pyrealsense2's own pipeline gives 2 to 4 sets of a 3-frame file from one playback to
/// the next. A playback short of sets is played again, at most [`ATTEMPTS`] times, and one that
/// never delivers every set fails the test.
fn play_complete(rec: &Recording, cfg: &RealsenseConfig) -> (RealsenseSource, Vec<Frame>) {
    let want = rec.stamps_ms.len() - FIRST_DELIVERED;
    let mut counts = Vec::new();
    for _ in 0..ATTEMPTS {
        let mut source = RealsenseSource::open(cfg, None).expect("open the bag");
        match try_play(&mut source) {
            Ok(frames) if frames.len() == want => return (source, frames),
            Ok(frames) => {
                eprintln!(
                    "librealsense delivered {} of {want} frame sets ({} passed over); playing again",
                    frames.len(),
                    source.repeated_sets()
                );
                counts.push(frames.len().to_string());
            }
            Err(e) => {
                eprintln!("playback failed: {e}; playing again");
                counts.push(e.to_string());
            }
        }
    }
    panic!("no playback of {ATTEMPTS} delivered all {want} frame sets: {counts:?}");
}

/// Plays the whole file: the frames as delivered.
fn play(source: &mut RealsenseSource) -> Vec<Frame> {
    try_play(source).expect("next_frame")
}

/// Plays the whole file: the frames as delivered, or the source's first error.
fn try_play(source: &mut RealsenseSource) -> Result<Vec<Frame>, SourceError> {
    let mut frames = Vec::new();
    let mut frame = Frame::new(source.intrinsics());
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(Instant::now() < deadline, "playback did not end");
        match source.next_frame(&mut frame)? {
            SourceStatus::Frame => frames.push(frame.clone()),
            SourceStatus::Pending => {}
            SourceStatus::EndOfStream => return Ok(frames),
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
    let _one = one_at_a_time();
    let rec = record(FRAMES);
    let (source, frames) = play_complete(&rec, &config(&rec, true, Rotation::None));
    assert_eq!(source.intrinsics(), rec.intrinsics, "intrinsics from the recording");
    assert!(!source.has_poses());
    assert_eq!(frames.len(), FRAMES - FIRST_DELIVERED, "frames delivered");
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
fn frames_come_from_the_driver_into_the_pooled_frame_without_allocating() {
    let _one = one_at_a_time();
    let rec = record(FRAMES);
    // Colour with twice the depth's pixels per degree: depth pixels fill rectangles, written as
    // blocks, and unturned through the aligner's turned buffer (made at the first frame).
    let (w2, h2, f2) = ((2 * W).to_string(), (2 * H).to_string(), (2.0 * rec.intrinsics.fx).to_string());
    let sharper = record_with(
        FRAMES,
        &[
            "--width",
            &W.to_string(),
            "--height",
            &H.to_string(),
            "--colour-width",
            &w2,
            "--colour-height",
            &h2,
            "--colour-fx",
            &f2,
            "--colour-fy",
            &f2,
            "--scene",
        ],
    );
    for (rec, align, rotate) in [
        (&rec, AlignMode::Op3dsg, Rotation::Cw90),
        (&rec, AlignMode::Librealsense, Rotation::Cw90),
        (&sharper, AlignMode::Op3dsg, Rotation::None),
        (&sharper, AlignMode::Op3dsg, Rotation::Cw90),
    ] {
        let mut source = RealsenseSource::open(&config_aligned_by(rec, align, rotate), None).expect("open");
        let mut frame = Frame::new(source.intrinsics());
        let (mut delivered, mut counted, mut allocations) = (0, 0, 0);
        loop {
            let region = Region::new(GLOBAL);
            let status = source.next_frame(&mut frame).expect("next_frame");
            let change = region.change();
            let made = change.allocations + change.reallocations;
            match status {
                // The first frame sets set up playback pacing (and warn once where they must).
                SourceStatus::Frame if delivered >= 2 => {
                    counted += 1;
                    allocations += made;
                }
                SourceStatus::Frame => {}
                // Passed-over sets and the end of the file are not frames.
                SourceStatus::Pending => continue,
                SourceStatus::EndOfStream => break,
            }
            delivered += 1;
        }
        let what = format!("{align:?}, {}x{} colour, {rotate:?}", rec.intrinsics.width, rec.intrinsics.height);
        assert!(counted >= FRAMES / 2, "{what}: only {counted} frames after the first two");
        assert_eq!(allocations, 0, "{what}: {allocations} allocations in {counted} frames");
    }
}

#[test]
fn rotation_puts_a_known_pixel_where_it_belongs() {
    let _one = one_at_a_time();
    let rec = record(3);
    let (source, frames) = play_complete(&rec, &config(&rec, true, Rotation::Cw90));
    let upright = Rotation::Cw90.intrinsics(&rec.intrinsics);
    assert_eq!(source.intrinsics(), upright);
    assert_eq!((upright.width, upright.height), (H, W));
    assert_eq!(source.camera_intrinsics(), rec.intrinsics);
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
    let _one = one_at_a_time();
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

/// A recording whose device reports `name` and `serial`, as a real camera's does.
fn record_camera(name: &str, serial: &str) -> Recording {
    let (w, h) = (W.to_string(), H.to_string());
    record_with(3, &["--width", &w, "--height", &h, "--name", name, "--serial", serial])
}

#[test]
fn a_recording_plays_only_when_its_camera_is_the_product_and_the_serial_is_not_checked() {
    let _one = one_at_a_time();
    // The Stretch profile's product under a recording of the gripper's D405: refused, naming it.
    let gripper = record_camera("Intel RealSense D405", "218622271111");
    let cfg = RealsenseConfig { product: "D435I".to_owned(), ..config(&gripper, false, Rotation::None) };
    let err = RealsenseSource::open(&cfg, None).expect_err("a D405 recording under product D435I");
    assert!(matches!(err, SourceError::Config(_)), "{err:?}");
    assert!(
        err.to_string().starts_with("config: source.realsense.product: \"D435I\", but ")
            && err.to_string().contains("was recorded with Intel RealSense D405 (serial 218622271111)"),
        "{err}"
    );
    // The head camera's recording plays under the product in any case, whatever the serial
    // (the unit recorded is another robot's as often as not).
    let head = record_camera("Intel RealSense D435I", "135322062222");
    let cfg =
        RealsenseConfig { product: "d435i".to_owned(), serial: "1".to_owned(), ..config(&head, false, Rotation::None) };
    let mut source = RealsenseSource::open(&cfg, None).expect("the recording's camera is a D435I");
    assert_eq!(source.kind(), op3dsg_drivers::source::SourceKind::Replay, "a bag is a replay");
    assert!(!play(&mut source).is_empty(), "frames delivered");
    // No product: any recording plays, a nameless one (the software device's default) too.
    let cfg = RealsenseConfig { product: String::new(), ..config(&gripper, false, Rotation::None) };
    assert!(RealsenseSource::open(&cfg, None).is_ok());
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

/// How far two aligned depth images are apart.
#[derive(Debug)]
struct Agreement {
    /// Pixels with the same value (both 0 included).
    equal_share: f64,
    /// Pixels with depth in one and none in the other.
    hole_mismatches: usize,
    /// Largest difference where both have depth, depth units.
    max_error: u16,
}

fn agreement(ours: &[u16], theirs: &[u16]) -> Agreement {
    assert_eq!(ours.len(), theirs.len());
    let equal = ours.iter().zip(theirs).filter(|(a, b)| a == b).count();
    let hole_mismatches = ours.iter().zip(theirs).filter(|(a, b)| (**a == 0) != (**b == 0)).count();
    let max_error =
        ours.iter().zip(theirs).filter(|(a, b)| **a != 0 && **b != 0).map(|(a, b)| a.abs_diff(*b)).max().unwrap_or(0);
    Agreement { equal_share: equal as f64 / ours.len() as f64, hole_mismatches, max_error }
}

/// Plays `rec` aligned by us and by librealsense and compares frame by frame. Tolerance: at
/// least 99.99 % of the pixels equal, and where both have depth at most 1 % of the larger value
/// apart (a colour pixel on the border of two depth pixels may take either's value when float
/// rounding differs); the colour images identical.
fn assert_alignments_agree(rec: &Recording, rotate: Rotation, what: &str) {
    // One after the other: an open playback runs (and drops frame sets nobody takes).
    let play_with = |align: AlignMode| {
        let (source, frames) = play_complete(rec, &config_aligned_by(rec, align, rotate));
        assert_eq!(
            source.intrinsics(),
            rotate.intrinsics(&rec.intrinsics),
            "frames have the colour stream's intrinsics"
        );
        frames
    };
    let (ours, theirs) = (play_with(AlignMode::Op3dsg), play_with(AlignMode::Librealsense));
    assert!(!ours.is_empty() && ours.len() == theirs.len(), "{what}: {} vs {} frames", ours.len(), theirs.len());
    for (k, (a, b)) in ours.iter().zip(&theirs).enumerate() {
        assert_eq!(a.stamp_ns, b.stamp_ns, "{what} frame {k}");
        assert!(a.rgb == b.rgb, "{what} frame {k}: colour differs");
        let with_depth = b.depth.iter().filter(|&&z| z != 0).count();
        assert!(with_depth > b.depth.len() / 2, "{what} frame {k}: librealsense's aligned depth is mostly empty");
        let agree = agreement(&a.depth, &b.depth);
        let largest = b.depth.iter().copied().max().unwrap_or(0);
        println!("{what} frame {k}: {agree:?} ({with_depth} of {} pixels with depth)", b.depth.len());
        assert!(agree.equal_share >= 0.9999, "{what} frame {k}: {agree:?}");
        assert!(agree.hole_mismatches <= b.depth.len() / 10_000, "{what} frame {k}: {agree:?}");
        assert!(u32::from(agree.max_error) * 100 <= u32::from(largest), "{what} frame {k}: {agree:?}");
    }
}

#[test]
fn own_alignment_equals_librealsense_align_on_a_d435i_like_recording() {
    let _one = one_at_a_time();
    // 848x480 depth to 1280x720 colour (rectangles: colour has more pixels per degree), a
    // 15 mm baseline with a little vertical and forward offset, 0.4 degrees of yaw; a slanted
    // wall, a box in front of it (occlusion), scattered holes.
    let rec = record_with(
        4,
        &[
            "--width",
            "848",
            "--height",
            "480",
            "--fx",
            "421",
            "--fy",
            "421",
            "--colour-width",
            "1280",
            "--colour-height",
            "720",
            "--colour-fx",
            "910",
            "--colour-fy",
            "909",
            "--translation",
            "0.015",
            "0.0003",
            "-0.0002",
            "--yaw-deg",
            "0.4",
            "--scene",
        ],
    );
    assert_alignments_agree(&rec, Rotation::None, "848x480 -> 1280x720");
    assert_alignments_agree(&rec, Rotation::Cw90, "848x480 -> 1280x720, rotate 90");
}

#[test]
fn own_alignment_equals_librealsense_align_with_lens_distortion() {
    let _one = one_at_a_time();
    // Radial coefficients of the size a D435i's colour camera reports (modified Brown-Conrady,
    // what librealsense's align projects with) and an inverse Brown-Conrady depth lens (what it
    // deprojects with), tangential terms zero: librealsense's SSE align applies those as
    // rs2_project_point_to_pixel does not (src/align/), so they are compared only where both
    // agree on the formula.
    let rec = record_with(
        3,
        &[
            "--width",
            "424",
            "--height",
            "240",
            "--fx",
            "211",
            "--fy",
            "211",
            "--colour-width",
            "640",
            "--colour-height",
            "360",
            "--colour-fx",
            "455",
            "--colour-fy",
            "455",
            "--translation",
            "0.015",
            "0.0003",
            "-0.0002",
            "--yaw-deg",
            "0.4",
            "--depth-distortion",
            "inverse_brown_conrady",
            "0.02",
            "-0.01",
            "0",
            "0",
            "0.003",
            "--colour-distortion",
            "modified_brown_conrady",
            "0.13",
            "-0.26",
            "0",
            "0",
            "0.1",
            "--scene",
        ],
    );
    assert_alignments_agree(&rec, Rotation::None, "424x240 -> 640x360, distorted lenses");
    assert_alignments_agree(&rec, Rotation::Cw90, "424x240 -> 640x360, distorted lenses, rotate 90");
}

#[test]
fn own_alignment_equals_librealsense_align_at_equal_resolution() {
    let _one = one_at_a_time();
    // Same size, colour with a shorter focal length (depth has more pixels per degree: each depth
    // pixel fills one colour pixel) and a 5 cm baseline: the box's shadow and the colour image's
    // rim beyond the depth's field of view are holes.
    let rec = record_with(
        4,
        &[
            "--width",
            "320",
            "--height",
            "240",
            "--fx",
            "200",
            "--fy",
            "200",
            "--colour-width",
            "320",
            "--colour-height",
            "240",
            "--colour-fx",
            "180",
            "--colour-fy",
            "181",
            "--translation",
            "-0.05",
            "0.0",
            "0.0",
            "--scene",
        ],
    );
    assert_alignments_agree(&rec, Rotation::None, "320x240 -> 320x240");
    assert_alignments_agree(&rec, Rotation::Cw270, "320x240 -> 320x240, rotate 270");
}

#[test]
fn imu_samples_come_through_stamped_and_exact() {
    let _one = one_at_a_time();
    // 30 Hz: as fast as possible, the file reader runs ahead of the reader by a frame set per
    // 40 motion samples at 5 Hz and librealsense drops most sets (2 of 9 delivered).
    let rec = record_with(FRAMES, &["--width", &W.to_string(), "--height", &H.to_string(), "--imu", "--fps", "30"]);
    assert!(rec.gyro.len() >= 40 && rec.accel.len() >= 20, "recorder wrote the motion streams");
    // As fast as the reader takes frames: in real time librealsense's playback itself skips a
    // motion frame now and then when its reading thread is late (seen here, not a camera's
    // behaviour).
    let with_imu = RealsenseConfig { imu: true, ..config(&rec, false, Rotation::None) };
    let (source, frames) = play_complete(&rec, &with_imu);
    let imu = source.imu().expect("imu buffer with imu = true");
    // Video as without the IMU.
    assert_eq!(frames.len(), FRAMES - FIRST_DELIVERED, "video frames with imu = true");
    for (k, frame) in frames.iter().enumerate() {
        assert_eq!(frame.depth[0], depth_at(k + FIRST_DELIVERED, 0, 0), "frame {k}");
    }
    let mut samples = Vec::new();
    imu.drain_into(&mut samples);
    assert_eq!(imu.dropped(), 0);
    for (kind, recorded) in [(MotionKind::Gyro, &rec.gyro), (MotionKind::Accel, &rec.accel)] {
        let got: Vec<&ImuSample> = samples.iter().filter(|s| s.kind == kind).collect();
        println!("{kind:?}: {} of {} recorded samples delivered", got.len(), recorded.len());
        // The motion sensor streams on its own queue from the first frame set on (what played
        // before it opened is not seen): every sample recorded from then, none lost or repeated.
        let first_ns = got.first().map_or(u64::MAX, |s| s.stamp_ns);
        let from_first = recorded.iter().filter(|r| r[0] * 1e6 >= first_ns as f64 - 1_000.0).count();
        assert_eq!(got.len(), from_first, "{kind:?}: every sample from the first one delivered on");
        assert!(got.len() * 2 >= recorded.len(), "{kind:?}: {} of {} samples", got.len(), recorded.len());
        assert!(got.windows(2).all(|w| w[0].stamp_ns < w[1].stamp_ns), "{kind:?}: stamps increase");
        for s in &got {
            let want = recorded
                .iter()
                .find(|r| (r[0] * 1e6 - s.stamp_ns as f64).abs() <= 1_000.0)
                .unwrap_or_else(|| panic!("{kind:?} sample at {} ns was not recorded", s.stamp_ns));
            assert_eq!(s.xyz, [want[1] as f32, want[2] as f32, want[3] as f32], "{kind:?} at {} ns", s.stamp_ns);
        }
    }
    // Without the key: no buffer.
    let (plain, frames) = play_complete(&rec, &config(&rec, true, Rotation::None));
    assert!(plain.imu().is_none());
    assert_eq!(frames.len(), FRAMES - FIRST_DELIVERED);
}
