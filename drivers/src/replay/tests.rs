//! Tests of the replay source: parsing and association on generated data, the real ICL-NUIM
//! sequence from `../shared/data` (skipped with a message when absent), and bad data in temp
//! copies of it.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use glam::{DQuat, DVec3};
use image::ExtendedColorType;
use image::ImageEncoder;
use image::codecs::png::PngEncoder;

use super::index::{EntryPose, GroundTruthPose, ListedImage, Tolerances, associate, pose_at};
use super::*;
use crate::frame::Frame;
use crate::pose::Isometry;
use crate::source::{FrameSource, SourceError, SourceStatus};

const ICL_FRAMES: usize = 211;
/// Lines before the first frame line in each ICL index file (two comment lines).
const ICL_HEADER_LINES: usize = 2;

/// The shared ICL-NUIM sequence, or `None` (with a message on stderr) when `../shared` is not
/// beside the repository; in CI its absence fails the test.
fn icl_dir() -> Option<PathBuf> {
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1/rgb.txt")?;
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1")
}

fn fast(path: &Path) -> ReplayConfig {
    ReplayConfig { mode: PlaybackMode::Fast, ..ReplayConfig::new(path.to_path_buf()) }
}

fn skip(mut config: ReplayConfig) -> ReplayConfig {
    config.on_bad_frame = OnBadFrame::Skip;
    config
}

/// Reads frames until the end; returns them and the error that ended the stream, if any.
fn play(source: &mut ReplaySource) -> (Vec<Frame>, Option<SourceError>) {
    let mut frames = Vec::new();
    loop {
        let mut frame = Frame::new(source.intrinsics());
        match source.next_frame(&mut frame) {
            Ok(SourceStatus::Frame) => frames.push(frame),
            Ok(SourceStatus::Pending) => {}
            Ok(SourceStatus::EndOfStream) => return (frames, None),
            Err(e) => {
                let mut after = Frame::new(source.intrinsics());
                assert_eq!(
                    source.next_frame(&mut after).unwrap(),
                    SourceStatus::EndOfStream,
                    "a stopped source stays stopped"
                );
                return (frames, Some(e));
            }
        }
    }
}

/// A temp copy of the first `n` ICL frames (index lines with their headers, images, camera.json).
fn icl_copy(n: usize) -> Option<tempfile::TempDir> {
    let src = icl_dir()?;
    let dst = tempfile::tempdir().unwrap();
    std::fs::copy(src.join("camera.json"), dst.path().join("camera.json")).unwrap();
    for sub in ["rgb", "depth"] {
        std::fs::create_dir(dst.path().join(sub)).unwrap();
    }
    for index in ["rgb.txt", "depth.txt", "groundtruth.txt"] {
        let text = std::fs::read_to_string(src.join(index)).unwrap();
        let lines: Vec<&str> = text.lines().take(ICL_HEADER_LINES + n).collect();
        if index != "groundtruth.txt" {
            for line in &lines[ICL_HEADER_LINES..] {
                let file = line.split_whitespace().nth(1).unwrap();
                std::fs::copy(src.join(file), dst.path().join(file)).unwrap();
            }
        }
        std::fs::write(dst.path().join(index), lines.join("\n") + "\n").unwrap();
    }
    Some(dst)
}

/// Line number (1-based) of ICL frame `k` in any of its index files.
fn icl_line(k: usize) -> usize {
    ICL_HEADER_LINES + k + 1
}

