//! Unit tests of the multi-view fusion.

use super::cloud::PointCloud;
use super::*;
use crate::flow::Mask;
use op3dsg_drivers::frame::Intrinsics;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn config() -> FusionConfig {
    crate::config::load(None, &[]).expect("built-in profile").profile.fusion
}

/// A frame looking at a grey wall `depth_mm` away (64 x 48 pixels, f = 60).
fn wall_frame(depth_mm: u16) -> Frame {
    let k = Intrinsics { width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 32.0, cy: 24.0 };
    let mut frame = Frame::new(k);
    frame.depth.fill(depth_mm);
    frame.rgb.fill(128);
    frame
}

fn paint(frame: &mut Frame, x0: u32, y0: u32, size: u32, rgb: [u8; 3]) {
    for y in y0..y0 + size {
        for x in x0..x0 + size {
            let i = ((y * frame.intrinsics.width + x) * 3) as usize;
            frame.rgb[i..i + 3].copy_from_slice(&rgb);
        }
    }
}

fn square(label: &str, kind: NodeKind, x0: u32, y0: u32, size: u32) -> Detection {
    Detection {
        label: label.into(),
        kind,
        score: 0.9,
        mask: Mask { x0, y0, width: size, height: size, data: vec![1; (size * size) as usize] },
        semantic_feature: None,
    }
}

fn dense() -> FusionConfig {
    FusionConfig {
        pixel_stride: 1,
        object_mask_erode_px: 0,
        part_mask_erode_px: 0,
        object_voxel_m: 0.01,
        object_nnr_radius_m: 0.01,
        part_voxel_m: 0.005,
        part_nnr_radius_m: 0.005,
        maintenance_every_keyframes: 0,
        ..config()
    }
}

#[test]
fn nnr_on_constructed_point_sets() {
    let g = KindGeometry::new(0.01, 0.01);
    assert!((g.cell_m - 0.02).abs() < 1e-6, "cell is the smallest voxel multiple >= 2 delta");
    let mut cloud = PointCloud::default();
    cloud.clear();
    // A 10 x 10 grid of points 1 cm apart (voxel centres) on z = 0.
    for i in 0..10 {
        for j in 0..10 {
            assert!(cloud.insert(Vec3::new(0.005 + 0.01 * i as f32, 0.005 + 0.01 * j as f32, 0.0), &g, 1000));
        }
    }
    assert_eq!(cloud.len(), 100);
    // Same voxel again: refused.
    assert!(!cloud.insert(Vec3::new(0.006, 0.006, 0.0005), &g, 1000));
    // 6 points 5 mm above grid points (neighbours), 3 points 5 cm above, 1 point 1.1 cm beside.
    let mut probe: Vec<Vec3> = (0..6).map(|i| Vec3::new(0.005 + 0.01 * i as f32, 0.025, 0.005)).collect();
    probe.extend((0..3).map(|i| Vec3::new(0.005 + 0.01 * i as f32, 0.025, 0.05)));
    probe.push(Vec3::new(0.095 + 0.011, 0.055, 0.0));
    assert!((cloud.nnr(&probe, &g, 256) - 0.6).abs() < 1e-6);
    // Subsampled to 5 points (every 2nd): indices 0, 2, 4 hit, 6, 8 miss.
    assert!((cloud.nnr(&probe, &g, 5) - 0.6).abs() < 1e-6);
    assert_eq!(cloud.nnr(&[], &g, 256), 0.0);
    // Within delta inclusive.
    assert!(cloud.has_neighbour(Vec3::new(0.005, 0.005, 0.0099), &g));
    assert!(!cloud.has_neighbour(Vec3::new(0.005, 0.005, -0.0101), &g));
}

#[test]
fn grid_neighbour_query_agrees_with_brute_force() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (voxel, radius) in [(0.005, 0.01), (0.025, 0.025), (0.01, 0.004), (0.02, 0.05)] {
        let g = KindGeometry::new(voxel, radius);
        let mut cloud = PointCloud::default();
        cloud.clear();
        for _ in 0..2000 {
            let p = Vec3::new(rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2), rng.random_range(-0.05..0.05));
            cloud.insert(p, &g, usize::MAX);
        }
        for _ in 0..2000 {
            let p =
                Vec3::new(rng.random_range(-0.25..0.25), rng.random_range(-0.25..0.25), rng.random_range(-0.1..0.1));
            let brute = cloud.points.iter().filter(|q| q.distance_squared(p) <= radius * radius).count() as u32;
            assert_eq!(cloud.count_neighbours(p, &g, NONE, u32::MAX), brute, "voxel {voxel} radius {radius} at {p}");
        }
    }
}

