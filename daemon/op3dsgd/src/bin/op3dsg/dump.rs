//! `op3dsg dump`: the current graph once, read with the client library's [`GraphSubscriber`] (or,
//! with `--zenoh`, its [`RemoteGraphSubscriber`] from another computer), as
//! a table, as graph JSON (`op3dsg.graph/1`), in the compact form for LLM prompts
//! (`op3dsg.llm/1`, see `docs/llm-graph.md`), or as a picture (Graphviz DOT or SVG, see
//! [`picture`](super::picture)).

use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
#[cfg(feature = "zenoh")]
use op3dsg_ipc_types::client::RemoteGraphSubscriber;
use op3dsg_ipc_types::{EdgeKind, Graph, GraphSubscriber, NodeView};
use op3dsg_runtime::ipc::graph_to_scene_graph;
use serde_json::{Value, json};

use super::DaemonAt;
use super::{connect_error, node_name, poll_until, write_output};

/// What `op3dsg dump` prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(super) enum DumpFormat {
    /// A table: a summary line, one line per node, one per edge.
    Table,
    /// The graph JSON form (op3dsg.graph/1).
    Json,
    /// The compact JSON form for LLM prompts (op3dsg.llm/1).
    Llm,
    /// Graphviz DOT: objects and parts as nodes, relations as labelled edges.
    Dot,
    /// The DOT picture drawn as SVG (laid out without Graphviz).
    Svg,
}

/// `op3dsg dump`: waits up to `timeout` for the daemon and its first graph, then writes it to
/// `out` (or standard output).
pub(super) fn dump(from: DaemonAt<'_>, format: DumpFormat, timeout: Duration, out: Option<&Path>) -> Result<()> {
    let graph = match from {
        DaemonAt::Iceoryx2 { prefix } => local_graph(prefix, timeout)?,
        #[cfg(feature = "zenoh")]
        DaemonAt::Zenoh { endpoint, key_prefix } => {
            let mut remote = RemoteGraphSubscriber::connect(endpoint, key_prefix)?;
            remote.wait_graph(timeout)?
        }
    };
    let text = match format {
        DumpFormat::Json => {
            let mut json = graph_to_scene_graph(&graph).to_json("op3dsgd");
            json.source_kind = Some(graph.source_kind().as_str().to_owned());
            json.world_frame = Some(graph.world_frame().to_owned());
            let mut text = serde_json::to_string_pretty(&json).context("serialising the graph JSON")?;
            text.push('\n');
            text
        }
        DumpFormat::Llm => llm_form(&graph),
        DumpFormat::Table => graph_table(&graph),
        DumpFormat::Dot => super::picture::dot(&graph),
        DumpFormat::Svg => super::picture::svg(&graph),
    };
    write_output(out, &text)
}

/// The first graph of the daemon's iceoryx2 services under `prefix`, waiting up to `timeout`.
fn local_graph(prefix: &str, timeout: Duration) -> Result<Graph> {
    let deadline = Instant::now() + timeout;
    let mut graphs =
        GraphSubscriber::open_wait(prefix, &node_name(), timeout).map_err(|e| connect_error(prefix, timeout, e))?;
    let remaining = deadline.saturating_duration_since(Instant::now());
    let Some(graph) = poll_until(remaining, || graphs.latest().map(|graph| graph.cloned()))
        .with_context(|| format!("reading service {prefix}/graph"))?
    else {
        bail!(
            "no graph received on service {prefix}/graph within {:.1} s (op3dsgd is up but has not published yet?)",
            timeout.as_secs_f64()
        );
    };
    Ok(graph)
}

fn fmt3(v: [f32; 3]) -> String {
    format!("{:.2},{:.2},{:.2}", v[0], v[1], v[2])
}

/// The table form: a summary line, one line per node (in id order), then one per edge. Each
/// affordance is written with its origin as an edge's is (`hook_pull:knowledge+llm`).
fn graph_table(graph: &Graph) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "graph version {}  instance {:#018x}  stamp {} ns  source {}  frame {}  {} objects  {} parts  {} edges",
        graph.version(),
        graph.instance_id(),
        graph.stamp_ns(),
        graph.source_kind().as_str(),
        graph.world_frame(),
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
        let affordances: Vec<String> =
            n.affordance_origins().map(|(name, origin)| format!("{name}:{}", origin.as_str())).collect();
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

/// Metres to two decimals (centimetres): enough for a planner's reasoning, short in a prompt.
fn metres(v: f32) -> Value {
    json!((f64::from(v) * 100.0).round() / 100.0)
}

