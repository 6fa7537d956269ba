//! The frame source interface shared by the synthetic scene, replay and the camera.

use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::frame::{Frame, Intrinsics};
use crate::pose::InputPose;

/// What a call to [`FrameSource::next_frame`] produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceStatus {
    /// The frame buffer now holds a new frame.
    Frame,
    /// No frame yet (the camera has not delivered); call again.
    Pending,
    /// A finite source has delivered all its frames.
    EndOfStream,
}

/// Errors of a frame source. Every variant names the input it is about.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// A file of a recording is missing or unreadable.
    #[error("{path}: {reason}")]
    File {
        /// The file.
        path: String,
        /// What went wrong.
        reason: String,
    },
    /// A line of an index file is malformed.
    #[error("{path}:{line}: {reason}")]
    Line {
        /// The index file.
        path: String,
        /// 1-based line number.
        line: usize,
        /// What went wrong.
        reason: String,
    },
    /// A frame does not fit the configured stream (size, format).
    #[error("frame {seq}: {reason}")]
    Frame {
        /// Sequence number of the frame.
        seq: u64,
        /// What went wrong.
        reason: String,
    },
    /// The device is gone (unplugged, driver error).
    #[error("device: {0}")]
    Device(String),
    /// Invalid source configuration.
    #[error("config: {0}")]
    Config(String),
}

/// The clock a source stamps its frames on (`Frame::stamp_ns`). Poses sent on `<prefix>/pose`
/// must be stamped on the same clock: they are looked up by the frame's stamp.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampClock {
    /// The host's clock through librealsense's global time (the camera's hardware timestamps
    /// mapped to the host's system clock, nanoseconds since the Unix epoch): the clock a
    /// navigation stack on the same computer stamps with.
    HostGlobalTime,
    /// The stamps stored in the recording (whatever clock it was recorded on); poses for a
    /// replay come from the recording or are stamped on its clock.
    Recording,
    /// Scene time of the synthetic source: 0 at the first frame, frame `k` at
    /// `k / frame_rate_hz`, independent of the wall clock and of the delivery rate.
    SceneTime,
    /// Not stated by the source.
    Unspecified,
}

impl StampClock {
    /// How the clock reads in logs and docs.
    pub fn describe(self) -> &'static str {
        match self {
            Self::HostGlobalTime => "the host clock (librealsense global time, ns since the Unix epoch)",
            Self::Recording => "the recording's own stamps",
            Self::SceneTime => "synthetic scene time (0 at the first frame, frame k at k / frame_rate_hz)",
            Self::Unspecified => "the source's clock (not stated)",
        }
    }
}

/// What a source reads, as the daemon tells its planners (the graph header's `source_kind`):
/// the world as it is now, a recording of it, or a simulated one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceKind {
    /// A live camera.
    LiveCamera,
    /// A recording played back, whoever plays it: a TUM RGB-D sequence, an MCAP recording, a
    /// librealsense `.bag` (played by the camera's own source).
    Replay,
    /// A simulated world (the synthetic rooms).
    Synthetic,
    /// None of these (a source of another kind; its [`FrameSource::describe`] says what).
    Other,
}

impl SourceKind {
    /// How the kind reads in logs: `live camera`, `replay`, `synthetic`, `other`.
    pub fn describe(self) -> &'static str {
        match self {
            Self::LiveCamera => "live camera",
            Self::Replay => "replay",
            Self::Synthetic => "synthetic",
            Self::Other => "other",
        }
    }
}

/// A source of RGB-D frames. Runs on the capture thread; `next_frame` fills a pooled buffer.
pub trait FrameSource: Send {
    /// Intrinsics of every frame this source delivers (fixed for the source's lifetime).
    fn intrinsics(&self) -> Intrinsics;

    /// What this source reads ([`SourceKind`]): decided by what it opened (the camera's source
    /// playing a `.bag` is a replay), not by the profile's `source.kind`.
    fn kind(&self) -> SourceKind;

