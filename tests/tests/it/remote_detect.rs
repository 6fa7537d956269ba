//! Remote detection with real processes over loopback: `op3dsgd` with `detector.kind =
//! "remote"` listens on a free port, `op3dsg-detectd` workers (YOLOX-nano, CPU execution
//! provider, `profiles/replay-icl.toml`'s detector) connect to it; multicast scouting stays off.
//!
//! - On the ICL-NUIM replay, two workers give the graph the same detector gives locally, every
//!   keyframe answered remotely and both workers used.
//! - On the synthetic kitchen (endless): killing one worker moves its keyframes to the other;
//!   killing both switches to the local fallback, and a returning worker takes over again.
//! - With the Zenoh stage on as well, the two share the daemon's one session: a worker that
//!   connects to the daemon and one the daemon connects to both answer, and an outside Zenoh
//!   consumer holds the same graph.
//! - Workers that answer garbage, late, for another request, with a mask outside the image or
//!   with embeddings of another dimension are rejected and counted by reason
//!   (`OP3DSG_DETECTD_FAULT`, built with `--features op3dsgd/fault-hooks`).
//!
//! The daemon's figures come from its `<prefix>/detect_status` queryable. Needs `.models/` and
//! the shared development data (skips with a message when absent, fails in CI).

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use op3dsg_tests::{Daemon, binary, unique_prefix};
use serde_json::Value;

use crate::remote_common;
use remote_common::{Status, StatusWatch, Worker, free_port, profile, remote_args};

/// The final graph of a daemon on the ICL replay (211 frames).
fn final_graph(daemon: &Daemon) -> Value {
    remote_common::final_graph(daemon, 211, Duration::from_secs(240))
}

/// A node as compared: id, label, kind, centre.
type NodeShape = (u64, String, String, Vec<f64>);

/// Nodes and edges of a dumped graph.
fn shape(graph: &Value) -> (Vec<NodeShape>, Vec<String>) {
    let nodes = graph["nodes"]
        .as_array()
        .expect("nodes")
        .iter()
        .map(|n| {
            let centre = n["centre_m"].as_array().expect("centre").iter().map(|v| v.as_f64().expect("f64")).collect();
            (
                n["id"].as_u64().expect("id"),
                n["label"].as_str().expect("label").to_owned(),
                n["kind"].as_str().expect("kind").to_owned(),
                centre,
            )
        })
        .collect();
    let mut edges: Vec<String> = graph["edges"]
        .as_array()
        .expect("edges")
        .iter()
        .map(|e| format!("{} {} {} {}", e["source"], e["target"], e["kind"], e["relation"]))
        .collect();
    edges.sort();
    (nodes, edges)
}

#[test]
fn two_remote_yolox_workers_give_the_graph_of_the_local_detector() {
    let Some(profile) = profile() else { return };
    let profile_arg = profile.display().to_string();
    // The profile exits at the end of the sequence; these daemons keep serving their last graph.
    let keep = ["--set", "run.exit_at_end=false"];
    let local = Daemon::start(&unique_prefix("remote-local"), &["--profile", &profile_arg, keep[0], keep[1]]);
    let local_graph = final_graph(&local);
    drop(local);

    let (port, key_prefix) = (free_port(), format!("rd{}", std::process::id()));
    let _workers: Vec<Worker> =
        ["w1", "w2"].iter().map(|id| Worker::start(&profile, port, &key_prefix, id, &[])).collect();
    let mut args = vec!["--profile".to_owned(), profile_arg];
    args.extend(remote_args(
        port,
        &key_prefix,
        &["w1", "w2"],
        &["detector.remote.timeout_ms=30000", "run.exit_at_end=false"],
    ));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let remote = Daemon::start(&unique_prefix("remote"), &args);
    let watch = StatusWatch::start(Status::connect(port, &key_prefix));
    let remote_graph = final_graph(&remote);
    let status = watch.finish();
    println!("local: {}\nremote: {}\nfigures: {status}", shape(&local_graph).0.len(), shape(&remote_graph).0.len());

    let (local_nodes, local_edges) = shape(&local_graph);
    let (remote_nodes, remote_edges) = shape(&remote_graph);
    assert!(!local_nodes.is_empty(), "YOLOX finds objects on the ICL sequence");
    assert_eq!(local_nodes.len(), remote_nodes.len(), "node count: {local_nodes:?} vs {remote_nodes:?}");
    for (a, b) in local_nodes.iter().zip(&remote_nodes) {
        assert_eq!((a.0, &a.1, &a.2), (b.0, &b.1, &b.2), "node {}", a.0);
        for (u, v) in a.3.iter().zip(&b.3) {
            assert!((u - v).abs() <= 1e-5 * u.abs().max(1.0), "node {} centre {:?} vs {:?}", a.0, a.3, b.3);
        }
    }
    assert_eq!(local_edges, remote_edges, "edges");
    // Every keyframe was answered remotely, by both workers between them.
    assert_eq!(status["fallback_keyframes"], 0, "{status}");
    for w in ["w1", "w2"] {
        let figures = &status["workers"][format!("{key_prefix}/detect/{w}")];
        assert!(figures["replies"].as_u64().unwrap_or(0) > 0, "worker {w} answered: {status}");
        assert!(figures["bytes_per_keyframe"].as_u64().unwrap_or(0) > 1000, "{status}");
    }
}

