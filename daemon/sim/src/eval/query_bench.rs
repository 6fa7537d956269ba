//! The language query benchmark (`op3dsg bench query`): needs phrased as users phrase them, asked
//! of the graph the daemon builds of each synthetic room, scored against the node kind and label
//! the room's ground truth gives for that need.
//!
//! Each room (kitchen, bathroom, bedroom, living room; one seed) runs through the batch pipeline
//! (oracle detector with knowledge-guided part prompts, fusion, prior graph, offline knowledge
//! reasoner) exactly as `bench quality`'s full row. The scorer ([`op3dsg_runtime::query`]) sees
//! only that reconstructed graph. A query counts as answered at k when one of its k best nodes
//! has the expected kind and label (any instance: a kitchen has several cabinet handles). The
//! expected answers were written from the rooms' ground truth (`op3dsg gt`), never given to the
//! scorer. Two runs: with the functional edges' phrases in the scoring and without (label,
//! parent label and affordances only).
//!
//! Latency: the worker's cost per query (one encoder call for the query text + the scoring), on
//! a graph of 50 and of 2,000 nodes (the rooms' nodes repeated with new ids), p50 and p99.

use std::collections::HashMap;
use std::time::Instant;

use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::graph::SceneGraph;
use op3dsg_runtime::onnx::text_encoder::TextEncoder;
use op3dsg_runtime::pipeline::make_enricher;
use op3dsg_runtime::query::{Hit, QueryIndex, ScoringOptions};
use op3dsg_runtime::reasoner::ReasonerKind;
use op3dsg_synthetic::RoomKind;
use serde::Serialize;

use super::fusion_match::{self, MatchCriteria};
use crate::batch::{self, VisibilityThresholds};

/// One benchmark query: the room, the words, and the node the room's ground truth gives.
#[derive(Debug, Clone, Copy)]
pub struct BenchQuery {
    /// Room asked.
    pub room: RoomKind,
    /// The need.
    pub text: &'static str,
    /// Expected kind.
    pub kind: NodeKind,
    /// Expected label.
    pub label: &'static str,
}

const fn q(room: RoomKind, text: &'static str, kind: NodeKind, label: &'static str) -> BenchQuery {
    BenchQuery { room, text, kind, label }
}

use NodeKind::{Object as O, Part as P};
use RoomKind::{Bathroom as BA, Bedroom as BE, Kitchen as KI, LivingRoom as LI};