fn edit_lines(path: &Path, edit: impl FnOnce(&mut Vec<String>)) {
    let mut lines: Vec<String> = std::fs::read_to_string(path).unwrap().lines().map(str::to_owned).collect();
    edit(&mut lines);
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

// ---------------------------------------------------------------------------------------------
// Parsing and association (no data needed)

#[test]
fn stamps_parse_exactly_to_nanoseconds() {
    assert_eq!(parse_stamp_ns("0.000000"), Ok(0));
    assert_eq!(parse_stamp_ns("0.033333"), Ok(33_333_000));
    assert_eq!(parse_stamp_ns("12"), Ok(12_000_000_000));
    assert_eq!(parse_stamp_ns("1305031102.175304"), Ok(1_305_031_102_175_304_000));
    assert_eq!(parse_stamp_ns("1.1234567891"), Ok(1_123_456_789));
    for bad in ["", "-1.0", "1e3", "abc", ".5", "1.2.3", "1,5", "99999999999999999999"] {
        assert!(parse_stamp_ns(bad).is_err(), "{bad:?} should be rejected");
    }
}

fn listed(stamps_ms: &[u64]) -> Vec<ListedImage> {
    stamps_ms
        .iter()
        .enumerate()
        .map(|(i, ms)| ListedImage { stamp_ns: ms * 1_000_000, path: PathBuf::from(format!("{i}.png")), line: i + 1 })
        .collect()
}

#[test]
fn association_pairs_nearest_one_to_one_within_tolerance() {
    let rgb = listed(&[0, 33, 66, 100, 200]);
    // 66 pairs with 80 (14 ms); 200 has no depth image within 20 ms, 300 no colour image.
    let depth = listed(&[1, 34, 80, 101, 300]);
    let pairs = associate(&rgb, &depth, 20_000_000);
    assert_eq!(pairs, vec![(0, 0), (1, 1), (2, 2), (3, 3)]);
    // One depth image near two colour images goes to the closer one only.
    let pairs = associate(&listed(&[0, 10]), &listed(&[8]), 20_000_000);
    assert_eq!(pairs, vec![(1, 0)]);
}

fn gt(stamp_ms: u64, x: f64, line: usize) -> GroundTruthPose {
    GroundTruthPose {
        stamp_ns: stamp_ms * 1_000_000,
        world_from_camera: Isometry::new(DQuat::from_rotation_z(x), DVec3::new(x, 0.0, 0.0)),
        line,
    }
}

#[test]
fn pose_lookup_interpolates_takes_the_nearest_and_flags_gaps() {
    let tol = Tolerances { association_ns: 20_000_000, max_pose_gap_ns: 100_000_000 };
    let poses = [gt(100, 0.0, 3), gt(200, 1.0, 4), gt(500, 2.0, 5)];
    let x = |p: EntryPose| match p {
        EntryPose::Known(p) => p.translation.x,
        other => panic!("expected a pose, got {other:?}"),
    };
    assert_eq!(x(pose_at(&poses, 100_000_000, tol)), 0.0);
    assert!((x(pose_at(&poses, 125_000_000, tol)) - 0.25).abs() < 1e-12);
    // In the 300 ms gap: nearest within 20 ms, else a gap naming both ends.
    assert_eq!(x(pose_at(&poses, 215_000_000, tol)), 1.0);
    match pose_at(&poses, 300_000_000, tol) {
        EntryPose::Gap { before, after } => assert_eq!((before.line, after.line), (4, 5)),
        other => panic!("expected a gap, got {other:?}"),
    }
    // Outside the span: nearest within tolerance, else no pose.
    assert_eq!(x(pose_at(&poses, 90_000_000, tol)), 0.0);
    assert_eq!(pose_at(&poses, 50_000_000, tol), EntryPose::OutsideGroundTruth);
    assert_eq!(pose_at(&poses, 600_000_000, tol), EntryPose::OutsideGroundTruth);
    assert_eq!(pose_at(&[], 0, tol), EntryPose::OutsideGroundTruth);
}

#[test]
fn config_validation_names_the_field() {
    let mut config = ReplayConfig::new(PathBuf::from("x"));
    assert_eq!(config.validate("source.replay"), Ok(()));
    config.max_pose_gap_ms = 0.0;
    assert_eq!(
        config.validate("source.replay").unwrap_err(),
        "source.replay.max_pose_gap_ms: must be within (0, 10000], got 0"
    );
    config.max_pose_gap_ms = 100.0;
    config.intrinsics = Some(crate::frame::Intrinsics { fx: -1.0, ..crate::frame::Intrinsics::d435i_640x480() });
    assert_eq!(config.validate("source.replay").unwrap_err(), "source.replay.intrinsics.fx: must be > 0, got -1");
}

// ---------------------------------------------------------------------------------------------
// A small generated recording (16x16, PNG colour and depth), independent of the shared data

const TINY: u32 = 16;

/// Writes a recording of `n` frames at 30 Hz whose depth pixel values are `1000 + k` and whose
/// camera moves 0.1 m along x per frame.
fn tiny_recording(n: usize) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    std::fs::create_dir(root.join("rgb")).unwrap();
    std::fs::create_dir(root.join("depth")).unwrap();
    std::fs::write(
        root.join("camera.json"),
        r#"{"width": 16, "height": 16, "fx": 20.0, "fy": 20.0, "cx": 7.5, "cy": 7.5, "depth_scale_per_m": 5000.0}"#,
    )
    .unwrap();
    let (mut rgb_txt, mut depth_txt, mut gt_txt) =
        ("# rgb\n".to_owned(), "# depth\n".to_owned(), "# groundtruth\n".to_owned());
    for k in 0..n {
        let stamp = format!("{}.{:06}", 100 + k / 30, (k % 30) * 33_333);
        let colour: Vec<u8> = (0..TINY * TINY * 3).map(|i| (i as usize + k) as u8).collect();
        let file = std::fs::File::create(root.join(format!("rgb/{k}.png"))).unwrap();
        PngEncoder::new(file).write_image(&colour, TINY, TINY, ExtendedColorType::Rgb8).unwrap();
        let depth: Vec<u16> = vec![1000 + k as u16; (TINY * TINY) as usize];
        let file = std::fs::File::create(root.join(format!("depth/{k}.png"))).unwrap();
        PngEncoder::new(file).write_image(bytemuck::cast_slice(&depth), TINY, TINY, ExtendedColorType::L16).unwrap();
        rgb_txt += &format!("{stamp} rgb/{k}.png\n");
        depth_txt += &format!("{stamp} depth/{k}.png\n");
        gt_txt += &format!("{stamp} {} 0 0 0 0 0 1\n", k as f64 * 0.1);
    }
    std::fs::write(root.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(root.join("depth.txt"), depth_txt).unwrap();
    std::fs::write(root.join("groundtruth.txt"), gt_txt).unwrap();
    dir
}

#[test]
fn generated_recording_round_trips_pixels_poses_and_stamps() {
    let dir = tiny_recording(3);
    let mut source = ReplaySource::new(&fast(dir.path())).unwrap();
    assert!(source.has_poses());
    assert_eq!(source.len_hint(), Some(3));
    let (frames, error) = play(&mut source);
    assert!(error.is_none());
    assert_eq!(frames.len(), 3);
    for (k, frame) in frames.iter().enumerate() {
        assert_eq!(frame.seq, k as u64);
        assert_eq!(frame.stamp_ns, 100_000_000_000 + k as u64 * 33_333_000);
        assert!(frame.depth.iter().all(|d| *d == 1000 + k as u16), "16-bit depth in native byte order");
        assert_eq!(frame.depth_units_per_m, 5000.0);
        assert!((frame.depth_m(0) - (1000 + k) as f32 / 5000.0).abs() < 1e-6);
        assert_eq!(frame.rgb[5], (5 + k) as u8);
        assert!((frame.world_from_camera.unwrap().translation.x - k as f64 * 0.1).abs() < 1e-12);
    }
}

#[test]
fn looping_keeps_seq_and_stamps_increasing() {
    let dir = tiny_recording(3);
    let config = ReplayConfig { looping: true, ..fast(dir.path()) };
    let mut source = ReplaySource::new(&config).unwrap();
    assert_eq!(source.len_hint(), None);
    let mut frame = Frame::new(source.intrinsics());
    let mut stamps = Vec::new();
    for expected_seq in 0..7u64 {
        assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
        assert_eq!(frame.seq, expected_seq);
        assert_eq!(frame.depth[0], 1000 + (expected_seq % 3) as u16, "pass restarts at the first frame");
        stamps.push(frame.stamp_ns);
    }
    // Each pass is shifted by the recording's length (66.666 ms) plus one interval (33.333 ms).
    assert_eq!(stamps[3] - stamps[0], 99_999_000);
    assert!(stamps.windows(2).all(|w| w[1] > w[0]));
}

#[test]
fn stepped_mode_delivers_only_on_step() {
    let dir = tiny_recording(3);
    let config = ReplayConfig { mode: PlaybackMode::Stepped, ..ReplayConfig::new(dir.path().to_path_buf()) };
    let mut source = ReplaySource::new(&config).unwrap();
    let step = source.step_control().expect("a stepped source has a step control");
    let mut frame = Frame::new(source.intrinsics());
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Pending);
    step.step(2);
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
    assert_eq!(frame.seq, 0);
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
    assert_eq!(frame.seq, 1);
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Pending);
    step.step(5);
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::EndOfStream);
    // Fast and recorded sources have no step control.
    assert!(ReplaySource::new(&fast(dir.path())).unwrap().step_control().is_none());
}

