//! The asynchronous refiner: its own named thread with its own (single-threaded) tokio runtime.
//!
//! ```text
//!  fusion thread ── offer(Arc<PriorGraph>) ──▶ slot (1, latest wins) ──▶ refiner thread
//!        ▲                                                                   │ 3 agents, joined
//!        └──────── try_result() ◀── results (1, latest wins) ◀── gate ◀──────┘
//! ```
//!
//! The fusion thread never waits: `offer` swaps a pointer under a lock the refiner holds only to
//! take it, `try_result` never blocks. The refiner refreshes when at least
//! `refresh_min_changed_nodes` nodes were added, removed or relabelled since the last successful
//! refresh, or after `refresh_period_s` when anything changed (a failed refresh waits a period
//! before the next try). A refresh sends the three agents' prompts concurrently (at most
//! `max_concurrent_calls` in flight), each call retried on timeouts, transport errors, 429 and 5xx
//! with exponential backoff (`Retry-After` honoured), every request counted against the rolling
//! hourly budget; `breaker_failures` consecutive failed calls open the circuit breaker for
//! `breaker_cooldown_s`. Stopping (drop) cancels whatever is in flight.
//!
//! | file | what |
//! |---|---|
//! | this file | [`LlmRefiner`], the fusion thread's handle, and the state it shares with the thread |
//! | `stats.rs` | [`RefinerStats`], [`RefinerState`] |
//! | `worker.rs` | the thread's refreshes |

mod stats;
#[cfg(test)]
mod tests;
mod worker;

use stats::{FORMAT_JSON_OBJECT, FORMAT_JSON_SCHEMA};
pub use stats::{RefinerState, RefinerStats};
use worker::{RateLimitedRejections, Worker};

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crossbeam_channel::Receiver;
use tokio::sync::{Notify, Semaphore};

use crate::knowledge::KnowledgeBase;
use crate::prior::PriorGraph;
use crate::reasoner::llm::client::{ApiKey, ChatClient};
use crate::reasoner::llm::config::LlmConfig;
use crate::reasoner::llm::gate::LabelMapper;
use crate::reasoner::llm::plausibility::Plausibility;
use crate::reasoner::llm::result::LlmResult;

/// What the refiner needs besides its configuration.
#[derive(Debug)]
pub struct RefinerParts {
    /// The knowledge base (remote candidates).
    pub knowledge: Arc<KnowledgeBase>,
    /// The API key, when there is one.
    pub key: Option<ApiKey>,
    /// Maps labels onto the canonical tables.
    pub mapper: LabelMapper,
}

pub(super) struct Shared {
    pub(super) slot: Mutex<Option<Arc<PriorGraph>>>,
    pub(super) wake: Notify,
    /// The next snapshot is refreshed whatever changed, and answered even on failure.
    pub(super) forced: AtomicBool,
    /// Only forced snapshots are refreshed (batch runs).
    pub(super) synchronous: AtomicBool,
    pub(super) stop: AtomicBool,
    pub(super) stop_notify: Notify,
    /// Where each call's exchange is recorded (`/op3dsg/llm`), when the daemon records.
    pub(super) recorder: Mutex<Option<crate::record::RecordSender>>,
}

/// How one agent's call went (all its retries), for the recording.
#[derive(Debug, Default)]
pub(super) struct CallRecord {
    pub(super) answer: Option<String>,
    pub(super) attempts: u32,
    pub(super) latency: Duration,
    pub(super) total: Duration,
    pub(super) error: Option<String>,
}

/// Handle of the refiner thread, owned by the fusion thread (or the batch runner).
pub struct LlmRefiner {
    shared: Arc<Shared>,
    results: Receiver<LlmResult>,
    stats: Arc<RefinerStats>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl std::fmt::Debug for LlmRefiner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LlmRefiner").field("state", &self.stats.state()).finish_non_exhaustive()
    }
}

