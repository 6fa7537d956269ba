//! The text report of one evaluation: the figures with their counts, then the nodes and edges
//! not retrieved at K = 3.

use std::fmt::Write as _;

use super::{EdgeMiss, EdgeResult, K3, K5, K10, KS, NodeResult, Recall, RecallReport};

fn cell(recall: &Recall, k: usize) -> String {
    recall.percent(k).map_or_else(|| "-".to_owned(), |p| format!("{p:.1}"))
}

/// A text report of one evaluation: the figures with their counts, then the misses at K = 3.
pub fn text_report(report: &RecallReport) -> String {
    let f = &report.figures;
    let mut s = String::new();
    let _ = writeln!(s, "{:<26} {:>7} {:>7} {:>7} {:>7}", "metric", "items", "R@3", "R@5", "R@10");
    let rows: [(&str, &Recall); 13] = [
        ("object node", &f.object),
        ("part node", &f.part),
        ("overall node", &f.overall),
        ("object node IoU>=0.10", &f.object_iou10),
        ("part node IoU>=0.10", &f.part_iou10),
        ("overall node IoU>=0.10", &f.overall_iou10),
        ("object node IoP>=0.25", &f.object_iop25),
        ("part node IoP>=0.25", &f.part_iop25),
        ("overall node IoP>=0.25", &f.overall_iop25),
        ("affordance", &f.affordance),
        ("functional triplet", &f.functional),
        ("spatial triplet", &f.spatial),
        ("associated node", &f.associated),
    ];
    for (name, r) in rows {
        let _ = writeln!(s, "{:<26} {:>7} {:>7} {:>7} {:>7}", name, r.total, cell(r, K3), cell(r, K5), cell(r, K10));
    }
    let _ = writeln!(
        s,
        "predicted nodes {}, of which {} retrieve no ground-truth node at R@10",
        f.predicted_nodes, f.predicted_unmatched
    );
    let missed: Vec<&NodeResult> = report.nodes.iter().filter(|n| n.best_rank.is_none_or(|r| r > KS[K3])).collect();
    if !missed.is_empty() {
        let _ = writeln!(s, "\nnodes not retrieved at R@3:");
        for n in missed {
            match (&n.best_rank, &n.best_predicted_label) {
                (Some(rank), Some(label)) => {
                    let _ = writeln!(
                        s,
                        "  {} {} '{}': best overlapping '{}' ranks it {rank}",
                        n.kind, n.id, n.label, label
                    );
                }
                _ => {
                    let _ = writeln!(s, "  {} {} '{}': no predicted {} overlaps it", n.kind, n.id, n.label, n.kind);
                }
            }
        }
    }
    let missed: Vec<&EdgeResult> = report.edges.iter().filter(|e| e.miss[K3].is_some()).collect();
    if !missed.is_empty() {
        let _ = writeln!(s, "\nedges not retrieved at R@3:");
        for e in missed {
            let why = e.miss[K3].map_or("", EdgeMiss::as_str);
            let _ = writeln!(s, "  {} {} --[{}]--> {}: {why}", e.kind, e.source, e.relation, e.target);
        }
    }
    s
}
