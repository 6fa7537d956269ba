//! `op3dsg bench perf` at CI size (30 frames, two small graph and map sizes, a few messages):
//! it runs the real pipeline, spawns its IPC subscriber process, and writes JSON, Markdown and a
//! PNG whose figures are sane. No timing is asserted; the release figures are in docs/benchmarks.md.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_sim::perf::{Percentiles, PerfReport, REPORT_SCHEMA};

const FRAMES: u64 = 30;
const IPC_NODES: [usize; 2] = [100, 300];
const IPC_MESSAGES: usize = 5;

fn sane(p: &Percentiles, what: &str) {
    for (name, v) in [("p50", p.p50_ms), ("p99", p.p99_ms), ("mean", p.mean_ms), ("max", p.max_ms)] {
        assert!(v.is_finite() && v > 0.0, "{what}: {name} = {v}");
    }
    assert!(p.count > 0, "{what}: no samples");
    assert!(p.p50_ms <= p.p99_ms && p.p99_ms <= p.max_ms * 1.04, "{what}: {p:?}");
}

fn run_bench(dir: &Path) -> std::process::Output {
    let child = Command::new(env!("CARGO_BIN_EXE_op3dsg"))
        .current_dir(dir)
        .env("RUST_LOG", "warn")
        .args(["bench", "perf", "--frames", &FRAMES.to_string()])
        .args(["--ipc-nodes", "100,300", "--ipc-messages", &IPC_MESSAGES.to_string(), "--ipc-warmup", "2"])
        .args(["--fusion-sizes", "100,300", "--fusion-steps", "5", "--fusion-keyframes", "4"])
        .args(["--rss-period-ms", "50", "--json", "perf.json", "--markdown", "perf.md", "--plot", "fusion.png"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start op3dsg bench perf");
    // Watchdog: a hung subscriber or pipeline must fail the test, not hang CI.
    let deadline = Instant::now() + Duration::from_secs(600);
    let mut child = child;
    loop {
        if child.try_wait().expect("poll").is_some() {
            return child.wait_with_output().expect("output");
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("op3dsg bench perf did not finish within 600 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn bench_perf_runs_and_reports_sane_figures() {
    let dir = tempfile::tempdir().expect("temp dir");
    let output = run_bench(dir.path());
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "bench perf failed: {}\n{stderr}", output.status);

    let text = std::fs::read_to_string(dir.path().join("perf.json")).expect("perf.json");
    let report: PerfReport = serde_json::from_str(&text).expect("valid report JSON");
    assert_eq!(report.schema, REPORT_SCHEMA);
    assert!(report.machine.cores >= 1);
    assert!(report.command.starts_with("op3dsg bench perf --frames 30"), "{}", report.command);

    // Pipeline: both runs, every stage measured.
    assert_eq!(report.pipeline.len(), 2);
    for run in &report.pipeline {
        assert_eq!(run.frames, FRAMES, "{}", run.mode);
        assert!(run.keyframes > 0 && run.keyframes <= FRAMES, "{}: {} keyframes", run.mode, run.keyframes);
        assert!(run.keyframes_per_s.is_finite() && run.keyframes_per_s > 0.0);
        assert!(run.frames_per_s >= run.keyframes_per_s);
        assert!(run.graph_versions > 0 && run.map_nodes > 0, "{}", run.mode);
        let names: Vec<&str> = run.stages.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["capture", "keyframe", "detection", "fusion", "prior", "publish", "end_to_end"]);
        for stage in &run.stages {
            sane(&stage.latency, &format!("{} {}", run.mode, stage.name));
        }
        let count = |name: &str| run.stages.iter().find(|s| s.name == name).map_or(0, |s| s.latency.count);
        assert_eq!(count("capture"), FRAMES);
        // Latest-wins queues may drop keyframes (camera rate) and graph versions (both runs).
        assert!(count("detection") <= run.keyframes && count("fusion") == count("detection"));
        assert!(count("prior") <= run.graph_versions && count("publish") <= run.graph_versions);
        assert_eq!(count("end_to_end"), count("publish"));
        assert_eq!(run.end_to_end.count, count("publish"));
        // A graph cannot be published before the keyframe it holds was detected.
        let p50 = |name: &str| run.stages.iter().find(|s| s.name == name).map_or(0.0, |s| s.latency.p50_ms);
        assert!(run.end_to_end.max_ms >= p50("detection") * 0.97, "{}: {:?}", run.mode, run.end_to_end);
        assert!(run.rss.len() >= 2, "{}: {} RSS samples", run.mode, run.rss.len());
        assert!(run.rss.iter().all(|r| r.rss_mib.is_finite() && r.rss_mib > 0.0));
        assert!(run.rss.windows(2).all(|w| w[0].t_s <= w[1].t_s));
        assert!(run.rss_peak_mib() >= run.rss_start_mib());
    }

    // IPC: one row per size, owned graph, view and raw measured in the same run.
    let ipc = report.ipc.as_ref().expect("IPC section");
    assert_eq!(ipc.messages, IPC_MESSAGES);
    assert_eq!(ipc.rows.iter().map(|r| r.nodes).collect::<Vec<_>>(), IPC_NODES);
    for row in &ipc.rows {
        sane(&row.graph, &format!("graph {}", row.nodes));
        sane(&row.raw, &format!("raw {}", row.nodes));
        assert_eq!(row.graph.count as usize, IPC_MESSAGES);
        sane(&row.graph_publish_call, &format!("graph publish call {}", row.nodes));
        sane(&row.raw_publish_call, &format!("raw publish call {}", row.nodes));
        sane(&row.graph_read_call, &format!("graph read call {}", row.nodes));
        assert_eq!(row.graph_read_call.count as usize, IPC_MESSAGES);
        let header = size_of::<op3dsg_ipc_types::GraphHeader>();
        assert_eq!(row.bytes, header + row.nodes * 144 + row.edges * 64, "header and records, nothing more");
        assert!(row.ratio_p50.is_finite() && row.ratio_p50 > 0.0);
        assert!(row.ratio_p99.is_finite() && row.ratio_p99 > 0.0);
        // The zero-copy view, measured in the same run.
        sane(&row.view, &format!("view {}", row.nodes));
        sane(&row.view_publish_call, &format!("view publish call {}", row.nodes));
        sane(&row.view_read_call, &format!("view read call {}", row.nodes));
        assert_eq!((row.view.count as usize, row.view_read_call.count as usize), (IPC_MESSAGES, IPC_MESSAGES));
        assert!(row.view_ratio_p50.is_finite() && row.view_ratio_p50 > 0.0);
        assert!(row.view_ratio_p99.is_finite() && row.view_ratio_p99 > 0.0);
    }
    assert!(ipc.rows[1].bytes > ipc.rows[0].bytes);

    // Fusion: maps grow, every step measured.
    let fusion = report.fusion.as_ref().expect("fusion section");
    assert_eq!(fusion.points.len(), 2);
    assert!(fusion.detections > 0 && fusion.objects > 0 && fusion.parts > 0);
    for p in &fusion.points {
        sane(&p.step, &format!("fusion at {} nodes", p.nodes));
        sane(&p.step_off, &format!("fusion with change handling off at {} nodes", p.nodes));
        assert_eq!(p.evidence.count, p.step.count, "the evidence step of every step");
        assert!(p.evidence.p99_ms <= p.step.max_ms, "the evidence step is part of the step: {p:?}");
        assert!(p.nodes > 0 && p.memory_mib > 0.0);
    }
    assert!(fusion.points[1].copies > fusion.points[0].copies);

    // Both fusions per keyframe on the same keyframes: ours, then the peer baseline's.
    let peer = report.peer_fusion.as_ref().expect("peer fusion section");
    assert_eq!(peer.keyframes, 4);
    assert!(peer.detections > 0);
    let names: Vec<&str> = peer.fusions.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["OP3DSG multi-view fusion", op3dsg_sim::conceptgraphs::PEER_ROW]);
    for f in &peer.fusions {
        sane(&f.keyframe, &f.name);
        assert_eq!(f.keyframe.count, 4, "{}", f.name);
        assert!(f.map_nodes > 0 && f.build_graph_ms >= 0.0, "{}", f.name);
    }

    // Markdown on stdout and in the file; a PNG of the plot size.
    let markdown = std::fs::read_to_string(dir.path().join("perf.md")).expect("perf.md");
    assert_eq!(markdown, stdout);
    for needle in [
        "### Performance",
        "| capture |",
        "| prior |",
        "| end_to_end |",
        "| 300 |",
        "| view, first node |",
        "fusion.png",
        "| peer: ConceptGraphs fusion |",
        "| evidence p50 ms | evidence p99 ms | step p99 ms, change handling off | p99 on / off |",
    ] {
        assert!(markdown.contains(needle), "markdown lacks {needle:?}:\n{markdown}");
    }
    let png = image::open(dir.path().join("fusion.png")).expect("a readable PNG").to_rgb8();
    assert_eq!(png.dimensions(), op3dsg_sim::perf::fusion_curve::PLOT_SIZE);
    assert!(png.pixels().any(|p| p.0 != [255, 255, 255]), "blank plot");
}

#[test]
fn bench_perf_rejects_bad_sizes_naming_the_option() {
    let output = Command::new(env!("CARGO_BIN_EXE_op3dsg"))
        .args(["bench", "perf", "--ipc-nodes", "100,99999"])
        .output()
        .expect("run op3dsg");
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("--ipc-nodes 99999"), "{stderr}");
}
