//! The scene-graph JSON form: one schema for the synthetic ground truth (`op3dsg gt`) and for a
//! published graph (`op3dsg dump --json`), so `op3dsg eval --pred a.json --gt b.json` compares
//! like with like.
//!
//! ```json
//! {
//!   "schema": "op3dsg.graph/1",
//!   "source": "synthetic kitchen seed 1",
//!   "graph_version": 0,
//!   "stamp_ns": 0,
//!   "nodes": [
//!     { "id": 1, "label": "cabinet", "kind": "object", "parent": null,
//!       "centre_m": [1.0, 0.3, 0.45], "box_min_m": [0.7, 0.0, 0.0], "box_max_m": [1.3, 0.6, 0.9],
//!       "obb": { "centre_m": [1.0, 0.3, 0.45], "size_m": [0.6, 0.6, 0.9], "yaw_rad": 0.0 },
//!       "affordances": [], "confidence": 1.0, "observation_count": 0 },
//!     { "id": 2, "label": "cabinet handle", "kind": "part", "parent": 1, ...,
//!       "affordances": ["hook_pull", "pinch_pull"],
//!       "affordance_origins": { "hook_pull": "knowledge+llm", "pinch_pull": "llm" } }
//!   ],
//!   "edges": [
//!     { "source": 2, "target": 1, "kind": "spatial", "relation": "part of",
//!       "confidence": 1.0, "origin": "geometry" },
//!     { "source": 2, "target": 1, "kind": "functional", "relation": "pull to open or close",
//!       "confidence": 1.0, "origin": "knowledge" }
//!   ]
//! }
//! ```
//!
//! Field by field:
//! - `schema`: always `op3dsg.graph/1` for this layout.
//! - `source`: free text naming what produced the file.
//! - `graph_version`, `stamp_ns`: the published graph version and the stamp of its newest
//!   keyframe (0 in ground truth).
//! - `source_kind`, `world_frame` (optional; `op3dsg dump --json` writes them from the graph
//!   header): what the daemon read its frames from (`live_camera`, `replay`, `synthetic`,
//!   `unknown`) and the name of the frame the coordinates are in (its `world.frame_id`).
//! - `nodes[].id`: unique within the file. `label`: text; a label of the form `a / b` means
//!   either name is correct (ground truth only). `kind`: `object` or `part`. `parent`: the id of
//!   a part's object, `null` otherwise. `centre_m`, `box_min_m`, `box_max_m`: world frame,
//!   metres, axis-aligned. `obb` (optional; published graphs have it, the synthetic ground truth,
//!   whose furniture is axis-aligned, does not): the gravity-aligned oriented box around the same
//!   points, `centre_m` (world, metres), `size_m` (extent along the box's first and second
//!   horizontal axes and along up, metres) and `yaw_rad` (the box's first axis turned from the
//!   world's first horizontal axis towards its second about the up axis, in (-pi/2, pi/2]; the
//!   axes per `world.up_axis` are in `op3dsg_runtime::world::oriented_box`). The evaluation
//!   (`op3dsg eval`) scores boxes by their axis-aligned `box_min_m`/`box_max_m`: the ground truth
//!   carries no orientation, so an oriented IoU would compare against boxes that have none.
//!   `affordances`: names from the 9 canonical affordances. `affordance_origins` (optional;
//!   published graphs have it for every node with affordances, ground truth does not): each of
//!   `affordances` with its origin, named as an edge's (`knowledge`, `llm`, `knowledge+llm`;
//!   `geometry` for one the publisher gave without an origin). A parallel map rather than objects
//!   in `affordances`, so that readers of the name list need no change.
//!   `confidence` in [0, 1] (1 in ground truth). `observation_count`: keyframe detections fused
//!   (0 in ground truth).
//! - `edges[].source`, `target`: node ids; the source relates to the target as `relation`
//!   says (handle `part of` cabinet, remote `remote to control` TV). `kind`: `spatial` or
//!   `functional`. `relation`: a canonical phrase (`op3dsg_ipc_types::SPATIAL_RELATIONS` or
//!   `FUNCTIONAL_RELATIONS`). `origin`: `geometry`, `knowledge`, `llm`, `knowledge+llm`, or
//!   `ground_truth`.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Schema tag written into every file.
pub const GRAPH_JSON_SCHEMA: &str = "op3dsg.graph/1";

