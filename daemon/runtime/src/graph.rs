//! The in-memory scene graph: what the fusion thread hands to the publisher, the recorder and the
//! refiner. Plain owned data; the publisher encodes it into a shared-memory graph sample
//! ([`op3dsg_ipc_types::GraphHeader`] and node and edge records) and `op3dsg dump --json` writes
//! its JSON form. A leaf above `world`: it imports nothing of the stages.

use op3dsg_drivers::graph_json::{EdgeJson, GraphJson, NodeJson, OrientedBoxJson};
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};

use crate::world::OrientedBox;

/// The colours viewers draw the graph in (RGBA, each in `0..=1`): the recorder's Foxglove scene
/// and the ROS markers alike, so both look the same.
pub mod colours {
    /// Object boxes: blue-grey, translucent.
    pub const OBJECT: [f32; 4] = [0.45, 0.58, 0.72, 0.35];
    /// Part boxes: orange.
    pub const PART: [f32; 4] = [1.0, 0.55, 0.1, 0.6];
    /// Spatial edges: grey.
    pub const SPATIAL_EDGE: [f32; 4] = [0.75, 0.75, 0.75, 0.9];
    /// Functional edges: green.
    pub const FUNCTIONAL_EDGE: [f32; 4] = [0.2, 0.85, 0.3, 1.0];
}

/// One node of the graph.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GraphNode {
    /// Stable id.
    pub id: u32,
    /// Object or part.
    pub kind: NodeKind,
    /// Parent object of a part.
    pub parent_id: Option<u32>,
    /// Voted label.
    pub label: String,
    /// Confidence in [0, 1].
    pub confidence: f32,
    /// Centre of the node's points, world, metres.
    pub centre_m: [f32; 3],
    /// Axis-aligned box, world, metres.
    pub box_min_m: [f32; 3],
    /// Axis-aligned box, world, metres.
    pub box_max_m: [f32; 3],
    /// Gravity-aligned oriented box around the same points (yaw about `world.up_axis`; see
    /// [`crate::world::oriented_box`]).
    pub obb: OrientedBox,
    /// Keyframe detections fused.
    pub observation_count: u32,
    /// Bit set over `op3dsg_ipc_types::AFFORDANCES`.
    pub affordance_bits: u16,
    /// The bits of `affordance_bits` the knowledge reasoner gave; with `affordance_llm_bits`
    /// they name each affordance's origin ([`GraphNode::affordance_origins`]).
    pub affordance_knowledge_bits: u16,
    /// The bits of `affordance_bits` an LLM agent gave, after the verification gate.
    pub affordance_llm_bits: u16,
    /// Stamp of the last keyframe that saw it, nanoseconds.
    pub last_seen_stamp_ns: u64,
    /// Stamp of the first keyframe that saw it, nanoseconds (kept across restarts and moves).
    pub first_seen_stamp_ns: u64,
    /// The depth of recent keyframes says it is gone; not removed yet (`[fusion.change]`).
    pub missing: bool,
}

impl GraphNode {
    /// Adds the affordances `bits` from `origin` (an origin's own mask; `knowledge+llm` sets both,
    /// `geometry` neither).
    pub fn add_affordances(&mut self, bits: u16, origin: EdgeOrigin) {
        self.affordance_bits |= bits;
        match origin {
            EdgeOrigin::Knowledge => self.affordance_knowledge_bits |= bits,
            EdgeOrigin::Llm => self.affordance_llm_bits |= bits,
            EdgeOrigin::KnowledgeAndLlm => {
                self.affordance_knowledge_bits |= bits;
                self.affordance_llm_bits |= bits;
            }
            EdgeOrigin::Geometry => {}
        }
    }

    /// The box viewers draw: its oriented box, or its axis-aligned box (yaw 0) when it has none
    /// (size all zero: a node restored from a map written before nodes had one).
    pub fn display_box(&self, up_axis: crate::world::UpAxis) -> OrientedBox {
        if self.obb.size_m == [0.0; 3] && self.box_max_m != self.box_min_m {
            OrientedBox::axis_aligned(self.box_min_m, self.box_max_m, up_axis)
        } else {
            self.obb
        }
    }

    /// Each affordance with its origin, in canonical order (see `op3dsg_ipc_types::Node`).
    pub fn affordance_origins(&self) -> impl Iterator<Item = (&'static str, EdgeOrigin)> + use<> {
        op3dsg_ipc_types::affordance_origins(
            self.affordance_bits,
            self.affordance_knowledge_bits,
            self.affordance_llm_bits,
        )
    }
}

/// One directed edge.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphEdge {
    /// Source node id.
    pub source_id: u32,
    /// Target node id.
    pub target_id: u32,
    /// Spatial or functional.
    pub kind: EdgeKind,
    /// Canonical relation id (see `op3dsg_ipc_types::relation_id`).
    pub relation_id: u16,
    /// Confidence in [0, 1].
    pub confidence: f32,
    /// Where it came from.
    pub origin: EdgeOrigin,
}

/// One consistent version of the graph.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SceneGraph {
    /// Graph version (increases with every published change).
    pub version: u64,
    /// Stamp of the newest fused keyframe, nanoseconds.
    pub stamp_ns: u64,
    /// Nodes sorted by id.
    pub nodes: Vec<GraphNode>,
    /// Edges.
    pub edges: Vec<GraphEdge>,
}

impl SceneGraph {
    /// Number of object nodes.
    pub fn object_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.kind == NodeKind::Object).count()
    }

    /// Number of part nodes.
    pub fn part_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.kind == NodeKind::Part).count()
    }

    /// The JSON form (see `op3dsg_drivers::graph_json`).
    pub fn to_json(&self, source: &str) -> GraphJson {
        let mut json = GraphJson::new(source);
        json.graph_version = self.version;
        json.stamp_ns = self.stamp_ns;
        json.nodes = self
            .nodes
            .iter()
            .map(|n| NodeJson {
                id: n.id,
                label: n.label.clone(),
                kind: n.kind.as_str().to_owned(),
                parent: n.parent_id,
                centre_m: n.centre_m,
                box_min_m: n.box_min_m,
                box_max_m: n.box_max_m,
                obb: Some(OrientedBoxJson { centre_m: n.obb.centre_m, size_m: n.obb.size_m, yaw_rad: n.obb.yaw_rad }),
                affordances: op3dsg_ipc_types::affordance_names(n.affordance_bits).map(str::to_owned).collect(),
                affordance_origins: n
                    .affordance_origins()
                    .map(|(name, origin)| (name.to_owned(), origin.as_str().to_owned()))
                    .collect(),
                confidence: n.confidence,
                observation_count: n.observation_count,
                seen_keyframes: None,
            })
            .collect();
        json.edges = self
            .edges
            .iter()
            .map(|e| EdgeJson {
                source: e.source_id,
                target: e.target_id,
                kind: e.kind.as_str().to_owned(),
                relation: op3dsg_ipc_types::relation_phrase(e.relation_id).unwrap_or("unknown").to_owned(),
                confidence: e.confidence,
                origin: e.origin.as_str().to_owned(),
            })
            .collect();
        json
    }
}

/// One point of a node's cloud, world frame (the recorder's `/op3dsg/node_points`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodePoint {
    /// The node's id (as in the graph).
    pub node_id: u32,
    /// Position, world, metres.
    pub position_m: [f32; 3],
}
