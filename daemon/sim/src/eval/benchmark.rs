//! The synthetic quality benchmark behind `op3dsg bench quality`: seeded scenes of the four
//! benchmark rooms, each run through the batch pipeline, scored with the benchmark's protocol
//! ([`super::recall`]), with the paper's ablations as extra rows.
//!
//! ## Scenes
//!
//! Scene `i` (0-based) is room `RoomKind::ALL[i % 4]` (kitchen, bathroom, bedroom, living room)
//! with seed `i / 4 + 1`, so 24 scenes are six of each. [`functional_mix`] counts their
//! functional relations next to the benchmark's (`../shared/data/reference/README.md`).
//!
//! ## Rows
//!
//! Every row is scored on the same keyframes (one rendering pass per scene,
//! [`crate::batch::run_lanes`]):
//!
//! | row | what changes |
//! |---|---|
//! | full | the oracle with knowledge-guided prompt lists (`part_prompts = "knowledge"`), colour features on, prior graph + split knowledge reasoner |
//! | w/o knowledge | the oracle's prompt lists use the fixed generic part vocabulary (`part_prompts = "generic"`) |
//! | w/o colour | `fusion.colour_features = false` |
//! | w/o prior graph | the reasoner gets a flat node list ([`op3dsg_runtime::reasoner::ablation`]) |
//! | w/o split | one reasoner instead of the split ([`op3dsg_runtime::reasoner::ablation`]) |
//!
//! Two rows isolate a stage, and one puts a peer's fusion in place of ours:
//!
//! | row | what it measures | what it cannot |
//! |---|---|---|
//! | reasoner on GT nodes | reasoning alone: the ground-truth nodes (exact labels, kinds, parents, boxes, `part of` edges) through the prior graph and the reasoner, scored on the same items as every row | its node columns are 100 by construction (the nodes are the ground truth's); says nothing of perception or fusion |
//! | peer: ConceptGraphs fusion | ConceptGraphs' association and merging ([`crate::conceptgraphs`], their published algorithm and config defaults) in place of OP3DSG's fusion, fed the full row's keyframes and detections in the same pass, reasoned by the same reasoner | ConceptGraphs' perception (CLIP crops, SAM masks, their tagger) is not reproduced: it gets the oracle's detections and their semantic feature; only fusion differs from the full row |
//! | fusion on exact detections | fusion alone: the oracle with its noise off (every visible instance, canonical label, exact mask, unperturbed feature; `OracleConfig::clean` with the run's seed and semantic source) fused and reasoned like the full row | node columns are fusion's; the relation columns still include the reasoner; the detections are exact, so it bounds fusion from above |
//!
//! ## Leave one category out
//!
//! For each object category of a scene's ground truth, the reasoner's tables lose it
//! ([`KnowledgeVariants::without_object`]: the category, its synonyms, its object-part pairs, the
//! part categories no other object has, its remote templates and its place among remote
//! targets). The full row's fused graph and the ground-truth nodes are reasoned again with
//! those tables, and the items that involve the category are scored: its nodes and their parts,
//! their affordances, and the triplets with one of them at either end. The same items of the
//! full row and of "reasoner on GT nodes" are the comparison. The reasoner has to fall back
//! ([`op3dsg_runtime::knowledge::fallback`]: nearest known category by MiniLM embedding, then
//! the part-label rule), and the fallbacks are counted. The detector's knowledge-guided part
//! prompts still come from the full tables (the rendering pass is shared), so the node columns
//! of "leave one out" are perception with the category known; only reasoning loses it.
//!
//! All rows reason with the offline knowledge reasoner and its label fallback (the embedding
//! part on the MiniLM encoder, loaded per scene). Ground-truth nodes seen in fewer than 3
//! keyframes are not scored (see [`super::recall`]); the vocabulary is the labels of all
//! scenes of the run.
//!
//! ## Ground truth and knowledge base
//!
//! The rooms' functional relations and affordances come from `op3dsg_synthetic::truth`, not
//! from the knowledge base; [`super::agreement`] measures, per scene on every ground-truth node,
//! how often the knowledge base gives the same answer (reported with the table).
//!
//! ## Where recall is lost
//!
//! For the full row, every scored item not retrieved at R@3 is attributed to a stage: nodes to
//! fusion evaluation's reasons ([`super::fusion_match::MissReason`]: never detected, too few
//! detections, merged, wrong label, lost in fusion) when fusion lost them, else to the protocol
//! ("no box overlap", "label ranks below 3"); triplets to a missing endpoint node, a missing
//! edge or a wrong relation phrase; affordances to a missing node or a wrong affordance.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_synthetic::RoomKind;
use serde::Serialize;

use super::agreement::{self, Agreement};
use super::fusion_match::{self, FusionMatchReport, MatchCriteria};
use super::recall::{AffordanceMiss, EdgeMiss, K3, K5, K10, Recall, RecallEvaluator, RecallFigures, Vocabulary};
use crate::backends::{oracle_config, set_oracle_config, set_synthetic_config, synthetic_config};
use crate::batch::{self, Lane, VisibilityThresholds};
use crate::conceptgraphs::{ConceptGraphsConfig, ConceptGraphsFusion};
use crate::knowledge_variants::KnowledgeVariants;
use crate::oracle::OracleConfig;
use crate::reasoning_ablation::ReasoningSetup;
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::knowledge::KnowledgeBase;
use op3dsg_runtime::knowledge::fallback::{self, FallbackCounts};
use op3dsg_runtime::pipeline::make_enricher;
use op3dsg_runtime::reasoner::ReasonerKind;
use std::sync::Arc;

