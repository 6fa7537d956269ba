//! Part → object attachment in the published graph (fusion's `part of` edges).

use std::cmp::Ordering;

use glam::Vec3;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};

use crate::graph::{GraphEdge, SceneGraph};

/// Sets each part's parent and adds its `part of` edge: among objects whose box, grown by
/// `margin_m`, contains the part's centre, one whose label is contained in the part's label
/// ("cabinet handle" → cabinet) wins, then the nearest.
pub fn attach_parts(graph: &mut SceneGraph, margin_m: f32) {
    let objects: Vec<(u32, String, Vec3, Vec3)> = graph
        .nodes
        .iter()
        .filter(|n| n.kind == NodeKind::Object)
        .map(|n| (n.id, n.label.clone(), Vec3::from(n.box_min_m), Vec3::from(n.box_max_m)))
        .collect();
    for part in graph.nodes.iter_mut().filter(|n| n.kind == NodeKind::Part) {
        let centre = Vec3::from(part.centre_m);
        let mut best: Option<(bool, f32, u32)> = None;
        for (id, label, lo, hi) in &objects {
            let gap = (*lo - centre).max(centre - *hi).max(Vec3::ZERO).length();
            if gap > margin_m {
                continue;
            }
            let lexical = !label.is_empty() && part.label.contains(label.as_str());
            let better = match best {
                None => true,
                Some((bl, bg, _)) => (lexical && !bl) || (lexical == bl && gap.total_cmp(&bg) == Ordering::Less),
            };
            if better {
                best = Some((lexical, gap, *id));
            }
        }
        if let Some((_, _, object_id)) = best {
            part.parent_id = Some(object_id);
            graph.edges.push(GraphEdge {
                source_id: part.id,
                target_id: object_id,
                kind: EdgeKind::Spatial,
                relation_id: 0,
                confidence: part.confidence,
                origin: EdgeOrigin::Geometry,
            });
        }
    }
}
