//! What remote detection counts, per worker and overall.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

use op3dsg_ipc_types::{MAX_REMOTE_WORKERS, RemoteHealth, RemoteWorkerHealth, write_fixed_str};

use crate::stats::LatencyHistogram;

/// Why a reply was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    /// The bytes are not a reply of this version ([`super::wire::WireError`]).
    Garbage,
    /// It answers another request id or keyframe.
    WrongId,
    /// A mask's box leaves the image, or its runs do not cover its box.
    MaskSize,
    /// A region embedding of another dimension than the robot expects.
    EmbeddingDim,
    /// The worker refused the model contract.
    Refused,
    /// The worker's detector failed.
    Failed,
}

impl Rejection {
    /// Every reason, in report order.
    pub const ALL: [Rejection; 6] =
        [Self::Garbage, Self::WrongId, Self::MaskSize, Self::EmbeddingDim, Self::Refused, Self::Failed];

    /// Its name in reports.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Garbage => "garbage",
            Self::WrongId => "wrong_id",
            Self::MaskSize => "mask_size",
            Self::EmbeddingDim => "embedding_dim",
            Self::Refused => "refused",
            Self::Failed => "failed",
        }
    }
}

/// One worker's figures.
#[derive(Debug, Default)]
pub struct WorkerCounters {
    /// Requests sent.
    pub requests: AtomicU64,
    /// Replies accepted.
    pub replies: AtomicU64,
    /// Requests that got no reply within `timeout_ms`.
    pub timeouts: AtomicU64,
    /// Replies that came after their request's timeout (dropped).
    pub late: AtomicU64,
    /// Requests that found no worker at the key (it is gone).
    pub unreachable: AtomicU64,
    /// Replies rejected, by [`Rejection::ALL`] index.
    pub rejections: [AtomicU64; 6],
    /// Request bytes sent.
    pub bytes_out: AtomicU64,
    /// Reply bytes received.
    pub bytes_in: AtomicU64,
    /// Requests outstanding now.
    pub in_flight: AtomicU64,
    /// Whether its liveliness token is present (`workers = "auto"`; configured keys always count
    /// as present).
    pub alive: AtomicBool,
    /// Round trips of accepted replies.
    pub round_trip: Mutex<LatencyHistogram>,
}

impl WorkerCounters {
    /// Counts a rejection.
    pub fn reject(&self, reason: Rejection) {
        let index = Rejection::ALL.iter().position(|r| *r == reason).unwrap_or(0);
        self.rejections[index].fetch_add(1, Ordering::Relaxed);
    }

    /// Rejections for `reason`.
    pub fn rejected(&self, reason: Rejection) -> u64 {
        let index = Rejection::ALL.iter().position(|r| *r == reason).unwrap_or(0);
        self.rejections[index].load(Ordering::Relaxed)
    }

    /// Records an accepted reply's round trip.
    pub fn record_round_trip(&self, duration: Duration) {
        self.round_trip.lock().unwrap_or_else(PoisonError::into_inner).record(duration);
    }

    /// The figures as JSON (`round_trip_p50_ms`, `bytes_per_keyframe`, rejections by reason).
    pub fn report(&self) -> serde_json::Value {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        let (p50, p99) = {
            let h = self.round_trip.lock().unwrap_or_else(PoisonError::into_inner);
            (h.quantile_us(0.5) / 1e3, h.quantile_us(0.99) / 1e3)
        };
        let requests = load(&self.requests);
        let bytes = load(&self.bytes_out) + load(&self.bytes_in);
        let rejections: serde_json::Map<String, serde_json::Value> =
            Rejection::ALL.iter().map(|r| (r.as_str().to_owned(), self.rejected(*r).into())).collect();
        serde_json::json!({
            "requests": requests,
            "replies": load(&self.replies),
            "timeouts": load(&self.timeouts),
            "late": load(&self.late),
            "unreachable": load(&self.unreachable),
            "rejections": rejections,
            "in_flight": load(&self.in_flight),
            "alive": self.alive.load(Ordering::Relaxed),
            "round_trip_p50_ms": p50,
            "round_trip_p99_ms": p99,
            "bytes_out": load(&self.bytes_out),
            "bytes_in": load(&self.bytes_in),
            "bytes_per_keyframe": bytes.checked_div(requests).unwrap_or(0),
        })
    }

    /// The figures into the health record's entry for worker `key`.
    pub fn fill(&self, key: &str, slot: &mut RemoteWorkerHealth) {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        write_fixed_str(&mut slot.key, key);
        slot.requests = load(&self.requests);
        slot.replies = load(&self.replies);
        slot.timeouts = load(&self.timeouts);
        slot.late = load(&self.late);
        slot.unreachable = load(&self.unreachable);
        for (out, count) in slot.rejections.iter_mut().zip(&self.rejections) {
            *out = load(count);
        }
        slot.bytes_out = load(&self.bytes_out);
        slot.bytes_in = load(&self.bytes_in);
        let h = self.round_trip.lock().unwrap_or_else(PoisonError::into_inner);
        (slot.round_trip_p50_us, slot.round_trip_p99_us) =
            if h.count() == 0 { (0.0, 0.0) } else { (h.quantile_us(0.5) as f32, h.quantile_us(0.99) as f32) };
        slot.in_flight = load(&self.in_flight).min(u64::from(u32::MAX)) as u32;
        slot.alive = u8::from(self.alive.load(Ordering::Relaxed));
    }
}