/// The rows of the table, in order.
pub const ROWS: [&str; 8] = [
    "full",
    "reasoner on GT nodes",
    "fusion on exact detections",
    PEER_ROW,
    "w/o knowledge",
    "w/o colour",
    "w/o prior graph",
    "w/o split",
];
/// The OP3DSG fusion of `profile` (the method's rows).
fn op3dsg_fusion(profile: &Profile) -> Box<dyn op3dsg_runtime::fusion::Fusion> {
    op3dsg_runtime::fusion::build(&profile.fusion, profile.world.up_axis)
}

/// The peer baseline's row: ConceptGraphs' association and merging
/// ([`crate::conceptgraphs`]) in place of OP3DSG's fusion, on the full row's
/// keyframes and detections, reasoned by the same reasoner.
pub const PEER_ROW: &str = "peer: ConceptGraphs fusion";
/// Index of "reasoner on GT nodes" in [`ROWS`].
pub const GT_NODES_ROW: usize = 1;
/// Targets of the full row at R@3, percent: object, part, affordance, functional, spatial.
pub const TARGETS_R3: [(&str, f64); 5] =
    [("object", 90.0), ("part", 88.0), ("affordance", 85.0), ("functional triplet", 70.0), ("spatial triplet", 70.0)];

/// The benchmark's functional-relation counts (FunGraph3D, SceneFun3D), from the reference
/// README.
pub const REFERENCE_MIX: [(&str, u32, u32); 11] = [
    ("pull to open or close", 111, 109),
    ("rotate to adjust the setting or temperature", 40, 10),
    ("provide power", 22, 15),
    ("control the water flow", 19, 14),
    ("rotate to open or close", 16, 14),
    ("turn on or turn off", 10, 6),
    ("press to start and operate", 4, 10),
    ("press to flush", 3, 3),
    ("remote to control", 2, 13),
    ("push or press to open", 2, 1),
    ("operate or adjust the flow or setting", 1, 0),
];

/// Scene `index` of the benchmark.
pub fn scene(index: usize) -> (RoomKind, u64) {
    (RoomKind::ALL[index % RoomKind::ALL.len()], (index / RoomKind::ALL.len()) as u64 + 1)
}

/// Functional relations of the first `scenes` scenes' ground truth, by phrase.
pub fn functional_mix(scenes: usize) -> BTreeMap<String, u32> {
    let mut mix = BTreeMap::new();
    for i in 0..scenes {
        let (room, seed) = scene(i);
        for edge in op3dsg_synthetic::Scene::generate(room, seed).edges() {
            if edge.kind == "functional" {
                *mix.entry(edge.relation.to_owned()).or_insert(0) += 1;
            }
        }
    }
    mix
}

/// What one scene produced (before scoring).
#[derive(Debug, Clone)]
pub struct SceneRun {
    /// Room.
    pub room: RoomKind,
    /// Seed.
    pub seed: u64,
    /// Ground truth.
    pub ground_truth: GraphJson,
    /// Ground-truth ids seen in enough keyframes to be scored.
    pub scored_ids: Vec<u32>,
    /// The predicted graph of each row of [`ROWS`].
    pub predictions: Vec<GraphJson>,
    /// Fusion evaluation of the full row (stage attribution).
    pub fusion: FusionMatchReport,
    /// Keyframes.
    pub keyframes: u64,
    /// How often the knowledge base gives the ground truth's answer on this scene's nodes.
    pub agreement: Agreement,
    /// The leave-one-category-out runs: one per object category of the scene.
    pub loco: Vec<LocoRun>,
}

/// One category left out of the knowledge base on one scene ([`run_scene`]).
#[derive(Debug, Clone)]
pub struct LocoRun {
    /// The object category the reasoner's tables lost (canonical name).
    pub category: String,
    /// Ground-truth ids of the scene's nodes of that category and of their parts.
    pub involved: Vec<u32>,
    /// The full row's fused graph reasoned with the reduced tables.
    pub fused: GraphJson,
    /// The ground-truth nodes reasoned with the reduced tables.
    pub gt_nodes: GraphJson,
    /// How often the reasoner fell back, on the fused graph and on the ground-truth nodes.
    pub fallback: [FallbackCounts; 2],
    /// The known category the embedding fallback gives the category's own name, with the
    /// cosine (`None`: nothing within the threshold).
    pub nearest: Option<(String, f32)>,
}

/// The peer baseline's fusion for `profile`: ConceptGraphs' defaults, with the profile's up axis
/// and part attachment margin (the published graph is built like OP3DSG's).
pub fn peer_fusion(profile: &Profile) -> Box<dyn op3dsg_runtime::fusion::Fusion> {
    let config = ConceptGraphsConfig {
        part_attach_margin_m: profile.fusion.part_attach_margin_m,
        ..ConceptGraphsConfig::default()
    };
    Box::new(ConceptGraphsFusion::new(config).with_up_axis(profile.world.up_axis))
}