#[test]
fn recorded_mode_paces_by_the_stamps() {
    let dir = tiny_recording(4);
    let mut source = ReplaySource::new(&ReplayConfig::new(dir.path().to_path_buf())).unwrap();
    let started = Instant::now();
    let (frames, error) = play(&mut source);
    assert!(error.is_none());
    assert_eq!(frames.len(), 4);
    // Three intervals of 33.333 ms lie between the first and the last delivery (a lower bound
    // only: a test never asserts a wall-clock maximum).
    assert!(started.elapsed() >= Duration::from_micros(3 * 33_333), "{:?}", started.elapsed());
}

#[test]
fn recorded_mode_returns_pending_across_a_long_pause() {
    let dir = tiny_recording(2);
    // Move the second frame 1 s later: the source must not block for that second in one call.
    for index in ["rgb.txt", "depth.txt", "groundtruth.txt"] {
        edit_lines(&dir.path().join(index), |lines| lines[2] = lines[2].replacen("100.033333", "101.033333", 1));
    }
    let mut source = ReplaySource::new(&ReplayConfig::new(dir.path().to_path_buf())).unwrap();
    let mut frame = Frame::new(source.intrinsics());
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
    let mut pending = 0;
    loop {
        match source.next_frame(&mut frame).unwrap() {
            SourceStatus::Pending => pending += 1,
            SourceStatus::Frame => break,
            SourceStatus::EndOfStream => panic!("second frame lost"),
        }
    }
    assert!(pending >= 5, "a 1 s pause in blocks of at most {MAX_BLOCK:?} gives several Pending, got {pending}");
    assert_eq!(frame.seq, 1);
}

