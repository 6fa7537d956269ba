//! `[live_view]`: the Foxglove WebSocket server (off by default, loopback unless configured).

use std::net::SocketAddr;

use serde::{Deserialize, Serialize};

/// `[live_view]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LiveViewConfig {
    /// Whether the daemon serves the live view.
    pub enabled: bool,
    /// Address and port the WebSocket server listens on: loopback by default (reach it from a
    /// laptop through an SSH tunnel); `0.0.0.0:8765` lets anyone who reaches the robot watch.
    /// Port 0 picks a free port (logged).
    pub bind: String,
    /// Whether the colour and depth images are served (`/camera/colour`, `/camera/depth`).
    pub images: bool,
    /// The images are downscaled by this factor in each direction (every n-th pixel), 1..=16.
    pub image_scale: u32,
    /// At most this many images per second, each of colour and depth, (0, 30].
    pub image_rate_hz: f64,
    /// Shortest time between two scene updates, milliseconds (the newest graph version goes
    /// out; versions in between are skipped), [0, 60000].
    pub scene_period_ms: u64,
    /// Messages the server keeps per viewer before it drops the oldest (a slow viewer loses
    /// messages, never slows the daemon), [1, 1024].
    pub backlog: usize,
}

impl Default for LiveViewConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            bind: "127.0.0.1:8765".to_owned(),
            images: false,
            image_scale: 2,
            image_rate_hz: 5.0,
            scene_period_ms: 0,
            backlog: 64,
        }
    }
}

impl LiveViewConfig {
    /// Range and format checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        self.bind_address().map_err(|e| format!("{path}.bind: {e}"))?;
        if !(1..=16).contains(&self.image_scale) {
            return Err(format!("{path}.image_scale: must be within [1, 16], got {}", self.image_scale));
        }
        let rate = self.image_rate_hz;
        if !(rate.is_finite() && rate > 0.0 && rate <= 30.0) {
            return Err(format!("{path}.image_rate_hz: must be within (0, 30] images per second, got {rate}"));
        }
        if self.scene_period_ms > 60_000 {
            return Err(format!("{path}.scene_period_ms: must be within [0, 60000] ms, got {}", self.scene_period_ms));
        }
        if !(1..=1024).contains(&self.backlog) {
            return Err(format!("{path}.backlog: must be within [1, 1024] messages, got {}", self.backlog));
        }
        Ok(())
    }

    /// [`Self::bind`] parsed (checked by [`Self::validate`]).
    pub fn bind_address(&self) -> Result<SocketAddr, String> {
        self.bind.parse::<SocketAddr>().map_err(|_| {
            format!("{:?} is not an address and port (e.g. \"127.0.0.1:8765\", \"0.0.0.0:8765\")", self.bind)
        })
    }

    /// Whether [`Self::bind`] reaches beyond this computer.
    pub fn open_beyond_loopback(&self) -> bool {
        self.bind_address().is_ok_and(|a| !a.ip().is_loopback())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn off_and_on_loopback_by_default() {
        let config = LiveViewConfig::default();
        assert!(!config.enabled);
        assert_eq!(config.validate("live_view"), Ok(()));
        assert!(!config.open_beyond_loopback());
    }

    #[test]
    fn every_bad_value_names_its_key() {
        let bad = |config: LiveViewConfig| config.validate("live_view").unwrap_err();
        let base = LiveViewConfig::default();
        assert!(bad(LiveViewConfig { bind: "localhost".into(), ..base.clone() }).starts_with("live_view.bind: "));
        assert!(bad(LiveViewConfig { bind: "1.2.3.4:99999".into(), ..base.clone() }).starts_with("live_view.bind: "));
        assert!(bad(LiveViewConfig { image_scale: 0, ..base.clone() }).starts_with("live_view.image_scale: "));
        assert!(bad(LiveViewConfig { image_rate_hz: 0.0, ..base.clone() }).starts_with("live_view.image_rate_hz: "));
        assert!(
            bad(LiveViewConfig { image_rate_hz: f64::NAN, ..base.clone() }).starts_with("live_view.image_rate_hz: ")
        );
        assert!(
            bad(LiveViewConfig { scene_period_ms: 60_001, ..base.clone() }).starts_with("live_view.scene_period_ms: ")
        );
        assert!(bad(LiveViewConfig { backlog: 0, ..base.clone() }).starts_with("live_view.backlog: "));
        assert!(LiveViewConfig { bind: "0.0.0.0:8765".into(), ..base }.open_beyond_loopback());
    }
}