/// Runs one scene: the full system and the ablations over one rendering pass.
pub fn run_scene(base: &Profile, room: RoomKind, seed: u64) -> Result<SceneRun, String> {
    let name = format!("{} seed {seed}", room.as_str());
    let (profile, mut oracle) = scene_profile(base, room, seed)?;
    // Enrichment runs below, once per row.
    let mut unenriched = profile.clone();
    unenriched.reasoner.kind = ReasonerKind::None;
    let mut no_colour = profile.clone();
    no_colour.fusion.colour_features = false;
    // Fusion alone: the oracle with its noise off (every visible instance, exact label, mask
    // and feature), its seed and semantic features kept.
    let mut exact = profile.clone();
    set_oracle_config(
        &mut exact,
        &OracleConfig {
            seed: oracle.seed,
            semantic_dim: oracle.semantic_dim,
            semantic_source: oracle.semantic_source,
            ..OracleConfig::clean()
        },
    );
    let mut generic = profile.clone();
    oracle.part_prompts = op3dsg_runtime::perception::candidates::CandidateMode::Generic;
    set_oracle_config(&mut generic, &oracle);
    let lanes = vec![
        Lane {
            detector: None,
            fusions: vec![op3dsg_fusion(&profile), op3dsg_fusion(&no_colour), peer_fusion(&profile)],
        },
        Lane { detector: Some(generic.clone()), fusions: vec![op3dsg_fusion(&generic)] },
        Lane { detector: Some(exact.clone()), fusions: vec![op3dsg_fusion(&exact)] },
    ];
    let mut runs = batch::run_lanes(&unenriched, &VisibilityThresholds::default(), lanes)
        .map_err(|e| format!("{name}: batch run: {e}"))?;
    let exact_run = runs.pop().and_then(|mut r| r.pop());
    let generic_run = runs.pop().and_then(|mut r| r.pop());
    let (Some(exact_run), Some(generic_run), Some(mut lane)) = (exact_run, generic_run, runs.pop()) else {
        return Err(format!("{name}: the batch runner returned fewer runs than asked"));
    };
    let (Some(peer_run), Some(no_colour_run), Some(full_run)) = (lane.pop(), lane.pop(), lane.pop()) else {
        return Err(format!("{name}: the batch runner returned fewer runs than asked"));
    };
    let Some(scene) = full_run.scene.as_ref() else { return Err(format!("{name}: no ground truth")) };
    // Every row reasons with the same reasoner: the knowledge tables and, for labels they do
    // not know, the embedding fallback on the MiniLM encoder.
    let embedder = op3dsg_runtime::onnx::text_encoder::load_shared(&profile.onnx, &profile.text_encoder)
        .map_err(|e| format!("{name}: label fallback: {e}"))?;
    let enricher = |knowledge: Option<Arc<KnowledgeBase>>, setup: ReasoningSetup| -> Result<_, String> {
        let Some(mut enricher) = make_enricher(&profile).map_err(|e| format!("{name}: {e}"))? else {
            return Ok(None);
        };
        if let Some(knowledge) = knowledge {
            enricher = enricher.with_knowledge(knowledge);
        }
        Ok(Some(setup.apply(enricher.with_label_embedder(embedder.clone()))))
    };
    let enrich_with = |graph: &op3dsg_runtime::graph::SceneGraph,
                       knowledge: Option<Arc<KnowledgeBase>>,
                       setup: ReasoningSetup|
     -> Result<(GraphJson, FallbackCounts), String> {
        let mut graph = graph.clone();
        let mut counts = FallbackCounts::default();
        if let Some(mut enricher) = enricher(knowledge, setup)? {
            enricher.enrich(&mut graph);
            counts = enricher.fallback_counts();
        }
        Ok((graph.to_json(&name), counts))
    };
    let enrich = |graph: &op3dsg_runtime::graph::SceneGraph, setup: ReasoningSetup| -> Result<GraphJson, String> {
        Ok(enrich_with(graph, None, setup)?.0)
    };
    let ground_truth = scene.ground_truth();
    let (gt_answer, _) = agreement::knowledge_answer_with(&ground_truth, &profile, None, Some(embedder.clone()))
        .map_err(|e| format!("{name}: reasoner on ground-truth nodes: {e}"))?;
    let predictions = vec![
        enrich(&full_run.graph, ReasoningSetup::Split)?,
        gt_answer.clone(),
        enrich(&exact_run.graph, ReasoningSetup::Split)?,
        enrich(&peer_run.graph, ReasoningSetup::Split)?,
        enrich(&generic_run.graph, ReasoningSetup::Split)?,
        enrich(&no_colour_run.graph, ReasoningSetup::Split)?,
        enrich(&full_run.graph, ReasoningSetup::FlatNodeList)?,
        enrich(&full_run.graph, ReasoningSetup::Single)?,
    ];
    // Leave one category out: for each object category of the scene, the reasoner's tables
    // without it (and its own parts), on the full row's fused graph and on the ground-truth nodes.
    let knowledge = KnowledgeBase::from_profile_dir(profile.reasoner.knowledge_dir.as_deref())
        .map_err(|e| format!("{name}: {e}"))?;
    let category_of = |label: &str| knowledge.object_category(label).map(|o| knowledge.object(o).name.clone());
    let mut categories: Vec<String> =
        ground_truth.nodes.iter().filter(|n| n.kind == "object").filter_map(|n| category_of(&n.label)).collect();
    categories.sort();
    categories.dedup();
    let mut loco = Vec::with_capacity(categories.len());
    for category in categories {
        let Some(reduced) = knowledge.without_object(&category) else { continue };
        let reduced = Arc::new(reduced);
        let of_category: Vec<u32> = ground_truth
            .nodes
            .iter()
            .filter(|n| n.kind == "object" && category_of(&n.label).as_deref() == Some(category.as_str()))
            .map(|n| n.id)
            .collect();
        let involved: Vec<u32> = ground_truth
            .nodes
            .iter()
            .filter(|n| of_category.contains(&n.id) || n.parent.is_some_and(|p| of_category.contains(&p)))
            .map(|n| n.id)
            .collect();
        let (fused, on_fused) = enrich_with(&full_run.graph, Some(reduced.clone()), ReasoningSetup::Split)?;
        let (gt_nodes, on_gt) =
            agreement::knowledge_answer_with(&ground_truth, &profile, Some(reduced.clone()), Some(embedder.clone()))
                .map_err(|e| format!("{name}: leave out {category}: {e}"))?;
        let nearest = fallback::LabelFallback::new(&reduced, Some(embedder.clone())).nearest(&category, true).and_then(
            |(c, cosine)| match c {
                op3dsg_runtime::knowledge::Category::Object(o) => Some((reduced.object(o).name.clone(), cosine)),
                op3dsg_runtime::knowledge::Category::Part(_) => None,
            },
        );
        loco.push(LocoRun { category, involved, fused, gt_nodes, fallback: [on_fused, on_gt], nearest });
    }
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let fusion = fusion_match::match_run(&full_run, &criteria);
    let scored_ids = scene
        .instances()
        .iter()
        .filter(|i| {
            full_run.visible_keyframes.get(usize::from(i.id)).is_some_and(|v| *v >= criteria.min_visible_keyframes)
        })
        .map(|i| u32::from(i.id))
        .collect();
    let deviations: Vec<(u32, &str)> = scene.deviations().iter().map(|d| (u32::from(d.instance), d.name)).collect();
    let agreement = agreement::compare(&ground_truth, &gt_answer, &deviations);
    Ok(SceneRun {
        room,
        seed,
        ground_truth,
        agreement,
        scored_ids,
        predictions,
        fusion,
        keyframes: full_run.keyframes,
        loco,
    })
}

