//! The knowledge reasoner on the synthetic kitchen's published graph (batch runner, no LLM).

use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, affordance_names, relation_phrase};
use op3dsg_sim::batch::{self, VisibilityThresholds};

/// With no LLM, the synthetic kitchen's published graph carries part-of, functional edges and
/// affordances that agree with the scene's ground truth.
#[test]
fn the_kitchen_graph_gets_functional_edges_and_affordances() {
    let mut profile = op3dsg_sim::load_profile(None, &[]).unwrap().profile;
    op3dsg_sim::backends::edit_synthetic(&mut profile, |s| s.frame_count = Some(600))
        .expect("[source.synthetic] of the profile");
    let run = batch::run(&profile, &VisibilityThresholds::default()).unwrap();
    let graph = &run.graph;
    let label = |id: u32| graph.nodes.iter().find(|n| n.id == id).map_or("?", |n| n.label.as_str());
    let functional: Vec<(&str, &str, &str)> = graph
        .edges
        .iter()
        .filter(|e| e.kind == EdgeKind::Functional)
        .inspect(|e| assert_eq!(e.origin, EdgeOrigin::Knowledge))
        .map(|e| (label(e.source_id), relation_phrase(e.relation_id).unwrap_or("?"), label(e.target_id)))
        .collect();
    assert!(
        functional.contains(&("stove knob", "rotate to adjust the setting or temperature", "stove")),
        "{functional:?}"
    );
    assert!(functional.iter().any(|(_, r, t)| *r == "control the water flow" && *t == "sink"), "{functional:?}");
    // Every handle fused onto a cabinet: "pull to open or close" to it and "hook_pull".
    let mut handles = 0;
    for part in graph.nodes.iter().filter(|n| n.label.ends_with("handle")) {
        let Some(parent) = part.parent_id else { continue };
        if label(parent) != "cabinet" {
            continue;
        }
        handles += 1;
        assert!(
            graph.edges.iter().any(|e| e.source_id == part.id
                && e.target_id == parent
                && relation_phrase(e.relation_id) == Some("pull to open or close")),
            "{} {}",
            part.id,
            part.label
        );
        assert_eq!(affordance_names(part.affordance_bits).collect::<Vec<_>>(), ["hook_pull"]);
    }
    assert!(handles >= 2, "{handles} cabinet handles");
    assert!(graph.edges.iter().any(|e| e.kind == EdgeKind::Spatial && e.relation_id != 0), "object relations");
}