/// Remote detection's figures: one entry per worker key seen, and the fallback's.
#[derive(Debug, Default)]
pub struct RemoteCounters {
    /// Per worker key, in the order first seen.
    pub workers: Mutex<Vec<(String, std::sync::Arc<WorkerCounters>)>>,
    /// Keyframes the fallback took (or skipped) because no worker answered.
    pub fallback_keyframes: AtomicU64,
    /// Whether the last keyframe went to the fallback.
    pub fallback_active: AtomicBool,
    /// Times the fallback took over from the workers.
    pub fallback_switches: AtomicU64,
}

impl RemoteCounters {
    /// The counters of worker `key`, made on first use.
    pub fn worker(&self, key: &str) -> std::sync::Arc<WorkerCounters> {
        let mut workers = self.workers.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((_, c)) = workers.iter().find(|(k, _)| k == key) {
            return c.clone();
        }
        let c = std::sync::Arc::new(WorkerCounters::default());
        workers.push((key.to_owned(), c.clone()));
        c
    }

    /// The health record's remote detection entry: the fallback's state and the first
    /// [`MAX_REMOTE_WORKERS`] workers seen.
    pub fn health(&self) -> RemoteHealth {
        let mut h = RemoteHealth {
            active: 1,
            fallback_active: u8::from(self.fallback_active.load(Ordering::Relaxed)),
            fallback_keyframes: self.fallback_keyframes.load(Ordering::Relaxed),
            fallback_switches: self.fallback_switches.load(Ordering::Relaxed),
            ..RemoteHealth::default()
        };
        let workers = self.workers.lock().unwrap_or_else(PoisonError::into_inner);
        for (slot, (key, counters)) in h.workers.iter_mut().zip(workers.iter()) {
            counters.fill(key, slot);
        }
        h.worker_count = workers.len().min(MAX_REMOTE_WORKERS) as u16;
        h.workers_not_reported = workers.len().saturating_sub(MAX_REMOTE_WORKERS).min(u32::MAX as usize) as u32;
        h
    }

    /// All figures as JSON, as `<prefix>/detect_status` answers them.
    pub fn report(&self) -> serde_json::Value {
        let workers: serde_json::Map<String, serde_json::Value> = self
            .workers
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .iter()
            .map(|(k, c)| (k.clone(), c.report()))
            .collect();
        serde_json::json!({
            "workers": workers,
            "fallback_active": self.fallback_active.load(Ordering::Relaxed),
            "fallback_keyframes": self.fallback_keyframes.load(Ordering::Relaxed),
            "fallback_switches": self.fallback_switches.load(Ordering::Relaxed),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejection_names_are_the_health_records() {
        let names: Vec<&str> = Rejection::ALL.iter().map(|r| r.as_str()).collect();
        assert_eq!(names, op3dsg_ipc_types::REMOTE_REJECTIONS);
    }

    #[test]
    fn health_reports_the_first_workers_and_counts_the_rest() {
        let counters = RemoteCounters::default();
        for i in 0..MAX_REMOTE_WORKERS + 2 {
            let worker = counters.worker(&format!("robot/op3dsg/detect/w{i}"));
            worker.requests.fetch_add(i as u64 + 1, Ordering::Relaxed);
            worker.bytes_out.fetch_add(1000 * (i as u64 + 1), Ordering::Relaxed);
            worker.bytes_in.fetch_add(10 * (i as u64 + 1), Ordering::Relaxed);
            worker.alive.store(i % 2 == 0, Ordering::Relaxed);
        }
        let first = counters.worker("robot/op3dsg/detect/w0");
        first.reject(Rejection::MaskSize);
        first.record_round_trip(Duration::from_millis(40));
        counters.fallback_active.store(true, Ordering::Relaxed);
        let h = counters.health();
        assert_eq!((h.active, h.fallback_active), (1, 1));
        assert_eq!((h.worker_count as usize, h.workers_not_reported), (MAX_REMOTE_WORKERS, 2));
        let w0 = &h.valid_workers()[0];
        assert_eq!((w0.key_str(), w0.requests, w0.alive), ("robot/op3dsg/detect/w0", 1, 1));
        assert_eq!(w0.rejections[2], 1);
        assert_eq!(w0.bytes_per_keyframe(), 1010);
        assert!((w0.round_trip_p50_us - 40_000.0).abs() < 4_000.0, "{}", w0.round_trip_p50_us);
        let w1 = &h.valid_workers()[1];
        assert_eq!((w1.requests, w1.alive, w1.round_trip_p50_us), (2, 0, 0.0));
    }
}