/// With the Zenoh stage on too (`zenoh.enabled`), remote detection and the graph share the one
/// session of `[zenoh]`, in both directions at once: worker w1 connects to the daemon's
/// `zenoh.listen`, worker w2 listens where the daemon's `zenoh.connect` points. Both answer,
/// no keyframe goes to the fallback, and an outside Zenoh consumer (PyPI `eclipse-zenoh`)
/// connected to the daemon's listener holds the graph `op3dsg dump --json` gives.
#[test]
fn remote_detection_and_the_zenoh_stage_share_one_session_whichever_side_listens() {
    let Some(profile) = profile() else { return };
    let (daemon_port, worker_port) = (free_port(), free_port());
    let key_prefix = format!("rz{}", std::process::id());
    let listening = format!("zenoh.listen=[\"tcp/127.0.0.1:{worker_port}\"]");
    let w1 = Worker::start(&profile, daemon_port, &key_prefix, "w1", &[]);
    let w2 = Worker::start_with(&profile, daemon_port, &key_prefix, "w2", &["zenoh.connect=[]", &listening]);
    let connect = format!("zenoh.connect=[\"tcp/127.0.0.1:{worker_port}\"]");
    let mut args = vec!["--profile".to_owned(), profile.display().to_string()];
    args.extend(remote_args(
        daemon_port,
        &key_prefix,
        &["w1", "w2"],
        &["zenoh.enabled=true", &connect, "detector.remote.timeout_ms=30000", "run.exit_at_end=false"],
    ));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let daemon = Daemon::start(&unique_prefix("remote-zenoh"), &args);
    let watch = StatusWatch::start(Status::connect(daemon_port, &key_prefix));
    let mut consumer = crate::zenoh_common::Consumer::start(daemon_port, &key_prefix);
    let graph = final_graph(&daemon);
    let figures = watch.finish();
    let instance_id = crate::zenoh_common::instance_of(&daemon);
    let (dumped, held) = crate::zenoh_common::same_version(&daemon, &mut consumer, instance_id);
    println!("nodes: {}\nfigures: {figures}", shape(&graph).0.len());
    crate::zenoh_common::assert_same_graph(&dumped, &held);
    assert_eq!(figures["fallback_keyframes"], 0, "no keyframe to the fallback: {figures}");
    for w in ["w1", "w2"] {
        let replies = figures["workers"][format!("{key_prefix}/detect/{w}")]["replies"].as_u64().unwrap_or(0);
        assert!(replies > 0, "worker {w} answered: {figures}");
    }
    let labels: Vec<&str> =
        graph["nodes"].as_array().expect("nodes").iter().filter_map(|n| n["label"].as_str()).collect();
    for label in ["chair", "tv"] {
        assert!(labels.contains(&label), "the ICL replay's {label} is in the graph: {labels:?}");
    }
    drop((w1, w2));
}

/// The stand-in of an open-vocabulary family (`.models/standins/`, `scripts/setup-standins.sh`).
fn standin(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.models/standins").join(name);
    assert!(path.is_file(), "{} missing: run ./scripts/setup-models.sh && ./scripts/setup-standins.sh", path.display());
    path.display().to_string()
}

