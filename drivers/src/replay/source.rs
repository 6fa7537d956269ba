//! [`ReplaySource`]: plays the associated frames of a TUM RGB-D recording.

use std::path::Path;
use std::time::{Duration, Instant};

use tracing::{info, trace};

use super::decode::ImageReader;
use super::index::{CameraFile, Entry, EntryPose, Index, ListedImage, SkipLog, Tolerances, file_error, seconds};
use super::{MAX_BLOCK, OnBadFrame, PlaybackMode, ReplayConfig};
use crate::frame::{Frame, Intrinsics};
use crate::source::{FrameSource, SourceError, SourceKind, SourceStatus, StepControl};

/// Frame interval assumed for a one-frame recording without `camera.json`'s `rate_hz`.
const DEFAULT_FRAME_INTERVAL_NS: u64 = 33_333_333;

/// A [`FrameSource`] over a recording in the TUM RGB-D layout (see [the module](super)).
#[derive(Debug)]
pub struct ReplaySource {
    config: ReplayConfig,
    intrinsics: Intrinsics,
    depth_units_per_m: f32,
    index: Index,
    /// Stamp shift of one pass when looping: the recording's length plus one frame interval.
    pass_period_ns: u64,
    reader: ImageReader,
    skips: SkipLog,
    step: Option<StepControl>,
    // Playback state.
    next_entry: usize,
    pass: u64,
    delivered: u64,
    delivered_this_pass: u64,
    finished: bool,
    /// Wall-clock instant and stamp of the first delivered frame (recorded mode).
    origin: Option<(Instant, u64)>,
}

impl ReplaySource {
    /// Opens the recording: reads `camera.json` and the index files and associates them.
    /// Fails on a bad configuration (`Config`), a missing or unreadable index file (`File`), or,
    /// with `on_bad_frame = "stop"`, a malformed index line (`Line`).
    pub fn new(config: &ReplayConfig) -> Result<Self, SourceError> {
        config.validate("").map_err(SourceError::Config)?;
        let dir = &config.path;
        if !dir.is_dir() {
            return Err(file_error(dir, "not a folder (expected a recording in the TUM RGB-D layout)"));
        }
        let camera = CameraFile::read(dir)?;
        let camera_path = dir.join("camera.json");
        let intrinsics = match (config.intrinsics, &camera) {
            (Some(k), _) => k,
            (None, Some(camera)) => camera.intrinsics(),
            (None, None) => {
                return Err(file_error(&camera_path, "missing, and the profile sets no source.replay.intrinsics"));
            }
        };
        let depth_units_per_m = match (config.depth_units_per_m, camera.and_then(|c| c.depth_scale_per_m)) {
            (Some(units), _) | (None, Some(units)) => units,
            (None, None) => {
                return Err(file_error(
                    &camera_path,
                    "no depth_scale_per_m, and the profile sets no source.replay.depth_units_per_m",
                ));
            }
        };
        let tolerances = Tolerances {
            association_ns: (config.association_tolerance_ms * 1e6) as u64,
            max_pose_gap_ns: (config.max_pose_gap_ms * 1e6) as u64,
        };
        let mut skips = SkipLog::default();
        let index = Index::open(dir, tolerances, config.on_bad_frame, &mut skips)?;
        let frame_interval_ns = median_interval_ns(&index.entries)
            .or_else(|| camera.and_then(|c| c.rate_hz).filter(|r| *r > 0.0).map(|r| (1e9 / r) as u64))
            .unwrap_or(DEFAULT_FRAME_INTERVAL_NS);
        let span_ns = match (index.entries.first(), index.entries.last()) {
            (Some(first), Some(last)) => last.stamp_ns - first.stamp_ns,
            _ => 0,
        };
        let outside = index.entries.iter().filter(|e| e.pose == EntryPose::OutsideGroundTruth).count();
        let gaps = index.entries.iter().filter(|e| matches!(e.pose, EntryPose::Gap { .. })).count();
        info!(
            path = %dir.display(),
            frames = index.entries.len(),
            unmatched_rgb = index.unmatched_rgb,
            without_pose = if index.ground_truth.is_some() { outside } else { index.entries.len() },
            pose_gaps = gaps,
            skipped_lines = skips.count,
            "replay opened"
        );
        let step = (config.mode == PlaybackMode::Stepped).then(StepControl::new);
        Ok(Self {
            config: config.clone(),
            intrinsics,
            depth_units_per_m,
            index,
            pass_period_ns: span_ns + frame_interval_ns,
            reader: ImageReader::default(),
            skips,
            step,
            next_entry: 0,
            pass: 0,
            delivered: 0,
            delivered_this_pass: 0,
            finished: false,
            origin: None,
        })
    }

