//! `[detector]`: the detection worker pool and the detector each worker runs.

use serde::{Deserialize, Serialize};

use super::open_vocab::OpenVocabConfig;
use super::region_encoder::RegionEncoderConfig;
use super::remote::{REMOTE_DETECTOR, RemoteConfig};
use super::yolox::YoloxConfig;

/// YOLOX through ONNX Runtime (`detector.kind`; `"onnx"` is accepted as a synonym).
pub const YOLOX_DETECTOR: &str = "yolox";
/// An open-vocabulary detector through ONNX Runtime (`detector.kind`).
pub const OPEN_VOCAB_DETECTOR: &str = "open_vocab";

/// `[detector]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    /// Backend: `yolox` (YOLOX, closed vocabulary, COCO, `[detector.yolox]`; `"onnx"` is a
    /// synonym), `open_vocab` (text-prompted, `[detector.open_vocab]`; contract in
    /// `perception/open_vocab.rs`), `remote` (`op3dsg-detectd` workers over Zenoh,
    /// `[detector.remote]`), or one registered with [`crate::backend::Backends`]
    /// (`oracle` in `op3dsgd`).
    pub kind: String,
    /// Worker threads (`op3dsg-detect-<i>`), each with its own detector instance.
    pub workers: usize,
    /// `[detector.yolox]`: model, thresholds, class map, depth masks (used with
    /// `kind = "yolox"`).
    #[serde(default)]
    pub yolox: YoloxConfig,
    /// `[detector.open_vocab]`: model contract, prompts, thresholds (used with
    /// `kind = "open_vocab"`).
    #[serde(default)]
    pub open_vocab: OpenVocabConfig,
    /// `[detector.region_encoder]`: a CLIP image encoder whose embedding of each detection's
    /// crop becomes its semantic feature, for any detector kind (contract in
    /// `perception/region_encoder.rs`). Unset: the detector's own features, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region_encoder: Option<RegionEncoderConfig>,
    /// `[detector.remote]`: the detection workers over Zenoh, the timeout and the fallback (used
    /// with `kind = "remote"`; `perception/remote/`).
    #[serde(default)]
    pub remote: RemoteConfig,
}

impl DetectorConfig {
    /// Range checks, and the section of the runtime's own detector `kind` names; messages start
    /// with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(1..=64).contains(&self.workers) {
            return Err(format!("{path}.workers: must be within [1, 64], got {}", self.workers));
        }
        // A remote detector's local fallback is checked as if it were the kind.
        let local = if self.kind == REMOTE_DETECTOR { self.remote.fallback.as_str() } else { self.kind.as_str() };
        if local == YOLOX_DETECTOR {
            self.yolox.validate(&format!("{path}.yolox"))?;
            if self.yolox.class_map.is_empty() {
                return Err(format!(
                    "{path}.yolox.class_map: must map at least one class of the model to a label (unmapped classes are dropped)"
                ));
            }
        }
        if local == OPEN_VOCAB_DETECTOR {
            self.open_vocab.validate(&format!("{path}.open_vocab"))?;
        }
        if self.kind == REMOTE_DETECTOR {
            self.remote.validate(&format!("{path}.remote"))?;
        }
        if let Some(encoder) = &self.region_encoder {
            encoder.validate(&format!("{path}.region_encoder"))?;
        }
        Ok(())
    }
}