fn vec3(v: [f32; 3]) -> Value {
    Value::Array(v.into_iter().map(metres).collect())
}

/// The node's outgoing edges of `kind` as `[phrase, target id]` pairs, in wire order; a part's
/// "part of" edge to its parent is left out (the nesting says it).
fn relations(node: &NodeView<'_>, kind: EdgeKind) -> Vec<Value> {
    let parent = node.parent_id();
    node.edges_from()
        .filter(|e| e.kind() == kind)
        .filter(|e| !(e.kind() == EdgeKind::Spatial && e.phrase() == "part of" && Some(e.target_id()) == parent))
        .map(|e| json!([e.phrase(), e.target_id()]))
        .collect()
}

/// One node of the LLM form; empty lists are left out to keep the prompt short.
fn llm_node(node: &NodeView<'_>, with_parts: bool) -> Value {
    let mut item = serde_json::Map::new();
    item.insert("id".into(), json!(node.id()));
    item.insert("label".into(), json!(node.label()));
    item.insert("centre_m".into(), vec3(node.centre_m()));
    item.insert("size_m".into(), vec3(node.size_m()));
    let affordances: Vec<&str> = node.affordances().collect();
    if !affordances.is_empty() {
        item.insert("affordances".into(), json!(affordances));
        let origins: serde_json::Map<String, Value> =
            node.affordance_origins().map(|(name, origin)| (name.to_owned(), json!(origin.as_str()))).collect();
        item.insert("affordance_origins".into(), Value::Object(origins));
    }
    let functional = relations(node, EdgeKind::Functional);
    if !functional.is_empty() {
        item.insert("functional".into(), Value::Array(functional));
    }
    let spatial = relations(node, EdgeKind::Spatial);
    if !spatial.is_empty() {
        item.insert("spatial".into(), Value::Array(spatial));
    }
    if with_parts {
        let parts: Vec<Value> = node.parts().map(|p| llm_node(&p, false)).collect();
        if !parts.is_empty() {
            item.insert("parts".into(), Value::Array(parts));
        }
    }
    Value::Object(item)
}

/// The compact form for LLM prompts (`op3dsg.llm/1`): objects in id order, each with its parts
/// nested; parts without a parent object in this graph listed apart; relations as `[phrase,
/// target id]` from the node they leave. One object per line, so a prompt stays readable and a
/// diff between versions stays small. Documented in `docs/llm-graph.md`.
fn llm_form(graph: &Graph) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}",
        json!({
            "format": "op3dsg.llm/1",
            "instance_id": format!("{:#018x}", graph.instance_id()),
            "version": graph.version(),
            "source_kind": graph.source_kind().as_str(),
            "world_frame": graph.world_frame(),
            "objects": graph.objects().count(),
            "parts": graph.parts().count(),
        })
    );
    for object in graph.objects() {
        let _ = writeln!(s, "{}", json!({ "object": llm_node(&object, true) }));
    }
    for part in graph.parts().filter(|p| p.parent().is_none()) {
        let _ = writeln!(s, "{}", json!({ "unattached_part": llm_node(&part, false) }));
    }
    s
}

#[cfg(test)]
pub(crate) mod tests {
    use op3dsg_ipc_types::publish::GraphBuffer;
    use op3dsg_ipc_types::{Edge, GraphHeader, NO_NODE, Node, SCHEMA_VERSION, affordance_bits, write_fixed_str};

    use super::*;

    fn node(id: u32, parent_id: u32, label: &str, affordances: &[&str]) -> Node {
        let mut n = Node {
            id,
            parent_id,
            kind: u8::from(parent_id != NO_NODE),
            centre_m: [1.234, 0.5, 0.987],
            box_min_m: [1.0, 0.25, 0.5],
            box_max_m: [1.5, 0.75, 1.5],
            affordance_bits: affordance_bits(affordances.iter().copied()).unwrap(),
            ..Node::default()
        };
        write_fixed_str(&mut n.label, label);
        n
    }

    /// An edge by its relation phrase (spatial, or functional with `functional`); shared by the
    /// picture's tests.
    pub(crate) fn edge(source_id: u32, target_id: u32, functional: bool, phrase: &str) -> Edge {
        let relation_id = if functional {
            op3dsg_ipc_types::FUNCTIONAL_RELATION_BASE
                + op3dsg_ipc_types::FUNCTIONAL_RELATIONS.iter().position(|r| *r == phrase).unwrap() as u16
        } else {
            op3dsg_ipc_types::SPATIAL_RELATIONS.iter().position(|r| *r == phrase).unwrap() as u16
        };
        let mut e = Edge { source_id, target_id, kind: u8::from(functional), relation_id, ..Edge::default() };
        write_fixed_str(&mut e.phrase, phrase);
        e
    }

