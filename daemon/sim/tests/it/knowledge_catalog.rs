//! The synthetic rooms against the knowledge base: every label the catalog uses resolves; the
//! rooms' functional relations and affordances come from their own ground-truth table
//! (`op3dsg_synthetic::truth`), and how often the knowledge base gives the same answer is
//! measured (`op3dsg_sim::eval::agreement`), not assumed.

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

/// The benchmark's 24 scenes, each with the ids its deviations concern.
fn benchmark_scenes() -> Vec<(op3dsg_drivers::graph_json::GraphJson, Vec<(u32, &'static str)>)> {
    (0..24)
        .map(|i| {
            let (room, seed) = op3dsg_sim::eval::benchmark::scene(i);
            let scene = op3dsg_synthetic::Scene::generate(room, seed);
            let deviations = scene.deviations().iter().map(|d| (u32::from(d.instance), d.name)).collect();
            (scene.ground_truth(), deviations)
        })
        .collect()
}

fn profile() -> op3dsg_runtime::config::Profile {
    op3dsg_sim::load_profile(None, &[]).unwrap_or_else(|e| panic!("{e}")).profile
}

#[test]
fn ground_truth_and_knowledge_base_agreement_is_measured_and_below_full_with_deviations() {
    use op3dsg_sim::eval::agreement::{self, Agreement};
    let profile = profile();
    let mut all = Agreement::default();
    for (gt, deviations) in benchmark_scenes() {
        all.add(&agreement::measure(&gt, &deviations, &profile).unwrap_or_else(|e| panic!("{}: {e}", gt.source)));
    }
    let text = agreement::text(&all);
    // Every deviation of the table is drawn somewhere in the benchmark's rooms.
    for d in op3dsg_synthetic::truth::DEVIATIONS {
        assert!(all.deviations.get(d.name).is_some_and(|n| *n > 0), "{} not drawn\n{text}", d.name);
    }
    // The rooms differ from the tables: agreement is below 100 %, on the deviations most of all,
    // and the two still describe the same homes for most items.
    let (functional, affordance) = (all.functional.percent().unwrap(), all.affordance.percent().unwrap());
    assert!(functional < 100.0 && affordance < 100.0, "{text}");
    assert!(functional > 50.0 && affordance > 50.0, "{text}");
    assert!(all.functional_deviations.agree < all.functional_deviations.total, "{text}");
    assert!(all.affordance_deviations.agree < all.affordance_deviations.total, "{text}");
    assert!(all.functional_deviations.percent().unwrap() < functional, "{text}");
    // An outlet with nothing plugged in has no "provide power" edge, but the knowledge base
    // powers the nearest appliance or not at all; either way its affordances differ.
    assert!(
        all.disagreements.keys().any(|k| k.starts_with("affordance power outlet: ground truth plug_in;")),
        "{text}"
    );
}

/// The figure is computed from the two graphs: a ground truth rewritten to the knowledge base's
/// own answer agrees fully, and each edit costs exactly one item.
#[test]
fn agreement_follows_the_graphs_it_compares() {
    use op3dsg_sim::eval::agreement;
    let profile = profile();
    let (gt, deviations) = benchmark_scenes().swap_remove(0);
    let answer = agreement::knowledge_answer(&gt, &profile).unwrap();
    let measured = agreement::compare(&gt, &answer, &deviations);
    assert_eq!(measured, agreement::measure(&gt, &deviations, &profile).unwrap());
    let mut same = gt.clone();
    same.edges.retain(|e| e.kind != "functional");
    same.edges.extend(answer.edges.iter().filter(|e| e.kind == "functional").cloned());
    for node in &mut same.nodes {
        node.affordances = answer.nodes.iter().find(|n| n.id == node.id).unwrap().affordances.clone();
    }
    let full = agreement::compare(&same, &answer, &[]);
    assert!(full.functional.total > 10 && full.affordance.total > 10, "{full:?}");
    assert_eq!(full.functional.agree, full.functional.total);
    assert_eq!(full.affordance.agree, full.affordance.total);
    assert!(full.disagreements.is_empty(), "{:?}", full.disagreements);
    assert!(measured.functional.agree < full.functional.total || measured.affordance.agree < full.affordance.total);
    // Drop one functional edge from the ground truth: the union keeps it (the knowledge base
    // has it), one fewer agrees.
    let mut edited = same.clone();
    let i = edited.edges.iter().position(|e| e.kind == "functional").unwrap();
    edited.edges.remove(i);
    let less = agreement::compare(&edited, &answer, &[]);
    assert_eq!((less.functional.agree, less.functional.total), (full.functional.agree - 1, full.functional.total));
    // Change one node's affordances.
    let mut edited = same.clone();
    let node = edited.nodes.iter_mut().find(|n| !n.affordances.is_empty()).unwrap();
    node.affordances = vec!["foot_push".to_owned(), "key_press".to_owned()];
    let less = agreement::compare(&edited, &answer, &[]);
    assert_eq!((less.affordance.agree, less.affordance.total), (full.affordance.agree - 1, full.affordance.total));
}
