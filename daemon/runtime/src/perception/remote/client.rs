//! The robot's side: the process's Zenoh session shared by the detection worker threads, the
//! workers it knows, and the detector each thread runs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use ::zenoh::Wait;
use ::zenoh::liveliness::LivelinessToken;
use ::zenoh::pubsub::Subscriber;
use ::zenoh::query::Queryable;
use ::zenoh::sample::SampleKind;
use crossbeam_channel::RecvTimeoutError;
use op3dsg_drivers::frame::Frame;
use tracing::{info, warn};

use super::config::RemoteConfig;
use super::counters::{Rejection, RemoteCounters, WorkerCounters};
use super::wire::{self, Contract, ReplyBody, WireError};
use super::{request_key, worker_key};
use crate::flow::Detection;
use crate::perception::{Detector, DetectorError};

/// How much longer than `timeout_ms` Zenoh keeps a query open, so that a late reply is still
/// seen (and counted) rather than silently lost.
const LATE_WINDOW: Duration = Duration::from_secs(5);

/// A worker the client knows.
#[derive(Debug)]
struct Worker {
    key: String,
    counters: Arc<WorkerCounters>,
    /// Left aside until then (it timed out, vanished or answered nonsense).
    aside_until: Option<Instant>,
    /// Whether its liveliness token is present (always true for configured keys).
    alive: bool,
    last_used: u64,
}

/// The session and the workers, shared by every [`RemoteDetector`] of the daemon.
pub struct RemoteClient {
    session: ::zenoh::Session,
    config: RemoteConfig,
    contract: Contract,
    workers: Mutex<Vec<Worker>>,
    counters: Arc<RemoteCounters>,
    next_request: AtomicU64,
    uses: AtomicU64,
    _liveliness: Option<Subscriber<()>>,
    _status: Option<Queryable<()>>,
}

impl std::fmt::Debug for RemoteClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteClient").field("workers", &self.config.workers).finish_non_exhaustive()
    }
}

impl RemoteClient {
    /// Finds the workers under `prefix` on `session` (the process's session of `[zenoh]`, which
    /// the Zenoh stage shares); errors name the key.
    pub fn open(session: ::zenoh::Session, prefix: &str, config: &RemoteConfig) -> Result<Arc<Self>, String> {
        let counters = Arc::new(RemoteCounters::default());
        let workers = if config.auto() {
            Vec::new()
        } else {
            config
                .workers
                .iter()
                .map(|key| Worker {
                    key: key.clone(),
                    counters: {
                        let c = counters.worker(key);
                        c.alive.store(true, Ordering::Relaxed);
                        c
                    },
                    aside_until: None,
                    alive: true,
                    last_used: 0,
                })
                .collect()
        };
        let contract = Contract {
            model: config.model.clone(),
            prompts: config.prompts.clone(),
            embedding_dim: config.embedding_dim,
        };
        let status_counters = counters.clone();
        let status = session
            .declare_queryable(format!("{prefix}/detect_status"))
            .callback(move |query| {
                let body = status_counters.report().to_string();
                let _ = query.reply(query.key_expr().clone(), body).wait();
            })
            .wait()
            .map_err(|e| format!("zenoh.key_prefix: declaring {prefix}/detect_status: {e}"))?;
        let client = Arc::new_cyclic(|weak: &std::sync::Weak<RemoteClient>| {
            let liveliness = config.auto().then(|| {
                let weak = weak.clone();
                session
                    .liveliness()
                    .declare_subscriber(format!("{prefix}/detect/*"))
                    .history(true)
                    .callback(move |sample| {
                        if let Some(client) = weak.upgrade() {
                            client.seen(sample.key_expr().as_str(), sample.kind() == SampleKind::Put);
                        }
                    })
                    .wait()
            });
            RemoteClient {
                session: session.clone(),
                config: config.clone(),
                contract,
                workers: Mutex::new(workers),
                counters,
                next_request: AtomicU64::new(1),
                uses: AtomicU64::new(0),
                _liveliness: liveliness.and_then(Result::ok),
                _status: Some(status),
            }
        });
        if config.auto() && client._liveliness.is_none() {
            return Err(format!("zenoh.key_prefix: cannot follow the workers' liveliness under {prefix}/detect/"));
        }
        info!(workers = ?config.workers, prefix, timeout_ms = config.timeout_ms, "remote detection ready");
        client.wait_for_workers(prefix);
        Ok(client)
    }

