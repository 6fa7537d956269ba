//! Tests of the whole protocol on hand-built graphs with a table embedder (exact ranks, K,
//! strict variants, triplet misses, the scoring filter, the cache) and on the real encoder.

use std::collections::HashMap;

use op3dsg_drivers::graph_json::{EdgeJson, GraphJson, NodeJson};

use super::*;

/// Embeds a phrase as a fixed vector from a table: texts in the same group share a
/// direction, so their similarity is high; groups are orthogonal; `near` pairs get a
/// similarity between.
struct TableEmbedder {
    dims: HashMap<String, Vec<f32>>,
    calls: usize,
}

impl TableEmbedder {
    fn new(entries: &[(&str, &[f32])]) -> Self {
        let dims = entries
            .iter()
            .map(|(t, v)| {
                let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
                ((*t).to_owned(), v.iter().map(|x| x / norm).collect())
            })
            .collect();
        Self { dims, calls: 0 }
    }
}

impl PhraseEmbedder for TableEmbedder {
    fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Vec<f32>>, String> {
        self.calls += 1;
        phrases.iter().map(|p| self.dims.get(*p).cloned().ok_or_else(|| format!("no vector for '{p}'"))).collect()
    }
}

/// One-hot vectors over 16 dimensions for every phrase the tests use, with a few synonyms
/// made close.
fn embedder() -> TableEmbedder {
    let mut entries: Vec<(String, Vec<f32>)> = Vec::new();
    let one_hot = |i: usize| {
        let mut v = vec![0.0f32; 40];
        v[i] = 1.0;
        v
    };
    let labels = [
        "cabinet",
        "drawer",
        "sink",
        "tv",
        "cabinet handle",
        "drawer handle",
        "knob",
        "handle",
        "faucet",
        "remote control",
        "lamp",
        "chair",
    ];
    for (i, l) in labels.iter().enumerate() {
        entries.push(((*l).to_owned(), one_hot(i)));
    }
    // "cupboard" is close to "cabinet", then to "drawer".
    let mut cupboard = one_hot(0);
    cupboard[1] = 0.5;
    entries.push(("cupboard".to_owned(), cupboard));
    // A predicted "pull" is as close to four handle-ish labels, "handle" best.
    let mut pull = vec![0.0f32; 40];
    pull[4] = 0.8;
    pull[5] = 0.8;
    pull[7] = 0.9;
    pull[6] = 0.7;
    entries.push(("pull".to_owned(), pull));
    let mut offset = labels.len();
    for p in op3dsg_ipc_types::FUNCTIONAL_RELATIONS.iter().chain(&op3dsg_ipc_types::SPATIAL_RELATIONS) {
        entries.push(((*p).to_owned(), one_hot(offset)));
        offset += 1;
    }
    let mut opens = one_hot(labels.len()); // "pull to open or close"
    opens[labels.len() + 10] = 0.9; // close to "rotate to open or close"
    entries.push(("open it".to_owned(), opens));
    for a in op3dsg_ipc_types::AFFORDANCES {
        entries.push((affordance_phrase(a), one_hot(offset % 40)));
        offset += 1;
    }
    let refs: Vec<(&str, &[f32])> = entries.iter().map(|(t, v)| (t.as_str(), v.as_slice())).collect();
    TableEmbedder::new(&refs)
}

fn node(id: u32, label: &str, kind: &str, min: [f32; 3], max: [f32; 3]) -> NodeJson {
    NodeJson {
        id,
        label: label.to_owned(),
        kind: kind.to_owned(),
        parent: None,
        centre_m: [(min[0] + max[0]) / 2.0, (min[1] + max[1]) / 2.0, (min[2] + max[2]) / 2.0],
        box_min_m: min,
        box_max_m: max,
        obb: None,
        affordances: Vec::new(),
        affordance_origins: Default::default(),
        confidence: 1.0,
        observation_count: 0,
        seen_keyframes: None,
    }
}

fn edge(source: u32, target: u32, kind: &str, relation: &str) -> EdgeJson {
    EdgeJson {
        source,
        target,
        kind: kind.to_owned(),
        relation: relation.to_owned(),
        confidence: 1.0,
        origin: "ground_truth".to_owned(),
    }
}