/// Runs scenes `0..scenes` on `threads` named threads; `progress` is called after each scene.
/// Results come back in scene order whatever thread ran them.
/// `base` on synthetic `room` / `seed` with the oracle's knowledge-guided part prompts, as the
/// benchmark runs every scene; the oracle's configuration with it.
pub fn scene_profile(base: &Profile, room: RoomKind, seed: u64) -> Result<(Profile, OracleConfig), String> {
    let name = format!("{} seed {seed}", room.as_str());
    let mut profile = base.clone();
    let setting = |e: op3dsg_runtime::backend::StartError| format!("{name}: {e}");
    let mut synthetic = synthetic_config(&profile).map_err(setting)?;
    synthetic.room = room;
    synthetic.seed = seed;
    set_synthetic_config(&mut profile, &synthetic);
    let mut oracle = oracle_config(&profile).map_err(setting)?;
    oracle.part_prompts = op3dsg_runtime::perception::candidates::CandidateMode::Knowledge;
    set_oracle_config(&mut profile, &oracle);
    Ok((profile, oracle))
}

pub fn run_scenes(
    base: &Profile,
    scenes: usize,
    threads: usize,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Vec<SceneRun>, String> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<SceneRun, String>>>> = Mutex::new((0..scenes).map(|_| None).collect());
    std::thread::scope(|scope| {
        let mut handles = Vec::new();
        for t in 0..threads.clamp(1, scenes.max(1)) {
            let (next, results) = (&next, &results);
            let handle = std::thread::Builder::new().name(format!("op3dsg-bench-{t}")).spawn_scoped(scope, move || {
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    if i >= scenes {
                        break;
                    }
                    let (room, seed) = scene(i);
                    let result = run_scene(base, room, seed);
                    progress(&format!("{} seed {seed}", room.as_str()));
                    let mut slots = results.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                    slots[i] = Some(result);
                }
            });
            match handle {
                Ok(h) => handles.push(h),
                Err(e) => return Err(format!("cannot start a benchmark thread: {e}")),
            }
        }
        for h in handles {
            h.join().map_err(|_| "a benchmark thread panicked".to_owned())?;
        }
        Ok(())
    })?;
    results
        .into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .into_iter()
        .enumerate()
        .map(|(i, r)| r.unwrap_or_else(|| Err(format!("scene {i} was not run"))))
        .collect()
}

/// Where the full row lost recall at R@3 (see the module docs).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Losses {
    /// Object nodes by reason.
    pub object: BTreeMap<String, usize>,
    /// Part nodes by reason.
    pub part: BTreeMap<String, usize>,
    /// Affordances by reason.
    pub affordance: BTreeMap<String, usize>,
    /// Functional triplets by reason.
    pub functional: BTreeMap<String, usize>,
    /// Spatial triplets by reason.
    pub spatial: BTreeMap<String, usize>,
    /// Node misses by label (`kind label: count`), most frequent first in reports.
    pub node_labels: BTreeMap<String, usize>,
    /// Triplet misses by relation.
    pub relations: BTreeMap<String, usize>,
}

