//! Zenoh for `op3dsg bench perf`: what the graph costs on its way off the robot.
//!
//! 1. **Latency** ([`zenoh_latency`]): a full graph message, encoded as the Zenoh stage encodes
//!    it (the graph encoder, then the envelope: `op3dsg_runtime::zenoh::codec::encode_full`) and
//!    put, until the client library's [`RemoteFollower`] on the other side holds it as an owned
//!    `Graph`; next to a raw Zenoh put of a byte buffer of the same size, received and copied
//!    out, message for message interleaved. Two Zenoh sessions of this process: a peer listening
//!    on a free TCP port of 127.0.0.1 (as the daemon with `zenoh.listen`) and a client connected
//!    to it (as `op3dsg dump --zenoh`), multicast scouting off; puts with congestion control
//!    `drop`, as the daemon's. Each message is sent only after the one before arrived, so none
//!    waits behind another; one that never arrives within [`RECEIVE_TIMEOUT`] is counted lost.
//!    Both ends read one clock (`Instant`).
//! 2. **The stage in the pipeline** ([`zenoh_stage`]): the camera-rate pipeline run twice, without
//!    and with `[zenoh]` (listening on loopback, one consumer: `op3dsg watch --zenoh` in a child
//!    process following full graphs, deltas and health): fusion and publish latency of both runs;
//!    the sizes of full graphs and deltas over the whole run and over its second half (the map
//!    no longer grows much: steady state); and the CPU the Zenoh stage's thread and Zenoh's own
//!    runtime threads used, from `/proc/self/task`.

use std::collections::BTreeMap;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context as _, anyhow, bail};
use crossbeam_channel::{Receiver, Sender};
use op3dsg_ipc_types::client::RemoteFollower;
use op3dsg_ipc_types::{MAX_EDGES, MAX_NODES};
use op3dsg_runtime::graph::SceneGraph;
use op3dsg_runtime::ipc::{GraphCapacity, GraphEncoder};
use op3dsg_runtime::pipeline::Counters;
use op3dsg_runtime::world::clock::wall_clock_ns;
use op3dsg_runtime::zenoh::codec::encode_full;
use zenoh::Wait as _;
use zenoh::qos::CongestionControl;

use super::ipc_latency::synthetic_graph;
use super::pipeline_run::PipelineRun;
use super::pipeline_run::{Mode, pipeline_run_observed, pipeline_run_with};
use super::zenoh_report::{
    MessageSizes, StageWithAndWithout, ZenohCpu, ZenohLatency, ZenohRow, ZenohSection, ZenohStage,
};
use super::{Percentiles, PerfOptions};

impl StageWithAndWithout {
    fn of(name: &str, without: &PipelineRun, with: &PipelineRun) -> Option<Self> {
        let find = |run: &PipelineRun| run.stages.iter().find(|s| s.name == name).map(|s| s.latency);
        let (without, with) = (find(without)?, find(with)?);
        let p99_ratio = if without.p99_ms > 0.0 { with.p99_ms / without.p99_ms } else { 0.0 };
        Some(Self { name: name.to_owned(), without, with, p99_ratio })
    }
}

impl MessageSizes {
    fn between(start: &Tally, end: &Tally) -> Self {
        let fulls = end.fulls - start.fulls;
        let deltas = end.deltas - start.deltas;
        let mean = |bytes: u64, n: u64| if n == 0 { 0.0 } else { bytes as f64 / n as f64 };
        let full_bytes_mean = mean(end.full_bytes - start.full_bytes, fulls);
        let delta_bytes_mean = mean(end.delta_bytes - start.delta_bytes, deltas);
        let delta_over_full = if full_bytes_mean > 0.0 { delta_bytes_mean / full_bytes_mean } else { 0.0 };
        Self { fulls, full_bytes_mean, deltas, delta_bytes_mean, delta_over_full }
    }
}

/// How long the sender waits for a message to arrive before counting it lost.
pub const RECEIVE_TIMEOUT: Duration = Duration::from_secs(2);

/// Clock ticks per second of `/proc/<pid>/task/<tid>/stat` (`USER_HZ`: 100 on Linux for every
/// architecture the daemon is built for).
const USER_HZ: f64 = 100.0;

