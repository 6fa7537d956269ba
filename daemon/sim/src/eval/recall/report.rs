//! The text report of one evaluation: the figures with their counts, then the nodes and edges
//! not retrieved at K = 3.

use std::fmt::Write as _;

use super::{EdgeMiss, EdgeResult, K3, K5, K10, KS, NodeResult, Recall, RecallReport};

fn cell(recall: &Recall, k: usize) -> String {
    recall.percent(k).map_or_else(|| "-".to_owned(), |p| format!("{p:.1}"))
}

/// A text report of one evaluation: the figures with their counts, the misses at K = 3, then
/// every scored ground-truth node with the best-ranked overlapping prediction of its kind and
/// their box IoU.
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
    if !report.nodes.is_empty() {
        let _ =
            writeln!(s, "\nground-truth nodes: the best-ranked overlapping prediction of the kind, its rank, box IoU");
        for n in &report.nodes {
            match (&n.best_predicted_label, n.best_rank, n.best_iou) {
                (Some(label), Some(rank), Some(iou)) => {
                    let _ = writeln!(s, "  {} {} '{}': '{label}', rank {rank}, IoU {iou:.2}", n.kind, n.id, n.label);
                }
                _ => {
                    let _ = writeln!(s, "  {} {} '{}': none", n.kind, n.id, n.label);
                }
            }
        }
        let retrieved: Vec<f32> = report
            .nodes
            .iter()
            .filter(|n| n.best_rank.is_some_and(|r| r <= KS[K3]))
            .filter_map(|n| n.best_iou)
            .collect();
        if !retrieved.is_empty() {
            let mean = retrieved.iter().sum::<f32>() / retrieved.len() as f32;
            let _ = writeln!(s, "mean box IoU of the {} nodes retrieved at R@3: {mean:.2}", retrieved.len());
        }
    }
    s
}
