//! The warnings `op3dsg watch` lists: derived from the health records and graphs it receives.
//!
//! The daemon publishes no warning text over IPC (its warnings go to its log, `journalctl -u
//! op3dsgd`), so the view says what the records show went wrong: frames without a pose, refused
//! poses, queue drops, stage errors, a disconnected source, a restarted daemon, a graph over its
//! capacity, LLM refiner failures and an open breaker, failed snapshot writes, recorder drops, tf
//! time jumps and refused transforms, remote detection's fallback taking over and its workers'
//! timeouts, late and rejected replies, a model on another execution provider than asked. A
//! counter reads as what it grew by between records (the first record: since the daemon
//! started); each kind of warning is kept once, newest first, with its total while watched.

use std::collections::VecDeque;
use std::time::Instant;

use op3dsg_ipc_types::Graph;
use op3dsg_runtime::ipc::{HealthReport, RemoteReport, RemoteWorkerReport};

/// Kinds of warnings kept (the oldest go first).
const KEPT: usize = 32;

/// One kind of warning.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Warning {
    /// What it is about (one entry per key).
    key: String,
    /// What went wrong, in words.
    pub(super) text: String,
    /// For a counter: the total seen while watching (the first record's: since start).
    pub(super) total: Option<u64>,
    /// When it was last seen.
    pub(super) at: Instant,
}

/// The warnings seen so far and the record they were derived from.
#[derive(Debug, Default)]
pub(super) struct Warnings {
    /// Newest first.
    entries: VecDeque<Warning>,
    /// The previous record.
    last: Option<HealthReport>,
    /// Whether the previous graph exceeded its capacity, and its daemon instance.
    last_graph: Option<(bool, u64)>,
}

impl Warnings {
    /// The warnings, newest first.
    pub(super) fn recent(&self) -> impl Iterator<Item = &Warning> {
        self.entries.iter()
    }

    /// Adds (or refreshes) a warning; `grew` is a counter's increase, `None` for a state.
    fn note(&mut self, key: String, text: String, grew: Option<u64>, at: Instant) {
        let total = match self.entries.iter().position(|w| w.key == key) {
            Some(i) => self.entries.remove(i).and_then(|w| w.total),
            None => None,
        };
        let total = grew.map(|n| total.unwrap_or(0) + n);
        self.entries.push_front(Warning { key, text, total, at });
        self.entries.truncate(KEPT);
    }

    /// A counter's growth since the previous record: a warning when it grew.
    fn counter(&mut self, key: String, text: impl FnOnce() -> String, before: u64, now: u64, at: Instant) {
        if now > before {
            self.note(key, text(), Some(now - before), at);
        }
    }

    /// Derives the warnings of a graph: over its capacity, or from a restarted daemon.
    pub(super) fn observe_graph(&mut self, graph: &Graph, at: Instant) {
        let exceeded = graph.capacity_exceeded();
        let instance = graph.instance_id();
        if let Some((was_exceeded, was_instance)) = self.last_graph {
            if instance != was_instance {
                self.note("restart".into(), "daemon restarted (a new instance publishes)".into(), None, at);
            }
            if exceeded && !was_exceeded {
                self.note("capacity".into(), "graph capacity exceeded: samples hold part of the map".into(), None, at);
            }
        } else if exceeded {
            self.note("capacity".into(), "graph capacity exceeded: samples hold part of the map".into(), None, at);
        }
        self.last_graph = Some((exceeded, instance));
    }

