//! # Language queries: a need in words → the graph's nodes that serve it
//!
//! A planner asks `<prefix>/query` (iceoryx2 request-response, [`op3dsg_ipc_types::query_types`])
//! "somewhere to wash my hands" or "what controls the ceiling light" and gets the top-k nodes,
//! objects and parts alike, with a score and the text that matched. Two threads of its own run
//! it ([`query_threads`]), never the fusion thread.
//!
//! ## Threads
//!
//! The query service's two threads: `op3dsg-query-rx` takes requests off `<prefix>/query` and
//! `op3dsg-query` answers them, one at a time, with its own text encoder.
//!
//! ```text
//! planners ──[iceoryx2 request-response <prefix>/query]──► query-rx ──[jobs: bounded, query.queue_capacity]──► query worker
//!                                        ◄── busy / bad request / encoder off (at once) ◄┘                      │
//!                                        ◄───────────────────────── top-k reply ◄───────────────────────────────┘
//! publisher ──[latest graph, latest wins]──────────────────────────────────────────────────────────────────────►┘
//! ```
//!
//! - The receiver never blocks: a request finds room in the bounded job queue or is refused at
//!   once with [`QueryStatus::Busy`] (counted; the count travels in every reply).
//! - Requests from off the computer (the Zenoh queryable `<prefix>/query`, `crate::zenoh`) enter
//!   through [`QueryReceiverThread::remote_intake`]: the same checks, the same job queue and
//!   worker; the worker replies to them from its thread as it does over iceoryx2. Malformed
//!   requests and, without the text encoder, every request get their error reply here.
//! - Every reply's hits carry approach poses ([`Navigator`]: the newest occupancy map the
//!   occupancy thread handed over, inflated and flooded once per map version, A* per hit; see
//!   [`crate::occupancy::nav`]). A request naming a node (`QueryRequest::node_id`) is answered
//!   with that node alone and needs no text encoder, so the worker runs with the encoder off
//!   too; text requests then get [`QueryStatus::EncoderOff`] from the receiver at once.
//! - The worker holds the only [`TextEncoder`] of the service (ONNX Runtime with the profile's
//!   `text_encoder.intra_op_threads`), so at most one query is scored at a time and the fusion
//!   thread never waits on a query. It takes the newest graph the publisher has sent
//!   ([`LatestGraph`]) and re-indexes only when the version changed.
//! - Shutdown: both end with the stop flag, or when the publisher has ended (the end of a
//!   finite source with `run.exit_at_end`); requests still queued get [`QueryStatus::ShuttingDown`].
//!
//! ## Scoring
//!
//! Each node of the newest published graph is described by a few short texts, built from the
//! graph alone ([`node_texts`]):
//!
//! | [`QueryMatch`] | text | example |
//! |---|---|---|
//! | `label` | the label | `sink` |
//! | `parent_label` | a part's label with its parent object's (parts with a parent only) | `knob of the stove` |
//! | `affordance` | each affordance as an action on the node ([`affordance_phrase`]) | `pull the fridge handle to open it` |
//! | `functional` | each functional edge the node is the source of: its phrase and the target's label ([`functional_phrase`]) | `light switch to turn on or turn off the ceiling light` |
//!
//! With the query's embedding `q` and each text's `t` (all-MiniLM-L6-v2, unit length, so the dot
//! product is the cosine) a node scores
//!
//! ```text
//! score(node) = max over the node's texts t of  q · t
//! ```
//!
//! and the reply lists the `k` best nodes, best first (ties: the lower id first), each with the
//! text that gave its score (the "why"). Without the functional texts
//! ([`ScoringOptions::functional`] = false) the same formula runs over label, parent label and
//! affordances only: what an object-and-part list without the unified graph's edges gives
//! (`op3dsg bench query` reports both).
//!
//! ## Cost
//!
//! Text embeddings are cached by text in the worker's [`TextEncoder`], and the per-graph index
//! ([`QueryIndex`]) keeps one embedding per distinct text of the graph, rebuilt only when a new
//! graph version arrives (a rebuild embeds only texts never seen before). A query then costs one
//! encoder call for its own text plus one dot product per distinct text and a max per node.

mod receiver;
mod worker;

pub use receiver::{QueryCounters, QueryReceiverThread};
pub use worker::{EncoderSetup, NavigationSetup, Navigator, QueryWorkerThread, to_wire};

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use crossbeam_channel::Receiver;

use op3dsg_ipc_types::{AFFORDANCES, EdgeKind, NO_NODE, NodeKind, QueryMatch, relation_phrase};
use serde::{Deserialize, Serialize};

