//! The batch runner makes the graph the threaded pipeline makes: same keyframes, same detections,
//! same fusion, when no queue drops a frame (`block` queues, as in `profiles/sim-batch.toml`).
//! The pipeline runs in this process with two detection workers and serves over iceoryx2 under a
//! prefix of its own; its final graph is read back with a real subscriber.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use op3dsg_ipc_types::GraphSubscriber;
use op3dsg_runtime::graph::SceneGraph;
use op3dsg_runtime::ipc::graph_to_scene_graph;
use op3dsg_runtime::pipeline::Pipeline;
use op3dsg_sim::batch;

const FRAMES: u64 = 120;

#[test]
fn batch_runner_makes_the_threaded_pipelines_graph() {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let prefix = format!("op3dsg-test-batch-{}", std::process::id());
    let sim_batch = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../profiles/sim-batch.toml");
    let sets = [
        format!("source.synthetic.frame_count={FRAMES}"),
        format!("ipc.prefix={prefix}"),
        "detector.workers=2".to_owned(),
        // Keep serving the final graph until this test has read it.
        "run.exit_at_end=false".to_owned(),
        "health.period_ms=100".to_owned(),
    ];
    let profile = op3dsg_sim::load_profile(Some(&sim_batch), &sets).expect("profile").profile;

    let batch_run = batch::run(&profile, &batch::VisibilityThresholds::default()).expect("batch run");
    assert!(batch_run.graph.nodes.len() >= 5, "a graph worth comparing: {} nodes", batch_run.graph.nodes.len());

    let stop = Arc::new(AtomicBool::new(false));
    let pipeline = Pipeline::start(&profile, &op3dsg_sim::backends(), stop.clone()).expect("pipeline starts");
    let mut graphs =
        GraphSubscriber::open_wait(&prefix, "batch-determinism", Duration::from_secs(30)).expect("graph subscriber");
    let stats = pipeline.counters().clone();
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut latest: Option<SceneGraph> = None;
    let mut settled_since: Option<(u64, Instant)> = None;
    let pipeline_graph = loop {
        assert!(Instant::now() < deadline, "the pipeline did not finish within 120 s");
        if let Some(graph) = graphs.latest_if_newer(latest.as_ref().map_or(0, |g| g.version)).expect("read graph") {
            latest = Some(graph_to_scene_graph(graph));
        }
        let version = stats.fusion.graph_version.load(Ordering::Relaxed);
        let drained = stats.capture.source_finished.load(Ordering::Relaxed)
            && stats.fusion.detections_fused.load(Ordering::Relaxed) == batch_run.detections;
        let received = latest.as_ref().is_some_and(|g| g.version == version);
        if drained && received {
            // The final graph is published right after the last keyframe is fused; wait a little
            // to be sure no later version follows.
            match settled_since {
                Some((v, since)) if v == version && since.elapsed() > Duration::from_millis(500) => {
                    break latest.take().expect("received");
                }
                Some((v, _)) if v == version => {}
                _ => settled_since = Some((version, Instant::now())),
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    stop.store(true, Ordering::SeqCst);
    let summary = pipeline.wait().expect("pipeline stops");

    assert_eq!(summary.frames, batch_run.frames);
    assert_eq!(summary.keyframes, batch_run.keyframes);
    assert_eq!(pipeline_graph.stamp_ns, batch_run.graph.stamp_ns);
    // The iceoryx2 record carries neither the first-seen stamp nor the missing state yet.
    let on_the_wire: Vec<_> = batch_run
        .graph
        .nodes
        .iter()
        .map(|n| op3dsg_runtime::graph::GraphNode { first_seen_stamp_ns: 0, missing: false, ..n.clone() })
        .collect();
    assert_eq!(pipeline_graph.nodes, on_the_wire);
    assert_eq!(pipeline_graph.edges, batch_run.graph.edges);
}
