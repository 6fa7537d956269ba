//! `op3dsg watch`: a live text view of the daemon, one line per graph update or per interval,
//! read with the client library's [`GraphSubscriber`] and [`HealthSubscriber`].

use std::fmt::Write as _;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use op3dsg_ipc_types::{ClientError, Graph, GraphSubscriber, Health, HealthSubscriber};

use super::node_name;

/// One line for `watch`.
fn watch_line(graph: Option<&Graph>, health: Option<&Health>) -> String {
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
        let p = &h.pose;
        let refused = p.unknown_kind
            + p.non_finite
            + p.non_unit_quaternion
            + p.no_base_from_camera
            + p.out_of_order
            + p.stale
            + p.future
            + p.queue_full;
        if p.accepted + refused > 0 {
            let _ = write!(s, " | poses ok {} refused {refused}", p.accepted);
        }
        for st in h.valid_stages() {
            let _ = write!(
                s,
                " | {} {:.1}Hz p50 {:.1}ms p99 {:.1}ms",
                op3dsg_ipc_types::fixed_str(&st.name),
                st.rate_hz,
                st.latency_p50_us / 1000.0,
                st.latency_p99_us / 1000.0
            );
        }
        for q in h.valid_queues() {
            let _ = write!(
                s,
                " | q {} {}/{} drop {}",
                op3dsg_ipc_types::fixed_str(&q.name),
                q.depth,
                q.capacity,
                q.dropped
            );
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
pub(super) fn watch(prefix: &str, interval: Duration) -> Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst)).context("installing the Ctrl-C handler")?;
    }
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
            println!("{}", watch_line(graphs.graph(), health.as_ref()));
            last_print = Instant::now();
        }
    }
    Ok(())
}