#[test]
fn frames_outside_the_ground_truth_carry_no_pose() {
    let dir = tiny_recording(4);
    // Ground truth only for frames 1 and 2.
    edit_lines(&dir.path().join("groundtruth.txt"), |lines| {
        lines.remove(4);
        lines.remove(1);
    });
    let mut source = ReplaySource::new(&fast(dir.path())).unwrap();
    let (frames, error) = play(&mut source);
    assert!(error.is_none());
    let posed: Vec<bool> = frames.iter().map(|f| f.world_from_camera.is_some()).collect();
    assert_eq!(posed, [false, true, true, false]);
}

#[test]
fn camera_json_problems_name_the_file() {
    let dir = tiny_recording(1);
    let camera = dir.path().join("camera.json");
    std::fs::write(&camera, r#"{"width": 16, "height": 16, "fx": 20.0, "fy": 20.0, "cx": 7.5, "cy": 7.5, "k1": 0.1}"#)
        .unwrap();
    let err = ReplaySource::new(&fast(dir.path())).unwrap_err().to_string();
    assert!(err.starts_with(&camera.display().to_string()) && err.contains("unknown field `k1`"), "{err}");
    // Without camera.json the profile must give intrinsics and depth scale.
    std::fs::remove_file(&camera).unwrap();
    let err = ReplaySource::new(&fast(dir.path())).unwrap_err().to_string();
    assert!(err.contains("camera.json: missing") && err.contains("source.replay.intrinsics"), "{err}");
    let config = ReplayConfig {
        intrinsics: Some(crate::frame::Intrinsics { width: 16, height: 16, fx: 20.0, fy: 20.0, cx: 7.5, cy: 7.5 }),
        depth_units_per_m: Some(1000.0),
        ..fast(dir.path())
    };
    let mut source = ReplaySource::new(&config).unwrap();
    let (frames, _) = play(&mut source);
    assert_eq!(frames[0].depth_units_per_m, 1000.0);
}

#[test]
fn a_folder_that_is_not_a_recording_is_a_file_error() {
    let dir = tempfile::tempdir().unwrap();
    let err = ReplaySource::new(&fast(&dir.path().join("nope"))).unwrap_err();
    assert!(matches!(err, SourceError::File { .. }), "{err}");
    let err = ReplaySource::new(&fast(dir.path())).unwrap_err().to_string();
    assert!(err.contains("camera.json"), "{err}");
    std::fs::write(
        dir.path().join("camera.json"),
        r#"{"width": 16, "height": 16, "fx": 1, "fy": 1, "cx": 0, "cy": 0, "depth_scale_per_m": 1000}"#,
    )
    .unwrap();
    let err = ReplaySource::new(&fast(dir.path())).unwrap_err().to_string();
    assert!(err.contains("rgb.txt: cannot read"), "{err}");
}

#[test]
fn looping_over_nothing_but_bad_frames_ends_with_an_error() {
    let dir = tiny_recording(2);
    for k in 0..2 {
        std::fs::write(dir.path().join(format!("depth/{k}.png")), b"not a png").unwrap();
    }
    let config = ReplayConfig { looping: true, ..skip(fast(dir.path())) };
    let mut source = ReplaySource::new(&config).unwrap();
    let (frames, error) = play(&mut source);
    assert!(frames.is_empty());
    let error = error.expect("ends with an error").to_string();
    assert!(error.contains("no frame of the recording could be read"), "{error}");
    assert_eq!(source.bad_data_skipped(), 2);
}

// ---------------------------------------------------------------------------------------------
// The real sequence

#[test]
fn icl_sequence_plays_every_frame_with_its_pose() {
    let Some(dir) = icl_dir() else { return };
    let mut source = ReplaySource::new(&fast(&dir)).unwrap();
    assert_eq!(source.frame_count(), ICL_FRAMES);
    assert_eq!(source.unmatched_rgb(), 0);
    let k = source.intrinsics();
    assert_eq!((k.width, k.height, k.fx, k.cx), (640, 480, 525.0, 319.5));
    let mut frame = Frame::new(k);
    let started = Instant::now();
    let mut count = 0u64;
    let mut previous: Option<Isometry> = None;
    while source.next_frame(&mut frame).unwrap() == SourceStatus::Frame {
        assert_eq!(frame.seq, count);
        // rgb.txt stamps: k / 30 s, written with 6 decimals.
        assert!(frame.stamp_ns.abs_diff(count * 1_000_000_000 / 30) < 1000, "frame {count} at {}", frame.stamp_ns);
        let pose = frame.world_from_camera.expect("every ICL frame has a ground-truth pose");
        if let Some(previous) = previous {
            // The camera moves smoothly: well under 5 cm and 2 degrees per frame.
            assert!(previous.translation.distance(pose.translation) < 0.05);
            assert!(previous.rotation.angle_between(pose.rotation).to_degrees() < 2.0);
        }
        previous = Some(pose);
        assert_eq!(frame.depth_units_per_m, 1000.0);
        let mut valid: Vec<u16> = frame.depth.iter().copied().filter(|d| *d > 0).collect();
        assert!(valid.len() > frame.depth.len() / 2, "frame {count}: most pixels have depth");
        let mid = valid.len() / 2;
        let median_m = f32::from(*valid.select_nth_unstable(mid).1) / 1000.0;
        assert!((0.5..6.0).contains(&median_m), "frame {count}: median depth {median_m} m");
        assert!(frame.rgb.iter().any(|v| *v > 50), "frame {count}: colour decoded");
        count += 1;
    }
    assert_eq!(count, ICL_FRAMES as u64);
    assert_eq!(source.bad_data_skipped(), 0);
    eprintln!(
        "ICL: {count} frames (JPEG colour + 16-bit PNG depth) in {:.2} s: {:.1} ms per frame (this build)",
        started.elapsed().as_secs_f64(),
        started.elapsed().as_secs_f64() * 1e3 / count as f64
    );
}

/// Frames `wanted` (ascending) of the ICL sequence.
fn icl_frames(dir: &Path, wanted: &[u64]) -> Vec<Frame> {
    let mut source = ReplaySource::new(&fast(dir)).unwrap();
    let mut frame = Frame::new(source.intrinsics());
    let mut out = Vec::new();
    while out.len() < wanted.len() && source.next_frame(&mut frame).unwrap() == SourceStatus::Frame {
        if wanted.contains(&frame.seq) {
            out.push(frame.clone());
        }
    }
    out
}

/// Back-projects every 4th pixel of `a` to the world with `pose_a`, projects it into `b` with
/// `pose_b`, back-projects `b`'s depth at that pixel, and returns the 3D distances, metres.
fn reprojection_errors_m(a: &Frame, pose_a: &Isometry, b: &Frame, pose_b: &Isometry) -> Vec<f64> {
    let k = a.intrinsics;
    let camera_b_from_world = pose_b.inverse();
    let mut errors = Vec::new();
    for v in (0..k.height).step_by(4) {
        for u in (0..k.width).step_by(4) {
            let depth_a = a.depth_m((v * k.width + u) as usize);
            if depth_a <= 0.0 {
                continue;
            }
            let point_in_world = pose_a.transform_point(k.point_in_camera(u as f32, v as f32, depth_a).as_dvec3());
            let Some((ub, vb)) = k.project(camera_b_from_world.transform_point(point_in_world).as_vec3()) else {
                continue;
            };
            let (ub, vb) = (ub.round(), vb.round());
            if ub < 0.0 || vb < 0.0 || ub >= k.width as f32 || vb >= k.height as f32 {
                continue;
            }
            let depth_b = b.depth_m((vb as u32 * k.width + ub as u32) as usize);
            if depth_b <= 0.0 {
                continue;
            }
            let seen_by_b = pose_b.transform_point(k.point_in_camera(ub, vb, depth_b).as_dvec3());
            errors.push(seen_by_b.distance(point_in_world));
        }
    }
    errors
}

fn median(values: &mut [f64]) -> f64 {
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f64::total_cmp).1
}