#[test]
fn an_open_vocabulary_stand_in_worker_gives_the_graph_of_the_local_detector() {
    if profile().is_none() {
        return;
    }
    let owl = Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles/replay-icl-owl.toml");
    let owl_arg = owl.display().to_string();
    let model = format!("detector.open_vocab.model_path=\"{}\"", standin("owl.onnx"));
    let local = Daemon::start(
        &unique_prefix("remote-owl-local"),
        &["--profile", &owl_arg, "--set", &model, "--set", "run.exit_at_end=false"],
    );
    let local_graph = final_graph(&local);
    drop(local);

    let (port, key_prefix) = (free_port(), format!("ro{}", std::process::id()));
    let mut worker = Worker::start_with(&owl, port, &key_prefix, "owl", &[&model]);
    let mut args = vec!["--profile".to_owned(), owl_arg.clone(), "--set".to_owned(), model.clone()];
    args.extend(remote_args(
        port,
        &key_prefix,
        &["owl"],
        &["detector.remote.model=\"open_vocab\"", "detector.remote.timeout_ms=30000", "run.exit_at_end=false"],
    ));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let remote = Daemon::start(&unique_prefix("remote-owl"), &args);
    let remote_graph = final_graph(&remote);
    let mut health = remote.health_subscriber("remote-owl-health");
    let h = op3dsg_tests::health_where(&mut health, "the worker's figures", Duration::from_secs(30), |h| {
        h.remote.worker_count == 1
    });
    worker.kill();
    let w = h.remote.valid_workers()[0];
    assert!(w.replies > 0 && h.remote.fallback_keyframes == 0, "every keyframe answered by the worker: {w:?}");
    let (local_nodes, local_edges) = shape(&local_graph);
    let (remote_nodes, remote_edges) = shape(&remote_graph);
    assert!(!local_nodes.is_empty(), "the stand-in finds regions on the ICL sequence");
    assert_eq!(
        local_nodes.iter().map(|n| (n.0, &n.1, &n.2)).collect::<Vec<_>>(),
        remote_nodes.iter().map(|n| (n.0, &n.1, &n.2)).collect::<Vec<_>>(),
        "nodes"
    );
    assert_eq!(local_edges, remote_edges, "edges");
}

#[test]
fn killed_workers_hand_over_to_each_other_then_to_the_fallback_and_back() {
    let Some(profile) = profile() else { return };
    let (port, key_prefix) = (free_port(), format!("rk{}", std::process::id()));
    let key = |w: &str| format!("{key_prefix}/detect/{w}");
    let mut w1 = Worker::start(&profile, port, &key_prefix, "w1", &[]);
    let mut w2 = Worker::start(&profile, port, &key_prefix, "w2", &[]);
    // The synthetic kitchen loops forever at 15 frames/s; the fallback is YOLOX on the robot.
    let mut args = vec!["--profile".to_owned(), profile.display().to_string()];
    args.extend(remote_args(
        port,
        &key_prefix,
        &["w1", "w2"],
        &[
            "source.kind=\"synthetic\"",
            "source.rate_hz=15.0",
            "detector.remote.timeout_ms=2000",
            "detector.remote.retry_after_ms=500",
            "detector.remote.fallback=\"yolox\"",
        ],
    ));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let _daemon = Daemon::start(&unique_prefix("remote-kill"), &args);
    let status = Status::connect(port, &key_prefix);
    let minute = Duration::from_secs(120);
    status.until("both workers answering", minute, |s| {
        ["w1", "w2"].iter().all(|w| s["workers"][key(w)]["replies"].as_u64().unwrap_or(0) > 0)
    });

    // One worker gone: the other takes every keyframe, no fallback.
    w1.kill();
    let w1_replies = status.worker(&key("w1"), "replies");
    let w2_replies = status.worker(&key("w2"), "replies");
    let (after, _) = status.until("w2 taking w1's keyframes", minute, |s| {
        s["workers"][key("w2")]["replies"].as_u64().unwrap_or(0) >= w2_replies + 10
    });
    assert_eq!(after["workers"][key("w1")]["replies"].as_u64(), Some(w1_replies), "{after}");
    assert_eq!(after["fallback_active"], false, "{after}");

    // Both gone: the fallback takes over.
    w2.kill();
    let (fallen, took) = status.until("the fallback on", minute, |s| s["fallback_active"] == true);
    println!("fallback on {} ms after the last worker died: {fallen}", took.as_millis());
    let fallback_keyframes = fallen["fallback_keyframes"].as_u64().unwrap_or(0);
    status.until("keyframes on the fallback", minute, |s| {
        s["fallback_keyframes"].as_u64().unwrap_or(0) >= fallback_keyframes + 3
    });

    // A worker returns: keyframes go to it again.
    let _w1 = Worker::start(&profile, port, &key_prefix, "w1", &[]);
    let (back, took) = status.until("w1 answering again, fallback off", minute, |s| {
        s["fallback_active"] == false && s["workers"][key("w1")]["replies"].as_u64().unwrap_or(0) > w1_replies
    });
    println!("back on a worker {} ms after it started: {back}", took.as_millis());
    let gone = back["workers"][key("w2")]["unreachable"].as_u64().unwrap_or(0)
        + back["workers"][key("w2")]["timeouts"].as_u64().unwrap_or(0);
    assert!(gone > 0, "requests to the dead worker are counted: {back}");
}

