//! Stage counters for `health`: per-stage latency figures, the watchdog's heartbeats
//! ([`Liveness`]), the pose input's outcomes ([`PoseStats`]) and the traits through which stages report into a health record
//! ([`ReportHealth`], [`HealthSource`]). A leaf: it imports nothing of the stages.
//!
//! Per-stage counters and latency figures, shared between a stage's thread and the health
//! reporter without locks on the hot path (one short mutex per recorded latency sample).
//!
//! Two views of a stage's latency: a window of the last [`LATENCY_WINDOW`] samples, reset by
//! every health report ([`StageStats::take_figures`]), and a histogram of every sample since
//! start ([`StageStats::since_start`], log-linear buckets, 1/[`SUB_BUCKETS`] relative
//! resolution) for whole-run figures such as `op3dsg bench perf`'s.

mod health;
mod liveness;
mod pose;

pub use health::{HealthSource, ReportHealth};
pub use liveness::{Liveness, WatchedStage};
pub use pose::PoseStats;

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Latency samples kept per stage between two health reports.
pub const LATENCY_WINDOW: usize = 512;

/// Counters of one pipeline stage.
#[derive(Debug)]
pub struct StageStats {
    /// Stage name as reported in health (`capture`, `detect/0`, `prior`, `end_to_end`, ...).
    pub name: String,
    /// Items processed since start.
    pub processed: AtomicU64,
    /// Items that failed since start.
    pub errors: AtomicU64,
    window: Mutex<LatencyWindow>,
    histogram: AtomicHistogram,
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
            histogram: AtomicHistogram::new(),
        }
    }

    /// Records one processed item that took `started.elapsed()`.
    pub fn record(&self, started: Instant) {
        self.record_duration(started.elapsed());
    }

    /// Records one processed item that took `duration`.
    pub fn record_duration(&self, duration: Duration) {
        let us = duration.as_micros().min(u32::MAX as u128) as u32;
        self.processed.fetch_add(1, Ordering::Relaxed);
        self.histogram.record(duration.as_nanos().min(u64::MAX as u128) as u64);
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

impl StageStats {
    /// Every latency recorded since start, as a histogram (not reset by health reports).
    pub fn since_start(&self) -> LatencyHistogram {
        self.histogram.snapshot()
    }
}

/// Sub-buckets per power of two of [`LatencyHistogram`]: values are kept to within 1/32 (3 %).
pub const SUB_BUCKETS: usize = 32;
const SUB_BITS: u32 = SUB_BUCKETS.trailing_zeros();
/// Buckets cover 0 ns to 2^64 ns.
const BUCKETS: usize = (64 - SUB_BITS as usize + 1) * SUB_BUCKETS;

fn bucket_of(ns: u64) -> usize {
    if ns < SUB_BUCKETS as u64 {
        return ns as usize;
    }
    let exponent = 63 - ns.leading_zeros(); // >= SUB_BITS
    let shift = exponent - SUB_BITS;
    let mantissa = (ns >> shift) as usize - SUB_BUCKETS; // 0..SUB_BUCKETS
    (shift as usize + 1) * SUB_BUCKETS + mantissa
}

/// The middle of bucket `index`, nanoseconds.
fn bucket_value(index: usize) -> f64 {
    if index < SUB_BUCKETS {
        return index as f64;
    }
    let shift = (index / SUB_BUCKETS - 1) as i32;
    let mantissa = (index % SUB_BUCKETS + SUB_BUCKETS) as f64;
    (mantissa + 0.5) * 2f64.powi(shift)
}

/// A lock-free latency histogram: log-linear buckets of atomic counters, allocated once.
#[derive(Debug)]
struct AtomicHistogram {
    counts: Box<[AtomicU64]>,
    sum_ns: AtomicU64,
    max_ns: AtomicU64,
}

impl AtomicHistogram {
    fn new() -> Self {
        Self {
            counts: (0..BUCKETS).map(|_| AtomicU64::new(0)).collect(),
            sum_ns: AtomicU64::new(0),
            max_ns: AtomicU64::new(0),
        }
    }

    fn record(&self, ns: u64) {
        self.counts[bucket_of(ns)].fetch_add(1, Ordering::Relaxed);
        self.sum_ns.fetch_add(ns, Ordering::Relaxed);
        self.max_ns.fetch_max(ns, Ordering::Relaxed);
    }

    fn snapshot(&self) -> LatencyHistogram {
        LatencyHistogram {
            counts: self.counts.iter().map(|c| c.load(Ordering::Relaxed)).collect(),
            sum_ns: self.sum_ns.load(Ordering::Relaxed),
            max_ns: self.max_ns.load(Ordering::Relaxed),
        }
    }
}

/// Latencies as a histogram: count, mean, max and percentiles to within 3 %; histograms of
/// several stages (the detection workers) merge.
#[derive(Debug, Clone, PartialEq)]
pub struct LatencyHistogram {
    counts: Vec<u64>,
    sum_ns: u64,
    max_ns: u64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self { counts: vec![0; BUCKETS], sum_ns: 0, max_ns: 0 }
    }
}

