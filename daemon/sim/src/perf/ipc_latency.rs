//! Graph publish → subscriber receive between two processes, next to raw iceoryx2 with a payload
//! of the same size, for `op3dsg bench perf`.
//!
//! This process publishes; a child process of the same binary (`op3dsg --prefix P bench
//! ipc-peer --rounds N`, see [`ipc_peer`]) subscribes. Services, under a private prefix:
//!
//! | service | what |
//! |---|---|
//! | `P/graph`, `P/graph_updated` | the daemon's own graph services ([`GraphServer`]) |
//! | `P/bench/raw`, `P/bench/raw_updated` | a `[u8]` publish-subscribe service and its event |
//! | `P/bench/ack` | event: the child took a message (or is ready) |
//!
//! Per graph size, messages go round graph (owned read), raw, graph (view read), graph, raw,
//! graph, ...; the publisher sends the next one only after the child's acknowledgement, so no
//! message waits behind another. The child waits on an iceoryx2 event listener for every kind
//! (as a planner waits on `graph_updated`).
//!
//! - **graph** (owned): `t0` just before [`GraphServer::publish_graph`] (choose the records, loan
//!   an uninitialised sample of exactly their size, write header, nodes and edges in place, send,
//!   notify); `t1` when the planner client
//!   library's [`GraphSubscriber::latest_if_newer`] returned the owned [`Graph`] in the child
//!   (newest sample received, checked, its nodes and edges copied out). The lookup indices are
//!   built on the first lookup; the child times one right after `t1` and reports it apart
//!   (`graph_index_build`), since a planner that only scans the nodes never pays it.
//! - **view**: the same publish; `t1` inside the closure of [`GraphSubscriber::with_latest`] once
//!   the first node's id and label were read through the [`GraphView`] (newest sample received,
//!   its header checked against its length, its records cast in place; nothing copied or
//!   scanned).
//! - **raw**: `t0` just before loaning a byte slice of the graph sample's size (header + nodes +
//!   edges); copy a prepared buffer in, send, notify; `t1` after the child received the sample
//!   and copied the bytes out.
//!
//! Both clocks are the system's wall clock (`CLOCK_REALTIME`, one clock for every process of the
//! machine). The ratio graph / raw per percentile is the figure.

use std::collections::HashMap;
use std::io::Read as _;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context as _, anyhow, bail};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections as _;
use iceoryx2::prelude::Node;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, GraphHeader, MAX_EDGES, MAX_NODES, NodeKind, graph_payload_bytes};
#[cfg(doc)]
use op3dsg_ipc_types::{Graph, GraphSubscriber, GraphView};
use serde::{Deserialize, Serialize};

use super::{Percentiles, PerfOptions, Receipts};
use op3dsg_runtime::graph::{GraphEdge, GraphNode, SceneGraph};
use op3dsg_runtime::ipc::{GraphServer, IpcConfig, IpcService, create_node, service_name};
use op3dsg_runtime::world::clock::wall_clock_ns;

/// How long either side waits for the other before giving up.
pub(super) const PEER_TIMEOUT: Duration = Duration::from_secs(20);