#[test]
fn workers_that_answer_garbage_late_or_mismatched_are_rejected_by_reason() {
    let Some(profile) = profile() else { return };
    let (port, key_prefix) = (free_port(), format!("rf{}", std::process::id()));
    let faults = ["garbage", "late", "wrong_id", "mask_size", "embedding_dim"];
    let _workers: Vec<Worker> = faults
        .iter()
        .map(|fault| {
            let env = [("OP3DSG_DETECTD_FAULT", *fault), ("OP3DSG_DETECTD_FAULT_DELAY_MS", "1500")];
            Worker::start(&profile, port, &key_prefix, fault, &env)
        })
        .collect();
    let mut args = vec!["--profile".to_owned(), profile.display().to_string()];
    args.extend(remote_args(
        port,
        &key_prefix,
        &faults,
        &[
            "source.kind=\"synthetic\"",
            "source.rate_hz=15.0",
            "detector.remote.timeout_ms=300",
            "detector.remote.retry_after_ms=100",
        ],
    ));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let daemon = Daemon::start(&unique_prefix("remote-faults"), &args);
    let status = Status::connect(port, &key_prefix);
    let reason = |s: &Value, worker: &str, field: &str| -> u64 {
        let w = &s["workers"][format!("{key_prefix}/detect/{worker}")];
        w["rejections"][field].as_u64().or_else(|| w[field].as_u64()).unwrap_or(0)
    };
    let (s, _) = status.until("every fault counted", Duration::from_secs(180), |s| {
        reason(s, "garbage", "garbage") > 0
            && reason(s, "late", "timeouts") > 0
            && reason(s, "late", "late") > 0
            && reason(s, "wrong_id", "wrong_id") > 0
            && reason(s, "mask_size", "mask_size") > 0
            && reason(s, "embedding_dim", "embedding_dim") > 0
    });
    println!("{s}");
    for w in faults {
        assert_eq!(s["workers"][format!("{key_prefix}/detect/{w}")]["replies"], 0, "nothing of {w} is used: {s}");
    }
    assert!(s["fallback_keyframes"].as_u64().unwrap_or(0) > 0, "{s}");

    // The health record carries the same figures per worker, as `op3dsg health` and `watch` show.
    let mut health = daemon.health_subscriber("remote-faults-health");
    let reasons = [("garbage", 0), ("wrong_id", 1), ("mask_size", 2), ("embedding_dim", 3)];
    let entry = |h: &op3dsg_ipc_types::Health, worker: &str| {
        let key = format!("{key_prefix}/detect/{worker}");
        h.remote.valid_workers().iter().find(|w| w.key_str() == key).copied()
    };
    let h = op3dsg_tests::health_where(&mut health, "every fault counted in health", Duration::from_secs(30), |h| {
        reasons.iter().all(|(fault, reason)| entry(h, fault).is_some_and(|w| w.rejections[*reason] > 0))
            && entry(h, "late").is_some_and(|w| w.late > 0)
    });
    assert_eq!((h.remote.active, h.remote.worker_count as usize), (1, faults.len()));
    for (fault, reason) in reasons {
        assert_eq!(op3dsg_ipc_types::REMOTE_REJECTIONS[reason], fault);
        let w = entry(&h, fault).expect("the worker in health");
        assert!(w.replies == 0 && w.requests > 0 && w.alive == 1, "{fault}: {w:?}");
        assert!(w.bytes_out > 1000, "{fault}: the keyframes sent are counted: {w:?}");
    }
    let late = entry(&h, "late").expect("the late worker");
    assert!(late.timeouts > 0 && late.replies == 0, "{late:?}");
    assert!(h.remote.fallback_keyframes > 0);
    let json = Command::new(binary("op3dsg"))
        .args(["--prefix", &daemon.prefix, "health", "--json"])
        .output()
        .expect("run op3dsg health");
    assert!(json.status.success(), "{}", String::from_utf8_lossy(&json.stderr));
    let json: Value = serde_json::from_slice(&json.stdout).expect("health JSON");
    let workers = json["remote"]["workers"].as_array().expect("remote workers in op3dsg health --json");
    assert_eq!(workers.len(), faults.len(), "{json}");
    assert!(workers.iter().all(|w| w["replies"] == 0 && w["requests"].as_u64().unwrap_or(0) > 0), "{json}");
}
