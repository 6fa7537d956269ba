//! The synthetic rooms against the knowledge base: every label the catalog uses resolves, and
//! the catalog's functional relations and affordances are those the tables give.

use op3dsg_ipc_types::relation_phrase;
use op3dsg_runtime::knowledge::KnowledgeBase;

fn kb() -> KnowledgeBase {
    KnowledgeBase::builtin().expect("built-in knowledge base")
}

#[test]
fn every_synthetic_catalog_label_resolves() {
    use op3dsg_synthetic::{InstanceKind, RoomKind, Scene};
    let kb = kb();
    for room in RoomKind::ALL.into_iter().chain(RoomKind::TEST_SCENES) {
        for seed in 0..8 {
            let scene = Scene::generate(room, seed);
            for instance in scene.instances() {
                let resolved = kb
                    .resolve(&instance.label)
                    .unwrap_or_else(|| panic!("{room:?} seed {seed}: \"{}\" does not resolve", instance.label));
                match instance.kind {
                    InstanceKind::Object => assert!(resolved.object().is_some(), "{}", instance.label),
                    InstanceKind::Part => assert!(resolved.part().is_some(), "{}", instance.label),
                }
                for synonym in &instance.synonyms {
                    assert!(kb.resolve(synonym).is_some(), "synonym \"{synonym}\" of \"{}\"", instance.label);
                }
            }
        }
    }
}

#[test]
fn synthetic_ground_truth_relations_and_affordances_follow_from_the_tables() {
    use op3dsg_synthetic::{InstanceKind, RoomKind, Scene};
    let kb = kb();
    for room in RoomKind::ALL.into_iter().chain(RoomKind::TEST_SCENES) {
        let scene = Scene::generate(room, 3);
        let by_id = |id: u16| scene.instance(id).expect("instance");
        for edge in scene.edges().iter().filter(|e| e.kind == "functional") {
            let source = by_id(edge.source);
            let target = by_id(edge.target);
            let target_cat = kb.object_category(&target.label).expect("target object");
            let resolved = kb.resolve(&source.label).expect("source");
            if source.kind == InstanceKind::Part && source.parent == Some(edge.target) {
                let part = resolved.part().expect("part");
                let relation = kb.local_relation(part, target_cat).map(|id| relation_phrase(id).unwrap_or(""));
                assert_eq!(relation, Some(edge.relation), "{} -> {}", source.label, target.label);
                let bits = kb.part_affordances(part, Some(target_cat));
                let expected = op3dsg_ipc_types::affordance_bits(scene.affordances(source.id).iter().copied());
                assert_eq!(Ok(bits), expected, "affordances of {} on {}", source.label, target.label);
            } else {
                let template = kb
                    .remote_templates_for(resolved.category)
                    .find(|t| t.targets.contains(&target_cat))
                    .unwrap_or_else(|| panic!("no remote template {} -> {}", source.label, target.label));
                assert_eq!(relation_phrase(template.relation_id), Some(edge.relation));
            }
        }
    }
}