/// One graph size of the IPC measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IpcRow {
    /// Nodes in the graph.
    pub nodes: usize,
    /// Edges in the graph.
    pub edges: usize,
    /// Bytes of the graph sample (header + nodes + edges): the raw payload size.
    pub bytes: usize,
    /// Graph publish → owned client `Graph` in the other process.
    pub graph: Percentiles,
    /// Raw iceoryx2 publish → bytes in the other process.
    pub raw: Percentiles,
    /// The publisher's share of `graph`: the `publish_graph` call alone.
    pub graph_publish_call: Percentiles,
    /// The publisher's share of `raw`: loan, copy, send, notify.
    pub raw_publish_call: Percentiles,
    /// The subscriber's share of `graph`: the `GraphSubscriber::latest_if_newer` call that
    /// returned it (receive and copy into the owned `Graph`).
    pub graph_read_call: Percentiles,
    /// After the graph was taken (not part of `graph`): the first id lookup on it, which builds
    /// the lookup indices a planner's first `node`, `parts_of`, `edges_from` ... call pays.
    #[serde(default)]
    pub graph_index_build: Percentiles,
    /// `graph.p50_ms / raw.p50_ms`.
    pub ratio_p50: f64,
    /// `graph.p99_ms / raw.p99_ms`.
    pub ratio_p99: f64,
    /// Graph publish → the first node read through the zero-copy `GraphView` of
    /// `GraphSubscriber::with_latest` in the other process.
    #[serde(default)]
    pub view: Percentiles,
    /// The publisher's share of `view`: the `publish_graph` call alone.
    #[serde(default)]
    pub view_publish_call: Percentiles,
    /// The subscriber's share of `view`: from the `with_latest` call to the first node read
    /// (receive, check, cast, read).
    #[serde(default)]
    pub view_read_call: Percentiles,
    /// `view.p50_ms / raw.p50_ms`.
    #[serde(default)]
    pub view_ratio_p50: f64,
    /// `view.p99_ms / raw.p99_ms`.
    #[serde(default)]
    pub view_ratio_p99: f64,
}

/// The IPC section of the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IpcLatency {
    /// How the subscriber waits.
    pub wait: String,
    /// Timed messages per size and kind.
    pub messages: usize,
    /// Untimed messages per size and kind before them.
    pub warmup: usize,
    /// Largest graph sample the publisher reserves (header + `ipc.max_nodes` nodes +
    /// `ipc.max_edges` edges), bytes; each sample is only as large as its graph.
    pub max_sample_bytes: usize,
    /// One row per graph size.
    pub rows: Vec<IpcRow>,
}

/// A graph of `nodes` nodes (three objects to one part, each part on the object before it) and
/// two spatial edges per node (capped by the snapshot's capacity), labelled like real ones.
pub fn synthetic_graph(nodes: usize, version: u64) -> SceneGraph {
    const OBJECTS: [&str; 6] = ["cabinet", "refrigerator", "microwave", "sink", "stove", "drawer"];
    const PARTS: [&str; 3] = ["handle", "knob", "button"];
    let nodes = nodes.min(MAX_NODES);
    let next_to = op3dsg_ipc_types::relation_id("next to").map_or(0, |(_, id)| id);
    let mut graph = SceneGraph { version, stamp_ns: version, ..SceneGraph::default() };
    let mut last_object = 0u32;
    for i in 0..nodes as u32 {
        let part = i % 4 == 3;
        let centre = [(i % 100) as f32 * 0.5, (i / 100) as f32 * 0.5, 0.8];
        let half = if part { 0.02 } else { 0.3 };
        let label = if part {
            format!("{} {}", OBJECTS[last_object as usize % OBJECTS.len()], PARTS[i as usize % PARTS.len()])
        } else {
            OBJECTS[i as usize % OBJECTS.len()].to_owned()
        };
        graph.nodes.push(GraphNode {
            id: i,
            kind: if part { NodeKind::Part } else { NodeKind::Object },
            parent_id: part.then_some(last_object),
            label,
            confidence: 0.8,
            centre_m: centre,
            box_min_m: centre.map(|v| v - half),
            box_max_m: centre.map(|v| v + half),
            obb: Default::default(),
            observation_count: 5,
            affordance_bits: if part { 0b1 } else { 0 },
            last_seen_stamp_ns: u64::from(i),
            first_seen_stamp_ns: 0,
            missing: false,
            ..Default::default()
        });
        if !part {
            last_object = i;
        }
    }
    let n = nodes as u32;
    for i in 0..n {
        for step in [1, 7] {
            if graph.edges.len() < MAX_EDGES && n > 1 {
                graph.edges.push(GraphEdge {
                    source_id: i,
                    target_id: (i + step) % n,
                    kind: EdgeKind::Spatial,
                    relation_id: next_to,
                    confidence: 0.9,
                    origin: EdgeOrigin::Geometry,
                });
            }
        }
    }
    graph
}

