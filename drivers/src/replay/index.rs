//! The recording's index files: `rgb.txt`, `depth.txt`, `groundtruth.txt`, `camera.json`;
//! association of colour, depth and pose by timestamp.

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};
use tracing::warn;

use super::OnBadFrame;
use crate::frame::Intrinsics;
use crate::pose::Isometry;
use crate::source::SourceError;

/// Largest deviation from 1 of a ground-truth quaternion's norm (TUM stores 4 decimals).
const MAX_QUATERNION_NORM_ERROR: f64 = 0.01;
/// Skipped items logged individually before the log thins out to powers of two.
const SKIPS_LOGGED_IN_FULL: u64 = 10;

/// Parses a timestamp in decimal seconds (`1305031102.175304`, `0.033333`, `12`) exactly into
/// nanoseconds; digits past the ninth decimal are dropped.
pub fn parse_stamp_ns(text: &str) -> Result<u64, String> {
    let bad = || format!("'{text}' is not a timestamp in decimal seconds");
    let (whole, fraction) = text.split_once('.').unwrap_or((text, ""));
    if whole.is_empty() || !whole.bytes().all(|b| b.is_ascii_digit()) || !fraction.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad());
    }
    let seconds: u64 = whole.parse().map_err(|_| bad())?;
    let mut fraction_ns = 0u64;
    for (i, digit) in fraction.bytes().take(9).enumerate() {
        fraction_ns += u64::from(digit - b'0') * 10u64.pow(8 - i as u32);
    }
    seconds.checked_mul(1_000_000_000).and_then(|ns| ns.checked_add(fraction_ns)).ok_or_else(bad)
}

/// `camera.json` beside the recording.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Depth units per metre (1000 = millimetres).
    #[serde(default)]
    pub depth_scale_per_m: Option<f32>,
    /// Nominal frame rate, Hz (informative; the timestamps pace playback).
    #[serde(default)]
    pub rate_hz: Option<f64>,
}

impl CameraFile {
    /// The pinhole intrinsics.
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics { width: self.width, height: self.height, fx: self.fx, fy: self.fy, cx: self.cx, cy: self.cy }
    }

    /// Reads `<dir>/camera.json`; `None` when there is none.
    pub fn read(dir: &Path) -> Result<Option<Self>, SourceError> {
        let path = dir.join("camera.json");
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(file_error(&path, format!("cannot read: {e}"))),
        };
        let camera: Self = serde_json::from_str(&text).map_err(|e| file_error(&path, e.to_string()))?;
        crate::frame::check_intrinsics(&camera.intrinsics())
            .map_err(|e| file_error(&path, format!("intrinsics{e}")))?;
        if let Some(units) = camera.depth_scale_per_m
            && !(units.is_finite() && units > 0.0)
        {
            return Err(file_error(&path, format!("depth_scale_per_m: must be > 0, got {units}")));
        }
        Ok(Some(camera))
    }
}

pub(crate) fn file_error(path: &Path, reason: impl Into<String>) -> SourceError {
    SourceError::File { path: path.display().to_string(), reason: reason.into() }
}

fn line_error(path: &Path, line: usize, reason: impl Into<String>) -> SourceError {
    SourceError::Line { path: path.display().to_string(), line, reason: reason.into() }
}

/// Counts what `on_bad_frame = "skip"` left out and logs it, thinning out after the first ten.
#[derive(Debug, Default)]
pub(crate) struct SkipLog {
    pub(crate) count: u64,
}

impl SkipLog {
    pub(crate) fn note(&mut self, error: &SourceError) {
        self.count += 1;
        if self.count <= SKIPS_LOGGED_IN_FULL || self.count.is_power_of_two() {
            warn!(error = %error, skipped = self.count, "replay: bad data skipped");
        }
    }
}

/// An image named by a line of an index file.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ListedImage {
    pub(crate) stamp_ns: u64,
    /// The image, joined to the recording's folder.
    pub(crate) path: PathBuf,
    /// 1-based line of the index file.
    pub(crate) line: usize,
}

/// A ground-truth pose and the line it came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GroundTruthPose {
    pub(crate) stamp_ns: u64,
    pub(crate) world_from_camera: Isometry,
    pub(crate) line: usize,
}

/// The pose a frame gets from the ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum EntryPose {
    /// Exact, interpolated, or nearest within the association tolerance.
    Known(Isometry),
    /// Before the first or after the last ground-truth pose (or no ground truth at all).
    OutsideGroundTruth,
    /// Inside the ground truth's span, but its neighbours are too far apart: bad data.
    Gap { before: GroundTruthPose, after: GroundTruthPose },
}