/// Message counters of the Zenoh stage at one moment.
#[derive(Debug, Clone, Copy, Default)]
struct Tally {
    fulls: u64,
    full_bytes: u64,
    deltas: u64,
    delta_bytes: u64,
}

impl Tally {
    fn of(counters: &Counters) -> Self {
        let Some(z) = counters.zenoh.as_ref() else { return Self::default() };
        Self {
            fulls: z.fulls.load(Ordering::Relaxed),
            full_bytes: z.full_bytes.load(Ordering::Relaxed),
            deltas: z.deltas.load(Ordering::Relaxed),
            delta_bytes: z.delta_bytes.load(Ordering::Relaxed),
        }
    }
}

/// A TCP port of 127.0.0.1 that was free a moment ago.
fn free_port() -> anyhow::Result<u16> {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").context("finding a free loopback port")?;
    Ok(listener.local_addr()?.port())
}

/// A Zenoh session: `mode` with `key: endpoints`, multicast scouting off.
fn session(mode: &str, key: &str, endpoint: &str) -> anyhow::Result<zenoh::Session> {
    let mut config = zenoh::Config::default();
    for (k, v) in [
        ("mode", format!("{mode:?}")),
        (key, format!("[{endpoint:?}]")),
        ("scouting/multicast/enabled", "false".to_owned()),
    ] {
        config.insert_json5(k, &v).map_err(|e| anyhow!("zenoh configuration {k}: {e}"))?;
    }
    zenoh::open(config).wait().map_err(|e| anyhow!("opening a zenoh {mode} session ({key} {endpoint}): {e}"))
}

/// Which of the two kinds a receipt is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Graph,
    Raw,
}

/// Measures, for every size of `options.zenoh.nodes`, graph and raw put → receive over TCP
/// loopback between two Zenoh sessions.
pub fn zenoh_latency(options: &PerfOptions) -> anyhow::Result<ZenohLatency> {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let sender = session("peer", "listen/endpoints", &endpoint)?;
    let receiver = session("client", "connect/endpoints", &endpoint)?;
    let key = format!("op3dsg-bench/{}", std::process::id());
    let (tx, rx) = crossbeam_channel::unbounded::<(Kind, u64, Instant)>();
    let _subscribers = subscribe(&receiver, &key, tx)?;
    let publisher = |suffix: &str| {
        sender
            .declare_publisher(format!("{key}/{suffix}"))
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(|e| anyhow!("declaring the publisher {key}/{suffix}: {e}"))
    };
    let (graph_pub, raw_pub) = (publisher("graph")?, publisher("raw")?);

    // The client's subscription reaches the peer a moment after it is declared: ping until a raw
    // message comes back.
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut seq = 1u64;
    loop {
        raw_pub.put(seq.to_le_bytes().to_vec()).wait().map_err(|e| anyhow!("put: {e}"))?;
        if let Ok((Kind::Raw, got, _)) = rx.recv_timeout(Duration::from_millis(100))
            && got == seq
        {
            break;
        }
        if Instant::now() > deadline {
            bail!("the Zenoh client on {endpoint} never received a message");
        }
        seq += 1;
    }
    while rx.try_recv().is_ok() {}

    let capacity = GraphCapacity { max_nodes: MAX_NODES, max_edges: MAX_EDGES };
    let mut encoder = GraphEncoder::new(capacity, 1);
    let mut rows = Vec::new();
    for &nodes in &options.zenoh.nodes {
        let mut graph = synthetic_graph(nodes, 0);
        let mut samples = [Vec::new(), Vec::new()];
        let mut lost = [0u64; 2];
        let mut bytes = 0;
        let mut message = Vec::new();
        let mut raw = Vec::new();
        for k in 0..options.zenoh.warmup + options.zenoh.messages {
            let timed = k >= options.zenoh.warmup;
            seq += 1;
            // The graph: encoded as the Zenoh stage does, then put.
            graph.version = seq;
            let t0 = Instant::now();
            encode_graph(&mut encoder, &graph, &mut message);
            graph_pub.put(message.as_slice()).wait().map_err(|e| anyhow!("put: {e}"))?;
            bytes = message.len();
            record(&rx, Kind::Graph, seq, t0, timed, &mut samples[0], &mut lost[0]);
            // The same number of bytes, raw.
            seq += 1;
            raw.clear();
            raw.resize(bytes, 0x5a);
            raw[..8].copy_from_slice(&seq.to_le_bytes());
            let t0 = Instant::now();
            raw_pub.put(raw.as_slice()).wait().map_err(|e| anyhow!("put: {e}"))?;
            record(&rx, Kind::Raw, seq, t0, timed, &mut samples[1], &mut lost[1]);
        }
        let [mut g, mut r] = samples;
        let (graph_p, raw_p) = (Percentiles::from_samples_ms(&mut g), Percentiles::from_samples_ms(&mut r));
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
        rows.push(ZenohRow {
            nodes: graph.nodes.len(),
            edges: graph.edges.len(),
            bytes,
            ratio_p50: ratio(graph_p.p50_ms, raw_p.p50_ms),
            ratio_p99: ratio(graph_p.p99_ms, raw_p.p99_ms),
            graph: graph_p,
            raw: raw_p,
            lost,
        });
    }
    let _ = receiver.close().wait();
    let _ = sender.close().wait();
    Ok(ZenohLatency {
        link: format!(
            "two Zenoh sessions of one process over TCP loopback ({endpoint}): a peer listening, a client \
             connected; congestion control drop"
        ),
        messages: options.zenoh.messages,
        warmup: options.zenoh.warmup,
        rows,
    })
}

