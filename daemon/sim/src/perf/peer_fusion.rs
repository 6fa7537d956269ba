//! The peer baseline's fusion cost next to ours for `op3dsg bench perf`: the kitchen path of
//! the fusion curve ([`crate::workload::Workload::kitchen`], seed 3, `fusion_keyframes`
//! keyframes 15 frames apart, realistic oracle), each keyframe integrated into OP3DSG's fusion
//! (the profile's `[fusion]`) and then into ConceptGraphs' ([`crate::conceptgraphs::peer_fusion`]),
//! on the calling thread with the same frame, pose and detections, each call timed. The graph
//! each builds at the end is timed too (ConceptGraphs' final denoise, filter and merge run in
//! it).

use std::time::Instant;

use anyhow::anyhow;
use op3dsg_runtime::fusion::Fusion;
use op3dsg_runtime::graph::SceneGraph;
use serde::{Deserialize, Serialize};

use super::{Percentiles, PerfOptions};
use crate::oracle::OracleConfig;
use crate::workload::Workload;

/// One fusion's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FusionCost {
    /// Which fusion.
    pub name: String,
    /// `Fusion::integrate` per keyframe.
    pub keyframe: Percentiles,
    /// The final `Fusion::build_graph`, ms.
    pub build_graph_ms: f64,
    /// Nodes in the map at the end (confirmed or not).
    pub map_nodes: usize,
    /// Nodes the final graph publishes.
    pub graph_nodes: usize,
    /// Heap the map holds at the end, MiB.
    pub memory_mib: f64,
}

/// The section of the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PeerFusionCost {
    /// Keyframes integrated.
    pub keyframes: usize,
    /// Detections over all keyframes.
    pub detections: usize,
    /// OP3DSG's fusion, then the peer's.
    pub fusions: Vec<FusionCost>,
}

/// Measures both fusions on the same keyframes (see the module docs).
pub fn peer_fusion_cost(options: &PerfOptions) -> anyhow::Result<PeerFusionCost> {
    let profile = crate::load_profile(options.profile.as_deref(), &options.overrides)
        .map_err(|e| anyhow!("bad profile: {e}"))?
        .profile;
    let workload = Workload::kitchen(3, options.fusion_keyframes.max(1), 15, OracleConfig::realistic());
    let mut fusions: Vec<(&str, Box<dyn Fusion>, Vec<f64>)> = vec![
        ("OP3DSG multi-view fusion", op3dsg_runtime::fusion::build(&profile.fusion, profile.world.up_axis), Vec::new()),
        (crate::conceptgraphs::PEER_ROW, crate::conceptgraphs::peer_fusion(&profile), Vec::new()),
    ];
    for keyframe in &workload.keyframes {
        for (_, fusion, times) in &mut fusions {
            let t = Instant::now();
            fusion.integrate(&keyframe.frame, &keyframe.pose, &keyframe.detections);
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    let mut out = Vec::new();
    for (name, fusion, mut times) in fusions {
        let mut graph = SceneGraph::default();
        let t = Instant::now();
        fusion.build_graph(&mut graph);
        let build_graph_ms = t.elapsed().as_secs_f64() * 1e3;
        let cost = FusionCost {
            name: name.to_owned(),
            keyframe: Percentiles::from_samples_ms(&mut times),
            build_graph_ms,
            map_nodes: fusion.node_count(),
            graph_nodes: graph.nodes.len(),
            memory_mib: op3dsg_runtime::stats::mib(fusion.memory_bytes() as u64),
        };
        eprintln!(
            "bench perf:   {name}: keyframe p50 {:.3} ms, p99 {:.3} ms, build_graph {:.3} ms, {} nodes published",
            cost.keyframe.p50_ms, cost.keyframe.p99_ms, cost.build_graph_ms, cost.graph_nodes
        );
        out.push(cost);
    }
    Ok(PeerFusionCost {
        keyframes: workload.keyframes.len(),
        detections: workload.keyframes.iter().map(|k| k.detections.len()).sum(),
        fusions: out,
    })
}