    /// Waits up to `wait_for_workers_ms` for the workers' liveliness tokens: every configured
    /// key, or one under `<prefix>/detect/` with `auto`.
    fn wait_for_workers(&self, prefix: &str) {
        if self.config.wait_for_workers_ms == 0 {
            return;
        }
        let deadline = Instant::now() + Duration::from_millis(self.config.wait_for_workers_ms);
        let wanted: Vec<String> =
            if self.config.auto() { vec![format!("{prefix}/detect/*")] } else { self.config.workers.clone() };
        let mut present = Vec::new();
        while Instant::now() < deadline {
            present = wanted.iter().filter(|key| self.token_present(key)).cloned().collect();
            if present.len() == wanted.len() {
                info!(workers = ?present, "detection workers present");
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let missing: Vec<_> = wanted.iter().filter(|k| !present.contains(k)).collect();
        warn!(
            missing = ?missing,
            waited_ms = self.config.wait_for_workers_ms,
            "detection workers absent at start-up; their keyframes go to the fallback until they come"
        );
    }

    /// Whether a liveliness token matches `key` now.
    fn token_present(&self, key: &str) -> bool {
        let Ok(replies) = self.session.liveliness().get(key).timeout(Duration::from_millis(500)).wait() else {
            return false;
        };
        replies.recv().is_ok_and(|reply| reply.result().is_ok())
    }

    /// The figures.
    pub fn counters(&self) -> &Arc<RemoteCounters> {
        &self.counters
    }

    /// A liveliness token appeared (`alive`) or went.
    fn seen(&self, key: &str, alive: bool) {
        let mut workers = self.workers.lock().unwrap_or_else(PoisonError::into_inner);
        match workers.iter_mut().find(|w| w.key == key) {
            Some(worker) => {
                worker.alive = alive;
                worker.counters.alive.store(alive, Ordering::Relaxed);
                if alive {
                    worker.aside_until = None;
                }
            }
            None if alive => workers.push(Worker {
                key: key.to_owned(),
                counters: {
                    let c = self.counters.worker(key);
                    c.alive.store(true, Ordering::Relaxed);
                    c
                },
                aside_until: None,
                alive: true,
                last_used: 0,
            }),
            None => {}
        }
        info!(worker = key, alive, "detection worker");
    }

    /// The worker to send to now: alive, not aside, below `max_in_flight`, the fewest requests
    /// outstanding, then the longest unused; `skip` names workers already tried.
    fn pick(&self, skip: &[String]) -> Option<(String, Arc<WorkerCounters>)> {
        let now = Instant::now();
        let mut workers = self.workers.lock().unwrap_or_else(PoisonError::into_inner);
        let limit = self.config.max_in_flight as u64;
        let best = workers
            .iter_mut()
            .filter(|w| w.alive && w.aside_until.is_none_or(|t| t <= now) && !skip.contains(&w.key))
            .filter(|w| w.counters.in_flight.load(Ordering::Relaxed) < limit)
            .min_by_key(|w| (w.counters.in_flight.load(Ordering::Relaxed), w.last_used))?;
        best.last_used = self.uses.fetch_add(1, Ordering::Relaxed) + 1;
        best.aside_until = None;
        best.counters.in_flight.fetch_add(1, Ordering::Relaxed);
        Some((best.key.clone(), best.counters.clone()))
    }

    /// Leaves worker `key` aside for `retry_after_ms`.
    fn set_aside(&self, key: &str) {
        let until = Instant::now() + Duration::from_millis(self.config.retry_after_ms);
        if let Some(w) = self.workers.lock().unwrap_or_else(PoisonError::into_inner).iter_mut().find(|w| w.key == key) {
            w.aside_until = Some(until);
        }
    }

    /// Sends `request` (for `frame`, id `request_id`) to one worker after another until one
    /// answers with detections that match, within `timeout_ms` in all. `None`: no worker did.
    fn detect_remote(&self, frame: &Frame, request_id: u64, request: &[u8]) -> Option<Vec<Detection>> {
        let deadline = Instant::now() + Duration::from_millis(self.config.timeout_ms);
        let mut tried = Vec::new();
        while let Some((key, counters)) = self.pick(&tried) {
            tried.push(key.clone());
            let outcome = self.ask(&key, &counters, frame, request_id, request, deadline);
            counters.in_flight.fetch_sub(1, Ordering::Relaxed);
            match outcome {
                Asked::Answered(detections) => return Some(detections),
                Asked::Gone => {
                    counters.unreachable.fetch_add(1, Ordering::Relaxed);
                    self.set_aside(&key);
                }
                Asked::TimedOut => {
                    counters.timeouts.fetch_add(1, Ordering::Relaxed);
                    self.set_aside(&key);
                    return None;
                }
                Asked::Rejected(reason, why) => {
                    counters.reject(reason);
                    warn!(worker = %key, frame_seq = frame.seq, reason = reason.as_str(), why, "remote detection rejected");
                    self.set_aside(&key);
                }
            }
            if Instant::now() >= deadline {
                return None;
            }
        }
        None
    }

    fn ask(
        &self,
        key: &str,
        counters: &Arc<WorkerCounters>,
        frame: &Frame,
        request_id: u64,
        request: &[u8],
        deadline: Instant,
    ) -> Asked {
        let (tx, rx) = crossbeam_channel::bounded::<Result<Vec<u8>, String>>(1);
        let late = counters.clone();
        let started = Instant::now();
        let sent = self
            .session
            .get(request_key(key))
            .payload(request.to_vec())
            .timeout(Duration::from_millis(self.config.timeout_ms) + LATE_WINDOW)
            .callback(move |reply| {
                let answer = match reply.result() {
                    Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
                    Err(e) => Err(format!("{:?}", e.payload().try_to_string())),
                };
                if tx.try_send(answer).is_err() {
                    late.late.fetch_add(1, Ordering::Relaxed);
                }
            })
            .wait();
        if let Err(e) = sent {
            return Asked::Rejected(Rejection::Failed, format!("query not sent: {e}"));
        }
        counters.requests.fetch_add(1, Ordering::Relaxed);
        counters.bytes_out.fetch_add(request.len() as u64, Ordering::Relaxed);
        let bytes = match rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            Ok(Ok(bytes)) => bytes,
            Ok(Err(e)) => return Asked::Rejected(Rejection::Failed, format!("error reply {e}")),
            Err(RecvTimeoutError::Timeout) => return Asked::TimedOut,
            Err(RecvTimeoutError::Disconnected) => return Asked::Gone,
        };
        counters.bytes_in.fetch_add(bytes.len() as u64, Ordering::Relaxed);
        match self.check(frame, request_id, &bytes) {
            Ok(detections) => {
                counters.replies.fetch_add(1, Ordering::Relaxed);
                counters.record_round_trip(started.elapsed());
                Asked::Answered(detections)
            }
            Err((reason, why)) => Asked::Rejected(reason, why),
        }
    }

    /// The reply's detections when it answers this request for this frame with masks inside
    /// the image and embeddings of the expected dimension.
    fn check(&self, frame: &Frame, request_id: u64, bytes: &[u8]) -> Result<Vec<Detection>, (Rejection, String)> {
        let reply = wire::decode_reply(bytes).map_err(|e| match e {
            WireError::MaskSize { .. } => (Rejection::MaskSize, e.to_string()),
            e => (Rejection::Garbage, e.to_string()),
        })?;
        // A refusal may come before the worker could read the request's id.
        match &reply.body {
            ReplyBody::Refused(why) => return Err((Rejection::Refused, why.clone())),
            ReplyBody::Failed(why) => return Err((Rejection::Failed, why.clone())),
            ReplyBody::Detections { .. } => {}
        }
        if reply.request_id != request_id || reply.frame_seq != frame.seq {
            return Err((
                Rejection::WrongId,
                format!(
                    "answers request {} for frame {}, asked {request_id} for frame {}",
                    reply.request_id, reply.frame_seq, frame.seq
                ),
            ));
        }
        let (embedding_dim, detections) = match reply.body {
            ReplyBody::Detections { embedding_dim, detections, .. } => (embedding_dim, detections),
            ReplyBody::Refused(why) => return Err((Rejection::Refused, why)),
            ReplyBody::Failed(why) => return Err((Rejection::Failed, why)),
        };
        let carries = detections.iter().any(|d| d.semantic_feature.is_some());
        if carries && embedding_dim != self.contract.embedding_dim {
            return Err((
                Rejection::EmbeddingDim,
                format!("embeddings of dimension {embedding_dim}, expected {}", self.contract.embedding_dim),
            ));
        }
        let k = &frame.intrinsics;
        for (i, d) in detections.iter().enumerate() {
            let m = &d.mask;
            if u64::from(m.x0) + u64::from(m.width) > u64::from(k.width)
                || u64::from(m.y0) + u64::from(m.height) > u64::from(k.height)
            {
                return Err((
                    Rejection::MaskSize,
                    format!(
                        "detection {i}: mask box {}x{} at ({}, {}) leaves the {}x{} image",
                        m.width, m.height, m.x0, m.y0, k.width, k.height
                    ),
                ));
            }
        }
        Ok(detections)
    }
}

/// What one worker did with a request.
enum Asked {
    Answered(Vec<Detection>),
    /// No queryable at its key (the query ended without a reply).
    Gone,
    TimedOut,
    Rejected(Rejection, String),
}

/// The detector of one detection worker thread: remote first, then its own fallback.
pub struct RemoteDetector {
    client: Arc<RemoteClient>,
    fallback: Option<Box<dyn Detector>>,
    request: Vec<u8>,
}

impl std::fmt::Debug for RemoteDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteDetector").field("fallback", &self.fallback.as_ref().map(|d| d.name())).finish()
    }
}