/// Ground truth: two cabinets, a sink, their handles and a faucet, with edges.
fn ground_truth() -> GraphJson {
    let mut gt = GraphJson::new("test");
    gt.nodes = vec![
        node(1, "cabinet", "object", [0.0, 0.0, 0.0], [0.6, 0.6, 0.9]),
        node(2, "cabinet", "object", [0.6, 0.0, 0.0], [1.2, 0.6, 0.9]),
        node(3, "sink", "object", [0.0, 0.0, 0.9], [0.6, 0.6, 0.95]),
        node(4, "cabinet handle", "part", [0.5, 0.6, 0.7], [0.52, 0.63, 0.8]),
        node(5, "handle / knob", "part", [1.1, 0.6, 0.7], [1.12, 0.63, 0.8]),
        node(6, "faucet", "part", [0.28, 0.05, 0.95], [0.32, 0.25, 1.2]),
    ];
    gt.nodes[3].affordances = vec!["hook_pull".to_owned()];
    gt.nodes[4].affordances = vec!["hook_pull".to_owned(), "rotate".to_owned()];
    gt.edges = vec![
        edge(4, 1, "spatial", "part of"),
        edge(5, 2, "spatial", "part of"),
        edge(3, 1, "spatial", "on"),
        edge(1, 2, "spatial", "next to"),
        edge(4, 1, "functional", "pull to open or close"),
        edge(5, 2, "functional", "pull to open or close"),
        edge(6, 3, "functional", "control the water flow"),
    ];
    gt
}

fn vocabulary(gt: &GraphJson) -> Vocabulary {
    let mut v = Vocabulary::from_ground_truths([gt]);
    v.add_node_labels(["drawer", "tv", "drawer handle", "remote control", "lamp", "chair"]);
    v
}

#[test]
fn a_perfect_prediction_retrieves_everything() {
    let gt = ground_truth();
    let mut pred = gt.clone();
    // "handle / knob" is not a predictable label; the detector says "knob".
    pred.nodes[4].label = "knob".to_owned();
    let mut e = embedder();
    let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    let f = report.figures;
    for (name, r) in [
        ("object", f.object),
        ("part", f.part),
        ("overall", f.overall),
        ("iou", f.overall_iou10),
        ("iop", f.overall_iop25),
        ("affordance", f.affordance),
        ("functional", f.functional),
        ("spatial", f.spatial),
        ("associated", f.associated),
    ] {
        assert!(r.total > 0, "{name}");
        assert_eq!(r.retrieved, [r.total; 3], "{name}: {r:?}");
    }
    assert_eq!((f.object.total, f.part.total, f.overall.total), (3, 3, 6));
    assert_eq!(f.affordance.total, 3);
    assert_eq!((f.functional.total, f.spatial.total), (3, 4));
    // Pairs: (4,1) (5,2) (3,1) (1,2) (6,3): functional duplicates of part-of pairs count once.
    assert_eq!(f.associated.total, 5);
    assert_eq!(f.predicted_unmatched, 0);
}

