//! The unified graph with no LLM: synthetic rooms through the batch pipeline (oracle detector,
//! realistic noise, paper fusion, prior graph, offline knowledge reasoner), the published graph
//! checked against the scene's ground truth. A ground-truth functional edge is checkable when
//! fusion matched both its endpoints; it is recovered when the graph has a functional edge with
//! the same relation between nodes matched to them. Affordances likewise per matched part.
//!
//! Checks every cabinet handle of the kitchen ("pull to open or close" to its cabinet, and
//! "hook pull"), the living room's remote ("remote to control" the TV), and that most of each
//! room's functional edges and part affordances are recovered.

use op3dsg_ipc_types::{EdgeKind, affordance_bits, relation_id};
use op3dsg_runtime::graph::GraphNode;
use op3dsg_sim::batch::{self, BatchRun};
use op3dsg_sim::eval::fusion_match::{FusionMatchReport, MatchCriteria, match_run};
use op3dsg_synthetic::{CameraPath, RoomKind, Scene};

const SEED: u64 = 1;
const FRAME_RATE_HZ: f64 = 10.0;

fn run(room: RoomKind) -> (BatchRun, FusionMatchReport) {
    let sets = [
        format!("source.synthetic.room={}", room.as_str()),
        format!("source.synthetic.seed={SEED}"),
        format!("source.synthetic.frame_rate_hz={FRAME_RATE_HZ}"),
        "detector.oracle.preset=realistic".to_owned(),
        "reasoner.kind=knowledge".to_owned(),
    ];
    let mut profile = op3dsg_sim::load_profile(None, &sets).expect("profile").profile;
    let path = CameraPath::new(&Scene::generate(room, SEED), SEED, FRAME_RATE_HZ);
    op3dsg_sim::backends::edit_synthetic(&mut profile, |s| s.frame_count = Some(path.period_frames()))
        .expect("[source.synthetic] of the profile");
    let run = batch::run(&profile, &batch::VisibilityThresholds::default()).expect("batch run");
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let report = match_run(&run, &criteria);
    (run, report)
}

/// Fused node ids matched to ground-truth instance `id`.
fn matched(report: &FusionMatchReport, id: u16) -> &[u32] {
    report.gt.iter().find(|g| g.id == u32::from(id)).map_or(&[], |g| g.matched_by.as_slice())
}

fn node(run: &BatchRun, id: u32) -> &GraphNode {
    run.graph.nodes.iter().find(|n| n.id == id).expect("matched node is in the graph")
}

/// Whether the graph links some node of `sources` to some node of `targets` by `relation`.
fn has_edge(run: &BatchRun, sources: &[u32], targets: &[u32], relation: &str) -> bool {
    let (kind, id) = relation_id(relation).expect("canonical relation");
    assert_eq!(kind, EdgeKind::Functional);
    run.graph.edges.iter().any(|e| {
        e.kind == EdgeKind::Functional
            && e.relation_id == id
            && sources.contains(&e.source_id)
            && targets.contains(&e.target_id)
    })
}

struct Recovered {
    functional: (usize, usize),
    affordances: (usize, usize),
}

