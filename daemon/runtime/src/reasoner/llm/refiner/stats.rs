//! The refiner's counters and state, shared with the health reporter.

use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, AtomicU64, Ordering};

use op3dsg_ipc_types::RefinerHealth;

use super::super::client::CallError;
use super::super::gate::{Rejection, Rejections};

/// Refiner states (`op3dsg_ipc_types::REFINER_STATES` order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum RefinerState {
    /// No LLM configured.
    Off = 0,
    /// Waiting for a graph that changed enough.
    Idle = 1,
    /// Requests in flight.
    Calling = 2,
    /// Waiting before a retry.
    Backoff = 3,
    /// Circuit breaker open.
    BreakerOpen = 4,
    /// Hourly budget spent.
    BudgetExhausted = 5,
}

/// Counters of the refiner, shared with the health reporter.
#[derive(Debug, Default)]
pub struct RefinerStats {
    pub(super) state: AtomicU8,
    pub(super) breaker_open: AtomicBool,
    pub(super) last_error: AtomicU8,
    pub(super) last_latency_us: AtomicU32,
    /// Refreshes started.
    pub refreshes: AtomicU64,
    /// HTTP requests sent.
    pub calls: AtomicU64,
    /// Requests that failed.
    pub failures: AtomicU64,
    /// Of `failures`: timeouts.
    pub timeouts: AtomicU64,
    /// Of `failures`: 429 answers.
    pub rate_limited: AtomicU64,
    /// Items that passed the gate.
    pub accepted: AtomicU64,
    /// Graph version of the last result sent.
    pub last_graph_version: AtomicU64,
    /// Results sent to the fusion thread.
    pub results: AtomicU64,
    /// Requests answered 400 to `response_format = json_schema` (each repeated at once with
    /// `json_object`, which is sent from then on).
    pub schema_refusals: AtomicU64,
    /// `op3dsg_ipc_types::REFINER_FORMATS` index of the `response_format` sent now.
    pub(super) response_format: AtomicU8,
    rejections: [AtomicU64; 8],
}

/// `op3dsg_ipc_types::REFINER_FORMATS`: `json_schema` as configured.
pub(super) const FORMAT_JSON_SCHEMA: u8 = 0;
/// `json_object` as configured.
pub(super) const FORMAT_JSON_OBJECT: u8 = 1;
/// `json_object` because the server refused `json_schema`.
pub(super) const FORMAT_JSON_OBJECT_FALLBACK: u8 = 2;

impl RefinerStats {
    /// The state now.
    pub fn state(&self) -> u8 {
        self.state.load(Ordering::Relaxed)
    }
    pub(super) fn set_state(&self, state: RefinerState) {
        self.state.store(state as u8, Ordering::Relaxed);
    }
    /// Rejections for `reason` since start.
    pub fn rejections(&self, reason: Rejection) -> u64 {
        self.rejections[reason as usize].load(Ordering::Relaxed)
    }
    /// Adds rejection counts.
    pub fn add_rejections(&self, rejections: &Rejections) {
        for (slot, n) in self.rejections.iter().zip(rejections.0) {
            slot.fetch_add(n, Ordering::Relaxed);
        }
    }
    /// What the last failed call failed of (`op3dsg_ipc_types::REFINER_ERRORS`; `none` until
    /// one fails).
    pub fn last_error(&self) -> &'static str {
        op3dsg_ipc_types::REFINER_ERRORS
            .get(self.last_error.load(Ordering::Relaxed) as usize)
            .copied()
            .unwrap_or("none")
    }
    pub(super) fn set_last_error(&self, error: &CallError) {
        let i = op3dsg_ipc_types::REFINER_ERRORS.iter().position(|n| *n == error.name()).unwrap_or(0);
        self.last_error.store(i as u8, Ordering::Relaxed);
    }
    /// The `response_format` sent now (`op3dsg_ipc_types::REFINER_FORMATS`).
    pub fn response_format(&self) -> &'static str {
        op3dsg_ipc_types::REFINER_FORMATS
            .get(self.response_format.load(Ordering::Relaxed) as usize)
            .copied()
            .unwrap_or("json_schema")
    }
    /// Whether the breaker is open.
    pub fn breaker_open(&self) -> bool {
        self.breaker_open.load(Ordering::Relaxed)
    }
    /// The health record's refiner section.
    pub fn health(&self) -> RefinerHealth {
        let mut h = RefinerHealth {
            state: self.state(),
            breaker_open: u8::from(self.breaker_open()),
            last_error: self.last_error.load(Ordering::Relaxed),
            response_format: self.response_format.load(Ordering::Relaxed),
            last_latency_us: self.last_latency_us.load(Ordering::Relaxed),
            refreshes: self.refreshes.load(Ordering::Relaxed),
            calls: self.calls.load(Ordering::Relaxed),
            failures: self.failures.load(Ordering::Relaxed),
            timeouts: self.timeouts.load(Ordering::Relaxed),
            rate_limited: self.rate_limited.load(Ordering::Relaxed),
            accepted: self.accepted.load(Ordering::Relaxed),
            last_graph_version: self.last_graph_version.load(Ordering::Relaxed),
            ..RefinerHealth::default()
        };
        for (slot, n) in h.rejections.iter_mut().zip(&self.rejections) {
            *slot = n.load(Ordering::Relaxed);
        }
        h
    }
}