use crate::embedding::Embedding;
use crate::flow::LatestGraph;
use crate::graph::SceneGraph;
use crate::ipc::IpcConfig;
use crate::onnx::OnnxError;
use crate::onnx::text_encoder::TextEncoder;

/// `[query]`: the language query service.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct QueryConfig {
    /// Serve `<prefix>/query`. With `text_encoder.enabled = false` the service still answers,
    /// with a clear "encoder off" error, so a planner learns why.
    pub enabled: bool,
    /// Requests waiting for the worker at most; more are refused at once with a "busy" reply.
    pub queue_capacity: usize,
    /// Score functional edges' phrases too (see the module docs).
    pub functional: bool,
}

impl Default for QueryConfig {
    fn default() -> Self {
        Self { enabled: true, queue_capacity: 8, functional: true }
    }
}

impl QueryConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(1..=1024).contains(&self.queue_capacity) {
            return Err(format!("{path}.queue_capacity: must be within [1, 1024], got {}", self.queue_capacity));
        }
        Ok(())
    }
}

/// The receiver and the worker of `<prefix>/query`, connected by the job queue
/// (`query.queue_capacity`); `encoder_setup` is `None` when the profile has the text encoder off
/// (node queries are answered all the same).
pub fn query_threads(
    ipc: &IpcConfig,
    config: &QueryConfig,
    encoder_setup: Option<EncoderSetup>,
    navigation: NavigationSetup,
    latest: Arc<LatestGraph>,
    stop: Arc<AtomicBool>,
) -> (QueryReceiverThread, QueryWorkerThread, Receiver<Result<(), String>>) {
    let counters = Arc::new(QueryCounters::default());
    let (jobs_tx, jobs_rx) = crossbeam_channel::bounded(config.queue_capacity);
    let (ready_tx, ready_rx) = crossbeam_channel::bounded(1);
    let receiver = QueryReceiverThread {
        ipc: ipc.clone(),
        ready: ready_tx,
        jobs: jobs_tx,
        encoder_on: encoder_setup.is_some(),
        capacity: config.queue_capacity,
        counters: counters.clone(),
        latest: latest.clone(),
        stop: stop.clone(),
    };
    let worker =
        QueryWorkerThread { encoder_setup, navigation, jobs: jobs_rx, config: config.clone(), counters, latest, stop };
    (receiver, worker, ready_rx)
}

/// Which texts a node is scored on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScoringOptions {
    /// Include the functional edges' phrases.
    pub functional: bool,
}

impl Default for ScoringOptions {
    fn default() -> Self {
        Self { functional: true }
    }
}

/// An affordance (one of [`AFFORDANCES`]) as an action on a node called `name`.
pub fn affordance_phrase(affordance: &str, name: &str) -> String {
    match affordance {
        "rotate" => format!("rotate the {name} to adjust it"),
        "key_press" => format!("press the keys of the {name}"),
        "tip_push" => format!("push the {name} with a fingertip"),
        "hook_pull" => format!("pull the {name} to open it"),
        "pinch_pull" => format!("pinch and pull the {name}"),
        "hook_turn" => format!("turn the {name} by its lever"),
        "foot_push" => format!("step on the {name} with a foot"),
        "plug_in" => format!("plug a device into the {name}"),
        "unplug" => format!("unplug a device from the {name}"),
        other => format!("{} the {name}", other.replace('_', " ")),
    }
}

/// A functional edge `source —phrase→ target` as one sentence: the canonical phrase (one of
/// [`op3dsg_ipc_types::FUNCTIONAL_RELATIONS`]) with its object put where English puts it.
pub fn functional_phrase(source: &str, phrase: &str, target: &str) -> String {
    let action = match phrase {
        "remote to control" => format!("control the {target} remotely"),
        "provide power" => format!("provide power to the {target}"),
        "control the water flow"
        | "rotate to adjust the setting or temperature"
        | "operate or adjust the flow or setting" => format!("{phrase} of the {target}"),
        _ => format!("{phrase} the {target}"),
    };
    format!("{source} to {action}")
}

/// What a node is called in its texts: a part whose label does not name its parent gets the
/// parent's ("handle" of "fridge" → "handle of the fridge"; "fridge handle" stays).
fn display_name(label: &str, parent: Option<&str>) -> String {
    match parent {
        Some(parent) if !label.contains(parent) => format!("{label} of the {parent}"),
        _ => label.to_owned(),
    }
}

