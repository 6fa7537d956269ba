//! Tests of [`match_fusion`] on hand-built ground truth and fused graphs: scores, fragments,
//! wrong merges, false positives, miss attribution, targets and tables.

use glam::Vec3;
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::graph::{GraphNode, SceneGraph};

use super::*;

fn gt(id: u32, kind: NodeKind, label: &str, lo: [f32; 3], hi: [f32; 3], material: &str) -> GtNode {
    GtNode {
        id,
        kind,
        label: label.into(),
        accepted_labels: label_alternatives(label).collect(),
        box_min_m: Vec3::from(lo),
        box_max_m: Vec3::from(hi),
        material: Some(material.into()),
    }
}

fn fused(id: u32, kind: NodeKind, label: &str, lo: [f32; 3], hi: [f32; 3]) -> GraphNode {
    GraphNode {
        id,
        kind,
        parent_id: None,
        label: label.into(),
        confidence: 1.0,
        centre_m: ((Vec3::from(lo) + Vec3::from(hi)) * 0.5).to_array(),
        box_min_m: lo,
        box_max_m: hi,
        obb: Default::default(),
        observation_count: 3,
        affordance_bits: 0,
        last_seen_stamp_ns: 0,
        first_seen_stamp_ns: 0,
        missing: false,
        ..Default::default()
    }
}

/// Three knobs 4.5 cm apart on a panel, a cabinet and a drawer.
fn scene() -> Vec<GtNode> {
    let knob = |id, x: f32, material| {
        gt(id, NodeKind::Part, "knob", [x - 0.015, 0.0, 1.0], [x + 0.015, 0.025, 1.03], material)
    };
    let mut nodes = vec![
        gt(1, NodeKind::Object, "cabinet / cupboard", [0.0, 0.0, 0.0], [0.6, 0.6, 0.9], "wood"),
        gt(2, NodeKind::Object, "drawer", [0.6, 0.0, 0.0], [1.0, 0.6, 0.3], "wood"),
    ];
    nodes.push(knob(3, 2.0, "red plastic"));
    nodes.push(knob(4, 2.045, "blue plastic"));
    nodes.push(knob(5, 2.09, "red plastic"));
    nodes
}

#[test]
fn perfect_fusion_scores_one() {
    let gt = scene();
    let graph = SceneGraph {
        nodes: vec![
            fused(10, NodeKind::Object, "cupboard", [0.02, 0.0, 0.02], [0.58, 0.6, 0.88]),
            fused(11, NodeKind::Object, "drawer", [0.62, 0.4, 0.0], [0.98, 0.6, 0.28]),
            fused(12, NodeKind::Part, "knob", [1.987, 0.018, 1.002], [2.013, 0.026, 1.028]),
            fused(13, NodeKind::Part, "knob", [2.032, 0.018, 1.002], [2.058, 0.026, 1.028]),
            fused(14, NodeKind::Part, "knob", [2.077, 0.018, 1.002], [2.103, 0.026, 1.028]),
        ],
        ..SceneGraph::default()
    };
    let visible = vec![0, 5, 5, 5, 5, 5];
    let r = match_fusion(&graph, &gt, &visible, &visible, &MatchCriteria::default());
    for kind in [&r.objects, &r.parts] {
        assert_eq!(kind.matched_fraction(), Some(1.0), "{r:#?}");
        assert_eq!(kind.fragmentation(), Some(1.0));
        assert_eq!((kind.false_positives, kind.wrong_merge_nodes, kind.misses.total()), (0, 0, 0));
    }
    assert_eq!(r.fused.iter().map(|f| f.matched).collect::<Vec<_>>(), [1, 2, 3, 4, 5].map(Some));
    assert!(QualityTargets::default().failures(&r).is_empty());
}