#[test]
fn icl_poses_back_project_one_surface_from_distant_frames() {
    let Some(dir) = icl_dir() else { return };
    let frames = icl_frames(&dir, &[0, 50, 150, 210]);
    let pose = |f: &Frame| f.world_from_camera.unwrap();
    for (a, b) in [(&frames[0], &frames[3]), (&frames[1], &frames[2])] {
        let mut errors = reprojection_errors_m(a, &pose(a), b, &pose(b));
        let samples = errors.len();
        assert!(samples > 2000, "frames {} and {} overlap in {samples} samples only", a.seq, b.seq);
        let median_m = median(&mut errors);
        let within_5cm = errors.iter().filter(|e| **e < 0.05).count() as f64 / samples as f64;
        // The opposite convention (the file holding camera_from_world) must be far off.
        let mut wrong = reprojection_errors_m(a, &pose(a).inverse(), b, &pose(b).inverse());
        let wrong_median_m = if wrong.len() > 100 { median(&mut wrong) } else { f64::INFINITY };
        let moved_m = pose(a).translation.distance(pose(b).translation);
        let turned_deg = pose(a).rotation.angle_between(pose(b).rotation).to_degrees();
        eprintln!(
            "frames {} -> {} (camera moved {moved_m:.2} m, turned {turned_deg:.1} deg): median 3D error \
             {:.2} cm over {samples} pixels, {:.0}% within 5 cm; inverted poses: {:.1} cm",
            a.seq,
            b.seq,
            median_m * 100.0,
            within_5cm * 100.0,
            wrong_median_m * 100.0
        );
        assert!(median_m < 0.03, "median back-projection error {median_m} m between frames {} and {}", a.seq, b.seq);
        assert!(within_5cm > 0.6, "only {within_5cm} of the points agree within 5 cm");
        assert!(wrong_median_m > 5.0 * median_m.max(0.01), "the test cannot tell conventions apart");
    }
}

