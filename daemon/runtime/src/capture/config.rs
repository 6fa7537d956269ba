//! `[source]`: which frame source the capture thread reads and how fast.

use op3dsg_drivers::replay::{PlaybackMode, ReplayConfig};
use serde::{Deserialize, Serialize};

/// The source the runtime itself provides (`source.kind`); other names are registered backends
/// ([`crate::backend`]).
pub const REPLAY_SOURCE: &str = "replay";

/// `[source]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceConfig {
    /// Which source backend: `replay`, or one registered with [`crate::backend::Backends`]
    /// (`synthetic` in `op3dsgd`).
    pub kind: String,
    /// Delivery rate for sources that can go faster than real time, Hz; 0 = as fast as the
    /// pipeline takes frames.
    pub rate_hz: f64,
    /// Frames allocated for the frame pool on top of the queue capacities and workers.
    pub pool_headroom: usize,
    /// `[source.replay]`: required with `kind = "replay"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replay: Option<ReplayConfig>,
}

impl SourceConfig {
    /// Range checks, and `[source.replay]` with `kind = "replay"`; messages start with
    /// `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(0.0..=1000.0).contains(&self.rate_hz) {
            return Err(format!(
                "{path}.rate_hz: must be within [0, 1000] (0 = as fast as possible), got {}",
                self.rate_hz
            ));
        }
        if self.pool_headroom > 64 {
            return Err(format!("{path}.pool_headroom: must be at most 64, got {}", self.pool_headroom));
        }
        if self.kind != REPLAY_SOURCE {
            return Ok(());
        }
        let Some(replay) = &self.replay else {
            return Err(format!(
                "{path}.replay: required with source.kind = \"replay\" (at least `path`, the recording's folder)"
            ));
        };
        replay.validate(&format!("{path}.replay"))?;
        if replay.mode != PlaybackMode::Fast && self.rate_hz != 0.0 {
            let mode = if replay.mode == PlaybackMode::Stepped { "stepped" } else { "recorded" };
            return Err(format!(
                "{path}.replay.mode: \"{mode}\" paces frames itself; set source.rate_hz = 0 (it is {})",
                self.rate_hz
            ));
        }
        Ok(())
    }
}
