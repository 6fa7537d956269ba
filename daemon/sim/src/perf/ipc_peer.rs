//! The subscriber process of the IPC measurement ([`ipc_latency`](super::ipc_latency)):
//! `op3dsg --prefix P bench ipc-peer --rounds N` takes, per round, a graph into the client
//! library's owned `Graph`, a raw iceoryx2 sample (copied out), and a graph through the zero-copy
//! `GraphView`, acknowledging each, and prints what it received as JSON ([`Receipts`]).

use std::time::{Duration, Instant};

use anyhow::{Context as _, anyhow, bail};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::subscriber::Subscriber;
use op3dsg_ipc_types::{GraphSubscriber, IpcRoot};
use serde::{Deserialize, Serialize};

use super::ipc_latency::{BenchServices, PEER_TIMEOUT};
use op3dsg_runtime::ipc::{IpcService, create_node, service_name};
use op3dsg_runtime::world::clock::wall_clock_ns;

/// What the child received: per kind, `(message id, receive wall clock ns)`.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct Receipts {
    /// Graph messages read into the owned graph (id = graph version).
    pub graph: Vec<(u64, u64)>,
    /// Per graph message, nanoseconds spent in the successful `GraphSubscriber::latest_if_newer`
    /// call.
    pub graph_read_ns: Vec<u64>,
    /// Per graph message, nanoseconds of the first id lookup after the read (the index build),
    /// taken after the receive stamp.
    #[serde(default)]
    pub graph_index_ns: Vec<u64>,
    /// Graph messages read through the view (id = graph version); the stamp is taken in the
    /// closure, once the first node was read.
    #[serde(default)]
    pub view: Vec<(u64, u64)>,
    /// Per view message, nanoseconds from the `with_latest` call to the first node read.
    #[serde(default)]
    pub view_read_ns: Vec<u64>,
    /// Raw messages (id = the first 8 bytes, little endian).
    pub raw: Vec<(u64, u64)>,
}

/// The ports of the subscriber process.
struct Peer {
    graphs: GraphSubscriber,
    raw: Subscriber<IpcService, [u8], ()>,
    raw_updated: Listener<IpcService>,
    ack: Notifier<IpcService>,
    names: BenchServices,
    _node: iceoryx2::node::Node<IpcService>,
}

impl Peer {
    fn open(prefix: &str) -> anyhow::Result<Self> {
        let graphs = GraphSubscriber::open_wait(prefix, "op3dsg-bench-subscriber", PEER_TIMEOUT)
            .context("opening the graph services")?;
        let names = BenchServices::new(prefix);
        let node = create_node(&IpcRoot::resolve(), "op3dsg-bench-subscriber-raw")?;
        let raw = node
            .service_builder(&service_name(prefix, &names.raw_name)?)
            .publish_subscribe::<[u8]>()
            .open()
            .map_err(|e| anyhow!("open service {}: {e:?}", names.raw_name))?
            .subscriber_builder()
            .create()
            .map_err(|e| anyhow!("create subscriber on {}: {e:?}", names.raw_name))?;
        let raw_updated = node
            .service_builder(&service_name(prefix, &names.raw_updated_name)?)
            .event()
            .open()
            .map_err(|e| anyhow!("open service {}: {e:?}", names.raw_updated_name))?
            .listener_builder()
            .create()
            .map_err(|e| anyhow!("create listener on {}: {e:?}", names.raw_updated_name))?;
        let ack = node
            .service_builder(&service_name(prefix, &names.ack_name)?)
            .event()
            .open()
            .map_err(|e| anyhow!("open service {}: {e:?}", names.ack_name))?
            .notifier_builder()
            .create()
            .map_err(|e| anyhow!("create notifier on {}: {e:?}", names.ack_name))?;
        Ok(Self { graphs, raw, raw_updated, ack, names, _node: node })
    }

    fn acknowledge(&self) -> anyhow::Result<()> {
        self.ack.notify().map(|_| ()).map_err(|e| anyhow!("notify {}: {e:?}", self.names.ack_name))
    }