/// The graph encoder's sample of `graph`, then the full graph message, into `out`.
fn encode_graph(encoder: &mut GraphEncoder, graph: &SceneGraph, out: &mut Vec<u8>) {
    encoder.encode(graph);
    let now = wall_clock_ns();
    encoder.set_publish_time_ns(now);
    encode_full(encoder.header(), encoder.payload(), now, out);
}

/// Waits for the receipt of (`kind`, `seq`) and keeps its latency when `timed`, or counts it lost.
fn record(
    rx: &Receiver<(Kind, u64, Instant)>,
    kind: Kind,
    seq: u64,
    t0: Instant,
    timed: bool,
    samples: &mut Vec<f64>,
    lost: &mut u64,
) {
    let deadline = Instant::now() + RECEIVE_TIMEOUT;
    while let Ok((got_kind, got, t1)) = rx.recv_deadline(deadline) {
        if got_kind == kind && got == seq {
            if timed {
                samples.push(t1.duration_since(t0).as_secs_f64() * 1e3);
            }
            return;
        }
    }
    *lost += 1;
}

/// The client's two subscribers: graphs go through the client library's follower into an owned
/// `Graph`, raw messages are copied out; each sends its receipt on `tx`.
fn subscribe(
    receiver: &zenoh::Session,
    key: &str,
    tx: Sender<(Kind, u64, Instant)>,
) -> anyhow::Result<[zenoh::pubsub::Subscriber<()>; 2]> {
    let graph_tx = tx.clone();
    let follower = std::sync::Mutex::new(RemoteFollower::new());
    let graph = receiver
        .declare_subscriber(format!("{key}/graph"))
        .callback(move |sample| {
            let mut follower = follower.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            if follower.apply(&sample.payload().to_bytes()).is_ok()
                && let Some(Ok(graph)) = follower.graph()
            {
                let _ = graph_tx.send((Kind::Graph, graph.version(), Instant::now()));
            }
        })
        .wait()
        .map_err(|e| anyhow!("subscribing to {key}/graph: {e}"))?;
    let raw = receiver
        .declare_subscriber(format!("{key}/raw"))
        .callback(move |sample| {
            let bytes = sample.payload().to_bytes().into_owned();
            if let Some(seq) = bytes.get(..8).and_then(|b| b.try_into().ok()).map(u64::from_le_bytes) {
                let _ = tx.send((Kind::Raw, seq, Instant::now()));
            }
        })
        .wait()
        .map_err(|e| anyhow!("subscribing to {key}/raw: {e}"))?;
    Ok([graph, raw])
}