    /// Number of associated frames in one pass.
    pub fn frame_count(&self) -> usize {
        self.index.entries.len()
    }

    /// Colour images left out because no depth image was within the association tolerance.
    pub fn unmatched_rgb(&self) -> usize {
        self.index.unmatched_rgb
    }

    /// Depth units per metre of the delivered frames.
    pub fn depth_units_per_m(&self) -> f32 {
        self.depth_units_per_m
    }

    /// The error that an entry's pose gap is.
    fn pose_gap_error(&self, k: usize, entry: &Entry) -> Option<SourceError> {
        let EntryPose::Gap { before, after } = entry.pose else { return None };
        let path = self.index.ground_truth.as_deref().unwrap_or(Path::new("groundtruth.txt"));
        Some(SourceError::Line {
            path: path.display().to_string(),
            line: after.line,
            reason: format!(
                "pose gap: frame {k} ({}:{}, t = {:.6} s) lies between ground-truth poses {:.0} ms apart \
                 (line {} at t = {:.6} s, line {} at t = {:.6} s); source.replay.max_pose_gap_ms is {}",
                self.index.rgb_index.display(),
                entry.rgb.line,
                seconds(entry.stamp_ns),
                (after.stamp_ns - before.stamp_ns) as f64 * 1e-6,
                before.line,
                seconds(before.stamp_ns),
                after.line,
                seconds(after.stamp_ns),
                self.config.max_pose_gap_ms,
            ),
        })
    }

    /// Decodes entry `k` into `frame`.
    fn load(&mut self, k: usize, frame: &mut Frame) -> Result<(), SourceError> {
        let entry = &self.index.entries[k];
        let listed = |image: &ListedImage, index: &Path, problem: String| {
            file_error(&image.path, format!("{problem} (frame {k}, listed at {}:{})", index.display(), image.line))
        };
        self.reader
            .read_rgb(&entry.rgb.path, &self.intrinsics, &mut frame.rgb)
            .map_err(|problem| listed(&entry.rgb, &self.index.rgb_index, problem))?;
        self.reader
            .read_depth(&entry.depth.path, &self.intrinsics, &mut frame.depth)
            .map_err(|problem| listed(&entry.depth, &self.index.depth_index, problem))?;
        Ok(())
    }

    /// Recorded mode: sleeps until `stamp_ns` is due (relative to the first delivered frame),
    /// at most `at_most`; `false` when it is still not due after that.
    fn wait_for_due(&self, stamp_ns: u64, at_most: Duration) -> bool {
        crate::source::wait_until_due(self.origin, stamp_ns, at_most)
    }
}

/// Median interval between consecutive frames.
fn median_interval_ns(entries: &[Entry]) -> Option<u64> {
    let mut intervals: Vec<u64> = entries.windows(2).map(|w| w[1].stamp_ns - w[0].stamp_ns).collect();
    if intervals.is_empty() {
        return None;
    }
    let mid = intervals.len() / 2;
    Some(*intervals.select_nth_unstable(mid).1).filter(|i| *i > 0)
}

