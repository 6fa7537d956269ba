//! `op3dsg dump`: the current graph once, read with the client library's [`GraphSubscriber`], as
//! a table or (with `--json`) as graph JSON (`op3dsg.graph/1`).

use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use op3dsg_ipc_types::{Graph, GraphSubscriber};
use op3dsg_runtime::ipc::graph_to_scene_graph;

use super::{node_name, poll_until, write_output};

/// `op3dsg dump`: waits up to `timeout` for the daemon and its first graph, then writes it to
/// `out` (or standard output).
pub(super) fn dump(prefix: &str, json: bool, timeout: Duration, out: Option<&Path>) -> Result<()> {
    let deadline = Instant::now() + timeout;
    let mut graphs = GraphSubscriber::open_wait(prefix, &node_name(), timeout).with_context(|| {
        format!("connecting to op3dsgd under prefix '{prefix}' (waited {:.1} s)", timeout.as_secs_f64())
    })?;
    let remaining = deadline.saturating_duration_since(Instant::now());
    let Some(graph) = poll_until(remaining, || graphs.latest().map(|graph| graph.cloned()))
        .with_context(|| format!("reading service {prefix}/graph"))?
    else {
        bail!(
            "no graph received on service {prefix}/graph within {:.1} s (op3dsgd is up but has not published yet?)",
            timeout.as_secs_f64()
        );
    };
    let text = if json {
        let json = graph_to_scene_graph(&graph).to_json("op3dsgd");
        let mut text = serde_json::to_string_pretty(&json).context("serialising the graph JSON")?;
        text.push('\n');
        text
    } else {
        graph_table(&graph)
    };
    write_output(out, &text)
}

fn fmt3(v: [f32; 3]) -> String {
    format!("{:.2},{:.2},{:.2}", v[0], v[1], v[2])
}

/// The table form: a summary line, one line per node (in id order), then one per edge.
fn graph_table(graph: &Graph) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "graph version {}  instance {:#018x}  stamp {} ns  {} objects  {} parts  {} edges",
        graph.version(),
        graph.instance_id(),
        graph.stamp_ns(),
        graph.objects().count(),
        graph.parts().count(),
        graph.edge_count()
    );
    let _ = writeln!(
        s,
        "{:>6}  {:<6}  {:<24}  {:>6}  {:<20}  {:<16}  {:>5}  affordances",
        "id", "kind", "label", "parent", "centre_m", "size_m", "obs"
    );
    for n in graph.nodes() {
        let parent = n.parent_id().map_or_else(|| "-".to_owned(), |p| p.to_string());
        let affordances: Vec<&str> = n.affordances().collect();
        let _ = writeln!(
            s,
            "{:>6}  {:<6}  {:<24}  {:>6}  {:<20}  {:<16}  {:>5}  {}",
            n.id(),
            n.kind().as_str(),
            n.label(),
            parent,
            fmt3(n.centre_m()),
            fmt3(n.size_m()),
            n.observation_count(),
            affordances.join(",")
        );
    }
    if graph.edge_count() > 0 {
        let _ = writeln!(s, "\nedges:");
        let label = |id: u32| graph.node(id).map_or("?", |n| n.label());
        for e in graph.edges() {
            let _ = writeln!(
                s,
                "  {} ({}) --[{}]--> {} ({})  {} {} conf {:.2}",
                e.source_id(),
                label(e.source_id()),
                op3dsg_ipc_types::relation_phrase(e.relation_id()).unwrap_or("unknown"),
                e.target_id(),
                label(e.target_id()),
                e.kind().as_str(),
                e.origin().as_str(),
                e.confidence()
            );
        }
    }
    s
}