/// The scored benchmark.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct QualityReport {
    /// Scenes.
    pub scenes: Vec<String>,
    /// Keyframes over all scenes.
    pub keyframes: u64,
    /// Per row of [`ROWS`], the pooled figures.
    pub rows: Vec<(String, RecallFigures)>,
    /// Where the full row lost recall.
    pub losses: Losses,
    /// Functional relations of the scenes' ground truth.
    pub mix: BTreeMap<String, u32>,
    /// Vocabulary size (node labels).
    pub vocabulary_labels: usize,
    /// Ground truth vs knowledge base over all scenes ([`super::agreement`]).
    pub agreement: Agreement,
    /// How much of the rooms the scores cover.
    pub coverage: Coverage,
    /// The leave-one-category-out test.
    pub loco: Loco,
}

/// The variants of the leave-one-category-out table, in order: the full tables and the tables
/// without the category, each on the full row's fused graph and on the ground-truth nodes.
pub const LOCO_ROWS: [&str; 4] =
    ["full, same items", "leave one out", "GT nodes, full tables", "GT nodes, leave one out"];

/// One category of the leave-one-category-out test, over the scenes that contain it.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct LocoCategory {
    /// Canonical name of the category left out.
    pub category: String,
    /// Scenes containing it.
    pub scenes: usize,
    /// Per [`LOCO_ROWS`] variant, the recalls over the items involving the category.
    pub figures: Vec<RecallFigures>,
    /// How often the reasoner fell back (on the fused graph, on the ground-truth nodes).
    pub fallback: [FallbackCounts; 2],
    /// The known category the embedding fallback gives the category's own name, with the cosine.
    pub nearest: Option<(String, f32)>,
}

/// The leave-one-category-out test ([`run_scene`], module docs).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Loco {
    /// Per category, sorted by name.
    pub categories: Vec<LocoCategory>,
    /// Per [`LOCO_ROWS`] variant, the items of all categories pooled.
    pub pooled: Vec<RecallFigures>,
    /// Per [`LOCO_ROWS`] variant and column (object, part, affordance, functional, spatial), the
    /// mean R@3 over the categories that have items in that column, percent.
    pub mean_r3: Vec<[Option<f64>; 5]>,
    /// Fallback counts over all categories (fused graph, ground-truth nodes).
    pub fallback: [FallbackCounts; 2],
}

fn r3_of(f: &RecallFigures) -> [Option<f64>; 5] {
    [f.object, f.part, f.affordance, f.functional, f.spatial].map(|r| r.percent(K3))
}

/// Ground-truth nodes scored (seen in enough keyframes) out of all nodes of the scenes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Coverage {
    /// Nodes scored.
    pub scored: usize,
    /// Nodes of the scenes' ground truth.
    pub total: usize,
}

impl Coverage {
    /// Percent, `None` without nodes.
    pub fn percent(&self) -> Option<f64> {
        (self.total > 0).then(|| 100.0 * self.scored as f64 / self.total as f64)
    }

    fn text(&self) -> String {
        format!(
            "{} of {} ground-truth nodes ({}) seen in at least 3 keyframes and scored; recall is over these",
            self.scored,
            self.total,
            self.percent().map_or_else(|| "-".to_owned(), |p| format!("{p:.1} %"))
        )
    }
}

