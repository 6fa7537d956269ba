//! The daemon's pipeline: named threads connected by bounded queues.
//!
//! ```text
//! capture ──[frames]──► keyframe gate ──[keyframes]──► detect/0..N-1 ──[detections]──► fusion ──[graph]──► publisher
//!  source,                pose lookup,                  one Detector                    sole owner     iceoryx2: graph,
//!  frame pool             motion gate                   per worker                      of the map     event, health;
//!                           ▲                                                                          pose input
//!                           └──────────────────────────── poses (from <prefix>/pose) ◄──────────────────┘
//! ```
//!
//! Health reports one latency entry per stage: `capture`, `keyframe`, `detect/0..N-1`, `fusion`
//! (one keyframe's integration), `prior` (prior graph + reasoner, once per published version, on
//! the fusion thread), `publish`, and `end_to_end`: from the moment the source delivered a
//! keyframe to the send of the first graph version holding it (queueing included).
//!
//! Workers take keyframes under a ticket lock, so every keyframe they take gets a gapless ticket;
//! fusion applies results strictly in ticket order (a small reorder buffer), which keeps the map
//! deterministic whatever the number of workers.
//!
//! With `reasoner.kind = "llm"` the fusion thread also owns the LLM refiner (thread `op3dsg-llm`,
//! `crate::reasoner::llm`): it hands each prior graph over (latest wins) and picks up verified
//! results without ever waiting; the refiner's counters are part of the health record.
//!
//! ## Shutdown ladder (SIGINT / SIGTERM, `run.max_frames`, or the end of a finite source)
//! 1. The stop flag is set (or the source ends): capture stops reading, returns its frames to the
//!    pool and closes the `frames` queue.
//! 2. The keyframe gate drains `frames`, then closes `keyframes`.
//! 3. Each worker finishes the keyframe it holds and exits; the last one closes `detections`.
//! 4. Fusion applies every result it received, publishes the final graph into `graph`, hands the
//!    final map snapshot to the snapshot writer (which writes it and exits) and exits (stopping
//!    the LLM refiner, which abandons any request in flight).
//! 5. The publisher sends that final graph and a last health record, then releases its iceoryx2
//!    services. At the end of a finite source without `run.exit_at_end` it keeps serving instead
//!    until a signal arrives.
//! 6. `query-rx` and `query` (the language query service, `crate::query`) end with the
//!    stop flag, or once the publisher has ended; requests still queued get a `shutting_down`
//!    reply.
//! 7. `occupancy` (the occupancy map, `crate::occupancy`) integrates what the gate
//!    queued and ends with the stop flag, or once the gate has ended with `run.exit_at_end`,
//!    after a last publish of the map.
//!
//! A stage that has not finished `run.shutdown_timeout_s` after the stop is named in the log and
//! the daemon exits with an error; a second signal exits at once (see the `op3dsgd` binary).
//!
//! This module wires the stages and nothing else: each stage's thread is a struct of the stage
//! (`CaptureThread`, `KeyframeThread`, `DetectThread`, `FusionThread`, `PublishThread`, ...)
//! built here from the profile (`stages.rs`) and spawned by name; the counters of every stage
//! are held together in [`Counters`], which the publisher reads as a
//! [`crate::stats::HealthSource`].

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use op3dsg_drivers::source::{FrameSource, StepControl};
use tracing::{debug, error, info};

use crate::backend::{Backends, OpenedSource, StartError};
use crate::config::Profile;
use crate::keyframe::PoseSourceKind;
use crate::query::QueryCounters;
use crate::queue::Latest;
use crate::reasoner::{EnricherError, EnricherSetup, GraphEnricher};
use crate::zenoh::ZenohSession;

mod counters;
mod off_robot;
mod stages;
#[cfg(feature = "zenoh")]
mod zenoh_stages;

pub use counters::{Counters, RunSummary};
use stages::{Queues, Stages};

/// A running pipeline.
pub struct Pipeline {
    stop: Arc<AtomicBool>,
    query_counters: Option<Arc<QueryCounters>>,
    step_control: Option<StepControl>,
    counters: Arc<Counters>,
    stages: Stages,
    shutdown_timeout: Duration,
    /// The process's Zenoh session, closed once every stage has ended.
    zenoh: Option<ZenohSession>,
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline").field("running", &self.stages.running).finish_non_exhaustive()
    }
}