#[test]
fn interpolated_poses_match_the_ground_truth_they_replace() {
    let Some(dst) = icl_copy(21) else { return };
    let original = std::fs::read_to_string(dst.path().join("groundtruth.txt")).unwrap();
    // Keep every other ground-truth pose (66.7 ms apart, within the 100 ms gap tolerance).
    edit_lines(&dst.path().join("groundtruth.txt"), |lines| {
        let kept: Vec<String> = lines
            .iter()
            .enumerate()
            .filter(|(i, _)| *i < ICL_HEADER_LINES || (*i - ICL_HEADER_LINES).is_multiple_of(2))
            .map(|(_, l)| l.clone())
            .collect();
        *lines = kept;
    });
    let (frames, error) = play(&mut ReplaySource::new(&fast(dst.path())).unwrap());
    assert!(error.is_none());
    assert_eq!(frames.len(), 21);
    let mut worst_m: f64 = 0.0;
    let mut worst_deg: f64 = 0.0;
    for (frame, line) in frames.iter().zip(original.lines().skip(ICL_HEADER_LINES)) {
        let v: Vec<f64> = line.split_whitespace().skip(1).map(|t| t.parse().unwrap()).collect();
        let truth = Isometry::new(DQuat::from_xyzw(v[3], v[4], v[5], v[6]), DVec3::new(v[0], v[1], v[2]));
        let pose = frame.world_from_camera.unwrap();
        worst_m = worst_m.max(pose.translation.distance(truth.translation));
        worst_deg = worst_deg.max(pose.rotation.angle_between(truth.rotation).to_degrees());
    }
    eprintln!("interpolated vs dropped ground truth: worst {:.2} mm, {:.3} deg", worst_m * 1e3, worst_deg);
    assert!(worst_m < 0.005 && worst_deg < 0.5, "{worst_m} m, {worst_deg} deg");
}

