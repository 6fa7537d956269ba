//! The refiner thread's work: a refresh per changed prior graph, three agents' calls with
//! retries, budget and circuit breaker, their answers through the gate.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use rustc_hash::FxHashMap;
use tokio::sync::Semaphore;
use tracing::{debug, info, warn};

use crate::knowledge::KnowledgeBase;
use crate::prior::PriorGraph;
use crate::reasoner::ReasonerOutput;
use crate::reasoner::llm::client::{CallError, ChatClient};
use crate::reasoner::llm::config::LlmConfig;
use crate::reasoner::llm::gate::{self, LabelMapper, ParseOptions, Rejection, RejectionLog, Rejections};
use crate::reasoner::llm::plausibility::Plausibility;
use crate::reasoner::llm::prompt::{self, Prompt, PromptSet};
use crate::reasoner::llm::result::{AgentResult, LlmResult};

use super::stats::FORMAT_JSON_OBJECT_FALLBACK;
use super::{CallRecord, RefinerState, RefinerStats, Shared};

pub(super) struct Worker {
    pub(super) config: LlmConfig,
    pub(super) client: ChatClient,
    pub(super) knowledge: Arc<KnowledgeBase>,
    pub(super) rules: Plausibility,
    pub(super) mapper: LabelMapper,
    pub(super) shared: Arc<Shared>,
    pub(super) stats: Arc<RefinerStats>,
    pub(super) results_tx: Sender<LlmResult>,
    pub(super) results_rx: Receiver<LlmResult>,
    /// Each agent's last accepted result.
    pub(super) held: LlmResult,
    pub(super) calls_in_hour: Mutex<VecDeque<Instant>>,
    pub(super) consecutive_failures: AtomicU32,
    pub(super) breaker_until: Mutex<Option<Instant>>,
    pub(super) permits: Semaphore,
    pub(super) rejection_log: RateLimitedRejections,
}

/// The gate's rejections in the log: per reason at most one line every
/// [`REJECTION_LOG_INTERVAL`], with the count since the last line and the first example's
/// detail (serde's message for `malformed`).
#[derive(Debug, Default)]
pub(super) struct RateLimitedRejections {
    pub(super) last: [Option<Instant>; op3dsg_ipc_types::REFINER_REJECTIONS.len()],
    pub(super) pending: [u64; op3dsg_ipc_types::REFINER_REJECTIONS.len()],
}

/// How often each rejection reason may be logged.
pub(super) const REJECTION_LOG_INTERVAL: Duration = Duration::from_secs(10);

impl RateLimitedRejections {
    /// Logs what `log` holds where its reason's interval has passed; the rest is carried over.
    pub(super) fn report(&mut self, graph_version: u64, log: &RejectionLog) -> usize {
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
pub(super) fn changed_nodes(before: &FxHashMap<u32, String>, prior: &PriorGraph) -> u32 {
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
    pub(super) async fn run(mut self) {
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
            let against = gate::Against { prior, prompts: &prompts, rules: &self.rules, options };
            let checked = gate::check(prompt.agent, answer, against, &mut self.mapper, &mut output, &mut log);
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