/// CPU ticks per thread of this process: `(name, utime + stime)` by thread id.
fn thread_ticks() -> BTreeMap<u32, (String, u64)> {
    let mut ticks = BTreeMap::new();
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else { return ticks };
    for task in tasks.flatten() {
        let Some(tid) = task.file_name().to_str().and_then(|t| t.parse::<u32>().ok()) else { continue };
        if let Ok(stat) = std::fs::read_to_string(task.path().join("stat"))
            && let Some((name, t)) = parse_stat(&stat)
        {
            ticks.insert(tid, (name, t));
        }
    }
    ticks
}

/// The name and `utime + stime` of a `/proc/.../stat` line.
fn parse_stat(stat: &str) -> Option<(String, u64)> {
    let open = stat.find('(')?;
    let close = stat.rfind(')')?;
    let name = stat.get(open + 1..close)?.to_owned();
    let fields: Vec<&str> = stat.get(close + 1..)?.split_whitespace().collect();
    // After the name: state (0), ..., utime (11), stime (12).
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    Some((name, utime + stime))
}

/// Whether `name` is one of Zenoh's runtime threads (`app-0`, `rx-1`, ... as Zenoh names them).
fn is_zenoh_runtime(name: &str) -> bool {
    name.rsplit_once('-').is_some_and(|(base, index)| {
        !index.is_empty()
            && index.chars().all(|c| c.is_ascii_digit())
            && ["app", "acc", "tx", "rx", "net"].iter().any(|b| base.eq_ignore_ascii_case(b))
    })
}

/// What the observer of the run with Zenoh saw.
struct Observed {
    half: Tally,
    first: BTreeMap<u32, (String, u64)>,
    last: BTreeMap<u32, (String, u64)>,
    process_ticks: u64,
    consumer: Result<(), String>,
}

/// Runs the camera-rate pipeline without and with the Zenoh stage (one consumer: `op3dsg watch
/// --zenoh` in a child process).
pub fn zenoh_stage(options: &PerfOptions) -> anyhow::Result<ZenohStage> {
    let rate = options.live_rate_hz;
    let mode = Mode::CameraRate(rate);
    let (off, _) = pipeline_run_with(options, mode, "zenoh-off", &[]).context("the run without Zenoh")?;
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let key_prefix = format!("op3dsg-bench/{}", std::process::id());
    let extra = [
        "zenoh.enabled=true".to_owned(),
        format!("zenoh.listen=[\"{endpoint}\"]"),
        format!("zenoh.key_prefix=\"{key_prefix}\""),
    ];
    let consumer = [
        "watch".to_owned(),
        "--interval-ms".to_owned(),
        "1000".to_owned(),
        "--zenoh".to_owned(),
        endpoint.clone(),
        "--key-prefix".to_owned(),
        key_prefix.clone(),
    ];
    let exe = options.peer_exe.clone();
    let half_after = Duration::from_secs_f64(options.frames as f64 / rate / 2.0);
    let (on, counters, observed) = pipeline_run_observed(options, mode, "zenoh-on", &extra, move |counters, ended| {
        observe(&counters, &ended, &exe, &consumer, half_after)
    })
    .context("the run with Zenoh")?;
    observed.consumer.map_err(|e| anyhow!("the Zenoh consumer: {e}"))?;
    let end = Tally::of(&counters);
    let mut stage_s = 0.0;
    let mut runtime_s = 0.0;
    let mut threads = Vec::new();
    for (tid, (name, last)) in &observed.last {
        let first = observed.first.get(tid).map_or(0, |(_, t)| *t);
        let seconds = last.saturating_sub(first) as f64 / USER_HZ;
        if name == "op3dsg-zenoh" {
            stage_s += seconds;
        } else if is_zenoh_runtime(name) {
            runtime_s += seconds;
        } else {
            continue;
        }
        threads.push(name.clone());
    }
    threads.sort();
    threads.dedup();
    let process_s = observed.process_ticks as f64 / USER_HZ;
    let used = stage_s + runtime_s;
    let versions_sent = counters.zenoh.as_ref().map_or(0, |z| z.stage.since_start().count());
    Ok(ZenohStage {
        rate_hz: rate,
        frames: options.frames,
        consumer: format!("op3dsg watch --zenoh {endpoint} (a child process following full graphs, deltas, health)"),
        stages: ["fusion", "publish"].iter().filter_map(|name| StageWithAndWithout::of(name, &off, &on)).collect(),
        versions_sent,
        whole_run: MessageSizes::between(&Tally::default(), &end),
        second_half: MessageSizes::between(&observed.half, &end),
        keyframes: on.keyframes,
        cpu: ZenohCpu {
            elapsed_s: on.elapsed_s,
            stage_thread_s: stage_s,
            runtime_threads_s: runtime_s,
            process_s,
            share_of_one_core: used / on.elapsed_s.max(1e-9),
            share_of_process: if process_s > 0.0 { used / process_s } else { 0.0 },
            threads,
        },
    })
}