#[test]
fn fragments_merges_false_positives_and_misses_are_told_apart() {
    let gt = scene();
    let graph = SceneGraph {
        nodes: vec![
            // The cabinet in two halves: fragmentation 2.
            fused(10, NodeKind::Object, "cabinet", [0.0, 0.0, 0.0], [0.3, 0.6, 0.9]),
            fused(11, NodeKind::Object, "cabinet", [0.3, 0.0, 0.0], [0.6, 0.6, 0.9]),
            // The drawer labelled as a stove: a false positive, and the drawer a wrong-label miss.
            fused(12, NodeKind::Object, "stove", [0.62, 0.4, 0.0], [0.98, 0.6, 0.28]),
            // Knobs 3 and 4 in one node, with both their detections (red and blue: across
            // materials); knob 5 alone.
            GraphNode {
                observation_count: 18,
                ..fused(13, NodeKind::Part, "knob", [1.985, 0.018, 1.0], [2.055, 0.026, 1.03])
            },
            fused(14, NodeKind::Part, "knob", [2.077, 0.018, 1.002], [2.103, 0.026, 1.028]),
            // A knob floating in the air.
            fused(15, NodeKind::Part, "knob", [3.0, 3.0, 1.0], [3.02, 3.02, 1.02]),
        ],
        ..SceneGraph::default()
    };
    let visible = vec![0, 9, 9, 9, 9, 9];
    let detected = vec![0, 9, 9, 9, 9, 9];
    let r = match_fusion(&graph, &gt, &visible, &detected, &MatchCriteria::default());
    assert_eq!(r.objects.eligible, 2);
    assert_eq!(r.objects.matched, 1);
    assert_eq!(r.objects.fragmentation(), Some(2.0));
    assert_eq!(r.objects.false_positives, 1);
    assert_eq!(r.objects.misses.wrong_label, 1);
    assert_eq!(r.parts.matched, 2);
    assert_eq!(r.parts.matched_fraction(), Some(2.0 / 3.0));
    assert_eq!(r.parts.false_positives, 1);
    assert_eq!(r.parts.wrong_merge_nodes, 1);
    assert_eq!(r.parts.wrong_merges_across_materials, 1);
    assert_eq!(r.parts.wrongly_merged_gt, 2);
    assert_eq!(r.parts.misses.merged, 1);
    let merged = r.fused.iter().find(|f| f.id == 13).unwrap();
    assert_eq!(merged.spans.len(), 2);
    let failures = QualityTargets::default().failures(&r);
    assert_eq!(failures.len(), 3, "{failures:?}");
    let table = table_header() + &table_row("test", 7, &r);
    assert!(table.contains("66.7"), "{table}");
    assert!(details(&r).contains("wrong label"));
}

/// A correct node whose box is bloated over its neighbour's centre (mask bleed, noise) is
/// no wrong merge: it fused no more detections than its instance had.
#[test]
fn a_bloated_box_alone_is_no_wrong_merge() {
    let gt = scene();
    let graph = SceneGraph {
        nodes: vec![
            GraphNode {
                centre_m: [2.0, 0.02, 1.015],
                observation_count: 9,
                ..fused(13, NodeKind::Part, "knob", [1.96, 0.0, 0.99], [2.04, 0.04, 1.04])
            },
            fused(14, NodeKind::Part, "knob", [2.032, 0.018, 1.002], [2.058, 0.026, 1.028]),
        ],
        ..SceneGraph::default()
    };
    let counts = vec![0, 0, 0, 9, 9, 9];
    let r = match_fusion(&graph, &gt, &counts, &counts, &MatchCriteria::default());
    assert_eq!(r.fused[0].spans.len(), 2, "the bloated box spans the neighbour's centre");
    assert_eq!((r.parts.wrong_merge_nodes, r.parts.wrongly_merged_gt), (0, 0));
    assert_eq!(r.parts.matched, 2);
    // Knob 5 is lost, not merged: nothing absorbed it.
    assert_eq!(r.parts.misses, MissCounts { lost_in_fusion: 1, ..Default::default() });
}

#[test]
fn misses_are_attributed_to_detection_before_fusion() {
    let gt = scene();
    let graph = SceneGraph::default();
    // Id 1 never detected, 2 once, 3 three times, 4 and 5 not visible enough.
    let visible = vec![0, 9, 9, 9, 2, 0];
    let detected = vec![0, 0, 1, 3, 2, 0];
    let r = match_fusion(&graph, &gt, &visible, &detected, &MatchCriteria::default());
    assert_eq!(r.objects.misses, MissCounts { never_detected: 1, too_few_detections: 1, ..Default::default() });
    assert_eq!(r.parts.eligible, 1);
    assert_eq!(r.parts.misses, MissCounts { lost_in_fusion: 1, ..Default::default() });
    assert_eq!(r.parts.fragmentation(), None);
}
