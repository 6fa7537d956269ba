//! Unit tests of the change evidence (`[fusion.change]`): removal on free space from two
//! keyframes apart, and no evidence from occlusion, missing depth or a detection in view.

use glam::DVec3;

use super::*;
use crate::flow::Mask;
use crate::fusion::change::ChangeKind;
use op3dsg_drivers::frame::Intrinsics;

/// A 64 x 48 frame (f = 60) at `stamp_s`: a wall `wall_mm` away, and where `object` is set a
/// 12 px square at (20, 18) 1.5 m away.
fn frame(stamp_s: f64, wall_mm: u16, object: bool) -> Frame {
    let k = Intrinsics { width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 32.0, cy: 24.0 };
    let mut frame = Frame::new(k);
    frame.depth.fill(wall_mm);
    frame.rgb.fill(128);
    frame.stamp_ns = (stamp_s * 1e9) as u64;
    if object {
        for y in 18..30 {
            for x in 20..32 {
                frame.depth[y * 64 + x] = 1500;
            }
        }
    }
    frame
}

fn cabinet() -> Detection {
    Detection {
        label: "cabinet".into(),
        kind: NodeKind::Object,
        score: 0.9,
        mask: Mask { x0: 20, y0: 18, width: 12, height: 12, data: vec![1; 144] },
        semantic_feature: None,
    }
}

fn config() -> FusionConfig {
    let base = crate::config::load(None, &[]).expect("built-in profile").profile.fusion;
    FusionConfig {
        pixel_stride: 1,
        object_mask_erode_px: 0,
        object_voxel_m: 0.01,
        object_nnr_radius_m: 0.01,
        maintenance_every_keyframes: 0,
        ..base
    }
}

/// A map with the cabinet confirmed (three keyframes at t = 0, 0.1, 0.2 s from the origin).
fn mapped() -> MultiViewFusion {
    let mut fusion = MultiViewFusion::new(config());
    for i in 0..3 {
        fusion.integrate(&frame(f64::from(i) * 0.1, 2500, true), &Isometry::IDENTITY, &[cabinet()]);
    }
    let mut graph = SceneGraph::default();
    fusion.build_graph(&mut graph);
    assert_eq!(graph.nodes.len(), 1, "{graph:?}");
    fusion
}

/// The camera `x` metres to the side of the origin.
fn at(x: f64) -> Isometry {
    Isometry::new(glam::DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0))
}

fn graph(fusion: &MultiViewFusion) -> SceneGraph {
    let mut graph = SceneGraph::default();
    fusion.build_graph(&mut graph);
    graph
}

#[test]
fn free_space_from_two_keyframes_apart_in_time_and_place_removes_a_node() {
    let mut fusion = mapped();
    let id = graph(&fusion).nodes[0].id;
    // The wall where the cabinet stood: a miss, and the node is missing but still published.
    let r = fusion.integrate(&frame(1.0, 2500, false), &at(0.05), &[]);
    assert_eq!((r.removed, r.state_changes), (0, 1));
    let g = graph(&fusion);
    assert!(g.nodes[0].missing, "{g:?}");
    // A second miss from the same place soon after is not enough.
    let r = fusion.integrate(&frame(1.1, 2500, false), &at(0.05), &[]);
    assert_eq!(r.removed, 0);
    // From 0.2 m further and a second later: removed, logged, remembered.
    let r = fusion.integrate(&frame(2.0, 2500, false), &at(0.25), &[]);
    assert_eq!(r.removed, 1);
    assert!(graph(&fusion).nodes.is_empty());
    let mut events = Vec::new();
    fusion.take_changes(&mut events);
    assert_eq!(events.len(), 1, "{events:?}");
    assert_eq!((events[0].kind, events[0].node_id, events[0].label.as_str()), (ChangeKind::Removed, id, "cabinet"));
    let from = events[0].from_m.unwrap();
    assert!((from[2] - 1.5).abs() < 0.05, "{from:?}");
    let removed = fusion.removed_nodes();
    assert_eq!(removed.len(), 1);
    assert_eq!((removed[0].id, removed[0].first_seen_stamp_ns), (id, 0));
    assert_eq!(removed[0].last_seen_stamp_ns, 200_000_000);
}