    /// Whether frames carry their own `world_from_camera`.
    fn has_poses(&self) -> bool {
        false
    }

    /// Whether the pipeline should wait for this source rather than drop any of its frames: a
    /// recording replayed to reproduce what the robot made (an MCAP replay with
    /// `source.mcap.lossless`). The pipeline then makes its queues up to fusion block, whatever
    /// the profile's policies, so every frame is processed as often as the replay runs. A live
    /// camera cannot wait. Default: `false`.
    fn lossless(&self) -> bool {
        false
    }

    /// `camera_from_upright`: the physical camera's optical frame from the frames' camera, when
    /// the source turns its images upright (a camera turned in its mount); identity otherwise.
    /// A pose of the physical camera (tf's camera frame) composed with it is the frames' pose.
    fn camera_from_upright(&self) -> crate::pose::Isometry {
        crate::pose::Isometry::IDENTITY
    }

    /// Whether the device behind the source is there (a camera that was unplugged and is being
    /// reconnected says `false`); the pipeline reports it as health's `source_connected`.
    fn connected(&self) -> bool {
        true
    }

    /// The clock of the frames' stamps ([`StampClock`]); poses from `<prefix>/pose` must use it.
    fn stamp_clock(&self) -> StampClock {
        StampClock::Unspecified
    }

    /// Fills `frame` with the next frame. A live source may block up to its frame period.
    fn next_frame(&mut self, frame: &mut Frame) -> Result<SourceStatus, SourceError>;

    /// Poses of the daemon's pose input that a recording holds before the frame
    /// [`FrameSource::next_frame`] just delivered (an MCAP replay of a run with
    /// `pose.source = "ipc"`), moved into `out`; the pipeline hands them to the keyframe gate
    /// before that frame, as if the navigation stack had sent them. After `EndOfStream`: the
    /// poses after the last frame. Default: none.
    fn take_input_poses(&mut self, out: &mut Vec<InputPose>) {
        let _ = out;
    }

    /// Total number of frames for a finite source.
    fn len_hint(&self) -> Option<u64> {
        None
    }

    /// A short description for logs ("synthetic kitchen seed 1", "replay /data/seq").
    fn describe(&self) -> String;

    /// Bad inputs (malformed index lines, unreadable images, pose gaps) the source skipped so
    /// far instead of failing (a replay with `on_bad_frame = "skip"`). Each was logged at warn by
    /// the source; the pipeline counts them as capture errors in `health`.
    fn bad_data_skipped(&self) -> u64 {
        0
    }

    /// Whether an error from [`FrameSource::next_frame`] ends the stream (a recording that hit
    /// bad data with `on_bad_frame = "stop"`; later calls return `EndOfStream`). A live camera's
    /// errors are transient and retried.
    fn stops_on_error(&self) -> bool {
        false
    }

    /// The handle that releases frames one by one when the source plays in stepped mode.
    fn step_control(&self) -> Option<StepControl> {
        None
    }

    /// Writes the next frame's `seq`, `stamp_ns` and `world_from_camera` into `frame` without
    /// producing its pixels and without advancing, when the source can do that cheaply (the
    /// synthetic renderer); `None` (the default) when it cannot. A caller that needs the pixels
    /// of only some frames (the batch runner's keyframe gate) then either takes the frame with
    /// [`FrameSource::next_frame`], which delivers exactly the frame previewed, or passes it
    /// with [`FrameSource::skip_frame`]. `Some(EndOfStream)` at the end.
    fn peek_pose(&mut self, _frame: &mut Frame) -> Option<SourceStatus> {
        None
    }

    /// Advances past the frame [`FrameSource::peek_pose`] previewed without producing it.
    /// Sources without `peek_pose` ignore it.
    fn skip_frame(&mut self) {}
}

