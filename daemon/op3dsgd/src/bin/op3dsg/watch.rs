//! `op3dsg watch`: a live text view of the daemon, one line per graph update or per interval,
//! read with the client library's [`GraphSubscriber`] and [`HealthSubscriber`] on the daemon's
//! computer, or its [`RemoteGraphSubscriber`] over Zenoh from another.

use std::fmt::Write as _;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use op3dsg_ipc_types::client::RemoteGraphSubscriber;
use op3dsg_ipc_types::{ClientError, Graph, GraphSubscriber, HealthSubscriber};
use op3dsg_runtime::ipc::HealthReport;

use super::{DaemonAt, node_name};

/// One line for `watch`.
fn watch_line(graph: Option<&Graph>, health: Option<&HealthReport>) -> String {
    let mut s = String::new();
    match graph {
        Some(g) => {
            let _ = write!(
                s,
                "v{} {} in {} objects {} parts {} edges {}{}{}",
                g.version(),
                g.source_kind().as_str(),
                if g.world_frame().is_empty() { "?" } else { g.world_frame() },
                g.objects().count(),
                g.parts().count(),
                g.edge_count(),
                if g.capacity_exceeded() { " CAPACITY EXCEEDED" } else { "" },
                if g.restarted() { " DAEMON RESTARTED" } else { "" }
            );
        }
        None => s.push_str("no graph yet"),
    }
    if let Some(h) = health {
        let _ =
            write!(s, " | frames {} keyframes {} no pose {}", h.frames_captured, h.keyframes, h.frames_without_pose);
        let accepted = h.poses.get("accepted").copied().unwrap_or(0);
        let refused: u64 = h.poses.iter().filter(|(outcome, _)| *outcome != "accepted").map(|(_, n)| n).sum();
        if accepted + refused > 0 {
            let _ = write!(s, " | poses ok {accepted} refused {refused}");
        }
        for st in &h.stages {
            let _ = write!(
                s,
                " | {} {:.1}Hz p50 {:.1}ms p99 {:.1}ms",
                st.name,
                st.rate_hz,
                st.latency_p50_us / 1000.0,
                st.latency_p99_us / 1000.0
            );
        }
        for q in &h.queues {
            let _ = write!(s, " | q {} {}/{} drop {}", q.name, q.depth, q.capacity, q.dropped);
        }
    }
    s
}

/// The graph and health subscribers of `watch`; "not serving" until the daemon has created
/// `graph`, `graph_updated` and `health`.
fn open_subscribers(prefix: &str, wait: Duration) -> Result<(GraphSubscriber, HealthSubscriber), ClientError> {
    let graphs = GraphSubscriber::open_wait(prefix, &node_name(), wait)?;
    let healths = HealthSubscriber::open_wait(prefix, &node_name(), wait)?;
    Ok((graphs, healths))
}

/// `op3dsg watch`: waits for the daemon (saying so once), then prints until Ctrl-C.
pub(super) fn watch(from: DaemonAt<'_>, interval: Duration) -> Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst)).context("installing the Ctrl-C handler")?;
    }
    match from {
        DaemonAt::Iceoryx2 { prefix } => watch_local(prefix, interval, &stop),
        DaemonAt::Zenoh { endpoint, key_prefix } => watch_remote(endpoint, key_prefix, interval, &stop),
    }
}

/// `watch` over iceoryx2, on the daemon's computer.
fn watch_local(prefix: &str, interval: Duration, stop: &AtomicBool) -> Result<()> {
    let mut announced = false;
    // Try once at once, so the "waiting" line appears immediately when the daemon is not up.
    let mut attempt = open_subscribers(prefix, Duration::ZERO);
    let (mut graphs, mut healths) = loop {
        match attempt {
            Ok(subscribers) => break subscribers,
            Err(e) if e.is_not_serving() => {}
            Err(e) => return Err(e).with_context(|| format!("connecting to op3dsgd under prefix '{prefix}'")),
        }
        if stop.load(Ordering::SeqCst) {
            return Ok(());
        }
        if !announced {
            eprintln!("waiting for op3dsgd under prefix {prefix}...");
            announced = true;
        }
        attempt = open_subscribers(prefix, Duration::from_millis(500));
    };
    eprintln!("connected to op3dsgd under prefix {prefix} (Ctrl-C to quit)");
    let mut last_print = Instant::now() - interval;
    while !stop.load(Ordering::SeqCst) {
        let woken = graphs.wait_for_update(Duration::from_millis(100)).context("waiting for graph updates")?;
        let changed = graphs.poll().with_context(|| format!("reading service {prefix}/graph"))?;
        let health = healths.latest().with_context(|| format!("reading service {prefix}/health"))?;
        if changed || woken || last_print.elapsed() >= interval {
            println!("{}", watch_line(graphs.graph(), health.as_ref().map(HealthReport::from).as_ref()));
            last_print = Instant::now();
        }
    }
    Ok(())
}

/// `watch` over Zenoh, from another computer: the graph followed from full graphs and deltas,
/// the health record as the daemon publishes it. A daemon not up yet shows as "no graph yet".
fn watch_remote(endpoint: &str, key_prefix: &str, interval: Duration, stop: &AtomicBool) -> Result<()> {
    let mut remote = RemoteGraphSubscriber::connect(endpoint, key_prefix)?;
    eprintln!("following {key_prefix}/graph on zenoh endpoint {endpoint} (Ctrl-C to quit)");
    let mut graph = None;
    let mut last_print = Instant::now() - interval;
    while !stop.load(Ordering::SeqCst) {
        let changed = remote.poll()?;
        if changed {
            graph = remote.graph()?;
        }
        if changed || last_print.elapsed() >= interval {
            let health = remote.health_json().and_then(|json| serde_json::from_str::<HealthReport>(json).ok());
            println!("{}", watch_line(graph.as_ref(), health.as_ref()));
            last_print = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(())
}
