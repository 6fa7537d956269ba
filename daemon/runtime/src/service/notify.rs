//! sd_notify: readiness, status, watchdog and stop notifications to systemd.
//!
//! Under `Type=notify` systemd hands the daemon `$NOTIFY_SOCKET` (a Unix datagram socket) and,
//! with `WatchdogSec=`, `$WATCHDOG_USEC`. Without `$NOTIFY_SOCKET` (a daemon started by hand)
//! every call here does nothing.
//!
//! * `READY=1` is sent by [`ServiceNotifier::start`], which the binary calls once
//!   [`crate::pipeline::Pipeline::start`] returned: every stage runs and the iceoryx2 services
//!   (graph, graph_updated, health, pose) exist, so a unit ordered `After=op3dsgd.service` can
//!   open them at once.
//! * `STATUS=` every status period (and with each ready / stopping message): graph version, map
//!   nodes, source state, snapshot state, e.g.
//!   `STATUS=serving: graph v42, 57 nodes, source delivering, snapshot v40`.
//! * `WATCHDOG=1` every half watchdog period, **only while the stages are alive**: the capture
//!   thread went round its loop within the watchdog period (it delivered a frame, or waited for
//!   the camera, a pooled frame or its pacing, all of which come back within a period), or its
//!   source legitimately ended; and the fusion thread went round its loop within the period (it
//!   polls its input every 20 ms when idle). A stalled stage stops the pings; systemd then kills
//!   and restarts the daemon. The reason is logged and put in `STATUS=`.
//! * `STOPPING=1` when the shutdown ladder starts (the stop flag is seen, or the pipeline ended
//!   by itself), once.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use sd_notify::NotifyState;
use tracing::{debug, warn};

use crate::pipeline::PipelineStats;

/// How often `STATUS=` is refreshed when no watchdog is configured.
const STATUS_PERIOD: Duration = Duration::from_secs(2);

/// Heartbeats of the stages the watchdog watches: each records when its thread last went round
/// its loop (milliseconds since the pipeline started; 0 = not yet).
#[derive(Debug)]
pub struct Liveness {
    started: Instant,
    capture_beat_ms: AtomicU64,
    fusion_beat_ms: AtomicU64,
    capture_ended: AtomicBool,
    fusion_ended: AtomicBool,
}

impl Default for Liveness {
    fn default() -> Self {
        Self {
            started: Instant::now(),
            capture_beat_ms: AtomicU64::new(0),
            fusion_beat_ms: AtomicU64::new(0),
            capture_ended: AtomicBool::new(false),
            fusion_ended: AtomicBool::new(false),
        }
    }
}

/// The stages [`Liveness`] watches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchedStage {
    /// The capture thread.
    Capture,
    /// The fusion thread.
    Fusion,
}

impl Liveness {
    fn now_ms(&self) -> u64 {
        // +1 so that a beat in the first millisecond is not "never".
        self.started.elapsed().as_millis() as u64 + 1
    }

    fn slots(&self, stage: WatchedStage) -> (&AtomicU64, &AtomicBool) {
        match stage {
            WatchedStage::Capture => (&self.capture_beat_ms, &self.capture_ended),
            WatchedStage::Fusion => (&self.fusion_beat_ms, &self.fusion_ended),
        }
    }

    /// The stage's thread went round its loop.
    pub fn beat(&self, stage: WatchedStage) {
        self.slots(stage).0.store(self.now_ms(), Ordering::Relaxed);
    }

    /// The stage's thread ended normally (end of a finite source, the shutdown ladder): it is
    /// no longer expected to beat.
    pub fn ended(&self, stage: WatchedStage) {
        self.slots(stage).1.store(true, Ordering::Relaxed);
    }

    /// `Ok` when every watched stage beat within `max_age` (or ended normally); otherwise what
    /// is stalled, e.g. `fusion thread silent for 12.3 s`. A stage that never beat counts from
    /// the pipeline's start.
    pub fn check(&self, max_age: Duration) -> Result<(), String> {
        let now = self.now_ms();
        let mut stalled = Vec::new();
        for (stage, name) in [(WatchedStage::Capture, "capture"), (WatchedStage::Fusion, "fusion")] {
            let (beat, ended) = self.slots(stage);
            if ended.load(Ordering::Relaxed) {
                continue;
            }
            let age_ms = now.saturating_sub(beat.load(Ordering::Relaxed));
            if age_ms > max_age.as_millis() as u64 {
                stalled.push(format!("{name} thread silent for {:.1} s", age_ms as f64 / 1000.0));
            }
        }
        if stalled.is_empty() { Ok(()) } else { Err(stalled.join(", ")) }
    }
}