/// The queries (64), written from the rooms' ground truth as a user would ask.
pub const QUERIES: [BenchQuery; 64] = [
    q(KI, "somewhere to wash my hands", O, "sink"),
    q(KI, "keep my milk cold", O, "fridge"),
    q(KI, "open the fridge door", P, "fridge handle"),
    q(KI, "boil water for tea", O, "kettle"),
    q(KI, "heat up leftovers quickly", O, "microwave"),
    q(KI, "start the microwave", P, "microwave button"),
    q(KI, "make toast for breakfast", O, "toaster"),
    q(KI, "push down the bread to toast it", P, "toaster lever"),
    q(KI, "cook eggs in a pan", O, "stove"),
    q(KI, "turn up the heat on the hob", P, "stove knob"),
    q(KI, "throw away the rubbish", O, "trash can"),
    q(KI, "open the bin lid with my foot", P, "pedal"),
    q(KI, "get running water for the kitchen sink", P, "faucet"),
    q(KI, "plug in the kettle", P, "power outlet"),
    q(KI, "what controls the ceiling light", P, "light switch"),
    q(KI, "pull out a kitchen drawer", P, "drawer handle"),
    q(KI, "get a plate from the cupboard", O, "cabinet"),
    q(KI, "open the cupboard door", P, "cabinet handle"),
    q(KI, "let some fresh air into the kitchen", O, "window"),
    q(KI, "open the kitchen window", P, "window handle"),
    q(KI, "leave the kitchen", O, "door"),
    q(KI, "open the door to the hallway", P, "door handle"),
    q(KI, "open the oven", P, "oven knob"),
    q(KI, "light for the whole room", O, "ceiling light"),
    q(BA, "take a relaxing bath", O, "bathtub"),
    q(BA, "flush the toilet", P, "flush button"),
    q(BA, "I need to use the loo", O, "toilet"),
    q(BA, "look at my reflection", O, "mirror"),
    q(BA, "dry my wet hair", O, "hair dryer"),
    q(BA, "warm up the cold bathroom", O, "radiator"),
    q(BA, "make the heating warmer", P, "radiator valve"),
    q(BA, "brush my teeth over a basin", O, "sink"),
    q(BA, "fill the tub with water", P, "faucet"),
    q(BA, "a lamp mounted on the wall", O, "wall light"),
    q(BA, "what turns on the wall light", P, "light switch"),
    q(BA, "open the little drawer", P, "drawer knob"),
    q(BA, "get a towel from the bathroom cupboard", O, "cabinet"),
    q(BA, "where can I plug in the hair dryer", P, "power outlet"),
    q(BA, "open the bathroom door", P, "door handle"),
    q(BE, "somewhere to sleep", O, "bed"),
    q(BE, "put my glass of water by the bed", O, "nightstand"),
    q(BE, "some light to read in bed", O, "lamp"),
    q(BE, "turn the bedside lamp on", P, "lamp switch"),
    q(BE, "hang up my coat", O, "wardrobe"),
    q(BE, "open the closet", P, "wardrobe handle"),
    q(BE, "store my folded clothes", O, "dresser"),
    q(BE, "open a drawer of the dresser", P, "drawer handle"),
    q(BE, "open the bedside table drawer", P, "drawer knob"),
    q(BE, "charge my phone overnight", P, "power outlet"),
    q(BE, "open the bedroom window", P, "window handle"),
    q(BE, "switch on the main light", P, "light switch"),
    q(LI, "something to turn on the TV", O, "remote control"),
    q(LI, "change the channel", O, "remote control"),
    q(LI, "watch the news", O, "tv"),
    q(LI, "sit down and relax", O, "sofa"),
    q(LI, "put my coffee cup down", O, "coffee table"),
    q(LI, "play a video game", O, "game console"),
    q(LI, "switch on the game console", P, "power button"),
    q(LI, "plug in several devices at once", O, "power strip"),
    q(LI, "a tall light standing in the corner", O, "floor lamp"),
    q(LI, "turn on the floor lamp", P, "lamp switch"),
    q(LI, "open the drawer under the television", P, "drawer handle"),
    q(LI, "where do I plug in the lamp", P, "power outlet"),
    q(LI, "somewhere to put the television", O, "tv stand"),
];

/// One room's reconstructed graph, with the ground-truth node each of its nodes was matched to
/// by `fusion_match` (position and label, synonyms included: "electric kettle" is the kettle).
#[derive(Debug, Clone)]
pub struct RoomGraph {
    /// Room.
    pub room: RoomKind,
    /// The graph the scorer sees.
    pub graph: SceneGraph,
    /// Graph node id → the kind and label of the ground-truth node it matches (evaluation only).
    pub truth_of: HashMap<u32, (NodeKind, String)>,
}

impl RoomGraph {
    /// `node` is the expected answer of `query`: it matches a ground-truth node of the expected
    /// kind and label, or (unmatched) carries that kind and label itself (or the label
    /// qualified by an object's name in front).
    fn answers(&self, node_id: u32, kind: NodeKind, label: &str, query: &BenchQuery) -> bool {
        match self.truth_of.get(&node_id) {
            Some((truth_kind, truth_label)) => *truth_kind == query.kind && truth_label == query.label,
            // Unmatched (fusion_match's 2 cm part margin is strict): the label itself, or the
            // label qualified by its object ("toilet flush button" for "flush button").
            None => kind == query.kind && (label == query.label || label.ends_with(&format!(" {}", query.label))),
        }
    }

    /// The graph holds a node that answers `query`.
    fn can_answer(&self, query: &BenchQuery) -> bool {
        self.graph.nodes.iter().any(|n| self.answers(n.id, n.kind, &n.label, query))
    }
}