/// Scores scene runs with `evaluator`'s embedder (the vocabulary is the scenes' labels).
pub fn score(runs: &[SceneRun], embedder: &mut dyn super::recall::PhraseEmbedder) -> Result<QualityReport, String> {
    let vocabulary = Vocabulary::from_ground_truths(runs.iter().map(|r| &r.ground_truth));
    let vocabulary_labels = vocabulary.node_labels.len();
    let mut evaluator = RecallEvaluator::new(embedder, vocabulary);
    let mut rows: Vec<(String, RecallFigures)> =
        ROWS.iter().map(|r| ((*r).to_owned(), RecallFigures::default())).collect();
    let mut losses = Losses::default();
    let mut mix = BTreeMap::new();
    let mut agreement = Agreement::default();
    let mut coverage = Coverage::default();
    let mut by_category: Vec<LocoCategory> = Vec::new();
    for run in runs {
        agreement.add(&run.agreement);
        coverage.scored += run.ground_truth.nodes.iter().filter(|n| run.scored_ids.contains(&n.id)).count();
        coverage.total += run.ground_truth.nodes.len();
        let scored = |id: u32| run.scored_ids.contains(&id);
        let mut kept: Vec<super::recall::RecallReport> = Vec::new();
        for (i, (row, prediction)) in rows.iter_mut().zip(&run.predictions).enumerate() {
            let report = evaluator
                .evaluate(prediction, &run.ground_truth, Some(&scored))
                .map_err(|e| format!("{} seed {}: {e}", run.room.as_str(), run.seed))?;
            row.1.add(&report.figures);
            if i == 0 || i == GT_NODES_ROW {
                kept.push(report.clone());
            }
            if row.0 != ROWS[0] {
                continue;
            }
            for node in report.nodes.iter().filter(|n| n.best_rank.is_none_or(|r| r > 3)) {
                let fusion_miss = run.fusion.gt.iter().find(|g| g.id == node.id).and_then(|g| g.miss);
                let reason = match (fusion_miss, node.best_rank) {
                    (Some(miss), _) => miss.as_str().to_owned(),
                    (None, None) => "no box overlap".to_owned(),
                    (None, Some(_)) => "label ranks below 3".to_owned(),
                };
                let bucket = if node.kind == "object" { &mut losses.object } else { &mut losses.part };
                *bucket.entry(reason).or_insert(0) += 1;
                *losses.node_labels.entry(format!("{} {}", node.kind, node.label)).or_insert(0) += 1;
            }
            for a in report.affordances.iter().filter_map(|a| a.miss[K3]) {
                let reason = match a {
                    AffordanceMiss::NoNode => "node not found",
                    AffordanceMiss::WrongAffordance => "wrong affordance",
                };
                *losses.affordance.entry(reason.to_owned()).or_insert(0) += 1;
            }
            for e in report.edges.iter().filter(|e| e.miss[K3].is_some()) {
                let reason = e.miss[K3].map_or("", EdgeMiss::as_str).to_owned();
                let bucket = if e.kind == "functional" { &mut losses.functional } else { &mut losses.spatial };
                *bucket.entry(reason).or_insert(0) += 1;
                *losses.relations.entry(format!("{} {}", e.kind, e.relation)).or_insert(0) += 1;
            }
        }
        for edge in run.ground_truth.edges.iter().filter(|e| e.kind == "functional") {
            *mix.entry(edge.relation.clone()).or_insert(0) += 1;
        }
        let [full_report, gt_report] = <[_; 2]>::try_from(kept).map_err(|_| "rows missing".to_owned())?;
        for l in &run.loco {
            let involved = |id: u32| l.involved.contains(&id);
            let evaluate = |evaluator: &mut RecallEvaluator<'_>, g: &GraphJson| {
                evaluator
                    .evaluate(g, &run.ground_truth, Some(&scored))
                    .map_err(|e| format!("{} seed {} without {}: {e}", run.room.as_str(), run.seed, l.category))
            };
            let fused = evaluate(&mut evaluator, &l.fused)?;
            let gt_nodes = evaluate(&mut evaluator, &l.gt_nodes)?;
            let figures = [&full_report, &fused, &gt_report, &gt_nodes].map(|r| r.subset(&involved));
            let entry = match by_category.iter_mut().find(|c| c.category == l.category) {
                Some(entry) => entry,
                None => {
                    by_category.push(LocoCategory {
                        category: l.category.clone(),
                        figures: vec![RecallFigures::default(); LOCO_ROWS.len()],
                        ..LocoCategory::default()
                    });
                    by_category.last_mut().ok_or("no category")?
                }
            };
            entry.scenes += 1;
            entry.nearest.clone_from(&l.nearest);
            for (a, b) in entry.figures.iter_mut().zip(&figures) {
                a.add(b);
            }
            for (a, b) in entry.fallback.iter_mut().zip(&l.fallback) {
                a.add(b);
            }
        }
    }
    by_category.sort_by(|a, b| a.category.cmp(&b.category));
    let mut loco = Loco { pooled: vec![RecallFigures::default(); LOCO_ROWS.len()], ..Loco::default() };
    for c in &by_category {
        for (a, b) in loco.pooled.iter_mut().zip(&c.figures) {
            a.add(b);
        }
        for (a, b) in loco.fallback.iter_mut().zip(&c.fallback) {
            a.add(b);
        }
    }
    loco.mean_r3 = (0..LOCO_ROWS.len())
        .map(|v| {
            let mut mean = [None; 5];
            for (column, m) in mean.iter_mut().enumerate() {
                let values: Vec<f64> = by_category.iter().filter_map(|c| r3_of(&c.figures[v])[column]).collect();
                *m = (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
            }
            mean
        })
        .collect();
    loco.categories = by_category;
    Ok(QualityReport {
        scenes: runs.iter().map(|r| format!("{} seed {}", r.room.as_str(), r.seed)).collect(),
        keyframes: runs.iter().map(|r| r.keyframes).sum(),
        rows,
        losses,
        mix,
        vocabulary_labels,
        agreement,
        coverage,
        loco,
    })
}

fn pct(r: &Recall, k: usize) -> String {
    r.percent(k).map_or_else(|| "-".to_owned(), |p| format!("{p:.1}"))
}

/// The row's cells: object, part, overall, affordance R@3 R@5; functional, spatial R@3 R@5;
/// associated R@3 R@5 R@10.
fn cells(f: &RecallFigures) -> Vec<String> {
    let mut c = Vec::new();
    for r in [&f.object, &f.part, &f.overall, &f.affordance, &f.functional, &f.spatial] {
        c.push(pct(r, K3));
        c.push(pct(r, K5));
    }
    for k in [K3, K5, K10] {
        c.push(pct(&f.associated, k));
    }
    c
}

const HEADER: [&str; 15] = [
    "Obj R@3",
    "Obj R@5",
    "Part R@3",
    "Part R@5",
    "All R@3",
    "All R@5",
    "Aff R@3",
    "Aff R@5",
    "Func R@3",
    "Func R@5",
    "Spat R@3",
    "Spat R@5",
    "Assoc R@3",
    "Assoc R@5",
    "Assoc R@10",
];

