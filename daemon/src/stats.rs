//! Per-stage counters and latency figures, shared between a stage's thread and the health
//! reporter without locks on the hot path (one short mutex per recorded latency sample).

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Latency samples kept per stage between two health reports.
pub const LATENCY_WINDOW: usize = 512;

/// Counters of one pipeline stage.
#[derive(Debug)]
pub struct StageStats {
    /// Stage name as reported in health (`capture`, `detect/0`, ...).
    pub name: String,
    /// Items processed since start.
    pub processed: AtomicU64,
    /// Items that failed since start.
    pub errors: AtomicU64,
    window: Mutex<LatencyWindow>,
}

#[derive(Debug)]
struct LatencyWindow {
    samples_us: [u32; LATENCY_WINDOW],
    len: usize,
    next: usize,
    processed_at_last_report: u64,
    last_report: Instant,
}

/// Figures of one stage over the last reporting period.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageFigures {
    /// Items processed since start.
    pub processed: u64,
    /// Items per second over the period.
    pub rate_hz: f32,
    /// Median latency, microseconds.
    pub p50_us: f32,
    /// 99th percentile latency, microseconds.
    pub p99_us: f32,
    /// Errors since start.
    pub errors: u64,
}

impl StageStats {
    /// New counters for `name`.
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            processed: AtomicU64::new(0),
            errors: AtomicU64::new(0),
            window: Mutex::new(LatencyWindow {
                samples_us: [0; LATENCY_WINDOW],
                len: 0,
                next: 0,
                processed_at_last_report: 0,
                last_report: Instant::now(),
            }),
        }
    }

    /// Records one processed item that took `started.elapsed()`.
    pub fn record(&self, started: Instant) {
        let us = started.elapsed().as_micros().min(u32::MAX as u128) as u32;
        self.processed.fetch_add(1, Ordering::Relaxed);
        if let Ok(mut w) = self.window.lock() {
            let i = w.next;
            w.samples_us[i] = us;
            w.next = (i + 1) % LATENCY_WINDOW;
            w.len = (w.len + 1).min(LATENCY_WINDOW);
        }
    }

    /// Records a failed item.
    pub fn record_error(&self) {
        self.errors.fetch_add(1, Ordering::Relaxed);
    }

    /// Figures since the previous call; starts a new period.
    pub fn take_figures(&self) -> StageFigures {
        let processed = self.processed.load(Ordering::Relaxed);
        let errors = self.errors.load(Ordering::Relaxed);
        let Ok(mut w) = self.window.lock() else {
            return StageFigures { processed, errors, ..Default::default() };
        };
        let elapsed_s = w.last_report.elapsed().as_secs_f32().max(1e-3);
        let rate_hz = (processed - w.processed_at_last_report) as f32 / elapsed_s;
        let mut sorted = [0u32; LATENCY_WINDOW];
        let len = w.len;
        sorted[..len].copy_from_slice(&w.samples_us[..len]);
        sorted[..len].sort_unstable();
        let pick = |q: f32| if len == 0 { 0.0 } else { sorted[((len - 1) as f32 * q).round() as usize] as f32 };
        let figures = StageFigures { processed, rate_hz, p50_us: pick(0.5), p99_us: pick(0.99), errors };
        w.len = 0;
        w.next = 0;
        w.processed_at_last_report = processed;
        w.last_report = Instant::now();
        figures
    }
}

/// Bytes as mebibytes, for logs and tables.
pub fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_cover_the_period_and_reset() {
        let s = StageStats::new("x");
        for _ in 0..10 {
            s.record(Instant::now());
        }
        s.record_error();
        let f = s.take_figures();
        assert_eq!(f.processed, 10);
        assert_eq!(f.errors, 1);
        assert!(f.rate_hz > 0.0);
        let g = s.take_figures();
        assert_eq!(g.processed, 10);
        assert_eq!(g.p50_us, 0.0);
    }
}