// ---------------------------------------------------------------------------------------------
// Bad data in temp copies of the sequence: the error names the file and line, and
// `on_bad_frame` decides between stopping and skipping.

/// Plays the copy with `stop` and with `skip`; returns (frames, error) and (frames, skipped).
fn stop_and_skip(dir: &Path) -> ((Vec<Frame>, String), (Vec<Frame>, u64)) {
    let (stopped, error) = play(&mut ReplaySource::new(&fast(dir)).unwrap());
    let error = error.expect("stop mode ends with the error").to_string();
    let mut source = ReplaySource::new(&skip(fast(dir))).unwrap();
    let (skipped, none) = play(&mut source);
    assert!(none.is_none(), "skip mode plays to the end");
    assert!(skipped.iter().enumerate().all(|(i, f)| f.seq == i as u64), "seqs stay gapless");
    ((stopped, error), (skipped, source.bad_data_skipped()))
}

#[test]
fn corrupt_png_names_the_file_and_line() {
    let Some(dst) = icl_copy(6) else { return };
    let bad = dst.path().join("depth/00002.png");
    let bytes = std::fs::read(&bad).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() / 3]).unwrap();
    let ((stopped, error), (skipped, count)) = stop_and_skip(dst.path());
    assert_eq!(stopped.len(), 2, "frames before the bad one are delivered");
    let listed = format!("listed at {}:{}", dst.path().join("depth.txt").display(), icl_line(2));
    assert!(error.starts_with(&bad.display().to_string()) && error.contains(&listed), "{error}");
    assert!(error.contains("cannot decode PNG"), "{error}");
    assert_eq!((skipped.len(), count), (5, 1));
    assert!(skipped[2].stamp_ns.abs_diff(3 * 1_000_000_000 / 30) < 1000, "frame 3 follows frame 1");
}

#[test]
fn missing_image_names_the_file_and_line() {
    let Some(dst) = icl_copy(6) else { return };
    let gone = dst.path().join("rgb/00003.jpg");
    std::fs::remove_file(&gone).unwrap();
    let ((stopped, error), (skipped, count)) = stop_and_skip(dst.path());
    assert_eq!(stopped.len(), 3);
    let listed = format!("listed at {}:{}", dst.path().join("rgb.txt").display(), icl_line(3));
    assert!(error.starts_with(&format!("{}: missing", gone.display())) && error.contains(&listed), "{error}");
    assert!(error.contains("frame 3"), "{error}");
    assert_eq!((skipped.len(), count), (5, 1));
}

