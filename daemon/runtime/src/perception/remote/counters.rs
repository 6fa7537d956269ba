//! What remote detection counts, per worker and overall.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

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
            "round_trip_p50_ms": p50,
            "round_trip_p99_ms": p99,
            "bytes_out": load(&self.bytes_out),
            "bytes_in": load(&self.bytes_in),
            "bytes_per_keyframe": bytes.checked_div(requests).unwrap_or(0),
        })
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