/// Sends sd_notify messages for the running daemon (a no-op without `$NOTIFY_SOCKET`).
#[derive(Debug)]
pub struct ServiceNotifier {
    done: Arc<AtomicBool>,
    stopping_sent: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

fn send(states: &[NotifyState]) {
    if let Err(e) = sd_notify::notify(states) {
        // Once per failure kind is enough; systemd is usually gone when this fails.
        debug!(error = %e, "sd_notify failed");
    }
}

/// The `STATUS=` text of this moment.
pub fn status_line(stats: &PipelineStats, state: &str) -> String {
    let version = stats.graph_version.load(Ordering::Relaxed);
    let nodes = stats.map_node_count.load(Ordering::Relaxed);
    let source = if stats.source_failed.load(Ordering::Relaxed) {
        "source failed"
    } else if stats.source_finished.load(Ordering::Relaxed) {
        "source ended"
    } else if stats.source_connected.load(Ordering::Relaxed) {
        "source delivering"
    } else {
        "source disconnected"
    };
    let snapshot = match stats.snapshot.version.load(Ordering::Relaxed) {
        0 => "no snapshot".to_owned(),
        v => format!("snapshot v{v}"),
    };
    format!("{state}: graph v{version}, {nodes} nodes, {source}, {snapshot}")
}

impl ServiceNotifier {
    /// Sends `READY=1` (with a first `STATUS=`) and starts the thread `op3dsg-notify`, which
    /// pings the watchdog while the stages are alive and sends `STOPPING=1` when `stop` is set.
    /// Call it once the pipeline has started.
    pub fn start(stats: Arc<PipelineStats>, stop: Arc<AtomicBool>) -> std::io::Result<Self> {
        let watchdog = sd_notify::watchdog_enabled();
        send(&[NotifyState::Ready, NotifyState::Status(&status_line(&stats, "serving"))]);
        let done = Arc::new(AtomicBool::new(false));
        let stopping_sent = Arc::new(AtomicBool::new(false));
        if let Some(period) = watchdog {
            tracing::info!(
                watchdog_s = period.as_secs_f64(),
                "systemd watchdog on: pinging every half period while the stages are alive"
            );
        }
        let thread = {
            let done = done.clone();
            let stopping_sent = stopping_sent.clone();
            std::thread::Builder::new()
                .name("op3dsg-notify".to_owned())
                .spawn(move || notify_loop(&stats, &stop, &done, &stopping_sent, watchdog))?
        };
        Ok(Self { done, stopping_sent, thread: Some(thread) })
    }

    /// Sends `STOPPING=1` unless it was sent already (the pipeline ended by itself).
    pub fn stopping(&self) {
        if !self.stopping_sent.swap(true, Ordering::SeqCst) {
            send(&[NotifyState::Stopping, NotifyState::Status("stopping")]);
        }
    }
}

impl Drop for ServiceNotifier {
    fn drop(&mut self) {
        self.stopping();
        self.done.store(true, Ordering::SeqCst);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn notify_loop(
    stats: &PipelineStats,
    stop: &AtomicBool,
    done: &AtomicBool,
    stopping_sent: &AtomicBool,
    watchdog: Option<Duration>,
) {
    let period = watchdog.map_or(STATUS_PERIOD, |w| (w / 2).max(Duration::from_millis(1)));
    let mut withheld = false;
    let mut next = Instant::now();
    while !done.load(Ordering::SeqCst) {
        if stop.load(Ordering::SeqCst) {
            if !stopping_sent.swap(true, Ordering::SeqCst) {
                send(&[NotifyState::Stopping, NotifyState::Status("stopping: shutdown ladder")]);
            }
            // After STOPPING=1 systemd watches TimeoutStopSec=, not the watchdog.
            std::thread::sleep(Duration::from_millis(20));
            continue;
        }
        let now = Instant::now();
        if now < next {
            std::thread::sleep((next - now).min(Duration::from_millis(20)));
            continue;
        }
        next = now + period;
        match watchdog {
            None => send(&[NotifyState::Status(&status_line(stats, "serving"))]),
            Some(w) => match stats.liveness.check(w) {
                Ok(()) => {
                    if withheld {
                        warn!("stages alive again; watchdog pings resume");
                        withheld = false;
                    }
                    send(&[NotifyState::Watchdog, NotifyState::Status(&status_line(stats, "serving"))]);
                }
                Err(stalled) => {
                    if !withheld {
                        warn!(stalled = %stalled, "withholding the systemd watchdog ping: a stage is stalled");
                        withheld = true;
                    }
                    send(&[NotifyState::Status(&format!("stalled ({stalled}), watchdog withheld"))]);
                }
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_silent_stage_is_named_and_an_ended_one_is_not() {
        let liveness = Liveness::default();
        liveness.beat(WatchedStage::Capture);
        liveness.beat(WatchedStage::Fusion);
        assert_eq!(liveness.check(Duration::from_secs(5)), Ok(()));
        std::thread::sleep(Duration::from_millis(30));
        liveness.beat(WatchedStage::Capture);
        let err = liveness.check(Duration::from_millis(10)).unwrap_err();
        assert!(err.starts_with("fusion thread silent for"), "{err}");
        liveness.ended(WatchedStage::Fusion);
        assert_eq!(liveness.check(Duration::from_millis(10)), Ok(()));
    }
}