/// The values of [`NodeJson::affordance_origins`].
pub const AFFORDANCE_ORIGINS: [&str; 5] = ["geometry", "knowledge", "llm", "knowledge+llm", "ground_truth"];

/// A whole graph in JSON form.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraphJson {
    /// Always [`GRAPH_JSON_SCHEMA`].
    pub schema: String,
    /// What produced the file.
    pub source: String,
    /// Published graph version (0 in ground truth).
    #[serde(default)]
    pub graph_version: u64,
    /// Stamp of the newest keyframe, nanoseconds (0 in ground truth).
    #[serde(default)]
    pub stamp_ns: u64,
    /// What the daemon read its frames from (the graph header's source kind by name); absent
    /// where no daemon published the graph (ground truth, evaluations).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_kind: Option<String>,
    /// The frame the coordinates are in (the daemon's `world.frame_id`); absent as `source_kind`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world_frame: Option<String>,
    /// Nodes.
    pub nodes: Vec<NodeJson>,
    /// Edges.
    pub edges: Vec<EdgeJson>,
}

/// A node in JSON form.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeJson {
    /// Unique id within the file.
    pub id: u32,
    /// Label; `a / b` lists alternatives (ground truth only).
    pub label: String,
    /// `object` or `part`.
    pub kind: String,
    /// Parent object of a part.
    #[serde(default)]
    pub parent: Option<u32>,
    /// Centre, world frame, metres.
    pub centre_m: [f32; 3],
    /// Axis-aligned box minimum corner, world frame, metres.
    pub box_min_m: [f32; 3],
    /// Axis-aligned box maximum corner, world frame, metres.
    pub box_max_m: [f32; 3],
    /// Gravity-aligned oriented box (module docs); absent in ground truth without orientation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub obb: Option<OrientedBoxJson>,
    /// Canonical affordance names.
    #[serde(default)]
    pub affordances: Vec<String>,
    /// Origin of each of `affordances` (`knowledge`, `llm`, `knowledge+llm`, `geometry`); empty,
    /// and left out of the file, in ground truth.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub affordance_origins: BTreeMap<String, String>,
    /// Confidence in [0, 1].
    #[serde(default = "one")]
    pub confidence: f32,
    /// Keyframe detections fused into the node.
    #[serde(default)]
    pub observation_count: u32,
    /// Ground truth written for a run (`op3dsg gt --frames N`): the keyframes of that run in
    /// which the node was visible. When a ground truth carries it, `op3dsg eval` scores only the
    /// nodes seen in at least 3 (and their edges and affordances), as `op3dsg bench quality`
    /// does; absent elsewhere.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seen_keyframes: Option<u32>,
}

/// A gravity-aligned oriented box in JSON form (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OrientedBoxJson {
    /// Centre, world frame, metres.
    pub centre_m: [f32; 3],
    /// Extent along the box's two horizontal axes and along up, metres.
    pub size_m: [f32; 3],
    /// Turn about the up axis, radians in (-pi/2, pi/2].
    pub yaw_rad: f32,
}

/// An edge in JSON form.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EdgeJson {
    /// Source node id.
    pub source: u32,
    /// Target node id.
    pub target: u32,
    /// `spatial` or `functional`.
    pub kind: String,
    /// Canonical relation phrase.
    pub relation: String,
    /// Confidence in [0, 1].
    #[serde(default = "one")]
    pub confidence: f32,
    /// `geometry`, `knowledge`, `llm`, `knowledge+llm` or `ground_truth`.
    pub origin: String,
}