/// Bytes of the graph sample of `graph`: the header and its nodes and edges.
pub fn filled_bytes(graph: &SceneGraph) -> usize {
    size_of::<GraphHeader>() + graph_payload_bytes(graph.nodes.len().min(MAX_NODES), graph.edges.len().min(MAX_EDGES))
}

pub(super) struct BenchServices {
    pub(super) raw_name: String,
    pub(super) raw_updated_name: String,
    pub(super) ack_name: String,
}

impl BenchServices {
    pub(super) fn new(prefix: &str) -> Self {
        Self {
            raw_name: format!("{prefix}/bench/raw"),
            raw_updated_name: format!("{prefix}/bench/raw_updated"),
            ack_name: format!("{prefix}/bench/ack"),
        }
    }
}

struct BenchPublisher {
    server: GraphServer,
    raw: Publisher<IpcService, [u8], ()>,
    raw_updated: Notifier<IpcService>,
    ack: Listener<IpcService>,
    _node: Node<IpcService>,
}

impl BenchPublisher {
    fn open(prefix: &str, max_bytes: usize) -> anyhow::Result<Self> {
        let config = IpcConfig { prefix: prefix.to_owned(), max_subscribers: 2, ..IpcConfig::default() };
        let server = GraphServer::open(&config, "op3dsg-bench-publisher").context("graph services")?;
        let names = BenchServices::new(prefix);
        let node = create_node(&config.ipc_root(), "op3dsg-bench-raw")?;
        let raw = node
            .service_builder(&service_name(prefix, &names.raw_name)?)
            .publish_subscribe::<[u8]>()
            .max_publishers(1)
            .max_subscribers(2)
            .subscriber_max_buffer_size(2)
            .history_size(0)
            .enable_safe_overflow(true)
            .create()
            .map_err(|e| anyhow!("create service {}: {e:?}", names.raw_name))?
            .publisher_builder()
            .initial_max_slice_len(max_bytes)
            .create()
            .map_err(|e| anyhow!("create publisher on {}: {e:?}", names.raw_name))?;
        let raw_updated = node
            .service_builder(&service_name(prefix, &names.raw_updated_name)?)
            .event()
            .create()
            .map_err(|e| anyhow!("create service {}: {e:?}", names.raw_updated_name))?
            .notifier_builder()
            .create()
            .map_err(|e| anyhow!("create notifier on {}: {e:?}", names.raw_updated_name))?;
        let ack = node
            .service_builder(&service_name(prefix, &names.ack_name)?)
            .event()
            .create()
            .map_err(|e| anyhow!("create service {}: {e:?}", names.ack_name))?
            .listener_builder()
            .create()
            .map_err(|e| anyhow!("create listener on {}: {e:?}", names.ack_name))?;
        Ok(Self { server, raw, raw_updated, ack, _node: node })
    }

    /// Waits for one acknowledgement from `child`.
    fn wait_ack(&self, child: &mut Child, what: &str) -> anyhow::Result<()> {
        let deadline = Instant::now() + PEER_TIMEOUT;
        loop {
            let count = self
                .ack
                .timed_wait(|_| {}, Duration::from_millis(100))
                .map_err(|e| anyhow!("waiting for the subscriber's acknowledgement of {what}: {e:?}"))?;
            if count > 0 {
                return Ok(());
            }
            if let Some(status) = child.try_wait().context("checking the subscriber process")? {
                bail!("the subscriber process exited ({status}) before acknowledging {what}");
            }
            if Instant::now() >= deadline {
                bail!("no acknowledgement of {what} from the subscriber within {} s", PEER_TIMEOUT.as_secs());
            }
        }
    }

