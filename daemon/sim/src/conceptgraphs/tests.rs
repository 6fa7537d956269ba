use op3dsg_drivers::frame::Intrinsics;
use op3dsg_runtime::flow::Mask;

use super::*;

/// A slanted surface 1 to 1.3 m away (depth grows with the column), 64 x 48 px, f = 60.
fn slanted_frame() -> Frame {
    let k = Intrinsics { width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 32.0, cy: 24.0 };
    let mut frame = Frame::new(k);
    for y in 0..48 {
        for x in 0..64 {
            frame.depth[y * 64 + x] = 1000 + (x as u16) * 5;
        }
    }
    frame
}

fn square(label: &str, x0: u32, y0: u32, size: u32, feature: [f32; 2]) -> Detection {
    Detection {
        label: label.into(),
        kind: NodeKind::Object,
        score: 0.9,
        mask: Mask { x0, y0, width: size, height: size, data: vec![1; (size * size) as usize] },
        semantic_feature: Some(feature.to_vec()),
    }
}

#[test]
fn overlapping_similar_detections_fuse_and_unseen_ones_are_filtered_at_publication() {
    let frame = slanted_frame();
    let mut fusion = ConceptGraphsFusion::new(ConceptGraphsConfig::default());
    let cabinet = square("cabinet", 4, 4, 20, [1.0, 0.0]);
    // Same place, orthogonal feature: spatial 1 + visual 0 < 1.2, a new object.
    let other = square("fridge", 4, 4, 20, [0.0, 1.0]);
    let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[cabinet.clone(), other]);
    assert_eq!((r.created, r.merged), (2, 0));
    for _ in 0..2 {
        let r = fusion.integrate(&frame, &Isometry::IDENTITY, std::slice::from_ref(&cabinet));
        assert_eq!((r.created, r.merged), (0, 1));
    }
    // A mask under 25 px is dropped before lifting.
    let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[square("knob", 40, 30, 4, [1.0, 0.0])]);
    assert_eq!(r.ignored, 1);
    assert_eq!(fusion.node_count(), 2);
    // Publication filters objects under 3 detections (the fridge) and leaves the map as it is.
    let mut graph = SceneGraph::default();
    fusion.build_graph(&mut graph);
    assert_eq!(graph.nodes.len(), 1);
    assert_eq!((graph.nodes[0].label.as_str(), graph.nodes[0].observation_count), ("cabinet", 3));
    assert_eq!(fusion.node_count(), 2);
}

#[test]
fn voxel_down_sample_averages_each_voxel() {
    let points = [Vec3::new(0.001, 0.001, 0.001), Vec3::new(0.009, 0.009, 0.009), Vec3::new(0.03, 0.0, 0.0)];
    let out = voxel_down_sample(&points, 0.025);
    assert_eq!(out.len(), 2);
    assert!((out[0] - Vec3::splat(0.005)).length() < 1e-6, "{out:?}");
    assert_eq!(out[1], Vec3::new(0.03, 0.0, 0.0));
}

#[test]
fn dbscan_keeps_the_largest_cluster_and_drops_noise() {
    let mut points: Vec<Vec3> = (0..30).map(|i| Vec3::new(i as f32 * 0.02, 0.0, 0.0)).collect();
    points.extend((0..12).map(|i| Vec3::new(5.0 + i as f32 * 0.02, 0.0, 0.0)));
    points.push(Vec3::new(10.0, 0.0, 0.0));
    let kept = dbscan_largest_cluster(points, 0.1, 10);
    assert_eq!(kept.len(), 30);
    assert!(kept.iter().all(|p| p.x < 1.0));
    // Under 5 points in the largest cluster: the cloud is left as it is.
    let few: Vec<Vec3> = (0..4).map(|i| Vec3::new(i as f32 * 0.02, 0.0, 0.0)).collect();
    assert_eq!(dbscan_largest_cluster(few.clone(), 0.1, 2), few);
}

#[test]
fn overlap_counts_points_within_one_voxel_of_the_other_cloud() {
    let cloud: Vec<[f32; 3]> = (0..10).map(|i| [i as f32 * 0.1, 0.0, 0.0]).collect();
    let tree = Tree::new_from_slice(&cloud);
    let near: Vec<Vec3> = (0..5).map(|i| Vec3::new(i as f32 * 0.1, 0.02, 0.0)).collect();
    let far: Vec<Vec3> = (0..5).map(|i| Vec3::new(i as f32 * 0.1, 0.03, 0.0)).collect();
    let both: Vec<Vec3> = near.iter().chain(&far).copied().collect();
    assert_eq!(overlap_ratio(&near, &tree, 0.025), 1.0);
    assert_eq!(overlap_ratio(&far, &tree, 0.025), 0.0);
    assert_eq!(overlap_ratio(&both, &tree, 0.025), 0.5);
}

#[test]
fn the_fusion_method_is_checked_by_name_and_its_section_by_field() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let path = write("cg.toml", "[fusion]\nmethod = \"conceptgraphs\"\n[fusion.conceptgraphs]\nvoxel_m = 0.02\n");
    let profile = crate::load_profile(Some(&path), &[]).unwrap().profile;
    assert_eq!(profile.fusion.method, CONCEPTGRAPHS_FUSION);
    assert_eq!(ConceptGraphsBackend::config(&profile).unwrap().voxel_m, 0.02);
    let map = crate::backends().fusion(&profile).unwrap();
    assert!(map.export_state().is_none(), "no saved form");
    let path = write("typo.toml", "[fusion]\nmethod = \"concept_graphs\"\n");
    let err = crate::load_profile(Some(&path), &[]).unwrap_err();
    assert!(err.message.starts_with("fusion.method") && err.message.contains("conceptgraphs"), "{err}");
    let path = write("bad.toml", "[fusion.conceptgraphs]\ndbscan_eps_m = 0.0\n");
    let err = crate::load_profile(Some(&path), &[]).unwrap_err();
    assert!(err.to_string().contains("fusion.conceptgraphs.dbscan_eps_m: must be within"), "{err}");
}