/// Which full-row targets are missed: `(metric, R@3 percent, target)`.
pub fn missed_targets(report: &QualityReport) -> Vec<(&'static str, f64, f64)> {
    let Some((_, f)) = report.rows.first() else { return Vec::new() };
    let values = [&f.object, &f.part, &f.affordance, &f.functional, &f.spatial];
    TARGETS_R3
        .iter()
        .zip(values)
        .filter_map(|((name, target), r)| {
            let value = r.percent(K3).unwrap_or(0.0);
            (value < *target).then_some((*name, value, *target))
        })
        .collect()
}

fn sorted(map: &BTreeMap<String, usize>) -> String {
    let mut v: Vec<(&String, &usize)> = map.iter().collect();
    v.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
    if v.is_empty() {
        return "none".to_owned();
    }
    v.iter().map(|(k, n)| format!("{k} {n}")).collect::<Vec<_>>().join(", ")
}

/// The text report: table, strict node recall, items, losses, targets, mix.
pub fn text(report: &QualityReport) -> String {
    let mut s = String::new();
    let _ = write!(s, "{:<26}", "row");
    for h in HEADER {
        let _ = write!(s, " {h:>10}");
    }
    s.push('\n');
    for (name, f) in &report.rows {
        let _ = write!(s, "{name:<26}");
        for c in cells(f) {
            let _ = write!(s, " {c:>10}");
        }
        s.push('\n');
    }
    if let Some((_, f)) = report.rows.first() {
        let _ = writeln!(
            s,
            "\nfull, strict R@3: object IoU>=0.10 {} IoP>=0.25 {} | part IoU>=0.10 {} IoP>=0.25 {} | overall IoU>=0.10 {} \
             IoP>=0.25 {}",
            pct(&f.object_iou10, K3),
            pct(&f.object_iop25, K3),
            pct(&f.part_iou10, K3),
            pct(&f.part_iop25, K3),
            pct(&f.overall_iou10, K3),
            pct(&f.overall_iop25, K3)
        );
        let _ = writeln!(
            s,
            "items: {} objects, {} parts, {} affordances, {} functional, {} spatial triplets, {} associated pairs; \
             {} predicted nodes, {} retrieve nothing at R@10; {} vocabulary labels",
            f.object.total,
            f.part.total,
            f.affordance.total,
            f.functional.total,
            f.spatial.total,
            f.associated.total,
            f.predicted_nodes,
            f.predicted_unmatched,
            report.vocabulary_labels
        );
    }
    let _ = writeln!(s, "coverage: {}", report.coverage.text());
    let l = &report.losses;
    let _ = writeln!(s, "\nwhere the full row loses recall at R@3:");
    let _ = writeln!(s, "  object nodes: {}", sorted(&l.object));
    let _ = writeln!(s, "  part nodes: {}", sorted(&l.part));
    let _ = writeln!(s, "  affordances: {}", sorted(&l.affordance));
    let _ = writeln!(s, "  functional triplets: {}", sorted(&l.functional));
    let _ = writeln!(s, "  spatial triplets: {}", sorted(&l.spatial));
    let _ = writeln!(s, "  missed nodes by label: {}", sorted(&l.node_labels));
    let _ = writeln!(s, "  missed triplets by relation: {}", sorted(&l.relations));
    let missed = missed_targets(report);
    if missed.is_empty() {
        let _ = writeln!(s, "\ntargets (full, R@3): all met");
    } else {
        let list: Vec<String> = missed.iter().map(|(n, v, t)| format!("{n} {v:.1} < {t:.0}")).collect();
        let _ = writeln!(s, "\ntargets (full, R@3) missed: {}", list.join("; "));
    }
    s.push_str(&loco_text(&report.loco));
    s.push_str(&agreement::text(&report.agreement));
    s.push_str(&mix_text(&report.mix));
    s
}

fn cell(v: Option<f64>) -> String {
    v.map_or_else(|| "-".to_owned(), |p| format!("{p:.1}"))
}

const LOCO_HEADER: [&str; 5] = ["Obj R@3", "Part R@3", "Aff R@3", "Func R@3", "Spat R@3"];

/// The leave-one-category-out table: per variant, pooled and mean over categories.
fn loco_lines(loco: &Loco) -> Vec<(String, Vec<String>)> {
    let mut lines = Vec::new();
    for (v, name) in LOCO_ROWS.iter().enumerate() {
        if let Some(f) = loco.pooled.get(v) {
            lines.push((format!("{name} (pooled)"), r3_of(f).map(cell).to_vec()));
        }
    }
    for (v, name) in LOCO_ROWS.iter().enumerate() {
        if let Some(m) = loco.mean_r3.get(v) {
            lines.push((format!("{name} (mean over categories)"), m.map(cell).to_vec()));
        }
    }
    lines
}

fn fallback_text(c: &[FallbackCounts; 2]) -> String {
    let one = |c: &FallbackCounts| {
        format!(
            "{} nodes given their nearest category by embedding, {} parts reasoned as on the nearest category that \
             has them, {} parts by the part-label rule, {} nodes unresolved",
            c.by_embedding, c.parts_by_embedding, c.by_part_rule, c.unresolved
        )
    };
    format!("on the fused graphs {}; on the ground-truth nodes {}", one(&c[0]), one(&c[1]))
}

