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

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use op3dsg_ipc_types::RefinerHealth;
use rustc_hash::FxHashMap;
use tokio::sync::{Notify, Semaphore};
use tracing::{debug, info, warn};

use super::client::{ApiKey, CallError, ChatClient};
use super::config::LlmConfig;
use super::gate::{self, LabelMapper, ParseOptions, Rejection, RejectionLog, Rejections};
use super::plausibility::Plausibility;
use super::prompt::{self, Prompt, PromptSet};
use super::result::{AgentResult, LlmResult};
use crate::knowledge::KnowledgeBase;
use crate::prior::PriorGraph;
use crate::reasoner::ReasonerOutput;

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
    state: AtomicU8,
    breaker_open: AtomicBool,
    last_error: AtomicU8,
    last_latency_us: AtomicU32,
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
    response_format: AtomicU8,
    rejections: [AtomicU64; 8],
}

/// `op3dsg_ipc_types::REFINER_FORMATS`: `json_schema` as configured.
const FORMAT_JSON_SCHEMA: u8 = 0;
/// `json_object` as configured.
const FORMAT_JSON_OBJECT: u8 = 1;
/// `json_object` because the server refused `json_schema`.
const FORMAT_JSON_OBJECT_FALLBACK: u8 = 2;

impl RefinerStats {
    /// The state now.
    pub fn state(&self) -> u8 {
        self.state.load(Ordering::Relaxed)
    }
    fn set_state(&self, state: RefinerState) {
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
    fn set_last_error(&self, error: &CallError) {
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

struct Shared {
    slot: Mutex<Option<Arc<PriorGraph>>>,
    wake: Notify,
    /// The next snapshot is refreshed whatever changed, and answered even on failure.
    forced: AtomicBool,
    /// Only forced snapshots are refreshed (batch runs).
    synchronous: AtomicBool,
    stop: AtomicBool,
    stop_notify: Notify,
    /// Where each call's exchange is recorded (`/op3dsg/llm`), when the daemon records.
    recorder: Mutex<Option<crate::record::RecordSender>>,
}

/// How one agent's call went (all its retries), for the recording.
#[derive(Debug, Default)]
struct CallRecord {
    answer: Option<String>,
    attempts: u32,
    latency: Duration,
    total: Duration,
    error: Option<String>,
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

struct Worker {
    config: LlmConfig,
    client: ChatClient,
    knowledge: Arc<KnowledgeBase>,
    rules: Plausibility,
    mapper: LabelMapper,
    shared: Arc<Shared>,
    stats: Arc<RefinerStats>,
    results_tx: Sender<LlmResult>,
    results_rx: Receiver<LlmResult>,
    /// Each agent's last accepted result.
    held: LlmResult,
    calls_in_hour: Mutex<VecDeque<Instant>>,
    consecutive_failures: AtomicU32,
    breaker_until: Mutex<Option<Instant>>,
    permits: Semaphore,
    rejection_log: RateLimitedRejections,
}

/// The gate's rejections in the log: per reason at most one line every
/// [`REJECTION_LOG_INTERVAL`], with the count since the last line and the first example's
/// detail (serde's message for `malformed`).
#[derive(Debug, Default)]
struct RateLimitedRejections {
    last: [Option<Instant>; op3dsg_ipc_types::REFINER_REJECTIONS.len()],
    pending: [u64; op3dsg_ipc_types::REFINER_REJECTIONS.len()],
}

/// How often each rejection reason may be logged.
const REJECTION_LOG_INTERVAL: Duration = Duration::from_secs(10);

impl RateLimitedRejections {
    /// Logs what `log` holds where its reason's interval has passed; the rest is carried over.
    fn report(&mut self, graph_version: u64, log: &RejectionLog) -> usize {
        let mut lines = 0;
        for (i, reason) in op3dsg_ipc_types::REFINER_REJECTIONS.iter().enumerate() {
            let n = log.counts.0[i];
            if n == 0 {
                continue;
            }
            self.pending[i] += n;
            if self.last[i].is_some_and(|t| t.elapsed() < REJECTION_LOG_INTERVAL) {
                continue;
            }
            let example = log.examples[i].as_deref().unwrap_or("");
            warn!(
                graph_version,
                reason,
                rejected = self.pending[i],
                example,
                "LLM answer items rejected by the verification gate"
            );
            self.last[i] = Some(Instant::now());
            self.pending[i] = 0;
            lines += 1;
        }
        lines
    }
}

/// How a refresh went.
#[derive(Debug, PartialEq)]
enum Outcome {
    /// At least one agent answered.
    Answered,
    /// Every call failed, or the breaker or the budget refused them.
    Failed,
}

/// Nodes added, removed or relabelled between two label maps.
fn changed_nodes(before: &FxHashMap<u32, String>, prior: &PriorGraph) -> u32 {
    let mut changed = 0u32;
    for node in &prior.nodes {
        if before.get(&node.id) != Some(&node.label) {
            changed += 1;
        }
    }
    let removed = before.keys().filter(|id| prior.index_of(**id).is_none()).count() as u32;
    changed + removed
}

impl Worker {
    async fn run(mut self) {
        info!(model = %self.config.model, "LLM refiner started");
        let shared = self.shared.clone();
        let tick = self.config.refresh_period().min(Duration::from_millis(500));
        let mut latest: Option<Arc<PriorGraph>> = None;
        let mut refreshed_labels: Option<FxHashMap<u32, String>> = None;
        let mut last_attempt: Option<(Instant, bool)> = None;
        loop {
            tokio::select! {
                () = self.shared.wake.notified() => {}
                () = tokio::time::sleep(tick) => {}
            }
            if self.shared.stop.load(Ordering::SeqCst) {
                break;
            }
            let mut forced = false;
            // The prior and its `forced` flag are taken together, under the lock that set them.
            let offered = shared
                .slot
                .lock()
                .ok()
                .and_then(|mut slot| slot.take().map(|prior| (prior, shared.forced.swap(false, Ordering::SeqCst))));
            if let Some((prior, was_forced)) = offered {
                self.prune_held(&prior);
                latest = Some(prior);
                forced = was_forced;
            }
            if self.stats.state() == RefinerState::BudgetExhausted as u8 && self.budget_left() > 0 {
                self.stats.set_state(RefinerState::Idle);
            }
            let Some(prior) = latest.clone() else { continue };
            if prior.nodes.is_empty() && !forced {
                continue;
            }
            let changed = refreshed_labels.as_ref().map_or(u32::MAX, |before| changed_nodes(before, &prior));
            let since = last_attempt.map(|(t, _)| t.elapsed());
            let period_passed = since.is_none_or(|s| s >= self.config.refresh_period());
            let last_ok = last_attempt.is_none_or(|(_, ok)| ok);
            let due = (changed >= self.config.refresh_min_changed_nodes && (last_ok || period_passed))
                || (changed > 0 && period_passed);
            let synchronous = self.shared.synchronous.load(Ordering::SeqCst);
            if !(forced || due && !synchronous) {
                continue;
            }
            let breaker_open = self.breaker_until.lock().ok().and_then(|b| *b).is_some_and(|t| Instant::now() < t);
            let refused = if breaker_open {
                self.stats.set_state(RefinerState::BreakerOpen);
                true
            } else if self.budget_left() == 0 {
                self.stats.set_state(RefinerState::BudgetExhausted);
                true
            } else {
                false
            };
            if refused {
                if forced {
                    // Refused calls change nothing accepted.
                    self.send_held(&prior);
                }
                continue;
            }
            let outcome = tokio::select! {
                outcome = self.refresh(&prior, forced) => outcome,
                () = shared.stop_notify.notified() => break,
            };
            last_attempt = Some((Instant::now(), outcome == Outcome::Answered));
            if outcome == Outcome::Answered {
                refreshed_labels = Some(prior.nodes.iter().map(|n| (n.id, n.label.clone())).collect());
            }
            if !self.stats.breaker_open() && self.stats.state() != RefinerState::BudgetExhausted as u8 {
                self.stats.set_state(RefinerState::Idle);
            }
        }
        self.stats.set_state(RefinerState::Idle);
        debug!("LLM refiner stopped");
    }

    /// Calls left in the rolling hour.
    fn budget_left(&self) -> u32 {
        let Ok(mut calls) = self.calls_in_hour.lock() else { return 0 };
        let hour = Duration::from_secs(3600);
        while calls.front().is_some_and(|t| t.elapsed() >= hour) {
            calls.pop_front();
        }
        self.config.hourly_call_budget.saturating_sub(calls.len() as u32)
    }

    fn take_budget(&self) -> bool {
        if self.budget_left() == 0 {
            return false;
        }
        self.calls_in_hour.lock().map(|mut c| c.push_back(Instant::now())).is_ok()
    }

    /// Sends every agent's last accepted result, re-checked against `prior` (the newest graph
    /// the refiner has), to the fusion thread.
    /// Drops the held items whose nodes `prior` no longer has with the kind they had (counted
    /// `stale`, once: they are gone from the held results for good).
    fn prune_held(&mut self, prior: &PriorGraph) {
        let stale =
            self.held.retain_valid(|id| prior.index_of(id).map(|i| (prior.nodes[i].kind, prior.nodes[i].parent_id)));
        if stale > 0 {
            let mut rejections = Rejections::default();
            rejections.0[Rejection::Stale as usize] = stale as u64;
            self.stats.add_rejections(&rejections);
            debug!(graph_version = prior.version, stale, "LLM results dropped: their nodes are gone or changed");
        }
    }

    fn send_held(&mut self, prior: &PriorGraph) {
        self.prune_held(prior);
        self.held.graph_version = prior.version;
        self.send(self.held.clone());
    }

    /// Sends a result to the fusion thread; latest wins (an unread older result is replaced).
    fn send(&self, output: LlmResult) {
        let _ = self.results_rx.try_recv();
        if self.results_tx.try_send(output).is_ok() {
            self.stats.results.fetch_add(1, Ordering::Relaxed);
        }
    }

    async fn refresh(&mut self, prior: &PriorGraph, forced: bool) -> Outcome {
        let prompts: PromptSet = prompt::build(prior, &self.knowledge, self.config.max_prompt_items as usize);
        if prompts.prompts.is_empty() {
            if forced {
                self.send_held(prior);
            }
            return Outcome::Answered;
        }
        self.stats.refreshes.fetch_add(1, Ordering::Relaxed);
        self.stats.set_state(RefinerState::Calling);
        debug!(graph_version = prior.version, prompts = prompts.prompts.len(), "LLM refresh");
        let answers = {
            let this = &*self;
            let calls = prompts.prompts.iter().map(|p| this.call_with_retries(p));
            futures_join_all(calls).await
        };
        let mut log = RejectionLog::default();
        let mut accepted = 0;
        let mut answered = false;
        let options = ParseOptions { ignore_unknown_fields: self.config.ignore_unknown_fields };
        for (prompt, call) in prompts.prompts.iter().zip(answers) {
            // A failed call leaves the agent's last accepted result as it was.
            let Some(answer) = call.answer.as_deref() else {
                self.record(prior.version, prompt, &call, None);
                continue;
            };
            let mut output = ReasonerOutput { graph_version: prior.version, ..ReasonerOutput::default() };
            let before = log.counts;
            let checked = gate::check(
                prompt.agent,
                answer,
                prior,
                &prompts,
                &mut self.mapper,
                options,
                &self.rules,
                &mut output,
                &mut log,
            );
            let mut rejected = Rejections::default();
            for ((r, after), before) in rejected.0.iter_mut().zip(log.counts.0).zip(before.0) {
                *r = after - before;
            }
            self.record(prior.version, prompt, &call, Some((checked, rejected)));
            // So does an answer with no usable JSON object in it.
            let Some(n) = checked else { continue };
            answered = true;
            accepted += n;
            self.held.accept(AgentResult::new(prompt.agent, prior, output));
        }
        self.stats.add_rejections(&log.counts);
        self.stats.accepted.fetch_add(accepted, Ordering::Relaxed);
        self.rejection_log.report(prior.version, &log);
        if !answered {
            if forced {
                self.send_held(prior);
            }
            return Outcome::Failed;
        }
        self.stats.last_graph_version.store(prior.version, Ordering::Relaxed);
        self.send_held(prior);
        Outcome::Answered
    }

    /// Offers one call's exchange to the recorder, when it records: `verdict` is the gate's
    /// (items accepted, `None` for an answer with no usable JSON object; rejections of this
    /// answer) when there was an answer. What is recorded is the prompt, the answer text and
    /// the counts: the key and the request headers never reach it.
    fn record(
        &self,
        graph_version: u64,
        prompt: &Prompt,
        call: &CallRecord,
        verdict: Option<(Option<u64>, Rejections)>,
    ) {
        let Ok(mut slot) = self.shared.recorder.lock() else { return };
        let Some(recorder) = slot.as_mut() else { return };
        use op3dsg_drivers::mcap::messages::{ChatMessage, LlmExchange, LlmVerdict};
        let ms = |d: Duration| d.as_secs_f64() * 1000.0;
        let verdict = verdict.map(|(accepted, rejections)| LlmVerdict {
            parsed: accepted.is_some(),
            accepted: accepted.unwrap_or(0),
            rejected: op3dsg_ipc_types::REFINER_REJECTIONS
                .iter()
                .zip(rejections.0)
                .filter(|(_, n)| *n > 0)
                .map(|(reason, n)| ((*reason).to_owned(), n))
                .collect(),
        });
        recorder.offer_llm_exchange(LlmExchange {
            graph_version,
            agent: prompt.agent.name().to_owned(),
            model: self.config.model.clone(),
            messages: vec![
                ChatMessage { role: "system".to_owned(), content: prompt.system.clone() },
                ChatMessage { role: "user".to_owned(), content: prompt.user.clone() },
            ],
            attempts: call.attempts,
            latency_ms: ms(call.latency),
            total_ms: ms(call.total),
            answer: call.answer.clone(),
            error: call.error.clone(),
            verdict,
        });
    }

    /// One agent's call with its retries; the answer is `None` when it finally failed or was
    /// refused.
    async fn call_with_retries(&self, prompt: &Prompt) -> CallRecord {
        let mut record = CallRecord::default();
        let call_started = Instant::now();
        let mut backoff = self.config.backoff_initial();
        let mut attempt = 0;
        let mut fell_back = false;
        loop {
            if self.breaker_until.lock().ok().and_then(|b| *b).is_some_and(|until| Instant::now() < until) {
                record.error = Some("breaker_open".to_owned());
                return record;
            }
            if !self.take_budget() {
                self.stats.set_state(RefinerState::BudgetExhausted);
                warn!(budget = self.config.hourly_call_budget, "LLM hourly call budget spent");
                record.error = Some("budget_exhausted".to_owned());
                return record;
            }
            let result = {
                let Ok(_permit) = self.permits.acquire().await else { return record };
                self.stats.set_state(RefinerState::Calling);
                self.stats.calls.fetch_add(1, Ordering::Relaxed);
                record.attempts += 1;
                let started = Instant::now();
                let result = self.client.complete(prompt).await;
                record.latency = started.elapsed();
                record.total = call_started.elapsed();
                self.stats
                    .last_latency_us
                    .store(record.latency.as_micros().min(u128::from(u32::MAX)) as u32, Ordering::Relaxed);
                result
            };
            let error = match result {
                Ok(answer) => {
                    self.consecutive_failures.store(0, Ordering::Relaxed);
                    if let Ok(mut breaker) = self.breaker_until.lock() {
                        *breaker = None;
                    }
                    self.stats.breaker_open.store(false, Ordering::Relaxed);
                    record.answer = Some(answer);
                    record.error = None;
                    return record;
                }
                // No structured output on this server: the same call again at once, with
                // `json_object` (the client sends it from now on); not a failure.
                Err(CallError::SchemaRefused { first, detail }) if !fell_back => {
                    fell_back = true;
                    self.stats.schema_refusals.fetch_add(1, Ordering::Relaxed);
                    self.stats.response_format.store(FORMAT_JSON_OBJECT_FALLBACK, Ordering::Relaxed);
                    if first {
                        warn!(
                            agent = prompt.agent.name(),
                            answer = %detail,
                            "the LLM server answered 400 to response_format json_schema; sending json_object from now on (set reasoner.llm.response_format = \"json_object\" to skip this)"
                        );
                    }
                    continue;
                }
                // A 2xx that is not a chat completion (an HTML page, no choices, null content)
                // is a failure like a 5xx: it counts, and feeds the breaker.
                Err(e) => e,
            };
            self.stats.failures.fetch_add(1, Ordering::Relaxed);
            self.stats.set_last_error(&error);
            record.error = Some(format!("{}: {error}", error.name()));
            let retry_after = match &error {
                CallError::Timeout => {
                    self.stats.timeouts.fetch_add(1, Ordering::Relaxed);
                    None
                }
                CallError::Status { status: 429, retry_after } => {
                    self.stats.rate_limited.fetch_add(1, Ordering::Relaxed);
                    *retry_after
                }
                CallError::Status { retry_after, .. } => *retry_after,
                _ => None,
            };
            warn!(agent = prompt.agent.name(), attempt, cause = error.name(), error = %error, "LLM call failed");
            if !error.retryable() || attempt >= self.config.max_retries {
                break;
            }
            let wait = retry_after.map_or(backoff, |r| r.max(backoff)).min(self.config.backoff_max());
            self.stats.set_state(RefinerState::Backoff);
            tokio::time::sleep(wait).await;
            backoff = (backoff * 2).min(self.config.backoff_max());
            attempt += 1;
        }
        let failures = self.consecutive_failures.fetch_add(1, Ordering::Relaxed) + 1;
        if failures >= self.config.breaker_failures {
            if let Ok(mut breaker) = self.breaker_until.lock() {
                *breaker = Some(Instant::now() + self.config.breaker_cooldown());
            }
            if !self.stats.breaker_open.swap(true, Ordering::Relaxed) {
                warn!(
                    failures,
                    cooldown_s = self.config.breaker_cooldown_s,
                    "LLM circuit breaker open after repeated failures"
                );
            }
            self.stats.set_state(RefinerState::BreakerOpen);
        }
        record
    }
}

/// Runs futures concurrently on the current task and returns their outputs in order.
async fn futures_join_all<F: std::future::Future>(futures: impl Iterator<Item = F>) -> Vec<F::Output> {
    let mut set = Vec::new();
    for f in futures {
        set.push(Box::pin(f));
    }
    let mut outputs: Vec<Option<F::Output>> = (0..set.len()).map(|_| None).collect();
    std::future::poll_fn(|cx| {
        let mut pending = false;
        for (fut, out) in set.iter_mut().zip(outputs.iter_mut()) {
            if out.is_some() {
                continue;
            }
            match fut.as_mut().poll(cx) {
                std::task::Poll::Ready(v) => *out = Some(v),
                std::task::Poll::Pending => pending = true,
            }
        }
        if pending { std::task::Poll::Pending } else { std::task::Poll::Ready(()) }
    })
    .await;
    outputs.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prior::PriorNode;

    fn prior(nodes: &[(u32, &str)]) -> PriorGraph {
        PriorGraph {
            nodes: nodes
                .iter()
                .map(|&(id, label)| PriorNode {
                    id,
                    kind: op3dsg_ipc_types::NodeKind::Object,
                    parent_id: None,
                    label: label.to_owned(),
                    category: None,
                    by_embedding: false,
                    confidence: 1.0,
                    centre_m: glam::Vec3::ZERO,
                    box_min_m: glam::Vec3::ZERO,
                    box_max_m: glam::Vec3::ZERO,
                })
                .collect(),
            ..PriorGraph::default()
        }
    }

    #[test]
    fn change_counts_added_removed_and_relabelled_nodes() {
        let before: FxHashMap<u32, String> =
            [(1, "cabinet"), (2, "stove"), (3, "tv")].iter().map(|&(id, l)| (id, l.to_owned())).collect();
        assert_eq!(changed_nodes(&before, &prior(&[(1, "cabinet"), (2, "stove"), (3, "tv")])), 0);
        // 2 relabelled, 3 removed, 4 added.
        assert_eq!(changed_nodes(&before, &prior(&[(1, "cabinet"), (2, "oven"), (4, "sink")])), 3);
    }

    #[test]
    fn rejections_are_logged_once_per_interval_per_reason() {
        let mut limiter = RateLimitedRejections::default();
        let mut log = RejectionLog::default();
        log.reject(Rejection::Malformed, || "local_relations: no JSON object".to_owned());
        log.reject(Rejection::UnknownNode, || "affordances: node 9 is not in the graph".to_owned());
        assert_eq!(limiter.report(1, &log), 2, "one line per reason");
        assert_eq!(limiter.report(2, &log), 0, "within the interval: carried over");
        assert_eq!(limiter.pending[Rejection::Malformed as usize], 1);
        limiter.last[Rejection::Malformed as usize] = Instant::now().checked_sub(REJECTION_LOG_INTERVAL);
        assert_eq!(limiter.report(3, &log), 1, "the interval passed for malformed only");
        assert_eq!(limiter.pending[Rejection::Malformed as usize], 0);
        assert_eq!(limiter.pending[Rejection::UnknownNode as usize], 2);
    }

    #[test]
    fn health_reports_the_state_and_the_rejections() {
        let stats = RefinerStats::default();
        assert_eq!(stats.health().state, RefinerState::Off as u8);
        stats.set_state(RefinerState::BreakerOpen);
        let mut rejections = Rejections::default();
        rejections.add(Rejection::NonCanonical);
        rejections.add(Rejection::NonCanonical);
        stats.add_rejections(&rejections);
        let h = stats.health();
        assert_eq!(op3dsg_ipc_types::REFINER_STATES[h.state as usize], "breaker_open");
        assert_eq!(h.rejections[..5], [0, 0, 0, 2, 0]);
        assert_eq!(op3dsg_ipc_types::REFINER_REJECTIONS[3], "non_canonical");
    }
}