#[test]
fn voxel_downsampling_and_the_point_cap() {
    let g = KindGeometry::new(0.01, 0.01);
    let mut cloud = PointCloud::default();
    cloud.clear();
    for i in 0..100 {
        // 100 points within one voxel.
        cloud.insert(Vec3::new(0.001 + 0.00008 * i as f32, 0.0051, 0.0052), &g, 1000);
    }
    assert_eq!(cloud.len(), 1);
    for i in 0..100 {
        cloud.insert(Vec3::new(0.015 + 0.01 * i as f32, 0.0, 0.0), &g, 10);
    }
    // A 1 m line of 1 cm voxels under a cap of 10: the voxel grows to 16 cm, the extent stays.
    assert!(cloud.len() <= 10, "{}", cloud.len());
    assert_eq!(cloud.scale, 16);
    assert!(cloud.max.x > 0.9 && cloud.min.x < 0.01, "{} {}", cloud.min, cloud.max);
    for i in 0..100 {
        let p = Vec3::new(0.015 + 0.01 * i as f32, 0.0, 0.0);
        assert!(cloud.points.iter().any(|q| q.distance(p) <= 0.16), "coverage at {p}");
    }
}

#[test]
fn repeated_views_fuse_and_distinct_places_do_not() {
    let mut fusion = MultiViewFusion::new(dense());
    let frame = wall_frame(2000);
    let pose = Isometry::IDENTITY;
    fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
    let r = fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 11, 10, 12)]);
    assert_eq!((r.merged, r.created), (1, 0));
    // A synonym without features: s^s = 0, s^g alone cannot reach 1.1.
    let r = fusion.integrate(&frame, &pose, &[square("cupboard", NodeKind::Object, 10, 10, 12)]);
    assert_eq!((r.merged, r.created), (0, 1));
    let r = fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 40, 10, 12)]);
    assert_eq!((r.merged, r.created), (0, 1));
    assert_eq!(fusion.node_count(), 3);
    let mut graph = SceneGraph::default();
    fusion.build_graph(&mut graph);
    // Only the node seen twice is confirmed (min_observations = 2).
    assert_eq!(graph.nodes.len(), 1);
    assert_eq!(graph.nodes[0].label, "cabinet");
    assert_eq!(graph.nodes[0].observation_count, 2);
    assert!((graph.nodes[0].centre_m[2] - 2.0).abs() < 1e-3);
}

#[test]
fn low_scoring_nodes_are_held_back_and_pruned() {
    let mut fusion = MultiViewFusion::new(FusionConfig {
        maintenance_every_keyframes: 1,
        prune_unconfirmed_after_keyframes: 2,
        ..dense()
    });
    let frame = wall_frame(2000);
    let mut weak = square("kettle", NodeKind::Object, 10, 10, 12);
    weak.score = 0.3;
    for _ in 0..3 {
        fusion.integrate(&frame, &Isometry::IDENTITY, std::slice::from_ref(&weak));
    }
    let mut graph = SceneGraph::default();
    fusion.build_graph(&mut graph);
    assert!(graph.nodes.is_empty(), "seen 3 times, mean score 0.3 < 0.5");
    assert_eq!(fusion.node_count(), 1);
    let pruned: u32 = (0..2).map(|_| fusion.integrate(&frame, &Isometry::IDENTITY, &[]).pruned).sum();
    assert_eq!((pruned, fusion.node_count()), (1, 0));
}

#[test]
fn semantic_features_let_synonyms_fuse() {
    let mut fusion = MultiViewFusion::new(dense());
    let frame = wall_frame(2000);
    let feature = |v: [f32; 2]| Some(v.to_vec());
    let mut a = square("cabinet", NodeKind::Object, 10, 10, 12);
    a.semantic_feature = feature([1.0, 0.0]);
    let mut b = square("cupboard", NodeKind::Object, 11, 10, 12);
    b.semantic_feature = feature([0.8, 0.6]); // s^s = 0.9
    let mut c = square("stove", NodeKind::Object, 10, 11, 12);
    c.semantic_feature = feature([-1.0, 0.0]); // s^s ≈ 0
    fusion.integrate(&frame, &Isometry::IDENTITY, &[a]);
    let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[b]);
    assert_eq!(r.merged, 1);
    let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[c]);
    assert_eq!(r.created, 1);
    // Running mean, re-normalised: (1, 0) + (0.8, 0.6) → (0.949, 0.316).
    let node = fusion.nodes.iter().find(|n| n.observation_count == 2).unwrap();
    assert!((node.semantic[0] - 0.9487).abs() < 1e-3 && (node.semantic[1] - 0.3162).abs() < 1e-3);
}