    /// Derives the warnings of a new health record from the change since the previous one.
    pub(super) fn observe(&mut self, h: &HealthReport, at: Instant) {
        let restarted = self.last.as_ref().is_some_and(|p| h.uptime_s < p.uptime_s);
        let before = if restarted { None } else { self.last.take() };
        if restarted {
            self.note("restart".into(), "daemon restarted (uptime went back)".into(), None, at);
        }
        let zero = HealthReport { source_connected: true, ..h.clone() };
        let was = before.as_ref().unwrap_or(&zero);
        if !h.source_connected && (was.source_connected || before.is_none()) {
            self.note("source".into(), format!("source {} disconnected", h.source_kind), None, at);
        } else if h.source_connected && !was.source_connected {
            self.note("source".into(), format!("source {} connected again", h.source_kind), None, at);
        }
        let first = before.is_none();
        let old = |v: u64| if first { 0 } else { v };
        self.counter(
            "no-pose".into(),
            || "frames dropped without a pose".into(),
            old(was.frames_without_pose),
            h.frames_without_pose,
            at,
        );
        for (outcome, n) in h.poses.iter().filter(|(outcome, _)| *outcome != "accepted") {
            let b = old(was.poses.get(outcome).copied().unwrap_or(0));
            self.counter(format!("pose:{outcome}"), || format!("poses refused: {outcome}"), b, *n, at);
        }
        for q in &h.queues {
            let b = old(was.queues.iter().find(|p| p.name == q.name).map_or(0, |p| p.dropped));
            self.counter(format!("queue:{}", q.name), || format!("queue {} dropped items", q.name), b, q.dropped, at);
        }
        for s in &h.stages {
            let b = old(was.stages.iter().find(|p| p.name == s.name).map_or(0, |p| u64::from(p.errors)));
            self.counter(format!("stage:{}", s.name), || format!("stage {} errors", s.name), b, s.errors.into(), at);
        }
        self.observe_subsystems(h, was, first, at);
        self.last = Some(h.clone());
    }

    /// The refiner, snapshots, recorder, tf input and models.
    fn observe_subsystems(&mut self, h: &HealthReport, was: &HealthReport, first: bool, at: Instant) {
        let old = |v: u64| if first { 0 } else { v };
        let r = &h.refiner;
        if r.breaker_open && (first || !was.refiner.breaker_open) {
            self.note(
                "llm-breaker".into(),
                format!("llm refiner breaker open (last error {})", r.last_error),
                None,
                at,
            );
        }
        let text = || format!("llm refiner calls failed (last error {})", r.last_error);
        self.counter("llm-failures".into(), text, old(was.refiner.failures), r.failures, at);
        let (snapshot, recorder) = (&h.snapshot, &h.recorder);
        self.counter(
            "snapshot".into(),
            || "snapshot writes failed".into(),
            old(was.snapshot.failures),
            snapshot.failures,
            at,
        );
        self.counter(
            "recorder".into(),
            || "recorder dropped messages".into(),
            old(was.recorder.messages_dropped),
            recorder.messages_dropped,
            at,
        );
        if let Some(tf) = &h.tf {
            let was_tf = was.tf.clone().filter(|_| !first).unwrap_or_default();
            let jumps = || "tf time went back: dynamic transforms cleared".into();
            self.counter("tf-jumps".into(), jumps, was_tf.time_jumps, tf.time_jumps, at);
            let refused = || "tf transforms refused".into();
            self.counter("tf-refused".into(), refused, was_tf.transforms_refused, tf.transforms_refused, at);
        }
        if let Some(remote) = &h.remote {
            self.observe_remote(remote, was.remote.as_ref().filter(|_| !first), at);
        }
        if first {
            for m in h.models.iter().filter(|m| m.provider != m.requested_provider) {
                let text = format!("model {} runs on {} (asked for {})", m.name, m.provider, m.requested_provider);
                self.note(format!("model:{}", m.name), text, None, at);
            }
        }
    }
}