    fn send_raw(&mut self, payload: &[u8]) -> anyhow::Result<()> {
        let sample = self.raw.loan_slice_uninit(payload.len()).map_err(|e| anyhow!("loan raw sample: {e:?}"))?;
        sample.write_from_slice(payload).send().map_err(|e| anyhow!("send raw sample: {e:?}"))?;
        self.raw_updated.notify().map_err(|e| anyhow!("notify raw: {e:?}"))?;
        Ok(())
    }

    /// Publishes `graph` as version `id`, records its send time under `kind` and waits for
    /// `child`'s acknowledgement.
    fn send_graph(
        &mut self,
        child: &mut Child,
        graph: &mut SceneGraph,
        id: u64,
        at: (usize, bool),
        kind: &mut SentKind,
    ) -> anyhow::Result<()> {
        let (size_index, timed) = at;
        graph.version = id;
        let t0 = wall_clock_ns();
        let call = Instant::now();
        self.server.publish_graph(graph).context("publishing a graph")?;
        let call_ms = call.elapsed().as_secs_f64() * 1e3;
        kind.at.insert(id, (size_index, t0, timed));
        if timed {
            kind.calls_ms[size_index].push(call_ms);
        }
        self.wait_ack(child, "a graph")
    }

    /// Sends, per size of `graphs`, `options.ipc_warmup + options.ipc_messages` rounds of a
    /// graph (read into an owned graph), a raw sample of the graph's size (the first 8 bytes of
    /// `payload` its id) and a graph (read through the view), each after `child`'s
    /// acknowledgement of the one before.
    fn send_rounds(
        &mut self,
        child: &mut Child,
        graphs: &[SceneGraph],
        options: &PerfOptions,
        payload: &mut [u8],
    ) -> anyhow::Result<Sent> {
        let mut sent = Sent {
            graph: SentKind::new(graphs.len()),
            raw: SentKind::new(graphs.len()),
            view: SentKind::new(graphs.len()),
        };
        let mut id = 0u64;
        for (size_index, graph) in graphs.iter().enumerate() {
            let mut graph = graph.clone();
            let bytes = filled_bytes(&graph);
            for k in 0..options.ipc_warmup + options.ipc_messages {
                let at = (size_index, k >= options.ipc_warmup);
                id += 1;
                self.send_graph(child, &mut graph, id, at, &mut sent.graph)?;

                id += 1;
                payload[..8].copy_from_slice(&id.to_le_bytes());
                let t0 = wall_clock_ns();
                let call = Instant::now();
                self.send_raw(&payload[..bytes])?;
                let call_ms = call.elapsed().as_secs_f64() * 1e3;
                sent.raw.at.insert(id, (size_index, t0, at.1));
                if at.1 {
                    sent.raw.calls_ms[size_index].push(call_ms);
                }
                self.wait_ack(child, "a raw sample")?;

                id += 1;
                self.send_graph(child, &mut graph, id, at, &mut sent.view)?;
            }
        }
        Ok(sent)
    }
}

/// Per message id: the index of its graph size, its send wall clock (ns), and whether it is
/// timed (not warm-up).
type SentAt = HashMap<u64, (usize, u64, bool)>;

/// What [`BenchPublisher::send_rounds`] sent of one kind, and its publish calls' durations per
/// size.
struct SentKind {
    at: SentAt,
    calls_ms: Vec<Vec<f64>>,
}

impl SentKind {
    fn new(sizes: usize) -> Self {
        Self { at: HashMap::new(), calls_ms: vec![Vec::new(); sizes] }
    }
}

/// What [`BenchPublisher::send_rounds`] sent: graphs read into an owned graph, raw samples,
/// graphs read through the view.
struct Sent {
    graph: SentKind,
    raw: SentKind,
    view: SentKind,
}

/// Kills the child on every early return.
struct ChildGuard(Option<Child>);