#[test]
fn occlusion_missing_depth_and_far_views_give_no_evidence() {
    // Something nearer in front, no depth at all, and the wall beyond the trusted range.
    for (name, wall_mm, x) in [("occluded", 800u16, 0.0), ("no depth", 0, 0.0), ("far", 2500, 0.0)] {
        let mut fusion = mapped();
        let back = if name == "far" { 2.0 } else { 0.0 };
        for i in 0..8 {
            let pose = Isometry::new(glam::DQuat::IDENTITY, DVec3::new(x + 0.1 * f64::from(i), 0.0, -back));
            let wall = if name == "far" { 6000 } else { wall_mm };
            let r = fusion.integrate(&frame(1.0 + f64::from(i), wall, false), &pose, &[]);
            assert_eq!((r.removed, r.state_changes), (0, 0), "{name}: keyframe {i}");
        }
        assert_eq!(graph(&fusion).nodes.len(), 1, "{name}");
        let mut events = Vec::new();
        fusion.take_changes(&mut events);
        assert!(events.is_empty(), "{name}: {events:?}");
    }
}

#[test]
fn a_detection_of_its_label_where_it_projects_vetoes_a_miss() {
    let mut fusion = mapped();
    let id = graph(&fusion).nodes[0].id;
    // The pose is off by 12 px: where the node projects the depth reads the wall (free), and
    // the detector sees the cabinet right beside it, at its range.
    let shifted = |stamp_s: f64| {
        let mut f = frame(stamp_s, 2500, false);
        for y in 18..30 {
            for x in 32..44 {
                f.depth[y * 64 + x] = 1500;
            }
        }
        f
    };
    let beside = Detection { mask: Mask { x0: 32, ..cabinet().mask }, ..cabinet() };
    for i in 0..6 {
        let r = fusion.integrate(&shifted(1.0 + f64::from(i)), &at(0.01 * f64::from(i)), std::slice::from_ref(&beside));
        assert_eq!(r.removed, 0, "keyframe {i}");
        let g = graph(&fusion);
        let old = g.nodes.iter().find(|n| n.id == id).expect("the cabinet is still there");
        assert!(!old.missing, "keyframe {i}: {old:?}");
    }
    // Without the detection the same view is a miss.
    let r = fusion.integrate(&shifted(8.0), &at(0.0), &[]);
    assert!(r.state_changes >= 1);
    assert!(graph(&fusion).nodes.iter().find(|n| n.id == id).unwrap().missing);
}

#[test]
fn seen_again_clears_a_miss_and_change_handling_off_never_removes() {
    let mut fusion = mapped();
    fusion.integrate(&frame(1.0, 2500, false), &at(0.05), &[]);
    assert!(graph(&fusion).nodes[0].missing);
    // Back in its place (depth agrees), not detected: present again.
    let r = fusion.integrate(&frame(2.0, 2500, true), &at(0.0), &[]);
    assert_eq!((r.removed, r.state_changes), (0, 1));
    assert!(!graph(&fusion).nodes[0].missing);

    let mut off = config();
    off.change.enabled = false;
    let mut fusion = MultiViewFusion::new(off);
    for i in 0..3 {
        fusion.integrate(&frame(f64::from(i) * 0.1, 2500, true), &Isometry::IDENTITY, &[cabinet()]);
    }
    for i in 0..6 {
        let r = fusion.integrate(&frame(1.0 + f64::from(i), 2500, false), &at(0.1 * f64::from(i)), &[]);
        assert_eq!((r.removed, r.state_changes), (0, 0));
    }
    assert_eq!(graph(&fusion).nodes.len(), 1);
}