/// The graph the daemon builds of `room` (seed `seed`) with `base`: batch pipeline, then the
/// profile's enricher (prior graph + knowledge reasoner).
pub fn room_graph(base: &Profile, room: RoomKind, seed: u64) -> Result<RoomGraph, String> {
    let name = format!("{} seed {seed}", room.as_str());
    let (profile, _) = super::benchmark::scene_profile(base, room, seed)?;
    let mut unenriched = profile.clone();
    unenriched.reasoner.kind = ReasonerKind::None;
    let run = batch::run(&unenriched, &VisibilityThresholds::default()).map_err(|e| format!("{name}: {e}"))?;
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let matched = fusion_match::match_run(&run, &criteria);
    let truth: HashMap<u32, (NodeKind, String)> =
        matched.gt.iter().map(|g| (g.id, (g.kind, g.label.clone()))).collect();
    let truth_of = matched
        .fused
        .iter()
        .filter_map(|f| f.matched.and_then(|gt| truth.get(&gt)).map(|t| (f.id, t.clone())))
        .collect();
    let mut graph = run.graph;
    if let Some(mut enricher) = make_enricher(&profile).map_err(|e| format!("{name}: {e}"))? {
        enricher.enrich(&mut graph);
    }
    Ok(RoomGraph { room, graph, truth_of })
}

/// Accuracy of one kind (objects or parts) in one scoring setup.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Accuracy {
    /// Queries.
    pub queries: u32,
    /// Queries whose answer is in the reconstructed graph at all.
    pub answerable: u32,
    /// Answered by the best node.
    pub top1: u32,
    /// Answered among the 3 best.
    pub top3: u32,
}

impl Accuracy {
    fn percent(value: u32, of: u32) -> f64 {
        if of == 0 { 0.0 } else { 100.0 * f64::from(value) / f64::from(of) }
    }
}

/// One query's outcome.
#[derive(Debug, Clone, Serialize)]
pub struct QueryOutcome {
    /// Room.
    pub room: &'static str,
    /// The words.
    pub text: &'static str,
    /// Expected "kind label".
    pub expected: String,
    /// The graph holds a node that answers it (else the map, not the query, missed it).
    pub answerable: bool,
    /// Rank of the first correct node (1-based) within the top 10, if any.
    pub rank: Option<usize>,
    /// The best node: "kind label (why: text)".
    pub best: String,
}

