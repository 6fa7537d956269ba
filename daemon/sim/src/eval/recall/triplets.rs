//! Edge retrieval: functional and spatial triplet R@K, with why each missed edge is missed
//! (an endpoint not retrieved, no predicted edge between retrieved endpoints, a wrong relation),
//! and associated node-pair R@K.

use std::collections::{HashMap, HashSet};

use super::evaluator::Scoring;
use super::nodes::{Overlap, retrievers};
use super::{EdgeMiss, EdgeResult, KS, Recall, RecallReport};
use crate::eval::fusion_match::normalise_label;

/// A predicted edge: source and target (indices into the predicted nodes), kind, normalised
/// relation phrase.
type PredictedEdge<'p> = (usize, usize, &'p str, String);

/// Triplet R@K (functional and spatial) of the scored ground-truth edges with their per-edge
/// results, then associated node-pair R@K.
pub(super) fn score_edges(scoring: &Scoring<'_>, report: &mut RecallReport) {
    let pred_index: HashMap<u32, usize> = scoring.pred.nodes.iter().enumerate().map(|(i, n)| (n.id, i)).collect();
    // Predicted edges by kind, as node indices.
    let pred_edges: Vec<PredictedEdge<'_>> = scoring
        .pred
        .edges
        .iter()
        .filter_map(|e| {
            let s = *pred_index.get(&e.source)?;
            let t = *pred_index.get(&e.target)?;
            Some((s, t, e.kind.as_str(), normalise_label(&e.relation)))
        })
        .collect();
    let pairs = score_triplets(scoring, &pred_edges, report);
    score_associated(&scoring.overlaps, &pairs, &pred_edges, &mut report.figures.associated);
}

/// Triplet R@K of every scored ground-truth edge; returns the ground-truth node pairs (indices,
/// in first-seen order, each unordered pair once) the edges join.
fn score_triplets(
    scoring: &Scoring<'_>,
    pred_edges: &[PredictedEdge<'_>],
    report: &mut RecallReport,
) -> Vec<(usize, usize)> {
    let gt_index: HashMap<u32, usize> = scoring.gt.nodes.iter().enumerate().map(|(i, n)| (n.id, i)).collect();
    let mut pairs: HashSet<(u32, u32)> = HashSet::new();
    let mut pair_list: Vec<(usize, usize)> = Vec::new();
    for e in &scoring.gt.edges {
        let (Some(&si), Some(&ti)) = (gt_index.get(&e.source), gt_index.get(&e.target)) else { continue };
        if !(scoring.is_scored(e.source) && scoring.is_scored(e.target)) {
            continue;
        }
        let key = (e.source.min(e.target), e.source.max(e.target));
        if pairs.insert(key) {
            pair_list.push((si, ti));
        }
        let relation = normalise_label(&e.relation);
        let functional = e.kind == "functional";
        let vocabulary = if functional { &scoring.vocabulary.functional } else { &scoring.vocabulary.spatial };
        let symmetric = relation == "next to";
        let mut miss = [None; 3];
        for (k_index, k) in KS.into_iter().enumerate() {
            let sources = retrievers(&scoring.overlaps[si], k);
            let targets = retrievers(&scoring.overlaps[ti], k);
            if sources.is_empty() || targets.is_empty() {
                miss[k_index] = Some(EdgeMiss::EndpointNotRetrieved);
                continue;
            }
            let joins = |ps: usize, pt: usize| {
                (sources.contains(&ps) && targets.contains(&pt))
                    || (symmetric && sources.contains(&pt) && targets.contains(&ps))
            };
            let candidates: Vec<&String> = pred_edges
                .iter()
                .filter(|(ps, pt, kind, _)| *kind == e.kind && joins(*ps, *pt))
                .map(|(_, _, _, r)| r)
                .collect();
            if candidates.is_empty() {
                miss[k_index] = Some(EdgeMiss::MissingEdge);
                continue;
            }
            let best_rank =
                candidates.iter().map(|r| scoring.cache.rank(vocabulary, r, &relation)).min().unwrap_or(usize::MAX);
            if best_rank > k {
                miss[k_index] = Some(EdgeMiss::WrongRelation);
            }
        }
        let counter = if functional { &mut report.figures.functional } else { &mut report.figures.spatial };
        counter.total += 1;
        for (k_index, m) in miss.iter().enumerate() {
            counter.retrieved[k_index] += usize::from(m.is_none());
        }
        report.edges.push(EdgeResult {
            source: e.source,
            target: e.target,
            kind: e.kind.clone(),
            relation: e.relation.clone(),
            miss,
        });
    }
    pair_list
}

/// Associated node-pair R@K: a pair is retrieved at K when a predicted edge of either kind, in
/// either direction, joins nodes retrieving its two nodes at K.
fn score_associated(
    overlaps: &[Vec<Overlap>],
    pairs: &[(usize, usize)],
    pred_edges: &[PredictedEdge<'_>],
    associated: &mut Recall,
) {
    for &(si, ti) in pairs {
        associated.total += 1;
        for (k_index, k) in KS.into_iter().enumerate() {
            let sources = retrievers(&overlaps[si], k);
            let targets = retrievers(&overlaps[ti], k);
            let joined = pred_edges.iter().any(|(ps, pt, _, _)| {
                (sources.contains(ps) && targets.contains(pt)) || (sources.contains(pt) && targets.contains(ps))
            });
            associated.retrieved[k_index] += usize::from(joined);
        }
    }
}