/// The prior graph + reasoner the profile asks for (`[reasoner]`, and the text encoder when
/// `[text_encoder] enabled`), shared by the pipeline and the batch runner.
pub fn make_enricher(profile: &Profile) -> Result<Option<GraphEnricher>, StartError> {
    let setup = EnricherSetup {
        reasoner: &profile.reasoner,
        up_axis: profile.world.up_axis,
        text_encoder: profile.text_encoder.enabled.then_some((&profile.onnx, &profile.text_encoder)),
    };
    GraphEnricher::from_setup(setup).map_err(|e| match e {
        EnricherError::Knowledge(e) => {
            StartError::Incompatible { field: "reasoner.knowledge_dir", reason: e.to_string() }
        }
        EnricherError::Llm { field, reason } => StartError::Incompatible { field, reason },
        EnricherError::TextEncoder(reason) => StartError::Incompatible { field: "text_encoder", reason },
    })
}

/// `pose.source = "frame"` needs a source whose frames carry their pose.
fn check_pose_source(profile: &Profile, source: &dyn FrameSource) -> Result<(), StartError> {
    if profile.pose.source == PoseSourceKind::Frame && !source.has_poses() {
        return Err(StartError::Incompatible {
            field: "pose.source",
            reason: format!("{} carries no poses; use pose.source = \"ipc\"", source.describe()),
        });
    }
    Ok(())
}

impl Pipeline {
    /// Opens the source and the iceoryx2 services and starts every stage, with the source,
    /// detector and fusion `backends` the profile names. Returns once the services exist (the
    /// daemon may then report ready).
    pub fn start(profile: &Profile, backends: &Backends, stop: Arc<AtomicBool>) -> Result<Self, StartError> {
        // One Zenoh session for the Zenoh stage and remote detection alike.
        let zenoh = crate::backend::zenoh_session(profile)?;
        let (opened, detector_factory) = backends.open(profile, zenoh.as_ref())?;
        let side_taps = backends.source(&profile.source.kind)?.side_channel_taps(&opened);
        let OpenedSource { source, .. } = opened;
        check_pose_source(profile, source.as_ref())?;
        info!(
            source = %source.describe(),
            source_kind = source.kind().describe(),
            world_frame = %profile.world.frame_id,
            workers = profile.detector.workers,
            "starting pipeline"
        );
        let step_control = source.step_control();
        let q = Queues::new(profile, &stop, source.lossless());
        // Before the counters: the LLM refiner (if any) owns its own.
        let enricher = make_enricher(profile)?;
        let refiner = enricher.as_ref().and_then(GraphEnricher::refiner_stats).unwrap_or_default();
        let mut counters = Counters::new(profile.detector.workers, q.stats.clone(), refiner);
        // The detectors before the counters are shared: remote detection brings its own figures.
        let detectors: Vec<_> = (0..counters.detect.len()).map(|worker| detector_factory(worker as u32)).collect();
        counters.remote = detectors.iter().find_map(|d| d.remote_counters());
        counters.zenoh = profile.zenoh.enabled.then(Arc::default);
        counters.ros2_tf = (profile.pose.source == PoseSourceKind::Ros2).then(Arc::default);
        counters.ros2_out = profile.ros2.out.any().then(Arc::default);
        counters.live_view = profile.live_view.enabled.then(Arc::default);
        let counters = Arc::new(counters);
        let stages::RestoredMap { fusion, resume, snapshots } = stages::restored_map(profile, backends, &counters)?;
        if resume.restored && source.lossless() {
            tracing::warn!(
                graph_version = resume.graph_version,
                "this replay starts from the map restored from the snapshot folder, not from the recording's start, \
                 so its graph is not the recorded one (snapshot.enabled = false replays from an empty map)"
            );
        }
        let (snapshot_sink, snapshot_writer) = snapshots.unzip();
        let mut s = Stages::new();
        // The recorder first, so it is there before anything is produced; it ends after the last
        // producer (the publisher) has dropped its sender.
        let recorder = stages::recorder(profile, source.intrinsics(), &side_taps, &counters)?
            .map(|(sender, thread)| s.spawn("record", move || thread.run()).map(|()| sender));
        let recorder = recorder.transpose()?;
        // The query service's view of the graph: the publisher fills it.
        let query_graph = profile.query.enabled.then(|| Arc::new(Latest::new()));
        // The Zenoh stage before the publisher that feeds it; the query service, started
        // below, fills in its intake for `<prefix>/query`.
        let remote_queries = crate::flow::RemoteQueries::default();
        // The occupancy thread's copy of its map, for the query worker and the Zenoh stage.
        let ros2_map = profile.ros2.out.occupancy;
        let latest_occupancy = (profile.occupancy.enabled
            && (query_graph.is_some() || profile.zenoh.enabled || ros2_map || profile.live_view.enabled))
            .then(|| Arc::new(Latest::new()));
        let shared = (remote_queries.clone(), latest_occupancy.clone(), zenoh.clone());
        let mut remote =
            off_robot::stages(&mut s, profile, source.kind(), (q.remote, q.ros2_out), &counters, shared, &stop)?;
        // The live view, fed like the off-robot stages; the gate hands it poses and images.
        let inputs = (source.intrinsics(), latest_occupancy.clone());
        let live = stages::live_view(&mut s, profile, (q.live_view, &mut remote), inputs, &counters, &stop)?;
        let (publisher, ready) = stages::publisher(
            profile,
            source.kind(),
            (q.graph.1, q.poses.0.clone()),
            &counters,
            &stop,
            recorder.clone(),
            (query_graph.clone(), remote),
        );
        s.spawn_serving("publish", &ready, move || publisher.run())?;
        // The occupancy map, fed by the keyframe gate.
        let occupancy_feed = if profile.occupancy.enabled {
            let (thread, feed) = stages::occupancy(profile, &source.intrinsics(), latest_occupancy.clone(), &stop)?;
            s.spawn("occupancy", move || thread.run())?;
            Some(feed)
        } else {
            None
        };
        let query_counters = match query_graph {
            Some(latest) => Some(stages::query(&mut s, profile, latest, latest_occupancy, &stop, &remote_queries)?),
            None => None,
        };
        if let Some(writer) = snapshot_writer {
            s.spawn("snapshot", move || writer.run())?;
        }
        let map = (fusion, resume, snapshot_sink);
        let fusion = stages::fusion(profile, map, enricher, (q.detections.1, q.graph.0), &counters, recorder.clone());
        s.spawn("fusion", move || fusion.run())?;
        stages::detectors(&mut s, detectors, q.keyframes.1, &q.detections.0, &counters)?;
        drop(q.detections.0);
        let recorder = recorder.map(|sender| (sender, side_taps));
        let gate = (q.frames.1, q.keyframes.0, q.poses.1);
        // The tf input hands poses to the gate and ends with it.
        let gate_alive = off_robot::tf_input(&mut s, profile, source.as_ref(), q.poses.0.clone(), &counters, &stop)?;
        let keyframe =
            stages::keyframe(profile, source.as_ref(), gate, &counters, &stop, recorder, (occupancy_feed, live));
        s.spawn("keyframe", move || {
            let _alive = gate_alive;
            keyframe.run();
        })?;
        // Capture last, so every consumer is ready.
        let capture = stages::capture(profile, source, q.frames.0, q.poses.0, &counters, &stop);
        s.spawn("capture", move || capture.run())?;
        let shutdown_timeout = Duration::from_secs_f64(profile.run.shutdown_timeout_s);
        Ok(Self { stop, query_counters, step_control, counters, stages: s, shutdown_timeout, zenoh })
    }