#[test]
fn known_recall_on_a_hand_built_prediction() {
    let gt = ground_truth();
    let mut pred = GraphJson::new("pred");
    pred.nodes = vec![
        // Cabinet 1 called "cupboard": ranks "cabinet" first.
        node(10, "cupboard", "object", [0.05, 0.05, 0.05], [0.55, 0.55, 0.85]),
        // Cabinet 2 called "tv": label wrong, so not retrieved at any K ≤ 10? It ranks "cabinet"
        // behind "tv" and every other one-hot label at equal similarity (ties count against).
        node(11, "tv", "object", [0.7, 0.0, 0.0], [1.2, 0.6, 0.9]),
        // Sink box offset so that it does not overlap the ground truth: missed.
        node(12, "sink", "object", [2.0, 2.0, 0.9], [2.6, 2.6, 0.95]),
        // Handle 4 as "pull": "handle" first, "cabinet handle" second (ties with "drawer
        // handle", which counts against): rank 3.
        node(13, "pull", "part", [0.5, 0.6, 0.7], [0.52, 0.63, 0.8]),
        // Handle 5 as "knob", its box only touching the ground truth's 10 % (IoU < 0.10).
        node(14, "knob", "part", [1.1, 0.62, 0.79], [1.2, 0.7, 0.85]),
        // The faucet is an object here: kinds must agree, so it is missed.
        node(15, "faucet", "object", [0.28, 0.05, 0.95], [0.32, 0.25, 1.2]),
    ];
    pred.nodes[3].affordances = vec!["hook_pull".to_owned()];
    pred.nodes[4].affordances = vec!["pinch_pull".to_owned()];
    pred.edges = vec![
        edge(13, 10, "spatial", "part of"),
        edge(14, 11, "spatial", "part of"),
        edge(10, 11, "spatial", "next to"),
        // Relation phrase "open it": ranks "pull to open or close" 1st.
        edge(13, 10, "functional", "open it"),
        // Between retrieved nodes but the wrong relation entirely.
        edge(14, 11, "functional", "provide power"),
    ];
    let mut e = embedder();
    let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    let f = report.figures;
    // Objects: cabinet 1 retrieved; cabinet 2 ("tv") not; sink not.
    assert_eq!(f.object, Recall { total: 3, retrieved: [1, 1, 1] });
    // Parts: handle 4 rank 3; handle/knob 5 via "knob" rank 1; faucet missed.
    assert_eq!(f.part, Recall { total: 3, retrieved: [2, 2, 2] });
    assert_eq!(f.overall, Recall { total: 6, retrieved: [3, 3, 3] });
    // Strict IoU: node 14 overlaps node 5 by 0.02*0.01*0.01 of a 0.02*0.03*0.1 box; below 0.10.
    assert_eq!(f.part_iou10.retrieved, [1, 1, 1]);
    // Strict IoP: node 14's box mostly outside the ground truth too.
    assert_eq!(f.part_iop25.retrieved, [1, 1, 1]);
    // Affordances: handle 4 hook_pull retrieved; node 5's hook_pull and rotate only at
    // K = 10 (pinch_pull is one-hot elsewhere: every one of the 9 phrases ties, rank 9).
    assert_eq!(f.affordance, Recall { total: 3, retrieved: [1, 1, 3] });
    // Functional: (4 pull 1) retrieved; (5 pull 2) endpoint 2 not retrieved; (6 water 3) not.
    assert_eq!(f.functional, Recall { total: 3, retrieved: [1, 1, 1] });
    let why = |s: u32, t: u32, kind: &str| {
        report.edges.iter().find(|e| e.source == s && e.target == t && e.kind == kind).unwrap().miss[K3]
    };
    assert_eq!(why(5, 2, "functional"), Some(EdgeMiss::EndpointNotRetrieved));
    assert_eq!(why(4, 1, "functional"), None);
    // Spatial: (4 part of 1) retrieved; the rest lack an endpoint.
    assert_eq!(f.spatial, Recall { total: 4, retrieved: [1, 1, 1] });
    assert_eq!(why(1, 2, "spatial"), Some(EdgeMiss::EndpointNotRetrieved));
    // Pairs: only (4,1).
    assert_eq!(f.associated, Recall { total: 5, retrieved: [1, 1, 1] });
    // Predicted nodes retrieving nothing: 11 (tv), 12 (sink elsewhere), 15 (faucet object).
    assert_eq!(f.predicted_unmatched, 3);
    let handle = report.nodes.iter().find(|n| n.id == 4).unwrap();
    assert_eq!((handle.best_rank, handle.best_predicted_label.as_deref()), (Some(3), Some("pull")));
    // "pull" has the handle's own box.
    assert_eq!(handle.best_iou, Some(1.0));
    assert!(report.nodes.iter().all(|n| n.best_iou.is_some() == n.best_rank.is_some()), "{:?}", report.nodes);
    assert!(report.nodes.iter().any(|n| n.best_iou.is_none()));
}

#[test]
fn rank_depends_on_k_and_the_relation_phrase() {
    let gt = ground_truth();
    let mut pred = gt.clone();
    pred.nodes[4].label = "knob".to_owned();
    // "open it" ranks "pull to open or close" 1st and "rotate to open or close" 2nd: a
    // predicted "rotate to open or close" ranks the ground truth's "pull ..." only by ties
    // (one-hot): last of 11.
    for e in &mut pred.edges {
        if e.relation == "pull to open or close" {
            e.relation = "rotate to open or close".to_owned();
        }
    }
    let mut e = embedder();
    let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    assert_eq!(report.figures.functional, Recall { total: 3, retrieved: [1, 1, 1] });
    let miss = report.edges.iter().find(|e| e.source == 4 && e.kind == "functional").unwrap().miss;
    assert_eq!(miss, [Some(EdgeMiss::WrongRelation); 3]);
    // A missing edge between retrieved nodes is told apart.
    let mut pred2 = gt.clone();
    pred2.nodes[4].label = "knob".to_owned();
    pred2.edges.retain(|e| e.relation != "control the water flow");
    let report = evaluator.evaluate(&pred2, &gt, None).unwrap();
    let miss = report.edges.iter().find(|e| e.source == 6).unwrap().miss;
    assert_eq!(miss, [Some(EdgeMiss::MissingEdge); 3]);
    assert_eq!(report.figures.associated.retrieved, [4, 4, 4]);
}