/// The texts node `index` of `graph` is scored on, with what each is ([`QueryMatch`]).
pub fn node_texts(graph: &SceneGraph, options: ScoringOptions) -> Vec<Vec<(QueryMatch, String)>> {
    let by_id: HashMap<u32, usize> = graph.nodes.iter().enumerate().map(|(i, n)| (n.id, i)).collect();
    let label_of = |id: u32| by_id.get(&id).map(|i| graph.nodes[*i].label.as_str());
    let mut texts: Vec<Vec<(QueryMatch, String)>> = graph
        .nodes
        .iter()
        .map(|node| {
            let parent = node.parent_id.and_then(label_of).filter(|p| !p.is_empty());
            let name = display_name(&node.label, parent);
            let mut out = vec![(QueryMatch::Label, node.label.clone())];
            if node.kind == NodeKind::Part && name != node.label {
                out.push((QueryMatch::ParentLabel, name.clone()));
            }
            for (bit, affordance) in AFFORDANCES.iter().enumerate() {
                if node.affordance_bits & (1 << bit) != 0 {
                    out.push((QueryMatch::Affordance, affordance_phrase(affordance, &name)));
                }
            }
            out
        })
        .collect();
    if options.functional {
        for edge in graph.edges.iter().filter(|e| e.kind == EdgeKind::Functional) {
            let (Some(&source), Some(&target)) = (by_id.get(&edge.source_id), by_id.get(&edge.target_id)) else {
                continue;
            };
            let Some(phrase) = relation_phrase(edge.relation_id) else { continue };
            // The target usually is the part's own parent ("faucet to control the water flow of
            // the sink"), so the source goes by its own label here.
            let text = functional_phrase(&graph.nodes[source].label, phrase, &graph.nodes[target].label);
            if !texts[source].iter().any(|(_, t)| *t == text) {
                texts[source].push((QueryMatch::Functional, text));
            }
        }
    }
    texts
}

/// One scored node.
#[derive(Debug, Clone, PartialEq)]
pub struct Hit {
    /// Node id.
    pub node_id: u32,
    /// Parent id, [`NO_NODE`] when none.
    pub parent_id: u32,
    /// Kind.
    pub kind: NodeKind,
    /// Label.
    pub label: String,
    /// Score (see the module docs).
    pub score: f32,
    /// Which text matched best.
    pub matched: QueryMatch,
    /// That text.
    pub matched_text: String,
}

struct IndexedNode {
    node_id: u32,
    parent_id: u32,
    kind: NodeKind,
    label: String,
    /// `(what, distinct text index)`.
    texts: Vec<(QueryMatch, u32)>,
}

/// One graph version ready to be queried: its nodes' texts, each distinct text embedded once.
pub struct QueryIndex {
    graph_version: u64,
    nodes: Vec<IndexedNode>,
    texts: Vec<String>,
    embeddings: Vec<Embedding>,
    similarity: Vec<f32>,
}

impl std::fmt::Debug for QueryIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QueryIndex")
            .field("graph_version", &self.graph_version)
            .field("nodes", &self.nodes.len())
            .field("texts", &self.texts.len())
            .finish_non_exhaustive()
    }
}

impl QueryIndex {
    /// Indexes `graph`: builds every node's texts and embeds the distinct ones (answered from the
    /// encoder's cache when seen before).
    pub fn build(graph: &SceneGraph, encoder: &mut TextEncoder, options: ScoringOptions) -> Result<Self, OnnxError> {
        let mut text_ids: HashMap<String, u32> = HashMap::new();
        let mut texts = Vec::new();
        let nodes = graph
            .nodes
            .iter()
            .zip(node_texts(graph, options))
            .map(|(node, node_texts)| IndexedNode {
                node_id: node.id,
                parent_id: node.parent_id.unwrap_or(NO_NODE),
                kind: node.kind,
                label: node.label.clone(),
                texts: node_texts
                    .into_iter()
                    .map(|(what, text)| {
                        let id = *text_ids.entry(text.clone()).or_insert_with(|| {
                            texts.push(text);
                            (texts.len() - 1) as u32
                        });
                        (what, id)
                    })
                    .collect(),
            })
            .collect();
        let refs: Vec<&str> = texts.iter().map(String::as_str).collect();
        let mut embeddings = Vec::with_capacity(refs.len());
        encoder.encode_batch_into(&refs, &mut embeddings)?;
        let similarity = vec![0.0; texts.len()];
        Ok(Self { graph_version: graph.version, nodes, texts, embeddings, similarity })
    }

    /// The graph version indexed.
    pub fn graph_version(&self) -> u64 {
        self.graph_version
    }