/// The leave-one-category-out block of the text report.
pub fn loco_text(loco: &Loco) -> String {
    let mut s = format!(
        "\nleave one category out ({} categories; items involving the category, in the scenes that contain it; a mean \
         is over the categories with items in its column):\n",
        loco.categories.len()
    );
    let _ = write!(s, "{:<48}", "variant");
    for h in LOCO_HEADER {
        let _ = write!(s, " {h:>9}");
    }
    s.push('\n');
    for (name, cells) in loco_lines(loco) {
        let _ = write!(s, "{name:<48}");
        for c in cells {
            let _ = write!(s, " {c:>9}");
        }
        s.push('\n');
    }
    let _ = writeln!(s, "  fallbacks: {}", fallback_text(&loco.fallback));
    let _ = writeln!(
        s,
        "  per category (as: its nearest known category by embedding), full -> leave one out (fused graph), R@3 aff / func:"
    );
    for c in &loco.categories {
        let [full, left] = [&c.figures[0], &c.figures[1]];
        let _ = writeln!(
            s,
            "    {:<22} {:<28} {} scenes, {} aff, {} func: aff {} -> {}, func {} -> {}; GT nodes func {} -> {}",
            c.category,
            c.nearest.as_ref().map_or_else(|| "(nothing near)".to_owned(), |(n, cos)| format!("(as {n}, {cos:.2})")),
            c.scenes,
            full.affordance.total,
            full.functional.total,
            cell(full.affordance.percent(K3)),
            cell(left.affordance.percent(K3)),
            cell(full.functional.percent(K3)),
            cell(left.functional.percent(K3)),
            cell(c.figures[2].functional.percent(K3)),
            cell(c.figures[3].functional.percent(K3)),
        );
    }
    s
}

/// The leave-one-category-out table in Markdown.
pub fn loco_markdown(loco: &Loco) -> String {
    let mut s = String::from("| leave one category out |");
    for h in LOCO_HEADER {
        let _ = write!(s, " {h} |");
    }
    s.push_str("\n|---|");
    for _ in LOCO_HEADER {
        s.push_str("---:|");
    }
    s.push('\n');
    for (name, cells) in loco_lines(loco) {
        let _ = writeln!(s, "| {name} | {} |", cells.join(" | "));
    }
    let _ = writeln!(s, "\nFallbacks of the reasoner without the category: {}.", fallback_text(&loco.fallback));
    s
}

/// The functional-relation mix next to the benchmark's, percent.
pub fn mix_text(mix: &BTreeMap<String, u32>) -> String {
    let total: u32 = mix.values().sum();
    let (f_total, s_total) = (230.0, 195.0);
    let mut s = format!(
        "\nfunctional relations: {:<44} {:>12} {:>12} {:>12}\n",
        "relation", "synthetic %", "FunGraph3D %", "SceneFun3D %"
    );
    for (relation, f, sf) in REFERENCE_MIX {
        let ours = mix.get(relation).copied().unwrap_or(0);
        let _ = writeln!(
            s,
            "                      {:<44} {:>12} {:>12.1} {:>12.1}",
            relation,
            format!("{:.1} ({ours})", 100.0 * f64::from(ours) / f64::from(total.max(1))),
            100.0 * f64::from(f) / f_total,
            100.0 * f64::from(sf) / s_total
        );
    }
    let _ = writeln!(s, "                      {:<44} {:>12}", "total edges", total);
    s
}

/// The Markdown table (and the strict figures) for the README.
pub fn markdown(report: &QualityReport) -> String {
    let mut s = String::from("| row |");
    for h in HEADER {
        let _ = write!(s, " {h} |");
    }
    s.push_str("\n|---|");
    for _ in HEADER {
        s.push_str("---:|");
    }
    s.push('\n');
    for (name, f) in &report.rows {
        let _ = write!(s, "| {name} |");
        for c in cells(f) {
            let _ = write!(s, " {c} |");
        }
        s.push('\n');
    }
    if let Some((_, f)) = report.rows.first() {
        let _ = writeln!(
            s,
            "\nStrict node R@3 (full): object {} / {}, part {} / {}, overall {} / {} (IoU ≥ 0.10 / IoP ≥ 0.25).",
            pct(&f.object_iou10, K3),
            pct(&f.object_iop25, K3),
            pct(&f.part_iou10, K3),
            pct(&f.part_iop25, K3),
            pct(&f.overall_iou10, K3),
            pct(&f.overall_iop25, K3)
        );
    }
    let _ = writeln!(s, "\nCoverage: {}.", report.coverage.text());
    s.push('\n');
    s.push_str(&loco_markdown(&report.loco));
    let a = &report.agreement;
    let share = |x: &agreement::Share| x.percent().map_or_else(|| "-".to_owned(), |p| format!("{p:.1} %"));
    let _ = writeln!(
        s,
        "\nGround truth vs knowledge base (reasoner on ground-truth nodes): functional triplets {} of {} agree ({}), \
         affordance sets {} of {} ({}); on the rooms' deviations {} / {}.",
        a.functional.agree,
        a.functional.total,
        share(&a.functional),
        a.affordance.agree,
        a.affordance.total,
        share(&a.affordance),
        share(&a.functional_deviations),
        share(&a.affordance_deviations)
    );
    s
}
