//! The frame source interface shared by the synthetic scene, replay and the camera.

use crate::frame::{Frame, Intrinsics};

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

/// A source of RGB-D frames. Runs on the capture thread; `next_frame` fills a pooled buffer.
pub trait FrameSource: Send {
    /// Intrinsics of every frame this source delivers (fixed for the source's lifetime).
    fn intrinsics(&self) -> Intrinsics;

    /// Whether frames carry `instance_ids` (only the synthetic source does).
    fn has_instance_ids(&self) -> bool {
        false
    }

    /// Whether frames carry their own `world_from_camera`.
    fn has_poses(&self) -> bool {
        false
    }

    /// Fills `frame` with the next frame. A live source may block up to its frame period.
    fn next_frame(&mut self, frame: &mut Frame) -> Result<SourceStatus, SourceError>;

    /// Total number of frames for a finite source.
    fn len_hint(&self) -> Option<u64> {
        None
    }

    /// A short description for logs ("synthetic kitchen seed 1", "replay /data/seq").
    fn describe(&self) -> String;
}