    /// Waits for the next graph newer than `last_version` and copies it into the owned graph;
    /// records the receipt, the read call and the index build.
    fn take_owned(&mut self, last_version: u64, receipts: &mut Receipts, deadline: Instant) -> anyhow::Result<u64> {
        let version = loop {
            if self.graphs.wait_for_update(Duration::from_millis(100)).context("waiting for a graph")? {
                let read = Instant::now();
                if let Some(graph) = self.graphs.latest_if_newer(last_version).context("reading a graph")? {
                    receipts.graph_read_ns.push(read.elapsed().as_nanos() as u64);
                    break graph.version();
                }
            }
            if Instant::now() >= deadline {
                bail!("no graph within {} s", PEER_TIMEOUT.as_secs());
            }
        };
        let received_ns = wall_clock_ns();
        if let Some(graph) = self.graphs.graph() {
            let index = Instant::now();
            std::hint::black_box(graph.node(0).is_some());
            receipts.graph_index_ns.push(index.elapsed().as_nanos() as u64);
        }
        receipts.graph.push((version, received_ns));
        Ok(version)
    }

    /// Waits for the next graph and reads its first node's id and label through the view;
    /// records the receipt (stamped in the closure) and the read call.
    fn take_view(&mut self, receipts: &mut Receipts, deadline: Instant) -> anyhow::Result<u64> {
        loop {
            if self.graphs.wait_for_update(Duration::from_millis(100)).context("waiting for a graph")? {
                let read = Instant::now();
                let taken = self
                    .graphs
                    .with_latest(|view| {
                        let first = view.nodes().next().map(|n| (n.id(), n.label().len()));
                        std::hint::black_box(first);
                        (view.version(), wall_clock_ns(), read.elapsed().as_nanos() as u64)
                    })
                    .context("reading a graph through the view")?;
                if let Some((version, received_ns, read_ns)) = taken {
                    receipts.view.push((version, received_ns));
                    receipts.view_read_ns.push(read_ns);
                    return Ok(version);
                }
            }
            if Instant::now() >= deadline {
                bail!("no graph for the view within {} s", PEER_TIMEOUT.as_secs());
            }
        }
    }

    /// Waits for the next raw sample and copies its bytes out (into `copy`); records the
    /// receipt.
    fn take_raw(&self, copy: &mut Vec<u8>, receipts: &mut Receipts, deadline: Instant) -> anyhow::Result<()> {
        let names = &self.names;
        let id = loop {
            let woken = self
                .raw_updated
                .timed_wait(|_| {}, Duration::from_millis(100))
                .map_err(|e| anyhow!("waiting on {}: {e:?}", names.raw_updated_name))?;
            if woken > 0
                && let Some(sample) = self.raw.receive().map_err(|e| anyhow!("receive on {}: {e:?}", names.raw_name))?
            {
                copy.clear();
                copy.extend_from_slice(sample.payload());
                let mut id = [0u8; 8];
                id.copy_from_slice(copy.get(..8).ok_or_else(|| anyhow!("raw sample shorter than 8 bytes"))?);
                break u64::from_le_bytes(id);
            }
            if Instant::now() >= deadline {
                bail!("no raw sample within {} s", PEER_TIMEOUT.as_secs());
            }
        };
        receipts.raw.push((id, wall_clock_ns()));
        Ok(())
    }
}

/// The subscriber process: opens the services under `prefix`, acknowledges start-up, then takes
/// `rounds` rounds of a graph (owned), a raw sample and a graph (view) in turn, acknowledging
/// each, and returns the receipts (the CLI prints them as JSON on standard output).
pub fn ipc_peer(prefix: &str, rounds: usize) -> anyhow::Result<Receipts> {
    let mut peer = Peer::open(prefix)?;
    peer.acknowledge()?;
    let mut receipts = Receipts {
        graph: Vec::with_capacity(rounds),
        graph_read_ns: Vec::with_capacity(rounds),
        graph_index_ns: Vec::with_capacity(rounds),
        view: Vec::with_capacity(rounds),
        view_read_ns: Vec::with_capacity(rounds),
        raw: Vec::with_capacity(rounds),
    };
    let mut copy: Vec<u8> = Vec::new();
    let mut last_version = 0;
    for _ in 0..rounds {
        let deadline = Instant::now() + PEER_TIMEOUT;
        last_version = peer.take_owned(last_version, &mut receipts, deadline)?;
        peer.acknowledge()?;
        peer.take_raw(&mut copy, &mut receipts, deadline)?;
        peer.acknowledge()?;
        let view_version = peer.take_view(&mut receipts, deadline)?;
        if view_version <= last_version {
            bail!("the view read graph version {view_version}, not newer than the owned read's {last_version}");
        }
        peer.acknowledge()?;
    }
    Ok(receipts)
}
