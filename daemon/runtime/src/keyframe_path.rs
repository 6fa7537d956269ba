//! One keyframe's path: detection → fusion → graph from the map → prior graph and reasoner.
//!
//! The threaded pipeline (a detection worker, then the fusion thread) and the deterministic
//! batch runner of `op3dsg-sim` both call these functions and nothing else between the
//! keyframe gate and a published graph, so the two cannot drift apart. The callers keep only
//! what differs: threads, queues and timing in the pipeline; lanes of several detectors and
//! fusions over one rendering pass in the batch runner.
//!
//! ```
//! use op3dsg_runtime::{config, keyframe_path, pipeline};
//! let profile = config::load(None, &[]).unwrap().profile;
//! let mut fusion = pipeline::make_fusion(&profile);
//! let frame = op3dsg_drivers::frame::Frame::new(op3dsg_drivers::frame::Intrinsics::d435i_640x480());
//! let world_from_camera = op3dsg_drivers::pose::Isometry::IDENTITY;
//! let changed = keyframe_path::fuse(fusion.as_mut(), &frame, &world_from_camera, &[]).changed();
//! assert!(!changed, "no detections, no new graph version");
//! let graph = keyframe_path::map_graph(fusion.as_ref(), 1, frame.stamp_ns);
//! assert_eq!(graph.version, 1);
//! ```

use std::sync::Arc;
use std::time::Duration;

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;

use crate::fusion::{Fusion, FusionReport};
use crate::graph::SceneGraph;
use crate::perception::{Detection, Detector, DetectorError};
use crate::prior::PriorGraph;
use crate::reasoner::GraphEnricher;

/// Runs `detector` on a keyframe into `out`. On failure `out` is left empty, so the keyframe is
/// fused as one where nothing was seen, and the error is returned for the caller to count and
/// log (the pipeline and the batch runner both go on).
pub fn detect(detector: &mut dyn Detector, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
    let result = detector.detect(frame, out);
    if result.is_err() {
        out.clear();
    }
    result
}

/// What fusing one keyframe did to the map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Fused {
    /// Fusion's own report.
    pub report: FusionReport,
}

impl Fused {
    /// Whether the map gained or updated a node, so that a new graph version is due.
    pub fn changed(&self) -> bool {
        self.report.merged + self.report.created > 0
    }
}

/// Integrates one keyframe's detections into the map.
pub fn fuse(fusion: &mut dyn Fusion, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> Fused {
    Fused { report: fusion.integrate(frame, world_from_camera, detections) }
}

/// The graph of the map as it stands: fusion's confirmed nodes and `part of` edges, with its
/// version and stamp. [`enrich`] adds the rest.
pub fn map_graph(fusion: &dyn Fusion, version: u64, stamp_ns: u64) -> SceneGraph {
    let mut graph = SceneGraph::default();
    fusion.build_graph(&mut graph);
    graph.version = version;
    graph.stamp_ns = stamp_ns;
    graph
}

/// How a graph receives the LLM refiner's answer (with `reasoner.kind = "llm"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refinement {
    /// The refiner's latest verified result is applied and the new prior graph offered to it;
    /// nothing waits (the pipeline: the fusion thread never waits on the network).
    Asynchronous,
    /// The graph is refined now: its prior graph is sent and the answer awaited up to the given
    /// time (the batch runner, so that a deterministic server gives a deterministic graph).
    Await(Duration),
}

/// Adds the prior graph (spatial relations, part → object attachment) and the reasoner's
/// functional relations and affordances to `graph`, then the LLM refiner's answer as
/// `refinement` says. Returns the prior graph.
pub fn enrich(enricher: &mut GraphEnricher, graph: &mut SceneGraph, refinement: Refinement) -> Arc<PriorGraph> {
    let prior = enricher.enrich(graph);
    if let Refinement::Await(timeout) = refinement {
        enricher.refine_now(graph, prior.clone(), timeout);
    }
    prior
}
