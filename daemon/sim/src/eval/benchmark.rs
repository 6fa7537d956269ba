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
//! All rows use the offline knowledge reasoner. Ground-truth nodes seen in fewer than 3
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
use op3dsg_runtime::config::{Profile, ReasonerKind};
use op3dsg_runtime::pipeline::{make_enricher, make_fusion};
use op3dsg_runtime::reasoner::ReasoningSetup;

/// The rows of the table, in order.
pub const ROWS: [&str; 5] = ["full", "w/o knowledge", "w/o colour", "w/o prior graph", "w/o split"];
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
}

/// Runs one scene: the full system and the ablations over one rendering pass.
pub fn run_scene(base: &Profile, room: RoomKind, seed: u64) -> Result<SceneRun, String> {
    let name = format!("{} seed {seed}", room.as_str());
    let mut profile = base.clone();
    let setting = |e: op3dsg_runtime::pipeline::StartError| format!("{name}: {e}");
    let mut synthetic = synthetic_config(&profile).map_err(setting)?;
    synthetic.room = room;
    synthetic.seed = seed;
    set_synthetic_config(&mut profile, &synthetic);
    let mut oracle = oracle_config(&profile).map_err(setting)?;
    oracle.part_prompts = op3dsg_runtime::perception::candidates::CandidateMode::Knowledge;
    set_oracle_config(&mut profile, &oracle);
    // Enrichment runs below, once per row.
    let mut unenriched = profile.clone();
    unenriched.reasoner.kind = ReasonerKind::None;
    let mut no_colour = profile.clone();
    no_colour.fusion.colour_features = false;
    let mut generic = profile.clone();
    oracle.part_prompts = op3dsg_runtime::perception::candidates::CandidateMode::Generic;
    set_oracle_config(&mut generic, &oracle);
    let lanes = vec![
        Lane { detector: None, fusions: vec![make_fusion(&profile), make_fusion(&no_colour)] },
        Lane { detector: Some(generic.clone()), fusions: vec![make_fusion(&generic)] },
    ];
    let mut runs = batch::run_lanes(&unenriched, &VisibilityThresholds::default(), lanes)
        .map_err(|e| format!("{name}: batch run: {e}"))?;
    let generic_run = runs.pop().and_then(|mut r| r.pop());
    let (Some(generic_run), Some(mut lane)) = (generic_run, runs.pop()) else {
        return Err(format!("{name}: the batch runner returned fewer runs than asked"));
    };
    let (Some(no_colour_run), Some(full_run)) = (lane.pop(), lane.pop()) else {
        return Err(format!("{name}: the batch runner returned fewer runs than asked"));
    };
    let Some(scene) = full_run.scene.as_ref() else { return Err(format!("{name}: no ground truth")) };
    let enrich = |graph: &op3dsg_runtime::graph::SceneGraph, setup: ReasoningSetup| -> Result<GraphJson, String> {
        let mut graph = graph.clone();
        if let Some(enricher) = make_enricher(&profile).map_err(|e| format!("{name}: {e}"))? {
            enricher.with_setup(setup).enrich(&mut graph);
        }
        Ok(graph.to_json(&name))
    };
    let predictions = vec![
        enrich(&full_run.graph, ReasoningSetup::Split)?,
        enrich(&generic_run.graph, ReasoningSetup::Split)?,
        enrich(&no_colour_run.graph, ReasoningSetup::Split)?,
        enrich(&full_run.graph, ReasoningSetup::FlatNodeList)?,
        enrich(&full_run.graph, ReasoningSetup::Single)?,
    ];
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
    let ground_truth = scene.ground_truth();
    let deviations: Vec<(u32, &str)> = scene.deviations().iter().map(|d| (u32::from(d.instance), d.name)).collect();
    let agreement =
        agreement::measure(&ground_truth, &deviations, &profile).map_err(|e| format!("{name}: agreement: {e}"))?;
    Ok(SceneRun { room, seed, ground_truth, agreement, scored_ids, predictions, fusion, keyframes: full_run.keyframes })
}

/// Runs scenes `0..scenes` on `threads` named threads; `progress` is called after each scene.
/// Results come back in scene order whatever thread ran them.
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
    for run in runs {
        agreement.add(&run.agreement);
        coverage.scored += run.ground_truth.nodes.iter().filter(|n| run.scored_ids.contains(&n.id)).count();
        coverage.total += run.ground_truth.nodes.len();
        let scored = |id: u32| run.scored_ids.contains(&id);
        for (row, prediction) in rows.iter_mut().zip(&run.predictions) {
            let report = evaluator
                .evaluate(prediction, &run.ground_truth, Some(&scored))
                .map_err(|e| format!("{} seed {}: {e}", run.room.as_str(), run.seed))?;
            row.1.add(&report.figures);
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
    }
    Ok(QualityReport {
        scenes: runs.iter().map(|r| format!("{} seed {}", r.room.as_str(), r.seed)).collect(),
        keyframes: runs.iter().map(|r| r.keyframes).sum(),
        rows,
        losses,
        mix,
        vocabulary_labels,
        agreement,
        coverage,
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
    let _ = write!(s, "{:<16}", "row");
    for h in HEADER {
        let _ = write!(s, " {h:>10}");
    }
    s.push('\n');
    for (name, f) in &report.rows {
        let _ = write!(s, "{name:<16}");
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
    s.push_str(&agreement::text(&report.agreement));
    s.push_str(&mix_text(&report.mix));
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