/// One frame of the recording: associated colour, depth and pose.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Entry {
    /// The colour image's stamp.
    pub(crate) stamp_ns: u64,
    pub(crate) rgb: ListedImage,
    pub(crate) depth: ListedImage,
    pub(crate) pose: EntryPose,
}

/// The associated frames of a recording.
#[derive(Debug)]
pub(crate) struct Index {
    pub(crate) rgb_index: PathBuf,
    pub(crate) depth_index: PathBuf,
    pub(crate) ground_truth: Option<PathBuf>,
    pub(crate) entries: Vec<Entry>,
    /// Colour images without a depth image within the tolerance (not frames).
    pub(crate) unmatched_rgb: usize,
}

/// Tolerances of association, nanoseconds.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tolerances {
    pub(crate) association_ns: u64,
    pub(crate) max_pose_gap_ns: u64,
}

impl Index {
    /// Reads the index files of `dir` and associates them. Malformed lines stop or are skipped
    /// (counted in `skips`) per `on_bad`.
    pub(crate) fn open(
        dir: &Path,
        tolerances: Tolerances,
        on_bad: OnBadFrame,
        skips: &mut SkipLog,
    ) -> Result<Self, SourceError> {
        let rgb_index = dir.join("rgb.txt");
        let depth_index = dir.join("depth.txt");
        let gt_path = dir.join("groundtruth.txt");
        let text = read_text(&rgb_index)?;
        let mut rgb =
            parse_lines(&rgb_index, &text, on_bad, skips, |fields, line| parse_image_line(dir, fields, line))?;
        let text = read_text(&depth_index)?;
        let mut depth =
            parse_lines(&depth_index, &text, on_bad, skips, |fields, line| parse_image_line(dir, fields, line))?;
        let (ground_truth, mut poses) = match std::fs::read_to_string(&gt_path) {
            Ok(text) => {
                let poses = parse_lines(&gt_path, &text, on_bad, skips, parse_pose_line)?;
                if poses.is_empty() {
                    return Err(file_error(&gt_path, "holds no pose (remove the file for a recording without poses)"));
                }
                (Some(gt_path), poses)
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (None, Vec::new()),
            Err(e) => return Err(file_error(&gt_path, format!("cannot read: {e}"))),
        };
        rgb.sort_by_key(|r| r.stamp_ns);
        depth.sort_by_key(|d| d.stamp_ns);
        poses.sort_by_key(|p| p.stamp_ns);

        let pairs = associate(&rgb, &depth, tolerances.association_ns);
        let unmatched_rgb = rgb.len() - pairs.len();
        let entries = pairs
            .into_iter()
            .map(|(i, j)| {
                let stamp_ns = rgb[i].stamp_ns;
                Entry {
                    stamp_ns,
                    rgb: rgb[i].clone(),
                    depth: depth[j].clone(),
                    pose: pose_at(&poses, stamp_ns, tolerances),
                }
            })
            .collect();
        Ok(Self { rgb_index, depth_index, ground_truth, entries, unmatched_rgb })
    }
}

fn read_text(path: &Path) -> Result<String, SourceError> {
    std::fs::read_to_string(path).map_err(|e| file_error(path, format!("cannot read: {e}")))
}

/// Parses every non-blank, non-`#` line of an index file with `parse(fields, 1-based line)`.
fn parse_lines<T>(
    path: &Path,
    text: &str,
    on_bad: OnBadFrame,
    skips: &mut SkipLog,
    mut parse: impl FnMut(&[&str], usize) -> Result<T, String>,
) -> Result<Vec<T>, SourceError> {
    let mut items = Vec::new();
    let mut fields = Vec::with_capacity(8);
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        fields.clear();
        fields.extend(trimmed.split_whitespace());
        match parse(&fields, i + 1) {
            Ok(item) => items.push(item),
            Err(reason) => {
                let error = line_error(path, i + 1, reason);
                match on_bad {
                    OnBadFrame::Stop => return Err(error),
                    OnBadFrame::Skip => skips.note(&error),
                }
            }
        }
    }
    Ok(items)
}

/// Parses `timestamp filename`.
fn parse_image_line(dir: &Path, fields: &[&str], line: usize) -> Result<ListedImage, String> {
    let [stamp, file] = fields else {
        return Err(format!("expected 'timestamp filename', found {} fields", fields.len()));
    };
    Ok(ListedImage { stamp_ns: parse_stamp_ns(stamp)?, path: dir.join(file), line })
}