/// The report.
#[derive(Debug, Clone, Serialize)]
pub struct QueryReport {
    /// Nodes of each room's graph.
    pub room_nodes: Vec<(&'static str, usize)>,
    /// `[with functional, without]` × `[objects, parts]`.
    pub accuracy: [[Accuracy; 2]; 2],
    /// Per query, with functional edges.
    pub outcomes: Vec<QueryOutcome>,
    /// Per query, without.
    pub outcomes_without_functional: Vec<QueryOutcome>,
    /// Latency per query (encode + score), microseconds: `(nodes, p50, p99, score-only p50, score-only p99)`.
    pub latency_us: Vec<(usize, f64, f64, f64, f64)>,
}

fn describe(hit: &Hit) -> String {
    format!("{} {} ({}: {})", hit.kind.as_str(), hit.label, hit.matched.as_str(), hit.matched_text)
}

/// Runs the benchmark on `graphs` (one per room of [`RoomKind::ALL`], in that order).
pub fn run(graphs: &[RoomGraph], encoder: &mut TextEncoder) -> Result<QueryReport, String> {
    let mut accuracy = [[Accuracy::default(); 2]; 2];
    let mut outcomes = [Vec::new(), Vec::new()];
    let mut hits = Vec::new();
    for (setup, functional) in [true, false].into_iter().enumerate() {
        for room in graphs {
            let mut index =
                QueryIndex::build(&room.graph, encoder, ScoringOptions { functional }).map_err(|e| e.to_string())?;
            for query in QUERIES.iter().filter(|q| q.room == room.room) {
                let embedding = encoder.encode(query.text).map_err(|e| e.to_string())?;
                index.top_k(&embedding, 10, &mut hits);
                let rank = hits.iter().position(|h| room.answers(h.node_id, h.kind, &h.label, query)).map(|p| p + 1);
                let answerable = room.can_answer(query);
                let cell = &mut accuracy[setup][usize::from(query.kind == NodeKind::Part)];
                cell.queries += 1;
                cell.answerable += u32::from(answerable);
                cell.top1 += u32::from(rank == Some(1));
                cell.top3 += u32::from(rank.is_some_and(|r| r <= 3));
                outcomes[setup].push(QueryOutcome {
                    answerable,
                    room: room.room.as_str(),
                    text: query.text,
                    expected: format!("{} {}", query.kind.as_str(), query.label),
                    rank,
                    best: hits.first().map(describe).unwrap_or_default(),
                });
            }
        }
    }
    let latency_us =
        [50usize, 2000].into_iter().map(|nodes| latency(graphs, nodes, encoder)).collect::<Result<Vec<_>, _>>()?;
    let [with, without] = outcomes;
    Ok(QueryReport {
        room_nodes: graphs.iter().map(|r| (r.room.as_str(), r.graph.nodes.len())).collect(),
        accuracy,
        outcomes: with,
        outcomes_without_functional: without,
        latency_us,
    })
}

/// A graph of `nodes` nodes: the rooms' nodes (and their edges) repeated with new ids.
fn grown_graph(graphs: &[RoomGraph], nodes: usize) -> SceneGraph {
    let mut out = SceneGraph { version: 1, ..SceneGraph::default() };
    let mut copy = 0u32;
    while out.nodes.len() < nodes {
        for graph in graphs.iter().map(|r| &r.graph) {
            let offset = copy * 100_000;
            for node in &graph.nodes {
                if out.nodes.len() >= nodes {
                    break;
                }
                let mut node = node.clone();
                node.id += offset;
                node.parent_id = node.parent_id.map(|p| p + offset);
                out.nodes.push(node);
            }
            for edge in &graph.edges {
                let mut edge = edge.clone();
                edge.source_id += offset;
                edge.target_id += offset;
                out.edges.push(edge);
            }
            copy += 1;
        }
        if graphs.iter().all(|r| r.graph.nodes.is_empty()) {
            break;
        }
    }
    out
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn latency(
    graphs: &[RoomGraph],
    nodes: usize,
    encoder: &mut TextEncoder,
) -> Result<(usize, f64, f64, f64, f64), String> {
    let graph = grown_graph(graphs, nodes);
    let mut index = QueryIndex::build(&graph, encoder, ScoringOptions::default()).map_err(|e| e.to_string())?;
    let mut total = Vec::new();
    let mut scoring = Vec::new();
    let mut hits = Vec::new();
    for _ in 0..4 {
        for query in &QUERIES {
            // The model runs for every query, as for a planner's own new words: the cache is
            // emptied first (the index holds the graph's embeddings already).
            encoder.clear_cache();
            let started = Instant::now();
            let embedding = encoder.encode(query.text).map_err(|e| e.to_string())?;
            let encoded = Instant::now();
            index.top_k(&embedding, 5, &mut hits);
            let done = Instant::now();
            total.push(done.duration_since(started).as_secs_f64() * 1e6);
            scoring.push(done.duration_since(encoded).as_secs_f64() * 1e6);
        }
    }
    total.sort_by(f64::total_cmp);
    scoring.sort_by(f64::total_cmp);
    Ok((
        graph.nodes.len(),
        percentile(&total, 0.5),
        percentile(&total, 0.99),
        percentile(&scoring, 0.5),
        percentile(&scoring, 0.99),
    ))
}

/// The report as text: the table, then each miss.
pub fn text(report: &QueryReport) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let rooms: Vec<String> = report.room_nodes.iter().map(|(r, n)| format!("{r} {n}")).collect();
    let _ = writeln!(out, "graph nodes per room: {}", rooms.join(", "));
    let _ = writeln!(
        out,
        "| scoring | objects top-1 | objects top-3 | parts top-1 | parts top-3 | all top-1 | all top-3 |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|---|");
    for (setup, name) in ["with functional edges", "without functional edges"].iter().enumerate() {
        let [objects, parts] = report.accuracy[setup];
        let all = Accuracy {
            queries: objects.queries + parts.queries,
            answerable: objects.answerable + parts.answerable,
            top1: objects.top1 + parts.top1,
            top3: objects.top3 + parts.top3,
        };
        let cell = |a: Accuracy, v: u32| format!("{:.1} % ({v}/{})", Accuracy::percent(v, a.queries), a.queries);
        let _ = writeln!(
            out,
            "| {name} | {} | {} | {} | {} | {} | {} |",
            cell(objects, objects.top1),
            cell(objects, objects.top3),
            cell(parts, parts.top1),
            cell(parts, parts.top3),
            cell(all, all.top1),
            cell(all, all.top3)
        );
    }
    let _ = writeln!(out, "\nover the queries whose answer is in the reconstructed graph (the scorer's own share):");
    let _ = writeln!(out, "| scoring | objects top-1 | objects top-3 | parts top-1 | parts top-3 |");
    let _ = writeln!(out, "|---|---|---|---|---|");
    for (setup, name) in ["with functional edges", "without functional edges"].iter().enumerate() {
        let [objects, parts] = report.accuracy[setup];
        let cell = |a: Accuracy, v: u32| format!("{:.1} % ({v}/{})", Accuracy::percent(v, a.answerable), a.answerable);
        let _ = writeln!(
            out,
            "| {name} | {} | {} | {} | {} |",
            cell(objects, objects.top1),
            cell(objects, objects.top3),
            cell(parts, parts.top1),
            cell(parts, parts.top3)
        );
    }
    let _ = writeln!(out, "\n| graph nodes | query p50 | query p99 | scoring only p50 | scoring only p99 |");
    let _ = writeln!(out, "|---|---|---|---|---|");
    for (nodes, p50, p99, s50, s99) in &report.latency_us {
        let _ = writeln!(
            out,
            "| {nodes} | {:.2} ms | {:.2} ms | {:.3} ms | {:.3} ms |",
            p50 / 1e3,
            p99 / 1e3,
            s50 / 1e3,
            s99 / 1e3
        );
    }
    let [objects, parts] = report.accuracy[0];
    let _ = writeln!(
        out,
        "\nanswer in the reconstructed graph at all: objects {}/{}, parts {}/{} (the rest the map missed)",
        objects.answerable, objects.queries, parts.answerable, parts.queries
    );
    let _ = writeln!(out, "\nnot answered by the best node (with functional edges):");
    for o in report.outcomes.iter().filter(|o| o.rank != Some(1)) {
        let rank = match (o.rank, o.answerable) {
            (Some(r), _) => format!("rank {r}"),
            (None, true) => "not in top 10".to_owned(),
            (None, false) => "no such node in the graph".to_owned(),
        };
        let _ = writeln!(out, "  {}: \"{}\" expected {} ({rank}); best {}", o.room, o.text, o.expected, o.best);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queries_cover_every_room_and_both_kinds_and_never_quote_the_label() {
        assert!(QUERIES.len() >= 60);
        for room in RoomKind::ALL {
            assert!(QUERIES.iter().any(|q| q.room == room), "{}", room.as_str());
        }
        let parts = QUERIES.iter().filter(|q| q.kind == NodeKind::Part).count();
        assert!(parts >= 20 && QUERIES.len() - parts >= 20);
        // Every expected node exists in its room's ground truth.
        for query in &QUERIES {
            let truth = op3dsg_synthetic::Scene::generate(query.room, 1).ground_truth();
            assert!(
                truth.nodes.iter().any(|n| n.label == query.label && n.kind == query.kind.as_str()),
                "{}: {:?} has no {} {}",
                query.room.as_str(),
                query.text,
                query.kind.as_str(),
                query.label
            );
        }
    }
}