impl RemoteDetector {
    /// A detector that asks `client`'s workers and falls back on `fallback` (`None`: skip).
    pub fn new(client: Arc<RemoteClient>, fallback: Option<Box<dyn Detector>>) -> Self {
        Self { client, fallback, request: Vec::new() }
    }
}

impl Detector for RemoteDetector {
    fn detect(&mut self, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        out.clear();
        let client = &self.client;
        let request_id = client.next_request.fetch_add(1, Ordering::Relaxed);
        wire::encode_request(&mut self.request, request_id, frame, &client.contract, client.config.encoding)
            .map_err(|e| DetectorError::Frame { seq: frame.seq, reason: format!("remote request: {e}") })?;
        let counters = &client.counters;
        if let Some(detections) = client.detect_remote(frame, request_id, &self.request) {
            if counters.fallback_active.swap(false, Ordering::Relaxed) {
                info!(frame_seq = frame.seq, "a detection worker answers again; fallback off");
            }
            *out = detections;
            return Ok(());
        }
        counters.fallback_keyframes.fetch_add(1, Ordering::Relaxed);
        if !counters.fallback_active.swap(true, Ordering::Relaxed) {
            counters.fallback_switches.fetch_add(1, Ordering::Relaxed);
            warn!(
                frame_seq = frame.seq,
                fallback = %client.config.fallback,
                "no detection worker answered within detector.remote.timeout_ms; fallback on"
            );
        }
        match &mut self.fallback {
            Some(fallback) => fallback.detect(frame, out),
            None => Ok(()),
        }
    }

    fn name(&self) -> &str {
        "remote"
    }

    fn remote_counters(&self) -> Option<Arc<RemoteCounters>> {
        Some(self.client.counters.clone())
    }
}

impl Drop for RemoteClient {
    fn drop(&mut self) {
        info!(figures = %self.counters.report(), "remote detection closing");
    }
}

/// Declares worker `id`'s liveliness token under `prefix` (for the worker binary).
pub fn announce(session: &::zenoh::Session, prefix: &str, id: &str) -> Result<LivelinessToken, String> {
    let key = worker_key(prefix, id);
    session.liveliness().declare_token(&key).wait().map_err(|e| format!("declaring the liveliness token {key}: {e}"))
}