/// The observer of the run with Zenoh: starts the consumer, samples the threads' CPU every
/// 100 ms (a thread's last sample before it ends is what counts) and the message counters at
/// `half_after`, until the run has ended.
fn observe(
    counters: &Counters,
    ended: &AtomicBool,
    exe: &std::path::Path,
    args: &[String],
    half_after: Duration,
) -> Observed {
    let started = Instant::now();
    let process_start = std::fs::read_to_string("/proc/self/stat").ok().and_then(|s| parse_stat(&s)).map_or(0, |p| p.1);
    let first = thread_ticks();
    let mut last = first.clone();
    let mut half = None;
    let child = Command::new(exe).args(args).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::null()).spawn();
    let mut child: Result<Child, String> =
        child.map_err(|e| format!("starting {} {}: {e}", exe.display(), args.join(" ")));
    while !ended.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(100));
        last.extend(thread_ticks());
        if half.is_none() && started.elapsed() >= half_after {
            half = Some(Tally::of(counters));
        }
        if let Ok(c) = &mut child
            && let Ok(Some(status)) = c.try_wait()
        {
            child = Err(format!("exited early ({status})"));
        }
    }
    let process_end = std::fs::read_to_string("/proc/self/stat").ok().and_then(|s| parse_stat(&s)).map_or(0, |p| p.1);
    let consumer = match child {
        Ok(mut c) => {
            let _ = c.kill();
            let _ = c.wait();
            Ok(())
        }
        Err(e) => Err(e),
    };
    Observed {
        half: half.unwrap_or_default(),
        first,
        last,
        process_ticks: process_end.saturating_sub(process_start),
        consumer,
    }
}

/// Both measurements `options.zenoh` asks for: the latency rows and the stage pair (at
/// `options.live_rate_hz`; skipped at 0).
pub fn zenoh_section(options: &PerfOptions) -> anyhow::Result<ZenohSection> {
    let latency = if options.zenoh.nodes.is_empty() {
        None
    } else {
        eprintln!(
            "bench perf: Zenoh latency, graphs of {:?} nodes, {} messages each ...",
            options.zenoh.nodes, options.zenoh.messages
        );
        Some(zenoh_latency(options).context("Zenoh latency")?)
    };
    let stage = if options.zenoh.stage && options.live_rate_hz > 0.0 {
        eprintln!(
            "bench perf: the Zenoh stage at {} Hz, without and with it, {} frames each ...",
            options.live_rate_hz, options.frames
        );
        Some(zenoh_stage(options).context("the Zenoh stage")?)
    } else {
        None
    };
    Ok(ZenohSection { latency, stage })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stat_line_gives_name_and_ticks() {
        let line = "4242 (rx-1) S 1 2 3 4 5 6 7 8 9 10 17 25 0 0 20 0 3 0 100 0 0";
        assert_eq!(parse_stat(line), Some(("rx-1".to_owned(), 42)));
        let odd = "7 (a (b) c) R 1 2 3 4 5 6 7 8 9 10 1 2 0 0";
        assert_eq!(parse_stat(odd), Some(("a (b) c".to_owned(), 3)));
    }

    #[test]
    fn zenoh_runtime_threads_are_told_apart() {
        for name in ["app-0", "rx-1", "tx-0", "net-12", "acc-0"] {
            assert!(is_zenoh_runtime(name), "{name}");
        }
        for name in ["op3dsg-fusion", "rx-", "tokio-runtime-worker", "rx-a"] {
            assert!(!is_zenoh_runtime(name), "{name}");
        }
    }
}
