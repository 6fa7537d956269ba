//! A lost camera: the pipeline stopped, then retried with a doubling backoff until the same
//! serial number is back with the same stream modes.

use std::time::{Duration, Instant};

use op3dsg_drivers::source::{SourceError, SourceStatus};
use tracing::{info, warn};

use super::streams::find_device;
use super::{RealsenseSource, device_err};

/// Longest a call to `next_frame` sleeps while waiting to retry a lost camera.
const RETRY_SLICE: Duration = Duration::from_millis(100);

impl RealsenseSource {
    /// Lost camera: stop, and retry after the backoff.
    pub(super) fn lose(&mut self, reason: &str) {
        self.stop_streams();
        self.connected = false;
        self.backoff = Duration::from_millis(self.config.reconnect.initial_ms);
        self.retry_at = Instant::now() + self.backoff;
        warn!(camera = %self.name(), reason, retry_in_ms = self.backoff.as_millis() as u64, "realsense camera lost; reconnecting");
    }

    pub(super) fn try_reconnect(&mut self) -> Result<SourceStatus, SourceError> {
        let now = Instant::now();
        if now < self.retry_at {
            std::thread::sleep((self.retry_at - now).min(RETRY_SLICE));
            return Ok(SourceStatus::Pending);
        }
        // By the serial of the camera first opened (chosen by product, or by serial).
        let attempt = find_device(&self.context, "", &self.serial).and_then(|_| self.start());
        match attempt {
            Ok(streams)
                if streams.colour == self.streams.colour && streams.colour_order == self.streams.colour_order =>
            {
                self.streams = streams;
                self.connected = true;
                info!(camera = %self.name(), "realsense camera reconnected");
                Ok(SourceStatus::Pending)
            }
            Ok(streams) => {
                self.stop_streams();
                self.schedule_retry();
                Err(device_err(format!(
                    "{}: reconnected camera delivers colour {}x{} (fx {}), not the {}x{} (fx {}) frames were sized for",
                    self.name(),
                    streams.colour.width,
                    streams.colour.height,
                    streams.colour.fx,
                    self.streams.colour.width,
                    self.streams.colour.height,
                    self.streams.colour.fx
                )))
            }
            Err(e) => {
                self.schedule_retry();
                tracing::debug!(error = %e, retry_in_ms = self.backoff.as_millis() as u64, "realsense reconnect attempt failed");
                Ok(SourceStatus::Pending)
            }
        }
    }

    fn schedule_retry(&mut self) {
        self.backoff = (self.backoff * 2).min(Duration::from_millis(self.config.reconnect.max_ms));
        self.retry_at = Instant::now() + self.backoff;
    }
}
