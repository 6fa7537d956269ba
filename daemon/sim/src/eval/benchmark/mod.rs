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
//!
//! | file | what |
//! |---|---|
//! | this file | the scenes and rows, running them ([`run_scene`], [`run_scenes`]) |
//! | `report.rs` | scoring the runs ([`score`], [`QualityReport`]) |
//! | `text.rs` | the printed report ([`text`], [`loco_text`]) |

mod report;
mod text;

pub use report::{Coverage, LOCO_ROWS, Loco, LocoCategory, Losses, QualityReport, score};
pub use text::{loco_markdown, loco_text, markdown, missed_targets, mix_text, text};

use std::collections::BTreeMap;

use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_synthetic::RoomKind;

use crate::backends::{oracle_config, set_oracle_config, set_synthetic_config, synthetic_config};
use crate::batch::{self, BatchRun, Lane, VisibilityThresholds};
use crate::eval::agreement::{self, Agreement};
use crate::eval::fusion_match::{self, FusionMatchReport, MatchCriteria};
use crate::knowledge_variants::KnowledgeVariants;
use crate::oracle::OracleConfig;
use crate::reasoning_ablation::ReasoningSetup;
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::embedding::SharedEmbedder;
use op3dsg_runtime::graph::SceneGraph;
use op3dsg_runtime::knowledge::KnowledgeBase;
use op3dsg_runtime::knowledge::fallback::{self, FallbackCounts};
use op3dsg_runtime::pipeline::make_enricher;
use op3dsg_runtime::reasoner::{GraphEnricher, ReasonerKind};
use std::sync::Arc;

/// The rows of the table, in order.
pub const ROWS: [&str; 8] = [
    "full",
    "reasoner on GT nodes",
    "fusion on exact detections",
    crate::conceptgraphs::PEER_ROW,
    "w/o knowledge",
    "w/o colour",
    "w/o prior graph",
    "w/o split",
];
/// The OP3DSG fusion of `profile` (the method's rows).
fn op3dsg_fusion(profile: &Profile) -> Box<dyn op3dsg_runtime::fusion::Fusion> {
    op3dsg_runtime::fusion::build(&profile.fusion, profile.world.up_axis)
}

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

/// Runs one scene: the full system and the ablations over one rendering pass.
pub fn run_scene(base: &Profile, room: RoomKind, seed: u64) -> Result<SceneRun, String> {
    let name = format!("{} seed {seed}", room.as_str());
    let (profile, oracle) = scene_profile(base, room, seed)?;
    let runs = RowRuns::run(&profile, oracle, &name)?;
    let full_run = &runs.full;
    let Some(scene) = full_run.scene.as_ref() else { return Err(format!("{name}: no ground truth")) };
    // Every row reasons with the same reasoner: the knowledge tables and, for labels they do
    // not know, the embedding fallback on the MiniLM encoder.
    let embedder = op3dsg_runtime::onnx::text_encoder::load_shared(&profile.onnx, &profile.text_encoder)
        .map_err(|e| format!("{name}: label fallback: {e}"))?;
    let reasoner = SceneReasoner { profile: &profile, name: &name, embedder };
    let ground_truth = scene.ground_truth();
    let (gt_answer, _) =
        agreement::knowledge_answer_with(&ground_truth, &profile, None, Some(reasoner.embedder.clone()))
            .map_err(|e| format!("{name}: reasoner on ground-truth nodes: {e}"))?;
    let predictions = vec![
        reasoner.enrich(&full_run.graph, ReasoningSetup::Split)?,
        gt_answer.clone(),
        reasoner.enrich(&runs.exact.graph, ReasoningSetup::Split)?,
        reasoner.enrich(&runs.peer.graph, ReasoningSetup::Split)?,
        reasoner.enrich(&runs.generic.graph, ReasoningSetup::Split)?,
        reasoner.enrich(&runs.no_colour.graph, ReasoningSetup::Split)?,
        reasoner.enrich(&full_run.graph, ReasoningSetup::FlatNodeList)?,
        reasoner.enrich(&full_run.graph, ReasoningSetup::Single)?,
    ];
    let loco = reasoner.leave_one_category_out(&ground_truth, &full_run.graph)?;
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let fusion = fusion_match::match_run(full_run, &criteria);
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

/// The batch runs of one scene's rows, unenriched (one rendering pass, three detector lanes).
struct RowRuns {
    /// The full row's fusion.
    full: BatchRun,
    /// "w/o colour".
    no_colour: BatchRun,
    /// The peer's fusion on the full row's detections.
    peer: BatchRun,
    /// "w/o knowledge": the oracle's generic part prompts.
    generic: BatchRun,
    /// "fusion on exact detections".
    exact: BatchRun,
}

impl RowRuns {
    /// Runs `profile` (the scene's, its oracle `oracle`) with every row's detector and fusion;
    /// errors start with the scene's `name`.
    fn run(profile: &Profile, mut oracle: OracleConfig, name: &str) -> Result<Self, String> {
        // Enrichment runs afterwards, once per row.
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
                fusions: vec![
                    op3dsg_fusion(profile),
                    op3dsg_fusion(&no_colour),
                    crate::conceptgraphs::peer_fusion(profile),
                ],
            },
            Lane { detector: Some(generic.clone()), fusions: vec![op3dsg_fusion(&generic)] },
            Lane { detector: Some(exact.clone()), fusions: vec![op3dsg_fusion(&exact)] },
        ];
        let mut runs = batch::run_lanes(&unenriched, &VisibilityThresholds::default(), lanes)
            .map_err(|e| format!("{name}: batch run: {e}"))?;
        let exact_run = runs.pop().and_then(|mut r| r.pop());
        let generic_run = runs.pop().and_then(|mut r| r.pop());
        let (Some(exact), Some(generic), Some(mut lane)) = (exact_run, generic_run, runs.pop()) else {
            return Err(format!("{name}: the batch runner returned fewer runs than asked"));
        };
        let (Some(peer), Some(no_colour), Some(full)) = (lane.pop(), lane.pop(), lane.pop()) else {
            return Err(format!("{name}: the batch runner returned fewer runs than asked"));
        };
        Ok(Self { full, no_colour, peer, generic, exact })
    }
}

