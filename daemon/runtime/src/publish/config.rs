//! `[health]`: how often the health record is published and summarised in the log.

use serde::{Deserialize, Serialize};

/// `[health]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HealthConfig {
    /// Period of health records and of the log summary, milliseconds.
    pub period_ms: u64,
    /// Log a one-line summary at info every this many periods (0 = never).
    pub log_every_periods: u32,
}

impl HealthConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(10..=60_000).contains(&self.period_ms) {
            return Err(format!("{path}.period_ms: must be within [10, 60000], got {}", self.period_ms));
        }
        Ok(())
    }
}
