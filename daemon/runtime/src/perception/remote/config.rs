//! `[detector.remote]`: where keyframes go for detection, how long the robot waits, and what it
//! does while no worker answers.

use serde::{Deserialize, Serialize};

use super::wire::ImageEncoding;

/// `workers = ["auto"]`: every worker that announces itself under `<prefix>/detect/`.
pub const AUTO_WORKERS: &str = "auto";
/// `fallback = "skip"`: a keyframe no worker answered is fused as one where nothing was seen.
pub const SKIP_FALLBACK: &str = "skip";

/// `[detector.remote]` (`detector.kind = "remote"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RemoteConfig {
    /// The workers' keys (`<prefix>/detect/<worker id>`, a request goes to `<key>/request`), or
    /// `["auto"]`: the workers whose liveliness token is under `<prefix>/detect/`.
    pub workers: Vec<String>,
    /// How long a keyframe waits for its reply before the fallback takes it, ms.
    pub timeout_ms: u64,
    /// Requests one worker may have outstanding; a keyframe finds another worker, or the
    /// fallback, when every worker is at its limit.
    pub max_in_flight: usize,
    /// How colour and depth travel: `raw`, `png`, `lz4`, `zstd` (lossless, all four) or `jpeg`
    /// (colour JPEG, lossy; depth zstd). `op3dsg bench remote` measures each.
    pub encoding: ImageEncoding,
    /// `skip`, or a local detector kind (`yolox`, with its own `[detector.yolox]`) that takes
    /// the keyframes no worker answers.
    pub fallback: String,
    /// A worker that timed out, refused, or answered nonsense is left aside this long, ms
    /// (then tried again).
    pub retry_after_ms: u64,
    /// At start-up, wait this long for the workers (every key named in `workers`; with `auto`,
    /// one) to announce themselves before the first keyframe, ms; 0: start at once (keyframes
    /// go to the fallback until one does).
    pub wait_for_workers_ms: u64,
    /// The model contract: the detector kind a worker must run (`yolox`, `open_vocab`).
    pub model: String,
    /// Labels the robot asks for; a worker whose model does not know one refuses. Empty: what
    /// the worker's model finds.
    pub prompts: Vec<String>,
    /// The dimension of the region embeddings the robot expects with each detection; 0: none
    /// (a reply that carries others is rejected).
    pub embedding_dim: u16,
}

impl Default for RemoteConfig {
    fn default() -> Self {
        Self {
            workers: vec![AUTO_WORKERS.to_owned()],
            timeout_ms: 500,
            max_in_flight: 2,
            encoding: ImageEncoding::default(),
            fallback: SKIP_FALLBACK.to_owned(),
            retry_after_ms: 1000,
            wait_for_workers_ms: 0,
            model: "yolox".to_owned(),
            prompts: Vec::new(),
            embedding_dim: 0,
        }
    }
}

impl RemoteConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.workers.is_empty() {
            return Err(format!("{path}.workers: name the workers' keys, or [\"auto\"]"));
        }
        if self.workers.len() > 1 && self.workers.iter().any(|w| w == AUTO_WORKERS) {
            return Err(format!("{path}.workers: \"auto\" stands alone (got {:?})", self.workers));
        }
        for key in self.workers.iter().filter(|w| *w != AUTO_WORKERS) {
            #[cfg(feature = "zenoh")]
            ::zenoh::key_expr::KeyExpr::try_from(key.as_str())
                .map_err(|e| format!("{path}.workers: {key:?} is not a Zenoh key expression: {e}"))?;
            if key.contains('*') || key.contains('$') {
                return Err(format!(
                    "{path}.workers: {key:?}: name one worker per entry (no wildcards), or [\"auto\"]"
                ));
            }
        }
        if !(10..=60_000).contains(&self.timeout_ms) {
            return Err(format!("{path}.timeout_ms: must be within [10, 60000] ms, got {}", self.timeout_ms));
        }
        if !(1..=64).contains(&self.max_in_flight) {
            return Err(format!("{path}.max_in_flight: must be within [1, 64], got {}", self.max_in_flight));
        }
        if !(10..=600_000).contains(&self.retry_after_ms) {
            return Err(format!("{path}.retry_after_ms: must be within [10, 600000] ms, got {}", self.retry_after_ms));
        }
        if self.wait_for_workers_ms > 600_000 {
            return Err(format!(
                "{path}.wait_for_workers_ms: must be within [0, 600000] ms, got {}",
                self.wait_for_workers_ms
            ));
        }
        if self.fallback == "remote" {
            return Err(format!("{path}.fallback: \"remote\" cannot be its own fallback (\"skip\" or a local kind)"));
        }
        if self.model.is_empty() {
            return Err(format!("{path}.model: name the detector kind the workers run (e.g. \"yolox\")"));
        }
        Ok(())
    }

    /// Whether the workers are found by their liveliness tokens.
    pub fn auto(&self) -> bool {
        self.workers.iter().any(|w| w == AUTO_WORKERS)
    }
}