#[test]
fn k_separates_ranks_and_the_filter_limits_the_scored_set() {
    // A one-hot "chair" prediction for cabinet 1 ranks "cabinet" behind every label
    // (ties count against): rank = vocabulary size > 10. With "cupboard" it is first.
    let gt = ground_truth();
    let mut pred = gt.clone();
    pred.nodes[4].label = "knob".to_owned();
    pred.nodes[0].label = "chair".to_owned();
    let mut e = embedder();
    let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    assert_eq!(report.figures.object.retrieved, [2, 2, 2]);
    // "pull" for the cabinet handle: rank 3, so retrieved at 3, 5 and 10.
    pred.nodes[0].label = "cabinet".to_owned();
    pred.nodes[3].label = "pull".to_owned();
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    assert_eq!(report.figures.part.retrieved, [3, 3, 3]);
    // Only score nodes 1..=3: parts and every edge touching them drop out.
    let only_objects = |id: u32| id <= 3;
    let report = evaluator.evaluate(&pred, &gt, Some(&only_objects)).unwrap();
    assert_eq!(report.figures.part.total, 0);
    assert_eq!(report.figures.object.total, 3);
    assert_eq!(report.figures.functional.total, 0);
    assert_eq!(report.figures.spatial.total, 2);
    assert_eq!(report.figures.affordance.total, 0);
}

#[test]
fn a_middle_rank_is_retrieved_at_five_but_not_three() {
    // Build a vocabulary where "pull" ranks "cabinet handle" 4th: add "drawer handle" and
    // "knob" above it by similarity.
    let gt = ground_truth();
    let mut pred = gt.clone();
    pred.nodes[4].label = "knob".to_owned();
    pred.nodes[3].label = "pull".to_owned();
    let mut e = embedder();
    // Make "cabinet handle" less similar than "knob" (0.7) by overriding the "pull" vector.
    let mut pull = [0.0f32; 40];
    pull[4] = 0.6;
    pull[5] = 0.8;
    pull[7] = 0.9;
    pull[6] = 0.7;
    let norm = pull.iter().map(|x| x * x).sum::<f32>().sqrt();
    e.dims.insert("pull".to_owned(), pull.iter().map(|x| x / norm).collect());
    let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    // handle 4: rank 4 → not at 3, yes at 5 and 10; the other two parts retrieved.
    assert_eq!(report.figures.part.retrieved, [2, 3, 3]);
    // Its triplets follow the node: (4 part of 1) and (4 pull 1) only from K = 5.
    assert_eq!(report.figures.functional.retrieved, [2, 3, 3]);
}

#[test]
fn embeddings_are_computed_once_per_text() {
    let gt = ground_truth();
    let mut pred = gt.clone();
    pred.nodes[4].label = "knob".to_owned();
    let mut e = embedder();
    {
        let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
        evaluator.evaluate(&pred, &gt, None).unwrap();
        evaluator.evaluate(&pred, &gt, None).unwrap();
    }
    assert_eq!(e.calls, 1);
}

/// The protocol on the real encoder (all-MiniLM-L6-v2; needs `.models/`, fails with the
/// set-up hint without it): synonyms and compound part names retrieve their ground truth
/// within the top 3 of the benchmark's vocabulary, an unrelated label does not.
#[test]
fn minilm_ranks_synonyms_first() {
    use op3dsg_runtime::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
    use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let mut encoder = TextEncoder::new(&runtime, &TextEncoderConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let gt = ground_truth();
    let mut vocabulary = vocabulary(&gt);
    vocabulary.add_node_labels(["stove", "stove knob", "fridge", "fridge handle", "toilet", "flush button", "bed"]);
    let mut evaluator = RecallEvaluator::new(&mut encoder, vocabulary);
    let mut pred = gt.clone();
    pred.nodes[0].label = "cupboard".to_owned();
    pred.nodes[2].label = "washbasin".to_owned();
    pred.nodes[3].label = "cupboard handle".to_owned();
    pred.nodes[4].label = "knob".to_owned();
    pred.nodes[5].label = "tap".to_owned();
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    let rank = |id: u32| report.nodes.iter().find(|n| n.id == id).and_then(|n| n.best_rank).unwrap();
    for id in [1, 3, 4, 5] {
        assert!(rank(id) <= 3, "node {id}: rank {}", rank(id));
    }
    assert!(rank(6) <= 5, "tap -> faucet: rank {}", rank(6));
    // Relation phrases rank their canonical form first.
    assert_eq!(report.figures.functional.retrieved[K3], report.figures.functional.total);
    pred.nodes[0].label = "banana".to_owned();
    let report = evaluator.evaluate(&pred, &gt, None).unwrap();
    let cabinet = report.nodes.iter().find(|n| n.id == 1).unwrap();
    assert!(cabinet.best_rank.unwrap() > 3, "{cabinet:?}");
}