impl Warnings {
    /// Remote detection: the fallback taking over, and each worker's timeouts, late replies,
    /// rejections and disappearance.
    fn observe_remote(&mut self, r: &RemoteReport, was: Option<&RemoteReport>, at: Instant) {
        let was_switches = was.map_or(0, |w| w.fallback_switches);
        let fallback = || "remote detection: no worker answered, keyframes went to the fallback".into();
        self.counter("remote-fallback".into(), fallback, was_switches, r.fallback_switches, at);
        for w in &r.workers {
            let before = was.and_then(|p| p.workers.iter().find(|p| p.key == w.key));
            let old = |f: fn(&RemoteWorkerReport) -> u64| before.map_or(0, f);
            let key = &w.key;
            let timeouts = || format!("remote worker {key}: requests timed out");
            self.counter(format!("remote-timeouts:{key}"), timeouts, old(|p| p.timeouts), w.timeouts, at);
            let late = || format!("remote worker {key}: late replies dropped");
            self.counter(format!("remote-late:{key}"), late, old(|p| p.late), w.late, at);
            let rejected = |p: &RemoteWorkerReport| p.rejections.values().sum::<u64>();
            let text = || format!("remote worker {key}: replies rejected");
            self.counter(format!("remote-rejected:{key}"), text, old(rejected), rejected(w), at);
            if !w.alive && before.is_none_or(|p| p.alive) {
                self.note(format!("remote-gone:{key}"), format!("remote worker {key} is gone"), None, at);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::Health;

    use super::*;

    fn report(f: impl FnOnce(&mut Health)) -> HealthReport {
        let mut health = Health { source_connected: 1, uptime_ns: 10_000_000_000, ..Health::default() };
        health.queue_count = 1;
        op3dsg_ipc_types::write_fixed_str(&mut health.queues[0].name, "frames");
        health.stage_count = 1;
        op3dsg_ipc_types::write_fixed_str(&mut health.stages[0].name, "fusion");
        f(&mut health);
        HealthReport::from(&health)
    }

    fn texts(w: &Warnings) -> Vec<(String, Option<u64>)> {
        w.recent().map(|w| (w.text.clone(), w.total)).collect()
    }

    #[test]
    fn counters_warn_by_what_they_grew_and_each_kind_is_kept_once_newest_first() {
        let mut w = Warnings::default();
        let at = Instant::now();
        w.observe(&report(|_| {}), at);
        assert!(texts(&w).is_empty(), "a healthy daemon: no warning");
        w.observe(&report(|h| h.queues[0].dropped = 3), at);
        w.observe(&report(|h| (h.queues[0].dropped, h.stages[0].errors) = (3, 2)), at);
        w.observe(&report(|h| (h.queues[0].dropped, h.stages[0].errors) = (7, 2)), at);
        assert_eq!(
            texts(&w),
            [("queue frames dropped items".into(), Some(7)), ("stage fusion errors".into(), Some(2))],
            "the queue's 3 then 4, newest first"
        );
    }

    #[test]
    fn the_first_record_reports_since_start_and_states_warn_on_change() {
        let mut w = Warnings::default();
        let at = Instant::now();
        w.observe(&report(|h| (h.frames_without_pose, h.pose.stale, h.source_connected) = (5, 2, 0)), at);
        let seen = texts(&w);
        assert!(seen.contains(&("frames dropped without a pose".into(), Some(5))), "{seen:?}");
        assert!(seen.contains(&("poses refused: stale".into(), Some(2))), "{seen:?}");
        assert!(seen.contains(&("source unknown disconnected".into(), None)), "{seen:?}");
        w.observe(&report(|h| (h.frames_without_pose, h.pose.stale) = (5, 2)), at);
        assert_eq!(texts(&w)[0], ("source unknown connected again".into(), None));
        // A restart: counters start again, and it says so.
        w.observe(&report(|h| (h.uptime_ns, h.refiner.breaker_open, h.refiner.last_error) = (1, 1, 2)), at);
        let seen = texts(&w);
        assert!(seen.contains(&("daemon restarted (uptime went back)".into(), None)), "{seen:?}");
        assert!(seen.contains(&("llm refiner breaker open (last error refused)".into(), None)), "{seen:?}");
    }

    #[test]
    fn tf_input_warns_on_time_jumps() {
        let mut w = Warnings::default();
        let at = Instant::now();
        w.observe(&report(|h| h.tf.active = 1), at);
        w.observe(&report(|h| (h.tf.active, h.tf.time_jumps) = (1, 1)), at);
        assert_eq!(texts(&w), [("tf time went back: dynamic transforms cleared".into(), Some(1))]);
    }
}