impl ChildGuard {
    /// Starts the subscriber process (`op3dsg --prefix PREFIX bench ipc-peer --rounds N`).
    fn spawn_peer(options: &PerfOptions, prefix: &str, rounds: usize) -> anyhow::Result<Self> {
        let child = Command::new(&options.peer_exe)
            .args(["--prefix", prefix, "bench", "ipc-peer", "--rounds", &rounds.to_string()])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("starting the subscriber process {}", options.peer_exe.display()))?;
        Ok(Self(Some(child)))
    }

    /// Waits for the subscriber process to exit and reads its receipts from its standard output.
    fn receipts(mut self) -> anyhow::Result<Receipts> {
        let mut child = self.0.take().ok_or_else(|| anyhow!("subscriber process missing"))?;
        let mut out = String::new();
        if let Some(mut stdout) = child.stdout.take() {
            stdout.read_to_string(&mut out).context("reading the subscriber's receipts")?;
        }
        let status = child.wait().context("waiting for the subscriber process")?;
        if !status.success() {
            bail!("the subscriber process failed ({status})");
        }
        serde_json::from_str(out.trim()).context("parsing the subscriber's receipts")
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        if let Some(child) = self.0.as_mut() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// Measures graph and raw publish → receive latency for every size of `options.ipc_nodes`.
pub fn ipc_latency(options: &PerfOptions) -> anyhow::Result<IpcLatency> {
    let prefix = format!("op3dsg-bench-{}-ipc", std::process::id());
    let graphs: Vec<SceneGraph> = options.ipc_nodes.iter().map(|&n| synthetic_graph(n, 0)).collect();
    let max_bytes = graphs.iter().map(filled_bytes).max().unwrap_or(8).max(8);
    let mut publisher = BenchPublisher::open(&prefix, max_bytes)?;
    let per_size = options.ipc_warmup + options.ipc_messages;
    let rounds = per_size * graphs.len();

    let mut guard = ChildGuard::spawn_peer(options, &prefix, rounds)?;
    let child = guard.0.as_mut().ok_or_else(|| anyhow!("subscriber process missing"))?;
    publisher.wait_ack(child, "start-up")?;
    publisher.server.update_connections()?;
    publisher.raw.update_connections().map_err(|e| anyhow!("update connections of the raw publisher: {e:?}"))?;

    let mut payload = vec![0u8; max_bytes];
    for (i, b) in payload.iter_mut().enumerate() {
        *b = (i % 251) as u8;
    }
    let mut sent = publisher.send_rounds(child, &graphs, options, &mut payload)?;
    let receipts = guard.receipts()?;
    Ok(IpcLatency {
        wait: "iceoryx2 event listener (timed_wait), every kind".to_owned(),
        messages: options.ipc_messages,
        warmup: options.ipc_warmup,
        max_sample_bytes: size_of::<GraphHeader>() + IpcConfig::default().graph_capacity().max_payload_bytes(),
        rows: ipc_rows(&graphs, &mut sent, &receipts, options.ipc_messages)?,
    })
}

/// Per size of `received` messages: the timed ones' latencies (receive − send), milliseconds.
/// `what` names the kind in errors.
fn latencies(sent: &SentAt, received: &[(u64, u64)], sizes: usize, what: &str) -> anyhow::Result<Vec<Vec<f64>>> {
    let mut per_size: Vec<Vec<f64>> = vec![Vec::new(); sizes];
    for &(id, t1) in received {
        let Some(&(size, t0, timed)) = sent.get(&id) else {
            bail!("the subscriber received {what} {id}, which was never sent");
        };
        if timed {
            per_size[size].push(t1.saturating_sub(t0) as f64 / 1e6);
        }
    }
    Ok(per_size)
}

/// Per size, the timed values of `values` (one per received message of `received`, in order),
/// milliseconds; messages not timed are left out.
fn per_size(sent: &SentAt, received: &[(u64, u64)], values: &[u64], sizes: usize) -> Vec<Vec<f64>> {
    let mut out: Vec<Vec<f64>> = vec![Vec::new(); sizes];
    for (&(id, _), &ns) in received.iter().zip(values) {
        if let Some(&(size, _, true)) = sent.get(&id) {
            out[size].push(ns as f64 / 1e6);
        }
    }
    out
}

/// One row per size of `graphs` from what was sent and what the subscriber received; every
/// size must have `messages` timed messages of each kind.
fn ipc_rows(
    graphs: &[SceneGraph],
    sent: &mut Sent,
    receipts: &Receipts,
    messages: usize,
) -> anyhow::Result<Vec<IpcRow>> {
    let sizes = graphs.len();
    let mut graph_ms = latencies(&sent.graph.at, &receipts.graph, sizes, "graph")?;
    let mut read_ms = per_size(&sent.graph.at, &receipts.graph, &receipts.graph_read_ns, sizes);
    let mut index_ms = per_size(&sent.graph.at, &receipts.graph, &receipts.graph_index_ns, sizes);
    let mut view_ms = latencies(&sent.view.at, &receipts.view, sizes, "graph read through the view")?;
    let mut view_read_ms = per_size(&sent.view.at, &receipts.view, &receipts.view_read_ns, sizes);
    let mut raw_ms = latencies(&sent.raw.at, &receipts.raw, sizes, "raw sample")?;
    let mut rows = Vec::new();
    for (i, graph) in graphs.iter().enumerate() {
        if graph_ms[i].len() != messages || raw_ms[i].len() != messages || view_ms[i].len() != messages {
            bail!(
                "graphs of {} nodes: {} graphs, {} raw samples and {} views received of {} sent each",
                graph.nodes.len(),
                graph_ms[i].len(),
                raw_ms[i].len(),
                view_ms[i].len(),
                messages
            );
        }
        let g = Percentiles::from_samples_ms(&mut graph_ms[i]);
        let r = Percentiles::from_samples_ms(&mut raw_ms[i]);
        let v = Percentiles::from_samples_ms(&mut view_ms[i]);
        rows.push(IpcRow {
            nodes: graph.nodes.len(),
            edges: graph.edges.len(),
            bytes: filled_bytes(graph),
            ratio_p50: g.p50_ms / r.p50_ms.max(1e-9),
            ratio_p99: g.p99_ms / r.p99_ms.max(1e-9),
            view_ratio_p50: v.p50_ms / r.p50_ms.max(1e-9),
            view_ratio_p99: v.p99_ms / r.p99_ms.max(1e-9),
            graph: g,
            raw: r,
            view: v,
            graph_publish_call: Percentiles::from_samples_ms(&mut sent.graph.calls_ms[i]),
            raw_publish_call: Percentiles::from_samples_ms(&mut sent.raw.calls_ms[i]),
            view_publish_call: Percentiles::from_samples_ms(&mut sent.view.calls_ms[i]),
            graph_read_call: Percentiles::from_samples_ms(&mut read_ms[i]),
            graph_index_build: Percentiles::from_samples_ms(&mut index_ms[i]),
            view_read_call: Percentiles::from_samples_ms(&mut view_read_ms[i]),
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn synthetic_graph_has_the_asked_size_and_valid_edges() {
        let g = synthetic_graph(2_000, 3);
        assert_eq!(g.nodes.len(), 2_000);
        assert_eq!(g.edges.len(), 4_000);
        assert_eq!(g.part_count(), 500);
        assert!(g.edges.iter().all(|e| (e.source_id as usize) < 2_000 && (e.target_id as usize) < 2_000));
        assert!(g.nodes.iter().filter(|n| n.kind == NodeKind::Part).all(|n| n.parent_id.is_some()));
        assert_eq!(filled_bytes(&g), size_of::<GraphHeader>() + 2_000 * 144 + 4_000 * 64);
        assert_eq!(synthetic_graph(MAX_NODES + 10, 1).nodes.len(), MAX_NODES);
    }
}