/// Two knobs with one label, one red and one blue, side by side on a wall; the second view
/// sees the blue knob where its mask half-overlaps the red knob's points.
fn two_knobs(colour_features: bool, second: [u8; 3]) -> usize {
    let mut fusion = MultiViewFusion::new(FusionConfig { colour_features, ..dense() });
    let mut frame = wall_frame(1000);
    paint(&mut frame, 20, 20, 8, [200, 40, 40]);
    fusion.integrate(&frame, &Isometry::IDENTITY, &[square("knob", NodeKind::Part, 20, 20, 8)]);
    let mut frame = wall_frame(1000);
    paint(&mut frame, 24, 20, 8, second);
    fusion.integrate(&frame, &Isometry::IDENTITY, &[square("knob", NodeKind::Part, 24, 20, 8)]);
    fusion.node_count()
}

#[test]
fn colour_keeps_apart_parts_that_geometry_and_semantics_would_merge() {
    let blue = [40, 40, 200];
    let red = [200, 40, 40];
    assert_eq!(two_knobs(true, blue), 2, "different colours stay apart");
    assert_eq!(two_knobs(true, red), 1, "same colour merges");
    assert_eq!(two_knobs(false, blue), 1, "without colour they merge");
}

#[test]
fn part_score_formula() {
    let fusion = MultiViewFusion::new(config());
    let mut red = ColourFeature::default();
    red.cn[8] = 1.0;
    red.ab[0] = 1.0;
    red.opp[0] = 1.0;
    red.valid_pixels = 10;
    let mut blue = ColourFeature::default();
    blue.cn[1] = 1.0;
    blue.ab[1] = 1.0;
    blue.opp[1] = 1.0;
    blue.valid_pixels = 10;
    // Identical colour: s^c = 1 → 0.4 x + 0.6.
    assert!((fusion.part_score(1.5, &red, &red) - (0.4 * 1.5 + 0.6)).abs() < 1e-6);
    // Disjoint: d^c = 1, s^c = 0.5.
    assert!((fusion.part_score(1.5, &red, &blue) - (0.4 * 1.5 + 0.3)).abs() < 1e-6);
    // No colour on one side: s^c := x / 2.
    assert!((fusion.part_score(1.5, &red, &ColourFeature::default()) - 0.7 * 1.5).abs() < 1e-6);
}

#[test]
fn one_detection_per_node_per_keyframe() {
    let mut fusion = MultiViewFusion::new(dense());
    let frame = wall_frame(2000);
    fusion.integrate(&frame, &Isometry::IDENTITY, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
    let both = [square("cabinet", NodeKind::Object, 10, 10, 12), square("cabinet", NodeKind::Object, 12, 10, 12)];
    let r = fusion.integrate(&frame, &Isometry::IDENTITY, &both);
    assert_eq!((r.merged, r.created), (1, 1));
    // Objects never match parts.
    let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[square("cabinet", NodeKind::Part, 10, 10, 12)]);
    assert_eq!((r.merged, r.created), (0, 1));
}

#[test]
fn maintenance_merges_duplicates_and_prunes_stale_candidates() {
    let mut fusion = MultiViewFusion::new(FusionConfig {
        maintenance_every_keyframes: 1,
        prune_unconfirmed_after_keyframes: 3,
        ..dense()
    });
    let frame = wall_frame(2000);
    // One keyframe sees the same surface twice: two nodes (one detection per node per keyframe).
    let twice = [square("cabinet", NodeKind::Object, 10, 10, 12), square("cabinet", NodeKind::Object, 10, 10, 12)];
    let r = fusion.integrate(&frame, &Isometry::IDENTITY, &twice);
    assert_eq!(r.created, 2);
    assert_eq!(r.maintenance_merged, 1, "maintenance folds the duplicate in");
    assert_eq!(fusion.node_count(), 1);
    assert_eq!(fusion.nodes.iter().find(|n| n.alive).unwrap().observation_count, 2);
    // A stray candidate elsewhere, then three keyframes without it: pruned.
    fusion.integrate(&frame, &Isometry::IDENTITY, &[square("kettle", NodeKind::Object, 40, 30, 10)]);
    assert_eq!(fusion.node_count(), 2);
    let mut pruned = 0;
    for _ in 0..3 {
        pruned += fusion.integrate(&frame, &Isometry::IDENTITY, &[]).pruned;
    }
    assert_eq!(pruned, 1);
    assert_eq!(fusion.node_count(), 1);
    // The freed slot is reused.
    fusion.integrate(&frame, &Isometry::IDENTITY, &[square("kettle", NodeKind::Object, 40, 30, 10)]);
    assert_eq!(fusion.nodes.len(), 2);
}

