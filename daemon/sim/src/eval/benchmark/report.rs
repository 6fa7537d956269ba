//! Scoring the scenes' runs: recall per row, where the full row lost it, coverage, the
//! leave-one-category-out test.

use std::collections::BTreeMap;

use op3dsg_drivers::graph_json::GraphJson;
use serde::Serialize;

use super::{GT_NODES_ROW, ROWS, SceneRun};
use crate::eval::agreement::Agreement;
use crate::eval::recall::{AffordanceMiss, EdgeMiss, K3, RecallEvaluator, RecallFigures, RecallReport, Vocabulary};
use op3dsg_runtime::knowledge::fallback::FallbackCounts;

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

pub(super) fn r3_of(f: &RecallFigures) -> [Option<f64>; 5] {
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

    pub(super) fn text(&self) -> String {
        format!(
            "{} of {} ground-truth nodes ({}) seen in at least 3 keyframes and scored; recall is over these",
            self.scored,
            self.total,
            self.percent().map_or_else(|| "-".to_owned(), |p| format!("{p:.1} %"))
        )
    }
}

/// Scores scene runs with `evaluator`'s embedder (the vocabulary is the scenes' labels).
pub fn score(
    runs: &[SceneRun],
    embedder: &mut dyn crate::eval::recall::PhraseEmbedder,
) -> Result<QualityReport, String> {
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
        let kept = score_rows(&mut evaluator, run, &mut rows, &mut losses)?;
        for edge in run.ground_truth.edges.iter().filter(|e| e.kind == "functional") {
            *mix.entry(edge.relation.clone()).or_insert(0) += 1;
        }
        let [full_report, gt_report] = <[_; 2]>::try_from(kept).map_err(|_| "rows missing".to_owned())?;
        score_loco(&mut evaluator, run, [&full_report, &gt_report], &mut by_category)?;
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
        loco: Loco::from_categories(by_category),
    })
}

/// Scores each row's prediction of `run` into `rows` and counts where the full row lost recall
/// into `losses`. The reports of the full row and of "reasoner on GT nodes", in that order.
fn score_rows(
    evaluator: &mut RecallEvaluator<'_>,
    run: &SceneRun,
    rows: &mut [(String, RecallFigures)],
    losses: &mut Losses,
) -> Result<Vec<RecallReport>, String> {
    let scored = |id: u32| run.scored_ids.contains(&id);
    let mut kept: Vec<RecallReport> = Vec::new();
    for (i, (row, prediction)) in rows.iter_mut().zip(&run.predictions).enumerate() {
        let report = evaluator
            .evaluate(prediction, &run.ground_truth, Some(&scored))
            .map_err(|e| format!("{} seed {}: {e}", run.room.as_str(), run.seed))?;
        row.1.add(&report.figures);
        if i == 0 || i == GT_NODES_ROW {
            kept.push(report.clone());
        }
        if row.0 == ROWS[0] {
            losses.add(&report, run);
        }
    }
    Ok(kept)
}

impl Losses {
    /// Counts the items the full row's `report` of `run` did not retrieve at R@3, by reason.
    fn add(&mut self, report: &RecallReport, run: &SceneRun) {
        for node in report.nodes.iter().filter(|n| n.best_rank.is_none_or(|r| r > 3)) {
            let fusion_miss = run.fusion.gt.iter().find(|g| g.id == node.id).and_then(|g| g.miss);
            let reason = match (fusion_miss, node.best_rank) {
                (Some(miss), _) => miss.as_str().to_owned(),
                (None, None) => "no box overlap".to_owned(),
                (None, Some(_)) => "label ranks below 3".to_owned(),
            };
            let bucket = if node.kind == "object" { &mut self.object } else { &mut self.part };
            *bucket.entry(reason).or_insert(0) += 1;
            *self.node_labels.entry(format!("{} {}", node.kind, node.label)).or_insert(0) += 1;
        }
        for a in report.affordances.iter().filter_map(|a| a.miss[K3]) {
            let reason = match a {
                AffordanceMiss::NoNode => "node not found",
                AffordanceMiss::WrongAffordance => "wrong affordance",
            };
            *self.affordance.entry(reason.to_owned()).or_insert(0) += 1;
        }
        for e in report.edges.iter().filter(|e| e.miss[K3].is_some()) {
            let reason = e.miss[K3].map_or("", EdgeMiss::as_str).to_owned();
            let bucket = if e.kind == "functional" { &mut self.functional } else { &mut self.spatial };
            *bucket.entry(reason).or_insert(0) += 1;
            *self.relations.entry(format!("{} {}", e.kind, e.relation)).or_insert(0) += 1;
        }
    }
}

/// Scores `run`'s leave-one-category-out graphs on the items of their category and adds them,
/// with `full_and_gt` (the reports of the full row and of "reasoner on GT nodes") on the same
/// items, to the category's entry of `by_category`.
fn score_loco(
    evaluator: &mut RecallEvaluator<'_>,
    run: &SceneRun,
    full_and_gt: [&RecallReport; 2],
    by_category: &mut Vec<LocoCategory>,
) -> Result<(), String> {
    let [full_report, gt_report] = full_and_gt;
    let scored = |id: u32| run.scored_ids.contains(&id);
    for l in &run.loco {
        let involved = |id: u32| l.involved.contains(&id);
        let evaluate = |evaluator: &mut RecallEvaluator<'_>, g: &GraphJson| {
            evaluator
                .evaluate(g, &run.ground_truth, Some(&scored))
                .map_err(|e| format!("{} seed {} without {}: {e}", run.room.as_str(), run.seed, l.category))
        };
        let fused = evaluate(evaluator, &l.fused)?;
        let gt_nodes = evaluate(evaluator, &l.gt_nodes)?;
        let figures = [full_report, &fused, gt_report, &gt_nodes].map(|r| r.subset(&involved));
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
    Ok(())
}

impl Loco {
    /// The test's summary of its categories: sorted by name, pooled, and mean R@3 per column.
    fn from_categories(mut by_category: Vec<LocoCategory>) -> Self {
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
        loco
    }
}
