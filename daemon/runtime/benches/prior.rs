//! Rebuilding the prior graph (neighbours, spatial relations) and running the knowledge
//! reasoner for a graph of 2,000 nodes (1,500 objects over a 30 m x 30 m floor, 500 parts on
//! them), on one thread. Issue 4's target for the prior-graph rebuild is 2 ms.
//!
//! `taskset -c 0 cargo bench -p op3dsg-runtime --bench prior` prints the median and p99 of 200
//! timed runs of each stage (the rebuild both one-off and with the reused `PriorBuilder` the
//! fusion thread keeps); criterion's own report follows.

use std::hint::black_box;
use std::sync::Arc;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};
use op3dsg_runtime::graph::{GraphEdge, GraphNode, SceneGraph};
use op3dsg_runtime::knowledge::KnowledgeBase;
use op3dsg_runtime::prior::{self, PriorConfig};
use op3dsg_runtime::reasoner::{KnowledgeReasoner, Reasoner};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const OBJECTS: u32 = 1_500;
const PARTS: u32 = 500;

fn graph(kb: &KnowledgeBase) -> SceneGraph {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut graph = SceneGraph { version: 1, ..SceneGraph::default() };
    for id in 0..OBJECTS {
        let object = &kb.objects()[id as usize % kb.objects().len()];
        let centre = [rng.random_range(0.0..30.0f32), rng.random_range(0.0..30.0f32), rng.random_range(0.2..2.0f32)];
        let half = [rng.random_range(0.05..0.6f32), rng.random_range(0.05..0.6f32), rng.random_range(0.05..0.5f32)];
        graph.nodes.push(GraphNode {
            id,
            kind: NodeKind::Object,
            parent_id: None,
            label: object.name.clone(),
            confidence: 0.8,
            centre_m: centre,
            box_min_m: std::array::from_fn(|i| centre[i] - half[i]),
            box_max_m: std::array::from_fn(|i| centre[i] + half[i]),
            obb: Default::default(),
            observation_count: 5,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            missing: false,
            ..Default::default()
        });
    }
    for k in 0..PARTS {
        let parent = rng.random_range(0..OBJECTS);
        let parent_node = graph.nodes[parent as usize].clone();
        let object = kb.object_category(&parent_node.label).expect("object");
        let pairs = kb.parts_of(object);
        let label = if pairs.is_empty() {
            "knob".to_owned()
        } else {
            format!("{} {}", parent_node.label, kb.part(pairs[k as usize % pairs.len()].part).name)
        };
        let c = parent_node.box_max_m;
        graph.nodes.push(GraphNode {
            id: OBJECTS + k,
            kind: NodeKind::Part,
            parent_id: Some(parent),
            label,
            confidence: 0.7,
            centre_m: c,
            box_min_m: c.map(|v| v - 0.02),
            box_max_m: c.map(|v| v + 0.02),
            obb: Default::default(),
            ..parent_node
        });
        graph.edges.push(GraphEdge {
            source_id: OBJECTS + k,
            target_id: parent,
            kind: EdgeKind::Spatial,
            relation_id: 0,
            confidence: 0.7,
            origin: EdgeOrigin::Geometry,
        });
    }
    graph
}

fn report(name: &str, mut samples_us: Vec<f64>) {
    samples_us.sort_by(f64::total_cmp);
    let at = |q: f64| samples_us[((samples_us.len() - 1) as f64 * q).round() as usize];
    println!("{name}: median {:.0} us, p99 {:.0} us", at(0.5), at(0.99));
}

fn bench_prior(c: &mut Criterion) {
    let kb = Arc::new(KnowledgeBase::builtin().expect("knowledge base"));
    let graph = graph(&kb);
    let config = PriorConfig::default();
    let mut reasoner = KnowledgeReasoner::new(kb.clone());
    let prior_graph = prior::build(&graph, &kb, &config);
    println!(
        "{} nodes, {} neighbour pairs, {} spatial edges",
        prior_graph.nodes.len(),
        prior_graph.neighbours.len(),
        prior_graph.spatial_edges.len()
    );
    let time = |f: &mut dyn FnMut()| {
        (0..200)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64() * 1e6
            })
            .collect::<Vec<_>>()
    };
    report(
        "prior graph rebuild (2,000 nodes)",
        time(&mut || {
            black_box(prior::build(&graph, &kb, &config));
        }),
    );
    let mut builder = prior::PriorBuilder::default();
    report(
        "prior graph rebuild, reused builder (2,000 nodes)",
        time(&mut || {
            black_box(builder.build(&graph, &kb, &config));
        }),
    );
    report(
        "knowledge reasoner (2,000 nodes)",
        time(&mut || {
            black_box(reasoner.reason(&prior_graph));
        }),
    );
    // Applying the reasoner's output to the published graph (which holds the prior graph's
    // spatial edges by then), as the fusion thread does for every published version.
    let output = reasoner.reason(&prior_graph);
    let mut enriched = graph.clone();
    enriched.edges.extend(prior_graph.spatial_edges.iter().cloned());
    println!("{} functional relations onto {} edges", output.functional.len(), enriched.edges.len());
    report(
        "apply reasoner output (2,000 nodes)",
        time(&mut || {
            let mut g = enriched.clone();
            op3dsg_runtime::reasoner::apply(&mut g, &output, op3dsg_ipc_types::EdgeOrigin::Knowledge);
            black_box(g);
        }),
    );
    c.bench_function("prior_build_2000", |b| b.iter(|| prior::build(black_box(&graph), &kb, &config)));
    c.bench_function("prior_rebuild_reused_2000", |b| b.iter(|| builder.build(black_box(&graph), &kb, &config)));
    c.bench_function("knowledge_reason_2000", |b| b.iter(|| reasoner.reason(black_box(&prior_graph))));
}

criterion_group!(benches, bench_prior);
criterion_main!(benches);
