//! Perception: detectors behind one trait, the detections and masks they produce. Each
//! detection worker (`[detector] workers`, [`DetectThread`]) owns one [`Detector`]; the backends
//! that make them are in the composition's registry (`crate::backend`).
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[detector]` ([`DetectorConfig`]) |
//! | `thread.rs` | [`DetectThread`], a detection worker |
//! | `yolox.rs`, `open_vocab/`, `mask_decoder.rs`, `region_encoder.rs`, `tagger.rs` | the ONNX detectors and their parts |
//! | `remote/` | remote detection over Zenoh: the wire format, `[detector.remote]`, the robot's client |
//! | `candidates.rs`, `depth_mask.rs`, `image_input.rs` | what they share: knowledge-guided prompts, masks from depth, image tensors |

use op3dsg_drivers::frame::Frame;
use serde::{Deserialize, Serialize};

pub mod candidates;
mod config;
pub mod depth_mask;
pub mod image_input;
pub mod mask_decoder;
pub mod open_vocab;
pub mod region_encoder;
pub mod remote;
pub mod tagger;
mod thread;
pub mod yolox;

pub use config::{DetectorConfig, OPEN_VOCAB_DETECTOR, YOLOX_DETECTOR};
pub use thread::{DetectThread, Tickets};

pub use crate::flow::{Detection, Mask};

/// Greedy non-maximum suppression over `candidates` already sorted best first: each is kept
/// unless `overlaps(kept, candidate)` holds for one kept before it; at most `max_kept`.
pub fn greedy_suppress<T>(candidates: Vec<T>, max_kept: usize, overlaps: impl Fn(&T, &T) -> bool) -> Vec<T> {
    let mut kept: Vec<T> = Vec::new();
    for c in candidates {
        if kept.len() == max_kept {
            break;
        }
        if !kept.iter().any(|k| overlaps(k, &c)) {
            kept.push(c);
        }
    }
    kept
}

/// The range checks every model detector shares; errors are `path.field: message`.
pub fn validate_detection_limits(
    path: &str,
    score_threshold: f32,
    nms_iou_threshold: f32,
    max_detections: usize,
    intra_op_threads: usize,
) -> Result<(), String> {
    if !(score_threshold > 0.0 && score_threshold < 1.0) {
        return Err(format!("{path}.score_threshold: must be within (0, 1), got {score_threshold}"));
    }
    if !(nms_iou_threshold > 0.0 && nms_iou_threshold <= 1.0) {
        return Err(format!("{path}.nms_iou_threshold: must be within (0, 1], got {nms_iou_threshold}"));
    }
    if max_detections == 0 {
        return Err(format!("{path}.max_detections: must be at least 1"));
    }
    if !(1..=64).contains(&intra_op_threads) {
        return Err(format!("{path}.intra_op_threads: must be within [1, 64], got {intra_op_threads}"));
    }
    Ok(())
}

/// How a detector's score is mapped onto the scale fusion's thresholds were set on (the
/// oracle's: `fusion.min_mean_score`, `score_threshold`), per detector, so a profile need not
/// retune fusion for each model (`[detector.<kind>.calibration]`):
///
/// - `none`: the score as the model gives it;
/// - `affine`: `clamp(a s + b, 0, 1)`;
/// - `logistic`: Platt scaling in logit space, `sigmoid(a logit(s) + b)` (`a = 1, b = 0` is the
///   identity; a model with logit outputs has `score_activation = "sigmoid"` before it).
///
/// `a` and `b` are fitted on the user's data: the detections `op3dsg eval` matches to ground
/// truth (label 1) and the rest (label 0), fitted by logistic regression of the label on
/// `logit(s)`. The calibrated score is the one thresholded and published.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScoreCalibration {
    /// `none`, `affine` or `logistic`.
    pub kind: CalibrationKind,
    /// Slope.
    pub a: f32,
    /// Offset.
    pub b: f32,
}

/// [`ScoreCalibration::kind`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CalibrationKind {
    /// Unchanged.
    #[default]
    None,
    /// `clamp(a s + b, 0, 1)`.
    Affine,
    /// `sigmoid(a logit(s) + b)`.
    Logistic,
}

impl Default for ScoreCalibration {
    fn default() -> Self {
        Self { kind: CalibrationKind::None, a: 1.0, b: 0.0 }
    }
}

impl ScoreCalibration {
    /// The calibrated score of `s` (in [0, 1]; NaN stays NaN).
    pub fn apply(&self, s: f32) -> f32 {
        match self.kind {
            CalibrationKind::None => s,
            CalibrationKind::Affine => (self.a * s + self.b).clamp(0.0, 1.0),
            CalibrationKind::Logistic => {
                let s = s.clamp(1e-7, 1.0 - 1e-7);
                let logit = (s / (1.0 - s)).ln();
                1.0 / (1.0 + (-(self.a * logit + self.b)).exp())
            }
        }
    }

    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(self.a.is_finite() && self.b.is_finite()) {
            return Err(format!("{path}: a and b must be finite, got a = {}, b = {}", self.a, self.b));
        }
        if self.kind != CalibrationKind::None && self.a <= 0.0 {
            return Err(format!(
                "{path}.a: must be positive (a calibration keeps the order of scores), got {}",
                self.a
            ));
        }
        Ok(())
    }
}

/// Errors of a detector.
#[derive(Debug, thiserror::Error)]
pub enum DetectorError {
    /// The frame lacks something this detector needs.
    #[error("frame {seq}: {reason}")]
    Frame {
        /// Frame sequence number.
        seq: u64,
        /// What is missing.
        reason: String,
    },
    /// The backend failed.
    #[error("detector backend: {0}")]
    Backend(String),
}

/// A detector: one instance per worker thread, so `detect` may keep scratch state.
pub trait Detector: Send {
    /// Detects instances in `frame`, replacing the contents of `out`.
    fn detect(&mut self, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError>;

    /// Name for logs and health (`oracle`, `yolox`).
    fn name(&self) -> &str;

    /// Remote detection's figures for the health record: only a detector that sends keyframes
    /// to remote workers has them.
    fn remote_counters(&self) -> Option<std::sync::Arc<remote::RemoteCounters>> {
        None
    }
}

/// Runs `detector` on a keyframe into `out`. On failure `out` is left empty, so the keyframe is
/// fused as one where nothing was seen, and the error is returned for the caller to count and
/// log (the pipeline's workers and the batch runner both go on).
pub fn detect(detector: &mut dyn Detector, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
    let result = detector.detect(frame, out);
    if result.is_err() {
        out.clear();
    }
    result
}

#[cfg(test)]
mod calibration_tests {
    use super::*;

    #[test]
    fn calibrations_map_scores_monotonically_into_the_unit_interval() {
        assert_eq!(ScoreCalibration::default().apply(0.42), 0.42);
        let affine = ScoreCalibration { kind: CalibrationKind::Affine, a: 2.0, b: 0.1 };
        assert!((affine.apply(0.2) - 0.5).abs() < 1e-6);
        assert_eq!(affine.apply(0.9), 1.0);
        let identity = ScoreCalibration { kind: CalibrationKind::Logistic, a: 1.0, b: 0.0 };
        assert!((identity.apply(0.3) - 0.3).abs() < 1e-5);
        // A detector whose scores run low (0.2 for a true object) lifted to the oracle's 0.6.
        let lift =
            ScoreCalibration { kind: CalibrationKind::Logistic, a: 1.0, b: (0.6f32 / 0.4).ln() - (0.2f32 / 0.8).ln() };
        assert!((lift.apply(0.2) - 0.6).abs() < 1e-5);
        assert!(lift.apply(0.1) < lift.apply(0.2) && lift.apply(0.9) < 1.0);
        let bad = ScoreCalibration { kind: CalibrationKind::Logistic, a: -1.0, b: 0.0 };
        assert!(
            bad.validate("detector.open_vocab.calibration")
                .unwrap_err()
                .starts_with("detector.open_vocab.calibration.a")
        );
    }
}