#[test]
fn outlier_removal_drops_isolated_points() {
    let mut fusion = MultiViewFusion::new(FusionConfig { maintenance_every_keyframes: 1, ..dense() });
    let mut frame = wall_frame(500);
    // One pixel of the mask sees a surface 20 cm nearer (within the depth band).
    frame.depth[(15 * 64 + 15) as usize] = 300;
    fusion.integrate(&frame, &Isometry::IDENTITY, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
    let node = fusion.nodes.iter().find(|n| n.alive).unwrap();
    assert!(node.cloud.len() > 50, "{}", node.cloud.len());
    assert!(node.cloud.points.iter().all(|p| (p.z - 0.5).abs() < 0.01), "the stray point is gone");
    assert!((node.cloud.min.z - 0.5).abs() < 0.01);
}

#[test]
fn eroded_masks_lose_their_border() {
    let m = Mask { x0: 0, y0: 0, width: 5, height: 5, data: vec![1; 25] };
    let inside: usize =
        (0..5).flat_map(|r| (0..5).map(move |c| (c, r))).filter(|&(c, r)| inside_eroded(&m, c, r, 1)).count();
    assert_eq!(inside, 9);
    assert!(inside_eroded(&m, 0, 0, 0));
    assert!(!inside_eroded(&m, 2, 2, 3));
}

/// Saving and restoring the map changes nothing: the graph is the same, and fusing on from
/// the restored map gives what fusing on from the original gives (same ids, same merges).
#[test]
fn a_restored_map_fuses_on_as_if_it_never_stopped() {
    let config = FusionConfig { maintenance_every_keyframes: 3, ..dense() };
    let mut original = MultiViewFusion::new(config.clone());
    let mut frame = wall_frame(2000);
    paint(&mut frame, 40, 30, 6, [200, 30, 30]);
    let pose = Isometry::IDENTITY;
    let views = [
        vec![square("cabinet", NodeKind::Object, 10, 10, 12), square("cabinet handle", NodeKind::Part, 40, 30, 6)],
        vec![square("cabinet", NodeKind::Object, 11, 10, 12), square("cabinet handle", NodeKind::Part, 40, 30, 6)],
        vec![square("stove", NodeKind::Object, 30, 5, 8)],
    ];
    for detections in &views {
        original.integrate(&frame, &pose, detections);
    }
    let state = original.export_state().expect("multiview fusion saves");
    // Through the snapshot's encoding, as a restart would read it.
    let bytes = postcard::to_stdvec(&state).expect("encode");
    let decoded: MapState = postcard::from_bytes(&bytes).expect("decode");
    assert_eq!(decoded, state);

    let mut restored = MultiViewFusion::new(config.clone());
    restored.restore_state(&decoded).expect("restore");
    let (mut a, mut b) = (SceneGraph::default(), SceneGraph::default());
    original.build_graph(&mut a);
    restored.build_graph(&mut b);
    assert!(!a.nodes.is_empty());
    assert_eq!(a.nodes, b.nodes);
    assert_eq!(restored.node_count(), original.node_count());
    assert_eq!(restored.export_state(), Some(state));

    // Go on fusing both: the same reports, the same graph, new ids continue from next_id.
    let more = [
        vec![square("cabinet", NodeKind::Object, 10, 11, 12), square("sink", NodeKind::Object, 45, 5, 8)],
        vec![square("stove", NodeKind::Object, 30, 5, 8)],
    ];
    // The reports, but for the evidence step's time.
    let untimed = |r: FusionReport| FusionReport { evidence_ns: 0, ..r };
    for detections in &more {
        assert_eq!(
            untimed(original.integrate(&frame, &pose, detections)),
            untimed(restored.integrate(&frame, &pose, detections))
        );
    }
    original.build_graph(&mut a);
    restored.build_graph(&mut b);
    assert_eq!(a.nodes, b.nodes);
}

#[test]
fn a_map_saved_under_other_voxels_is_refused() {
    let mut fusion = MultiViewFusion::new(dense());
    fusion.integrate(&wall_frame(2000), &Isometry::IDENTITY, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
    let state = fusion.export_state().expect("saves");
    let mut other = MultiViewFusion::new(FusionConfig { object_voxel_m: 0.02, object_nnr_radius_m: 0.02, ..dense() });
    let err = other.restore_state(&state).unwrap_err();
    assert!(err.contains("fusion.object_voxel_m = 0.01"), "{err}");
    let mut broken = state.clone();
    broken.nodes[0].votes = vec![(99, 1)];
    let err = MultiViewFusion::new(dense()).restore_state(&broken).unwrap_err();
    assert!(err.starts_with("node 1:"), "{err}");
}