    /// The handle that releases frames of a stepped source (`[source.replay] mode = "stepped"`):
    /// each `step(n)` lets `n` more frames into the pipeline. `None` for other sources and modes.
    pub fn step_control(&self) -> Option<&StepControl> {
        self.step_control.as_ref()
    }

    /// The query service's counters (`None` with `query.enabled = false`).
    pub fn query_counters(&self) -> Option<&Arc<QueryCounters>> {
        self.query_counters.as_ref()
    }

    /// Every stage's counters (for tests, the service status and the binary's summary).
    pub fn counters(&self) -> &Arc<Counters> {
        &self.counters
    }

    /// Waits until every stage has ended: after the stop flag is set (signal), or by itself
    /// when the source ended with `run.exit_at_end` / `run.max_frames`. Fails naming the stuck
    /// stages when they do not end within the shutdown timeout after a stop.
    pub fn wait(mut self) -> Result<RunSummary, Vec<&'static str>> {
        let mut stop_seen_at: Option<Instant> = None;
        while !self.stages.running.is_empty() {
            if let Ok(name) = self.stages.finished_rx.recv_timeout(Duration::from_millis(50)) {
                self.stages.running.retain(|n| *n != name);
                debug!(stage = name, "stage ended");
                continue;
            }
            if self.stop.load(Ordering::Relaxed) {
                let since = *stop_seen_at.get_or_insert_with(Instant::now);
                if since.elapsed() > self.shutdown_timeout {
                    error!(stages = ?self.stages.running, "stages did not end within the shutdown timeout");
                    return Err(self.stages.running.clone());
                }
            }
        }
        for handle in self.stages.handles.drain(..) {
            let _ = handle.join();
        }
        if let Some(session) = self.zenoh.take() {
            session.close();
        }
        Ok(RunSummary::of(&self.counters))
    }
}
