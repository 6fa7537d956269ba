//! `[snapshot]`: whether and where the map is saved.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// `[snapshot]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SnapshotConfig {
    /// Save the map and restore it at start.
    pub enabled: bool,
    /// Directory of `map.snapshot`; relative to the profile file that sets it. Empty: under
    /// systemd `$STATE_DIRECTORY/snapshots` (`StateDirectory=op3dsg`: /var/lib/op3dsg), else no
    /// snapshots (a daemon started by hand writes nothing unless told where).
    pub dir: String,
    /// Seconds between snapshots of a changing map (0 = only at shutdown and on request).
    pub period_s: f64,
}

impl Default for SnapshotConfig {
    fn default() -> Self {
        Self { enabled: true, dir: String::new(), period_s: 30.0 }
    }
}

impl SnapshotConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(self.period_s.is_finite() && (0.0..=86_400.0).contains(&self.period_s)) {
            return Err(format!("{path}.period_s: must be within [0, 86400] seconds, got {}", self.period_s));
        }
        Ok(())
    }

    /// The directory snapshots go to, `None` when they are off (see [`Self::dir`]).
    pub fn resolve_dir(&self) -> Option<PathBuf> {
        self.resolve_dir_with(std::env::var_os("STATE_DIRECTORY").map(PathBuf::from))
    }

    /// [`Self::resolve_dir`] with `$STATE_DIRECTORY` given (systemd may list several, `:`-separated:
    /// the first is ours).
    pub fn resolve_dir_with(&self, state_directory: Option<PathBuf>) -> Option<PathBuf> {
        if !self.enabled {
            return None;
        }
        if !self.dir.is_empty() {
            return Some(PathBuf::from(&self.dir));
        }
        let state = state_directory?;
        let first = state.to_string_lossy().split(':').next().unwrap_or("").to_owned();
        (!first.is_empty()).then(|| Path::new(&first).join("snapshots"))
    }
}