fn one() -> f32 {
    1.0
}

impl GraphJson {
    /// An empty graph from `source`.
    pub fn new(source: impl Into<String>) -> Self {
        Self {
            schema: GRAPH_JSON_SCHEMA.to_owned(),
            source: source.into(),
            graph_version: 0,
            stamp_ns: 0,
            source_kind: None,
            world_frame: None,
            nodes: Vec::new(),
            edges: Vec::new(),
        }
    }

    /// Reads and checks a file: the schema tag, unique node ids, edges between existing nodes.
    /// Errors name the file and the offending entry.
    pub fn read(path: &std::path::Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let graph: Self = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        graph.check().map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(graph)
    }

    /// Checks the schema tag, unique node ids, known kinds and edge endpoints.
    pub fn check(&self) -> Result<(), String> {
        if self.schema != GRAPH_JSON_SCHEMA {
            return Err(format!("schema: expected \"{GRAPH_JSON_SCHEMA}\", found \"{}\"", self.schema));
        }
        let mut ids = std::collections::HashSet::new();
        for (i, node) in self.nodes.iter().enumerate() {
            if !ids.insert(node.id) {
                return Err(format!("nodes[{i}].id: duplicate id {}", node.id));
            }
            if node.kind != "object" && node.kind != "part" {
                return Err(format!("nodes[{i}].kind: expected \"object\" or \"part\", found \"{}\"", node.kind));
            }
            for (name, origin) in &node.affordance_origins {
                if !node.affordances.contains(name) {
                    return Err(format!(
                        "nodes[{i}].affordance_origins.{name}: not among the node's affordances {:?}",
                        node.affordances
                    ));
                }
                if !AFFORDANCE_ORIGINS.contains(&origin.as_str()) {
                    return Err(format!(
                        "nodes[{i}].affordance_origins.{name}: expected one of {AFFORDANCE_ORIGINS:?}, found \"{origin}\""
                    ));
                }
            }
            if let Some(obb) = &node.obb {
                if !obb.size_m.iter().all(|v| v.is_finite() && *v >= 0.0) {
                    return Err(format!("nodes[{i}].obb.size_m: expected finite sizes >= 0, found {:?}", obb.size_m));
                }
                let half_turn = std::f32::consts::FRAC_PI_2 + 1e-4;
                if !(obb.yaw_rad.is_finite() && obb.yaw_rad.abs() <= half_turn) {
                    return Err(format!(
                        "nodes[{i}].obb.yaw_rad: expected within [-pi/2, pi/2], found {}",
                        obb.yaw_rad
                    ));
                }
            }
        }
        for (i, edge) in self.edges.iter().enumerate() {
            for (field, id) in [("source", edge.source), ("target", edge.target)] {
                if !ids.contains(&id) {
                    return Err(format!("edges[{i}].{field}: no node with id {id}"));
                }
            }
            if edge.kind != "spatial" && edge.kind != "functional" {
                return Err(format!(
                    "edges[{i}].kind: expected \"spatial\" or \"functional\", found \"{}\"",
                    edge.kind
                ));
            }
        }
        Ok(())
    }