/// Parses `timestamp tx ty tz qx qy qz qw`.
fn parse_pose_line(fields: &[&str], line: usize) -> Result<GroundTruthPose, String> {
    let [stamp, rest @ ..] = fields else { return Err("empty line".into()) };
    if rest.len() != 7 {
        return Err(format!("expected 'timestamp tx ty tz qx qy qz qw', found {} fields", fields.len()));
    }
    let stamp_ns = parse_stamp_ns(stamp)?;
    let mut values = [0.0f64; 7];
    for (value, text) in values.iter_mut().zip(rest) {
        *value =
            text.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| format!("'{text}' is not a number"))?;
    }
    let [tx, ty, tz, qx, qy, qz, qw] = values;
    let norm = (qx * qx + qy * qy + qz * qz + qw * qw).sqrt();
    if (norm - 1.0).abs() > MAX_QUATERNION_NORM_ERROR {
        return Err(format!("quaternion (qx qy qz qw) has norm {norm:.4}; expected a unit quaternion"));
    }
    let world_from_camera = Isometry::new(DQuat::from_xyzw(qx, qy, qz, qw), DVec3::new(tx, ty, tz));
    Ok(GroundTruthPose { stamp_ns, world_from_camera, line })
}

/// Pairs each colour image with a depth image at most `tolerance_ns` away, one to one, taking
/// the closest pairs first; returns `(rgb index, depth index)` in colour order. Both lists must
/// be sorted by stamp.
pub(crate) fn associate(rgb: &[ListedImage], depth: &[ListedImage], tolerance_ns: u64) -> Vec<(usize, usize)> {
    let mut candidates = Vec::new();
    for (i, r) in rgb.iter().enumerate() {
        let first = depth.partition_point(|d| d.stamp_ns < r.stamp_ns.saturating_sub(tolerance_ns));
        for (j, d) in depth.iter().enumerate().skip(first) {
            if d.stamp_ns > r.stamp_ns.saturating_add(tolerance_ns) {
                break;
            }
            candidates.push((d.stamp_ns.abs_diff(r.stamp_ns), i, j));
        }
    }
    candidates.sort_unstable();
    let mut rgb_taken = vec![false; rgb.len()];
    let mut depth_taken = vec![false; depth.len()];
    let mut pairs = Vec::new();
    for (_, i, j) in candidates {
        if !rgb_taken[i] && !depth_taken[j] {
            rgb_taken[i] = true;
            depth_taken[j] = true;
            pairs.push((i, j));
        }
    }
    pairs.sort_unstable();
    pairs
}

/// The ground-truth pose at `stamp_ns` (see the module docs for the rule). `poses` is sorted.
pub(crate) fn pose_at(poses: &[GroundTruthPose], stamp_ns: u64, tolerances: Tolerances) -> EntryPose {
    let after = poses.partition_point(|p| p.stamp_ns < stamp_ns);
    let next = poses.get(after);
    let prev = after.checked_sub(1).and_then(|i| poses.get(i));
    if let Some(n) = next
        && n.stamp_ns == stamp_ns
    {
        return EntryPose::Known(n.world_from_camera);
    }
    let near = |p: &GroundTruthPose| p.stamp_ns.abs_diff(stamp_ns) <= tolerances.association_ns;
    match (prev, next) {
        (Some(p), Some(n)) => {
            if n.stamp_ns - p.stamp_ns <= tolerances.max_pose_gap_ns {
                let t = (stamp_ns - p.stamp_ns) as f64 / (n.stamp_ns - p.stamp_ns) as f64;
                EntryPose::Known(p.world_from_camera.interpolate(&n.world_from_camera, t))
            } else {
                let nearest = if stamp_ns - p.stamp_ns <= n.stamp_ns - stamp_ns { p } else { n };
                if near(nearest) {
                    EntryPose::Known(nearest.world_from_camera)
                } else {
                    EntryPose::Gap { before: *p, after: *n }
                }
            }
        }
        (Some(p), None) if near(p) => EntryPose::Known(p.world_from_camera),
        (None, Some(n)) if near(n) => EntryPose::Known(n.world_from_camera),
        _ => EntryPose::OutsideGroundTruth,
    }
}

/// Seconds of a stamp, for messages.
pub(crate) fn seconds(stamp_ns: u64) -> f64 {
    stamp_ns as f64 * 1e-9
}