/// Releases frames of a stepped source: each [`StepControl::step`] lets `n` more frames through;
/// without credit the source's `next_frame` waits briefly and returns
/// [`SourceStatus::Pending`]. Cloneable and shareable across threads (the daemon, a test, a
/// control service drive it while the capture thread reads).
#[derive(Debug, Clone, Default)]
pub struct StepControl {
    shared: Arc<StepShared>,
}

#[derive(Debug, Default)]
struct StepShared {
    credit: Mutex<u64>,
    granted: Condvar,
}

impl StepControl {
    /// A control with no credit.
    pub fn new() -> Self {
        Self::default()
    }

    /// Lets `frames` more frames through.
    pub fn step(&self, frames: u64) {
        let mut credit = self.shared.credit.lock().unwrap_or_else(PoisonError::into_inner);
        *credit = credit.saturating_add(frames);
        self.shared.granted.notify_all();
    }

    /// Frames allowed but not delivered yet.
    pub fn pending(&self) -> u64 {
        *self.shared.credit.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Takes one frame of credit, waiting up to `timeout` for it; `false` when none came.
    pub fn take(&self, timeout: Duration) -> bool {
        let credit = self.shared.credit.lock().unwrap_or_else(PoisonError::into_inner);
        let (mut credit, _) = self
            .shared
            .granted
            .wait_timeout_while(credit, timeout, |credit| *credit == 0)
            .unwrap_or_else(PoisonError::into_inner);
        if *credit == 0 {
            return false;
        }
        *credit -= 1;
        true
    }
}

/// Checks that `frame`'s buffers fit `intrinsics` (RGB8 colour and one depth value per pixel), as
/// a source must before it fills them; the error names frame `seq` and both sizes.
pub fn check_frame_buffers(frame: &Frame, intrinsics: &Intrinsics, seq: u64) -> Result<(), SourceError> {
    let pixels = intrinsics.pixel_count();
    if frame.rgb.len() == pixels * 3 && frame.depth.len() == pixels {
        return Ok(());
    }
    Err(SourceError::Frame {
        seq,
        reason: format!(
            "frame buffers hold {} colour bytes and {} depth values; the source's {}x{} need {} and {}",
            frame.rgb.len(),
            frame.depth.len(),
            intrinsics.width,
            intrinsics.height,
            pixels * 3,
            pixels
        ),
    })
}

/// Longest a call to `next_frame` blocks in `recorded` and `stepped` modes before it returns
/// `Pending`.
pub const MAX_BLOCK: Duration = Duration::from_millis(100);

/// How frames are paced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlaybackMode {
    /// At the recording's own rate, by its timestamps.
    #[default]
    Recorded,
    /// As fast as the caller asks.
    Fast,
    /// One frame per step of the [`StepControl`].
    Stepped,
}

/// Recorded-pace playback: sleeps until the frame stamped `stamp_ns` is due, `origin` being when
/// the first delivered frame was played and its stamp (`None`: nothing played yet, due now), at
/// most `at_most`; `false` when it is still not due after that.
pub fn wait_until_due(origin: Option<(Instant, u64)>, stamp_ns: u64, at_most: Duration) -> bool {
    let Some((origin_at, origin_stamp_ns)) = origin else { return true };
    let due = origin_at + Duration::from_nanos(stamp_ns.saturating_sub(origin_stamp_ns));
    let now = Instant::now();
    if due <= now {
        return true;
    }
    let wait = due - now;
    std::thread::sleep(wait.min(at_most));
    wait <= at_most
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_control_counts_credit_across_threads() {
        let control = StepControl::new();
        assert!(!control.take(Duration::from_millis(1)));
        let remote = control.clone();
        let waiter = std::thread::Builder::new()
            .name("step-waiter".into())
            .spawn(move || remote.take(Duration::from_secs(30)))
            .unwrap();
        control.step(2);
        assert!(waiter.join().unwrap());
        assert_eq!(control.pending(), 1);
        assert!(control.take(Duration::ZERO));
        assert!(!control.take(Duration::ZERO));
    }
}