#[test]
fn malformed_line_names_the_file_and_line() {
    let Some(dst) = icl_copy(6) else { return };
    let index = dst.path().join("groundtruth.txt");
    edit_lines(&index, |lines| {
        lines[icl_line(4) - 1] = "0.133333 -0.307389 0.669701 2.119101 -0.6079891 oops 0.7931267 -0.0218147".into()
    });
    // Stop: the source does not open, naming file:line.
    let err = ReplaySource::new(&fast(dst.path())).unwrap_err();
    let text = err.to_string();
    assert!(matches!(&err, SourceError::Line { line, .. } if *line == icl_line(4)), "{text}");
    assert!(text.starts_with(&format!("{}:{}: 'oops' is not a number", index.display(), icl_line(4))), "{text}");
    // Skip: the line is left out and counted; frame 4 is posed by interpolation instead.
    let mut source = ReplaySource::new(&skip(fast(dst.path()))).unwrap();
    assert_eq!(source.bad_data_skipped(), 1);
    let (frames, error) = play(&mut source);
    assert!(error.is_none());
    assert_eq!(frames.len(), 6);
    assert!(frames[4].world_from_camera.is_some());

    // A malformed image line drops that frame.
    let Some(dst) = icl_copy(6) else { return };
    let index = dst.path().join("rgb.txt");
    edit_lines(&index, |lines| lines[icl_line(1) - 1] = "0.033333rgb/00001.jpg".into());
    let text = ReplaySource::new(&fast(dst.path())).unwrap_err().to_string();
    assert_eq!(text, format!("{}:{}: expected 'timestamp filename', found 1 fields", index.display(), icl_line(1)));
    let mut source = ReplaySource::new(&skip(fast(dst.path()))).unwrap();
    assert_eq!((source.frame_count(), source.bad_data_skipped()), (5, 1));
    // Its depth image has no colour partner now: not bad data, just unmatched.
    assert_eq!(source.unmatched_rgb(), 0);
    assert_eq!(play(&mut source).0.len(), 5);
}

#[test]
fn pose_gap_names_the_file_line_and_frame() {
    let Some(dst) = icl_copy(8) else { return };
    let index = dst.path().join("groundtruth.txt");
    // Drop the poses of frames 2..=4: frames 1 and 5 are 133 ms apart (> 100 ms).
    edit_lines(&index, |lines| {
        lines.drain(icl_line(2) - 1..icl_line(5) - 1);
    });
    let ((stopped, error), (skipped, count)) = stop_and_skip(dst.path());
    assert_eq!(stopped.len(), 2);
    // After the edit, frame 5's pose is on the line frame 2's was.
    assert!(error.starts_with(&format!("{}:{}: pose gap: frame 2", index.display(), icl_line(2))), "{error}");
    assert!(error.contains(&format!("{}:{}", dst.path().join("rgb.txt").display(), icl_line(2))), "{error}");
    assert!(error.contains("133 ms apart"), "{error}");
    assert_eq!((skipped.len(), count), (5, 3));
    assert!(skipped.iter().all(|f| f.world_from_camera.is_some()));
    // A wider tolerance bridges the gap by interpolation.
    let config = ReplayConfig { max_pose_gap_ms: 150.0, ..fast(dst.path()) };
    let (frames, error) = play(&mut ReplaySource::new(&config).unwrap());
    assert!(error.is_none());
    assert_eq!(frames.len(), 8);
}

#[test]
fn image_size_not_matching_the_intrinsics_names_the_file() {
    let Some(dst) = icl_copy(2) else { return };
    let config = ReplayConfig {
        intrinsics: Some(crate::frame::Intrinsics {
            width: 320,
            height: 240,
            fx: 262.5,
            fy: 262.5,
            cx: 159.5,
            cy: 119.5,
        }),
        ..fast(dst.path())
    };
    let (frames, error) = play(&mut ReplaySource::new(&config).unwrap());
    assert!(frames.is_empty());
    let error = error.unwrap().to_string();
    let image = dst.path().join("rgb/00000.jpg");
    assert!(
        error.starts_with(&format!("{}: image is 640x480 pixels, the intrinsics say 320x240", image.display())),
        "{error}"
    );
    let mut source = ReplaySource::new(&skip(config)).unwrap();
    assert!(play(&mut source).0.is_empty());
    assert_eq!(source.bad_data_skipped(), 2);
}