    /// The node with `id`.
    pub fn node(&self, id: u32) -> Option<&NodeJson> {
        self.nodes.iter().find(|n| n.id == id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_names_the_bad_entry() {
        let mut g = GraphJson::new("test");
        let node = NodeJson {
            id: 1,
            label: "cabinet".into(),
            kind: "object".into(),
            parent: None,
            centre_m: [0.0; 3],
            box_min_m: [0.0; 3],
            box_max_m: [1.0; 3],
            obb: None,
            affordances: vec![],
            affordance_origins: BTreeMap::new(),
            confidence: 1.0,
            observation_count: 0,
            seen_keyframes: None,
        };
        g.nodes.push(node.clone());
        g.edges.push(EdgeJson {
            source: 1,
            target: 7,
            kind: "spatial".into(),
            relation: "on".into(),
            confidence: 1.0,
            origin: "geometry".into(),
        });
        assert_eq!(g.check().unwrap_err(), "edges[0].target: no node with id 7");
        g.edges.clear();
        g.nodes.push(node.clone());
        assert_eq!(g.check().unwrap_err(), "nodes[1].id: duplicate id 1");
        g.nodes.truncate(1);
        g.nodes[0].obb = Some(OrientedBoxJson { centre_m: [0.5; 3], size_m: [1.0, -1.0, 1.0], yaw_rad: 0.3 });
        assert_eq!(g.check().unwrap_err(), "nodes[0].obb.size_m: expected finite sizes >= 0, found [1.0, -1.0, 1.0]");
        g.nodes[0].obb = Some(OrientedBoxJson { centre_m: [0.5; 3], size_m: [1.0; 3], yaw_rad: 2.0 });
        assert_eq!(g.check().unwrap_err(), "nodes[0].obb.yaw_rad: expected within [-pi/2, pi/2], found 2");
        g.nodes[0].obb = None;
        g.nodes[0].affordances = vec!["rotate".into()];
        g.nodes[0].affordance_origins = BTreeMap::from([("rotate".into(), "llm".into())]);
        assert_eq!(g.check(), Ok(()));
        g.nodes[0].affordance_origins.insert("unplug".into(), "knowledge".into());
        assert_eq!(
            g.check().unwrap_err(),
            "nodes[0].affordance_origins.unplug: not among the node's affordances [\"rotate\"]"
        );
        g.nodes[0].affordance_origins = BTreeMap::from([("rotate".into(), "oracle".into())]);
        assert_eq!(
            g.check().unwrap_err(),
            "nodes[0].affordance_origins.rotate: expected one of [\"geometry\", \"knowledge\", \"llm\", \"knowledge+llm\", \"ground_truth\"], found \"oracle\""
        );
    }

    #[test]
    fn round_trips_through_json() {
        let g = GraphJson::new("x");
        let text = serde_json::to_string(&g).unwrap();
        assert_eq!(serde_json::from_str::<GraphJson>(&text).unwrap(), g);
        // A node with an oriented box, and one without (ground truth): both read back as written.
        let node = r#"{"id": 1, "label": "counter", "kind": "object", "centre_m": [0, 0, 0],
            "box_min_m": [-1, -1, 0], "box_max_m": [1, 1, 1],
            "obb": {"centre_m": [0, 0, 0.5], "size_m": [2.2, 0.6, 1], "yaw_rad": 0.785}}"#;
        let parsed: NodeJson = serde_json::from_str(node).unwrap();
        assert_eq!(parsed.obb.map(|b| b.yaw_rad), Some(0.785));
        let text = serde_json::to_string(&parsed).unwrap();
        assert_eq!(serde_json::from_str::<NodeJson>(&text).unwrap(), parsed);
        let plain = NodeJson { obb: None, ..parsed };
        assert!(!serde_json::to_string(&plain).unwrap().contains("obb"), "absent, not null");
        assert!(!serde_json::to_string(&plain).unwrap().contains("affordance_origins"), "absent when empty");
        // A published node's affordances with their origins read back as written.
        let node = r#"{"id": 2, "label": "cabinet handle", "kind": "part", "parent": 1, "centre_m": [0, 0, 0],
            "box_min_m": [0, 0, 0], "box_max_m": [0.1, 0.1, 0.1], "affordances": ["hook_pull", "pinch_pull"],
            "affordance_origins": {"hook_pull": "knowledge+llm", "pinch_pull": "llm"}}"#;
        let parsed: NodeJson = serde_json::from_str(node).unwrap();
        assert_eq!(parsed.affordance_origins["pinch_pull"], "llm");
        let text = serde_json::to_string(&parsed).unwrap();
        assert_eq!(serde_json::from_str::<NodeJson>(&text).unwrap(), parsed);
    }
}