impl FrameSource for ReplaySource {
    fn kind(&self) -> SourceKind {
        SourceKind::Replay
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn has_poses(&self) -> bool {
        self.index.ground_truth.is_some()
    }

    fn stamp_clock(&self) -> crate::source::StampClock {
        crate::source::StampClock::Recording
    }

    fn next_frame(&mut self, frame: &mut Frame) -> Result<SourceStatus, SourceError> {
        if self.finished {
            return Ok(SourceStatus::EndOfStream);
        }
        crate::source::check_frame_buffers(frame, &self.intrinsics, self.delivered)?;
        let mut stepped = false;
        loop {
            if self.next_entry == self.index.entries.len() {
                if !self.config.looping || self.index.entries.is_empty() {
                    self.finished = true;
                    return Ok(SourceStatus::EndOfStream);
                }
                if self.delivered_this_pass == 0 {
                    self.finished = true;
                    return Err(file_error(
                        &self.config.path,
                        format!(
                            "no frame of the recording could be read in a whole pass ({} bad lines and frames \
                             skipped so far); stopping instead of looping",
                            self.skips.count
                        ),
                    ));
                }
                self.pass += 1;
                self.next_entry = 0;
                self.delivered_this_pass = 0;
            }
            let k = self.next_entry;
            let stamp_ns = self.index.entries[k].stamp_ns + self.pass * self.pass_period_ns;
            match self.config.mode {
                PlaybackMode::Recorded => {
                    if !self.wait_for_due(stamp_ns, MAX_BLOCK) {
                        return Ok(SourceStatus::Pending);
                    }
                }
                PlaybackMode::Stepped if !stepped => {
                    let granted = self.step.as_ref().is_some_and(|step| step.take(MAX_BLOCK));
                    if !granted {
                        return Ok(SourceStatus::Pending);
                    }
                    stepped = true;
                }
                PlaybackMode::Stepped | PlaybackMode::Fast => {}
            }
            self.next_entry += 1;
            let entry_pose = self.index.entries[k].pose;
            let loaded = match self.pose_gap_error(k, &self.index.entries[k]) {
                Some(gap) => Err(gap),
                None => self.load(k, frame),
            };
            if let Err(error) = loaded {
                match self.config.on_bad_frame {
                    OnBadFrame::Stop => {
                        self.finished = true;
                        return Err(error);
                    }
                    OnBadFrame::Skip => {
                        self.skips.note(&error);
                        continue;
                    }
                }
            }
            frame.seq = self.delivered;
            frame.stamp_ns = stamp_ns;
            frame.intrinsics = self.intrinsics;
            frame.depth_units_per_m = self.depth_units_per_m;
            frame.world_from_camera = match entry_pose {
                EntryPose::Known(pose) => Some(pose),
                EntryPose::OutsideGroundTruth | EntryPose::Gap { .. } => None,
            };
            self.delivered += 1;
            self.delivered_this_pass += 1;
            if self.config.mode == PlaybackMode::Recorded {
                match self.origin {
                    None => self.origin = Some((Instant::now(), stamp_ns)),
                    // Decoding took part of the wait; sleep the rest (under MAX_BLOCK here).
                    Some(_) => {
                        self.wait_for_due(stamp_ns, MAX_BLOCK);
                    }
                }
            }
            trace!(frame_seq = frame.seq, entry = k, pass = self.pass, "replay frame");
            return Ok(SourceStatus::Frame);
        }
    }

    fn len_hint(&self) -> Option<u64> {
        (!self.config.looping).then_some(self.index.entries.len() as u64)
    }

    fn describe(&self) -> String {
        let mode = match self.config.mode {
            PlaybackMode::Recorded => "recorded rate",
            PlaybackMode::Fast => "fast",
            PlaybackMode::Stepped => "stepped",
        };
        let looping = if self.config.looping { ", looping" } else { "" };
        format!("replay {} ({} frames, {mode}{looping})", self.config.path.display(), self.index.entries.len())
    }

    fn bad_data_skipped(&self) -> u64 {
        self.skips.count
    }

    fn stops_on_error(&self) -> bool {
        true
    }

    fn step_control(&self) -> Option<StepControl> {
        self.step.clone()
    }
}