    /// Nodes indexed.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Distinct texts embedded.
    pub fn text_count(&self) -> usize {
        self.texts.len()
    }

    /// The `k` best nodes for a query embedding, best first, into `out` (cleared first).
    pub fn top_k(&mut self, query: &Embedding, k: usize, out: &mut Vec<Hit>) {
        out.clear();
        for (similarity, embedding) in self.similarity.iter_mut().zip(&self.embeddings) {
            *similarity = dot(query, embedding);
        }
        let mut scored: Vec<(f32, usize, usize)> = Vec::with_capacity(self.nodes.len());
        for (index, node) in self.nodes.iter().enumerate() {
            let best =
                node.texts.iter().enumerate().map(|(slot, (_, text))| (self.similarity[*text as usize], slot)).fold(
                    None,
                    |best: Option<(f32, usize)>, c| match best {
                        Some(b) if b.0 >= c.0 => Some(b),
                        _ => Some(c),
                    },
                );
            if let Some((score, slot)) = best {
                scored.push((score, index, slot));
            }
        }
        let by_score = |a: &(f32, usize, usize), b: &(f32, usize, usize)| {
            b.0.total_cmp(&a.0).then(self.nodes[a.1].node_id.cmp(&self.nodes[b.1].node_id))
        };
        let k = k.min(scored.len());
        if k == 0 {
            return;
        }
        if k < scored.len() {
            scored.select_nth_unstable_by(k - 1, by_score);
            scored.truncate(k);
        }
        scored.sort_unstable_by(by_score);
        out.extend(scored.into_iter().map(|(score, index, slot)| {
            let node = &self.nodes[index];
            let (matched, text) = node.texts[slot];
            Hit {
                node_id: node.node_id,
                parent_id: node.parent_id,
                kind: node.kind,
                label: node.label.clone(),
                score,
                matched,
                matched_text: self.texts[text as usize].clone(),
            }
        }));
    }
}

fn dot(a: &Embedding, b: &Embedding) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::{GraphEdge, GraphNode};
    use op3dsg_ipc_types::{EdgeOrigin, affordance_bits, relation_id};

    fn node(id: u32, kind: NodeKind, label: &str, parent_id: Option<u32>, affordances: &[&str]) -> GraphNode {
        GraphNode {
            id,
            kind,
            parent_id,
            label: label.to_owned(),
            affordance_bits: affordance_bits(affordances.iter().copied()).expect("canonical"),
            ..GraphNode::default()
        }
    }

    fn functional(source_id: u32, target_id: u32, phrase: &str) -> GraphEdge {
        let (kind, relation_id) = relation_id(phrase).expect("canonical phrase");
        GraphEdge { source_id, target_id, kind, relation_id, confidence: 1.0, origin: EdgeOrigin::Knowledge }
    }

    #[test]
    fn texts_name_parent_affordance_and_functional_edges() {
        let graph = SceneGraph {
            version: 3,
            nodes: vec![
                node(1, NodeKind::Object, "stove", None, &[]),
                node(2, NodeKind::Part, "knob", Some(1), &["rotate"]),
                node(3, NodeKind::Object, "ceiling light", None, &[]),
                node(4, NodeKind::Part, "light switch", None, &["tip_push"]),
            ],
            edges: vec![functional(4, 3, "turn on or turn off")],
            ..SceneGraph::default()
        };
        let texts = node_texts(&graph, ScoringOptions::default());
        assert_eq!(texts[0], [(QueryMatch::Label, "stove".to_owned())]);
        assert_eq!(
            texts[1],
            [
                (QueryMatch::Label, "knob".to_owned()),
                (QueryMatch::ParentLabel, "knob of the stove".to_owned()),
                (QueryMatch::Affordance, "rotate the knob of the stove to adjust it".to_owned()),
            ]
        );
        assert_eq!(
            texts[3].last(),
            Some(&(QueryMatch::Functional, "light switch to turn on or turn off the ceiling light".to_owned()))
        );
        let without = node_texts(&graph, ScoringOptions { functional: false });
        assert!(without.iter().flatten().all(|(what, _)| *what != QueryMatch::Functional));
    }

    #[test]
    fn config_validation_names_the_field() {
        assert_eq!(QueryConfig::default().validate("query"), Ok(()));
        let bad = QueryConfig { queue_capacity: 0, ..QueryConfig::default() };
        assert_eq!(bad.validate("query"), Err("query.queue_capacity: must be within [1, 1024], got 0".to_owned()));
    }
}