/// The reasoner every row of one scene is enriched with: the profile's, with the label
/// fallback on `embedder`.
struct SceneReasoner<'a> {
    profile: &'a Profile,
    /// The scene, for errors and graph sources.
    name: &'a str,
    embedder: SharedEmbedder,
}

impl SceneReasoner<'_> {
    /// A fresh enricher with `knowledge` in place of the profile's tables (`None`: the
    /// profile's) and the reasoning of `setup`; `None` when the profile reasons not at all.
    fn enricher(
        &self,
        knowledge: Option<Arc<KnowledgeBase>>,
        setup: ReasoningSetup,
    ) -> Result<Option<GraphEnricher>, String> {
        let Some(mut enricher) = make_enricher(self.profile).map_err(|e| format!("{}: {e}", self.name))? else {
            return Ok(None);
        };
        if let Some(knowledge) = knowledge {
            enricher = enricher.with_knowledge(knowledge);
        }
        Ok(Some(setup.apply(enricher.with_label_embedder(self.embedder.clone()))))
    }

    /// `graph` enriched by [`Self::enricher`], and how often its reasoner fell back.
    fn enrich_with(
        &self,
        graph: &SceneGraph,
        knowledge: Option<Arc<KnowledgeBase>>,
        setup: ReasoningSetup,
    ) -> Result<(GraphJson, FallbackCounts), String> {
        let mut graph = graph.clone();
        let mut counts = FallbackCounts::default();
        if let Some(mut enricher) = self.enricher(knowledge, setup)? {
            enricher.enrich(&mut graph);
            counts = enricher.fallback_counts();
        }
        Ok((graph.to_json(self.name), counts))
    }

    /// `graph` enriched with the profile's tables.
    fn enrich(&self, graph: &SceneGraph, setup: ReasoningSetup) -> Result<GraphJson, String> {
        Ok(self.enrich_with(graph, None, setup)?.0)
    }

    /// Leave one category out: for each object category of the scene, the reasoner's tables
    /// without it (and its own parts), on the full row's fused graph `full` and on the
    /// ground-truth nodes.
    fn leave_one_category_out(&self, ground_truth: &GraphJson, full: &SceneGraph) -> Result<Vec<LocoRun>, String> {
        let name = self.name;
        let knowledge = KnowledgeBase::from_profile_dir(self.profile.reasoner.knowledge_dir.as_deref())
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
            let involved = involved_ids(ground_truth, |label| category_of(label).as_deref() == Some(category.as_str()));
            let (fused, on_fused) = self.enrich_with(full, Some(reduced.clone()), ReasoningSetup::Split)?;
            let (gt_nodes, on_gt) = agreement::knowledge_answer_with(
                ground_truth,
                self.profile,
                Some(reduced.clone()),
                Some(self.embedder.clone()),
            )
            .map_err(|e| format!("{name}: leave out {category}: {e}"))?;
            let nearest = fallback::LabelFallback::new(&reduced, Some(self.embedder.clone()))
                .nearest(&category, true)
                .and_then(|(c, cosine)| match c {
                    op3dsg_runtime::knowledge::Category::Object(o) => Some((reduced.object(o).name.clone(), cosine)),
                    op3dsg_runtime::knowledge::Category::Part(_) => None,
                });
            loco.push(LocoRun { category, involved, fused, gt_nodes, fallback: [on_fused, on_gt], nearest });
        }
        Ok(loco)
    }
}

/// Ground-truth ids of the objects whose label `of_category` accepts, and of their parts.
fn involved_ids(ground_truth: &GraphJson, of_category: impl Fn(&str) -> bool) -> Vec<u32> {
    let objects: Vec<u32> =
        ground_truth.nodes.iter().filter(|n| n.kind == "object" && of_category(&n.label)).map(|n| n.id).collect();
    ground_truth
        .nodes
        .iter()
        .filter(|n| objects.contains(&n.id) || n.parent.is_some_and(|p| objects.contains(&p)))
        .map(|n| n.id)
        .collect()
}

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

/// Runs scenes `0..scenes` on `threads` named threads; `progress` is called after each scene.
/// Results come back in scene order whatever thread ran them.
pub fn run_scenes(
    base: &Profile,
    scenes: usize,
    threads: usize,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Vec<SceneRun>, String> {
    crate::eval::parallel::in_order(scenes, threads, "op3dsg-bench", &|i| {
        let (room, seed) = scene(i);
        let result = run_scene(base, room, seed);
        progress(&format!("{} seed {seed}", room.as_str()));
        result
    })
}