impl LatencyHistogram {
    /// Adds one sample.
    pub fn record(&mut self, duration: Duration) {
        let ns = duration.as_nanos().min(u64::MAX as u128) as u64;
        self.counts[bucket_of(ns)] += 1;
        self.sum_ns = self.sum_ns.saturating_add(ns);
        self.max_ns = self.max_ns.max(ns);
    }

    /// Adds every sample of `other`.
    pub fn merge(&mut self, other: &LatencyHistogram) {
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        self.sum_ns = self.sum_ns.saturating_add(other.sum_ns);
        self.max_ns = self.max_ns.max(other.max_ns);
    }

    /// Samples recorded.
    pub fn count(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Mean, microseconds (0 without samples).
    pub fn mean_us(&self) -> f64 {
        let n = self.count();
        if n == 0 { 0.0 } else { self.sum_ns as f64 / n as f64 / 1e3 }
    }

    /// Largest sample, microseconds.
    pub fn max_us(&self) -> f64 {
        self.max_ns as f64 / 1e3
    }

    /// The `q` quantile (0..=1), microseconds: the middle of the bucket holding the sample of
    /// rank `round((n - 1) q)`, never above the largest sample; 0 without samples.
    pub fn quantile_us(&self, q: f64) -> f64 {
        let n = self.count();
        if n == 0 {
            return 0.0;
        }
        let rank = ((n - 1) as f64 * q.clamp(0.0, 1.0)).round() as u64;
        let mut seen = 0u64;
        for (index, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen > rank {
                return bucket_value(index).min(self.max_ns as f64) / 1e3;
            }
        }
        self.max_us()
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
        // The whole-run histogram is not reset by reports.
        assert_eq!(s.since_start().count(), 10);
    }

    #[test]
    fn histogram_quantiles_within_resolution() {
        let mut h = LatencyHistogram::default();
        assert_eq!(h.quantile_us(0.5), 0.0);
        // 1..=1000 microseconds.
        for us in 1..=1000u64 {
            h.record(Duration::from_micros(us));
        }
        assert_eq!(h.count(), 1000);
        let close = |got: f64, want: f64| (got - want).abs() <= want / SUB_BUCKETS as f64 + 1e-9;
        assert!(close(h.quantile_us(0.5), 500.0), "{}", h.quantile_us(0.5));
        assert!(close(h.quantile_us(0.99), 990.0), "{}", h.quantile_us(0.99));
        assert_eq!(h.max_us(), 1000.0);
        assert!((h.mean_us() - 500.5).abs() < 1e-6);
        assert!(h.quantile_us(1.0) <= 1000.0);
        let mut other = LatencyHistogram::default();
        other.record(Duration::from_secs(2));
        h.merge(&other);
        assert_eq!(h.count(), 1001);
        assert_eq!(h.max_us(), 2e6);
        // Small and huge values land in buckets whose middle is within resolution.
        for ns in [0u64, 1, 31, 32, 33, 1 << 20, u64::MAX / 3] {
            let v = bucket_value(bucket_of(ns));
            assert!((v - ns as f64).abs() <= (ns as f64 / SUB_BUCKETS as f64).max(0.5), "{ns} -> {v}");
        }
    }
}