    #[test]
    fn llm_form_nests_parts_under_their_object_and_lists_relations_by_id() {
        let mut buffer = GraphBuffer::new();
        buffer.header = GraphHeader {
            schema_version: SCHEMA_VERSION,
            graph_version: 7,
            instance_id: 0xabc,
            node_capacity: 16,
            edge_capacity: 16,
            ..GraphHeader::default()
        };
        let stove_phrase = op3dsg_ipc_types::FUNCTIONAL_RELATIONS[0];
        buffer.nodes = vec![
            node(1, NO_NODE, "stove", &[]),
            Node { affordance_knowledge_bits: 1, affordance_llm_bits: 1, ..node(2, 1, "stove knob", &["rotate"]) },
            node(3, NO_NODE, "counter", &[]),
            node(9, 42, "handle", &["hook_pull"]),
        ];
        buffer.edges = vec![edge(2, 1, true, stove_phrase), edge(2, 1, false, "part of"), edge(1, 3, false, "next to")];
        let graph = Graph::from_message(&buffer.encode()).unwrap();
        let text = llm_form(&graph);
        let lines: Vec<Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        assert_eq!(lines.len(), 4, "{text}");
        assert_eq!(lines[0]["format"], "op3dsg.llm/1");
        assert_eq!(lines[0]["version"], 7);
        assert_eq!(lines[0]["objects"], 2);
        assert_eq!(lines[0]["parts"], 2);
        let stove = &lines[1]["object"];
        assert_eq!(stove["id"], 1);
        assert_eq!(stove["centre_m"], json!([1.23, 0.5, 0.99]));
        assert_eq!(stove["size_m"], json!([0.5, 0.5, 1.0]));
        assert_eq!(stove["spatial"], json!([["next to", 3]]));
        assert!(stove.get("functional").is_none(), "empty lists are left out: {stove}");
        assert_eq!(stove["parts"][0]["label"], "stove knob");
        assert_eq!(stove["parts"][0]["affordances"], json!(["rotate"]));
        assert_eq!(stove["parts"][0]["functional"], json!([[stove_phrase, 1]]));
        assert!(stove["parts"][0].get("spatial").is_none(), "the nesting says part of: {stove}");
        assert_eq!(lines[2]["object"]["label"], "counter");
        assert_eq!(lines[3]["unattached_part"]["id"], 9);
        // Each affordance's origin beside the names: both masks, neither (geometry).
        assert_eq!(stove["parts"][0]["affordance_origins"], json!({"rotate": "knowledge+llm"}));
        assert_eq!(lines[3]["unattached_part"]["affordance_origins"], json!({"hook_pull": "geometry"}));
        assert!(stove.get("affordance_origins").is_none(), "no affordances, no origins: {stove}");
    }

    #[test]
    fn the_table_writes_each_affordance_with_its_origin() {
        let mut buffer = GraphBuffer::new();
        buffer.header = GraphHeader {
            schema_version: SCHEMA_VERSION,
            graph_version: 3,
            node_capacity: 16,
            edge_capacity: 16,
            ..GraphHeader::default()
        };
        let handle = node(2, 1, "cabinet handle", &["hook_pull", "pinch_pull", "tip_push"]);
        // hook_pull from both, pinch_pull from the LLM alone, tip_push from the knowledge base alone.
        let [hook, pinch, push] = ["hook_pull", "pinch_pull", "tip_push"].map(|a| affordance_bits([a]).unwrap());
        buffer.nodes = vec![
            node(1, NO_NODE, "cabinet", &[]),
            Node { affordance_knowledge_bits: hook | push, affordance_llm_bits: hook | pinch, ..handle },
            node(9, NO_NODE, "door", &["hook_turn"]),
        ];
        let graph = Graph::from_message(&buffer.encode()).unwrap();
        let table = graph_table(&graph);
        // The node row of `id`: its last column (the affordances, or the observation count).
        let row = |id: &str| {
            let line = table.lines().find(|l| l.split_whitespace().next() == Some(id)).unwrap();
            line.split_whitespace().last().unwrap()
        };
        let mut handle_row: Vec<&str> = row("2").split(',').collect();
        handle_row.sort_unstable();
        assert_eq!(handle_row, ["hook_pull:knowledge+llm", "pinch_pull:llm", "tip_push:knowledge"], "{table}");
        assert_eq!(row("9"), "hook_turn:geometry", "no origin bits: {table}");
        assert_eq!(row("1"), "0", "no affordances, an empty column after the count: {table}");
    }
}