impl LlmRefiner {
    /// Starts the refiner thread (`op3dsg-llm`).
    pub fn start(config: &LlmConfig, parts: RefinerParts) -> Result<Self, String> {
        let client = ChatClient::new(config, parts.key.as_ref())?;
        let shared = Arc::new(Shared {
            slot: Mutex::new(None),
            wake: Notify::new(),
            forced: AtomicBool::new(false),
            synchronous: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            stop_notify: Notify::new(),
            recorder: Mutex::new(None),
        });
        let stats = Arc::new(RefinerStats::default());
        stats.set_state(RefinerState::Idle);
        let format = match config.response_format {
            super::ResponseFormat::JsonSchema => FORMAT_JSON_SCHEMA,
            super::ResponseFormat::JsonObject => FORMAT_JSON_OBJECT,
        };
        stats.response_format.store(format, Ordering::Relaxed);
        // Results: latest wins (the refiner pops an unread older one before pushing).
        let (results_tx, results_rx) = crossbeam_channel::bounded::<LlmResult>(1);
        let worker = Worker {
            config: config.clone(),
            client,
            rules: Plausibility::new(&config.plausibility, parts.knowledge.clone()),
            knowledge: parts.knowledge,
            mapper: parts.mapper,
            shared: shared.clone(),
            stats: stats.clone(),
            results_tx,
            results_rx: results_rx.clone(),
            held: LlmResult::default(),
            calls_in_hour: Mutex::new(VecDeque::new()),
            consecutive_failures: AtomicU32::new(0),
            breaker_until: Mutex::new(None),
            permits: Semaphore::new(config.max_concurrent_calls as usize),
            rejection_log: RateLimitedRejections::default(),
        };
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| format!("tokio runtime: {e}"))?;
        let thread = std::thread::Builder::new()
            .name("op3dsg-llm".to_owned())
            .spawn(move || runtime.block_on(worker.run()))
            .map_err(|e| format!("thread op3dsg-llm: {e}"))?;
        Ok(Self { shared, results: results_rx, stats, thread: Some(thread) })
    }

    /// Hands the latest prior graph over (replaces one not yet taken). Never blocks on the
    /// refiner's work.
    pub fn offer(&self, prior: Arc<PriorGraph>) {
        if let Ok(mut slot) = self.shared.slot.lock() {
            *slot = Some(prior);
        }
        self.shared.wake.notify_one();
    }

    /// Hands `prior` over for an immediate refresh whatever changed; its result (every agent's
    /// last accepted one, unchanged where calls failed or were refused) follows on the results
    /// channel (the batch runner).
    pub fn offer_forced(&self, prior: Arc<PriorGraph>) {
        if let Ok(mut slot) = self.shared.slot.lock() {
            *slot = Some(prior);
            self.shared.forced.store(true, Ordering::SeqCst);
        }
        self.shared.wake.notify_one();
    }

    /// `true`: refresh only what [`LlmRefiner::offer_forced`] hands over (batch runs, where each
    /// result must belong to the graph just offered).
    pub fn set_synchronous(&self, synchronous: bool) {
        self.shared.synchronous.store(synchronous, Ordering::SeqCst);
    }

    /// The latest verified result (every agent's last accepted one), if one arrived since the
    /// last call.
    pub fn try_result(&self) -> Option<LlmResult> {
        self.results.try_recv().ok()
    }

    /// Waits up to `timeout` for a result (the batch runner; never the fusion thread).
    pub fn wait_result(&self, timeout: Duration) -> Option<LlmResult> {
        self.results.recv_timeout(timeout).ok()
    }

    /// The counters.
    pub fn stats(&self) -> &Arc<RefinerStats> {
        &self.stats
    }

    /// Records every call from now on (`/op3dsg/llm`: prompt, answer, the gate's verdict); the
    /// refiner offers each with `try_send` and never waits on the recorder.
    pub fn record_to(&self, recorder: crate::record::RecordSender) {
        if let Ok(mut slot) = self.shared.recorder.lock() {
            *slot = Some(recorder);
        }
    }
}

impl Drop for LlmRefiner {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        self.shared.stop_notify.notify_one();
        self.shared.wake.notify_one();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
        // The recorder finishes its file when every sender is gone.
        if let Ok(mut slot) = self.shared.recorder.lock() {
            *slot = None;
        }
    }
}
