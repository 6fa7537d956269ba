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
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use sd_notify::NotifyState;
use tracing::{debug, warn};

use crate::pipeline::Counters;

/// How often `STATUS=` is refreshed when no watchdog is configured.
const STATUS_PERIOD: Duration = Duration::from_secs(2);

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
pub fn status_line(counters: &Counters, state: &str) -> String {
    let version = counters.fusion.graph_version.load(Ordering::Relaxed);
    let nodes = counters.fusion.map_node_count.load(Ordering::Relaxed);
    let source = counters.capture.source_state();
    let snapshot = match counters.fusion.snapshot.version.load(Ordering::Relaxed) {
        0 => "no snapshot".to_owned(),
        v => format!("snapshot v{v}"),
    };
    format!("{state}: graph v{version}, {nodes} nodes, source {source}, {snapshot}")
}

impl ServiceNotifier {
    /// Sends `READY=1` (with a first `STATUS=`) and starts the thread `op3dsg-notify`, which
    /// pings the watchdog while the stages are alive and sends `STOPPING=1` when `stop` is set.
    /// Call it once the pipeline has started.
    pub fn start(stats: Arc<Counters>, stop: Arc<AtomicBool>) -> std::io::Result<Self> {
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
    stats: &Counters,
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