/// (recovered, checkable) functional edges and part affordance sets, printing the misses.
fn recovered(room: RoomKind, run: &BatchRun, report: &FusionMatchReport) -> Recovered {
    let scene = run.scene.as_ref().expect("synthetic scene");
    let label = |id: u16| scene.instance(id).map_or("?", |i| i.label.as_str());
    let (mut functional, mut functional_checkable) = (0, 0);
    for edge in scene.edges().iter().filter(|e| e.kind == "functional") {
        let (sources, targets) = (matched(report, edge.source), matched(report, edge.target));
        if sources.is_empty() || targets.is_empty() {
            continue;
        }
        functional_checkable += 1;
        if has_edge(run, sources, targets, edge.relation) {
            functional += 1;
        } else {
            let instead: Vec<String> = run
                .graph
                .edges
                .iter()
                .filter(|e| e.kind == EdgeKind::Functional && sources.contains(&e.source_id))
                .map(|e| {
                    let phrase = op3dsg_ipc_types::relation_phrase(e.relation_id).unwrap_or("?");
                    format!("[{phrase}] -> {}", node(run, e.target_id).label)
                })
                .collect();
            println!(
                "{}: missing {} --[{}]--> {}; the graph has {instead:?}",
                room.as_str(),
                label(edge.source),
                edge.relation,
                label(edge.target)
            );
        }
    }
    let (mut affordances, mut affordances_checkable) = (0, 0);
    for instance in scene.instances() {
        let expected = scene.affordances(instance.id);
        let nodes = matched(report, instance.id);
        if expected.is_empty() || nodes.is_empty() {
            continue;
        }
        affordances_checkable += 1;
        let bits = affordance_bits(expected.iter().copied()).expect("canonical affordances");
        if nodes.iter().any(|&n| node(run, n).affordance_bits & bits == bits) {
            affordances += 1;
        } else {
            println!("{}: {} lacks affordances {expected:?}", room.as_str(), instance.label);
        }
    }
    println!(
        "{}: functional edges {functional}/{functional_checkable}, affordances {affordances}/{affordances_checkable}",
        room.as_str()
    );
    Recovered { functional: (functional, functional_checkable), affordances: (affordances, affordances_checkable) }
}

fn assert_most(what: &str, (got, of): (usize, usize), min_fraction: f64) {
    assert!(of > 0, "{what}: nothing checkable");
    assert!(got as f64 >= min_fraction * of as f64, "{what}: {got} of {of} recovered");
}

#[test]
fn kitchen_handles_pull_their_cabinets_open_and_afford_hook_pull() {
    let (run, report) = run(RoomKind::Kitchen);
    let scene = run.scene.as_ref().expect("synthetic scene");
    let pull = affordance_bits(["hook_pull"]).expect("canonical");
    let mut handles = 0;
    for edge in scene.edges().iter().filter(|e| e.kind == "functional") {
        let (source, target) =
            (scene.instance(edge.source).expect("source"), scene.instance(edge.target).expect("target"));
        if source.label != "cabinet handle" {
            continue;
        }
        let (sources, targets) = (matched(&report, edge.source), matched(&report, edge.target));
        if sources.is_empty() || targets.is_empty() {
            continue;
        }
        handles += 1;
        assert_eq!(edge.relation, "pull to open or close", "the scene's own relation");
        assert!(
            has_edge(&run, sources, targets, "pull to open or close"),
            "cabinet handle {} --[pull to open or close]--> {} {}",
            edge.source,
            target.label,
            edge.target
        );
        assert!(
            sources.iter().any(|&n| node(&run, n).affordance_bits & pull == pull),
            "handle {} affords hook pull",
            edge.source
        );
        // Part-of: the handle's node hangs on its cabinet's node.
        assert!(sources.iter().any(|&n| node(&run, n).parent_id.is_some_and(|p| targets.contains(&p))));
    }
    assert!(handles >= 4, "the kitchen's cabinet handles were checked ({handles})");
    let figures = recovered(RoomKind::Kitchen, &run, &report);
    assert_most("kitchen functional edges", figures.functional, 0.9);
    assert_most("kitchen affordances", figures.affordances, 0.9);
}

#[test]
fn living_room_remote_controls_the_tv() {
    let (run, report) = run(RoomKind::LivingRoom);
    let scene = run.scene.as_ref().expect("synthetic scene");
    let edge = scene
        .edges()
        .iter()
        .find(|e| e.relation == "remote to control")
        .expect("the living room has a remote for its TV");
    assert_eq!(scene.instance(edge.target).expect("tv").label, "tv");
    let (remote, tv) = (matched(&report, edge.source), matched(&report, edge.target));
    assert!(!remote.is_empty() && !tv.is_empty(), "fusion found the remote and the TV");
    assert!(has_edge(&run, remote, tv, "remote to control"), "remote --[remote to control]--> TV");
    let figures = recovered(RoomKind::LivingRoom, &run, &report);
    assert_most("living room functional edges", figures.functional, 0.8);
    assert_most("living room affordances", figures.affordances, 0.8);
}
