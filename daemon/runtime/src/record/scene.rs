//! `foxglove.SceneUpdate` of a graph version: a cube per node at its gravity-aligned oriented box
//! (`obb`: centre, size along the box's own axes, turned by its yaw about the world's up axis;
//! objects blue-grey and translucent, parts orange), its label as a billboard text above the
//! box's top, and the edges as lines
//! between node centres: spatial edges grey, functional edges green, each kind one entity
//! (`edges/spatial`, `edges/functional`) so Foxglove's topic settings can hide one.
//!
//! [`node_shapes`] and [`edge_lines`] hold these decisions once: the recorder writes them as
//! JSON here, the live view (`crate::live_view`) sends them through the `foxglove` crate.
//!
//! Each update first deletes every entity of the topic (`ALL`), so removed nodes disappear; the
//! scene at any time is exactly the graph version written last.

use serde::Serialize;

use op3dsg_drivers::mcap::messages::Time;
use op3dsg_ipc_types::{EdgeKind, NodeKind};

use crate::graph::{SceneGraph, colours};
use crate::world::UpAxis;

/// Object cubes.
pub const OBJECT_COLOUR: Colour = Colour::rgba(colours::OBJECT);
/// Part cubes.
pub const PART_COLOUR: Colour = Colour::rgba(colours::PART);
/// Spatial edges.
pub const SPATIAL_EDGE_COLOUR: Colour = Colour::rgba(colours::SPATIAL_EDGE);
/// Functional edges.
pub const FUNCTIONAL_EDGE_COLOUR: Colour = Colour::rgba(colours::FUNCTIONAL_EDGE);
const TEXT_COLOUR: Colour = Colour { r: 1.0, g: 1.0, b: 1.0, a: 1.0 };

/// `foxglove.Color`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Colour {
    /// Red, 0..=1.
    pub r: f32,
    /// Green, 0..=1.
    pub g: f32,
    /// Blue, 0..=1.
    pub b: f32,
    /// Opacity, 0..=1.
    pub a: f32,
}

impl Colour {
    const fn rgba([r, g, b, a]: [f32; 4]) -> Self {
        Self { r, g, b, a }
    }
}

#[derive(Debug, Serialize)]
struct Vector3 {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Debug, Serialize)]
struct Quaternion {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(Debug, Serialize)]
struct Pose {
    position: Vector3,
    orientation: Quaternion,
}

impl Pose {
    fn at(position: [f64; 3]) -> Self {
        Self::new(position, glam::DQuat::IDENTITY)
    }

    fn new(position: [f64; 3], rotation: glam::DQuat) -> Self {
        let [x, y, z] = position;
        let glam::DQuat { x: qx, y: qy, z: qz, w: qw } = rotation;
        Self { position: Vector3 { x, y, z }, orientation: Quaternion { x: qx, y: qy, z: qz, w: qw } }
    }
}

#[derive(Debug, Serialize)]
struct Cube {
    pose: Pose,
    size: Vector3,
    color: Colour,
}

#[derive(Debug, Serialize)]
struct Text {
    pose: Pose,
    billboard: bool,
    font_size: f64,
    scale_invariant: bool,
    color: Colour,
    text: String,
}

#[derive(Debug, Serialize)]
struct Line {
    #[serde(rename = "type")]
    kind: u8,
    pose: Pose,
    thickness: f64,
    scale_invariant: bool,
    points: Vec<Vector3>,
    color: Colour,
    colors: Vec<Colour>,
    indices: Vec<u32>,
}

#[derive(Debug, Serialize)]
struct KeyValue {
    key: &'static str,
    value: String,
}

#[derive(Debug, Serialize)]
struct Duration {
    sec: i64,
    nsec: u32,
}

#[derive(Debug, Serialize)]
struct Entity<'a> {
    timestamp: Time,
    frame_id: &'a str,
    id: String,
    lifetime: Duration,
    frame_locked: bool,
    metadata: Vec<KeyValue>,
    arrows: [(); 0],
    cubes: Vec<Cube>,
    spheres: [(); 0],
    cylinders: [(); 0],
    lines: Vec<Line>,
    triangles: [(); 0],
    texts: Vec<Text>,
    models: [(); 0],
}

impl<'a> Entity<'a> {
    fn new(timestamp: Time, frame_id: &'a str, id: String) -> Self {
        Self {
            timestamp,
            frame_id,
            id,
            lifetime: Duration { sec: 0, nsec: 0 },
            frame_locked: false,
            metadata: Vec::new(),
            arrows: [],
            cubes: Vec::new(),
            spheres: [],
            cylinders: [],
            lines: Vec::new(),
            triangles: [],
            texts: Vec::new(),
            models: [],
        }
    }
}

#[derive(Debug, Serialize)]
struct Deletion {
    timestamp: Time,
    #[serde(rename = "type")]
    kind: u8,
    id: &'static str,
}

#[derive(Debug, Serialize)]
struct SceneUpdate<'a> {
    deletions: Vec<Deletion>,
    entities: Vec<Entity<'a>>,
}

fn v3(p: [f32; 3]) -> [f64; 3] {
    p.map(f64::from)
}

/// A node as the viewers draw it (the recorder's scene and the live view alike): a cube on its
/// oriented box and a label above the box's top.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeShape {
    /// The entity's id, `node/<id>`.
    pub entity_id: String,
    /// Whether the node is a part (drawn apart from objects).
    pub part: bool,
    /// The cube's centre, world, metres.
    pub centre_m: [f64; 3],
    /// The cube's rotation: the box's yaw about the world's up axis.
    pub rotation: glam::DQuat,
    /// The cube's size along its own axes, metres.
    pub size_m: [f64; 3],
    /// The cube's colour.
    pub colour: Colour,
    /// Where the label sits: 5 cm above the box's top along up.
    pub label_position_m: [f64; 3],
    /// The label's font size (scale-invariant pixels).
    pub font_size: f64,
    /// The label.
    pub label: String,
    /// `graph_version`, `node_id`, `kind`, `label`, `yaw_rad`, and `affordances` when any.
    pub metadata: Vec<(&'static str, String)>,
}

/// The lines of one kind of edge between node centres.
#[derive(Debug, Clone, PartialEq)]
pub struct EdgeLines {
    /// The entity's id, `edges/spatial` or `edges/functional`.
    pub entity_id: &'static str,
    /// Pairs of points (a line list), world, metres.
    pub points_m: Vec<[f64; 3]>,
    /// The lines' colour.
    pub colour: Colour,
    /// Scale-invariant thickness, pixels.
    pub thickness: f64,
}

/// The labels' colour.
pub const LABEL_COLOUR: Colour = TEXT_COLOUR;

/// The shapes of `graph`'s nodes, in node order; `up_axis` is the world's, about which the
/// boxes' yaw turns.
pub fn node_shapes(graph: &SceneGraph, up_axis: UpAxis) -> impl Iterator<Item = NodeShape> + '_ {
    graph.nodes.iter().map(move |node| {
        let obb = node.display_box(up_axis);
        let (rotation, up) = obb.rotation(up_axis);
        let centre = v3(obb.centre_m);
        let size = v3(obb.size_m).map(|v| v.max(0.0));
        let top = glam::DVec3::from_array(centre) + up * (size[2] / 2.0 + 0.05);
        let part = node.kind == NodeKind::Part;
        let mut metadata = vec![
            ("graph_version", graph.version.to_string()),
            ("node_id", node.id.to_string()),
            ("kind", node.kind.as_str().to_owned()),
            ("label", node.label.clone()),
            ("yaw_rad", obb.yaw_rad.to_string()),
        ];
        if node.affordance_bits != 0 {
            // "hook_pull:knowledge+llm,pinch_pull:llm": each affordance with its origin.
            let affordances: Vec<String> =
                node.affordance_origins().map(|(name, origin)| format!("{name}:{}", origin.as_str())).collect();
            metadata.push(("affordances", affordances.join(",")));
        }
        NodeShape {
            entity_id: format!("node/{}", node.id),
            part,
            centre_m: centre,
            rotation,
            size_m: size,
            colour: if part { PART_COLOUR } else { OBJECT_COLOUR },
            label_position_m: top.to_array(),
            font_size: if part { 12.0 } else { 16.0 },
            label: node.label.clone(),
            metadata,
        }
    })
}

/// The edges of `graph` as two line lists between node centres: spatial (part-of among them)
/// grey, functional green; an edge whose end is not in the graph is left out.
pub fn edge_lines(graph: &SceneGraph) -> [EdgeLines; 2] {
    let centre_of = |id: u32| graph.nodes.binary_search_by_key(&id, |n| n.id).ok().map(|i| v3(graph.nodes[i].centre_m));
    [
        (EdgeKind::Spatial, "edges/spatial", SPATIAL_EDGE_COLOUR, 1.5),
        (EdgeKind::Functional, "edges/functional", FUNCTIONAL_EDGE_COLOUR, 3.0),
    ]
    .map(|(kind, entity_id, colour, thickness)| {
        let mut points_m = Vec::new();
        for edge in graph.edges.iter().filter(|e| e.kind == kind) {
            if let (Some(a), Some(b)) = (centre_of(edge.source_id), centre_of(edge.target_id)) {
                points_m.push(a);
                points_m.push(b);
            }
        }
        EdgeLines { entity_id, points_m, colour, thickness }
    })
}

fn vector([x, y, z]: [f64; 3]) -> Vector3 {
    Vector3 { x, y, z }
}

/// Writes the `foxglove.SceneUpdate` JSON of `graph` into `out` (cleared first); `up_axis` is the
/// world's (`world.up_axis`), about which the boxes' yaw turns, and every entity is in the frame
/// `world_frame` (`world.frame_id`).
pub fn write_scene_update(graph: &SceneGraph, up_axis: UpAxis, world_frame: &str, out: &mut Vec<u8>) {
    out.clear();
    let timestamp = Time::from_ns(graph.stamp_ns);
    let mut entities = Vec::with_capacity(graph.nodes.len() + 2);
    for shape in node_shapes(graph, up_axis) {
        let mut entity = Entity::new(timestamp, world_frame, shape.entity_id);
        entity.metadata = shape.metadata.into_iter().map(|(key, value)| KeyValue { key, value }).collect();
        entity.cubes.push(Cube {
            pose: Pose::new(shape.centre_m, shape.rotation),
            size: vector(shape.size_m),
            color: shape.colour,
        });
        entity.texts.push(Text {
            pose: Pose::at(shape.label_position_m),
            billboard: true,
            font_size: shape.font_size,
            scale_invariant: true,
            color: TEXT_COLOUR,
            text: shape.label,
        });
        entities.push(entity);
    }
    for lines in edge_lines(graph) {
        let mut entity = Entity::new(timestamp, world_frame, lines.entity_id.to_owned());
        entity.metadata = vec![KeyValue { key: "graph_version", value: graph.version.to_string() }];
        if !lines.points_m.is_empty() {
            entity.lines.push(Line {
                kind: 2, // LINE_LIST
                pose: Pose::at([0.0; 3]),
                thickness: lines.thickness,
                scale_invariant: true,
                points: lines.points_m.into_iter().map(vector).collect(),
                color: lines.colour,
                colors: Vec::new(),
                indices: Vec::new(),
            });
        }
        entities.push(entity);
    }
    let update = SceneUpdate { deletions: vec![Deletion { timestamp, kind: 1, id: "" }], entities };
    // Serialising plain structs into a Vec cannot fail.
    let _ = serde_json::to_writer(out, &update);
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::EdgeOrigin;

    use super::*;
    use crate::graph::{GraphEdge, GraphNode};
    use crate::world::OrientedBox;

    fn node(id: u32, kind: NodeKind, min: [f32; 3], max: [f32; 3]) -> GraphNode {
        GraphNode {
            id,
            kind,
            parent_id: None,
            label: format!("n{id}"),
            confidence: 1.0,
            centre_m: [0, 1, 2].map(|i| (min[i] + max[i]) / 2.0),
            box_min_m: min,
            box_max_m: max,
            observation_count: 1,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            obb: OrientedBox::axis_aligned(min, max, UpAxis::Z),
            ..Default::default()
        }
    }

    #[test]
    fn cubes_sit_on_the_boxes_and_edges_split_by_kind() {
        let graph = SceneGraph {
            version: 7,
            stamp_ns: 2_000_000_003,
            nodes: vec![
                node(1, NodeKind::Object, [0.0, 0.0, 0.0], [1.0, 2.0, 0.5]),
                GraphNode {
                    affordance_bits: 0b1_1000,
                    affordance_knowledge_bits: 0b1000,
                    affordance_llm_bits: 0b1_1000,
                    ..node(2, NodeKind::Part, [0.9, 0.1, 0.2], [1.0, 0.3, 0.3])
                },
            ],
            edges: vec![
                GraphEdge {
                    source_id: 2,
                    target_id: 1,
                    kind: EdgeKind::Spatial,
                    relation_id: 0,
                    confidence: 1.0,
                    origin: EdgeOrigin::Geometry,
                },
                GraphEdge {
                    source_id: 2,
                    target_id: 1,
                    kind: EdgeKind::Functional,
                    relation_id: 0,
                    confidence: 1.0,
                    origin: EdgeOrigin::Knowledge,
                },
            ],
        };
        let mut out = Vec::new();
        write_scene_update(&graph, UpAxis::Z, "map", &mut out);
        let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(v["deletions"][0]["type"], 1);
        let entities = v["entities"].as_array().unwrap();
        assert_eq!(entities.len(), 4);
        let cube = &entities[0]["cubes"][0];
        assert_eq!(cube["pose"]["position"]["y"], 1.0);
        assert_eq!(cube["size"]["z"], 0.5);
        assert_ne!(entities[0]["cubes"][0]["color"], entities[1]["cubes"][0]["color"], "parts apart from objects");
        assert_eq!(entities[1]["texts"][0]["text"], "n2");
        let metadata = |i: usize, key: &str| {
            entities[i]["metadata"].as_array().unwrap().iter().find(|kv| kv["key"] == key).map(|kv| kv["value"].clone())
        };
        assert_eq!(metadata(1, "affordances"), Some("hook_pull:knowledge+llm,pinch_pull:llm".into()));
        assert_eq!(metadata(0, "affordances"), None, "no affordances, no entry");
        assert_eq!(entities[2]["id"], "edges/spatial");
        assert_eq!(entities[2]["lines"][0]["points"].as_array().unwrap().len(), 2);
        assert_ne!(entities[2]["lines"][0]["color"], entities[3]["lines"][0]["color"]);
        assert_eq!(entities[0]["timestamp"]["nsec"], 3);
        assert!(entities.iter().all(|e| e["frame_id"] == "map"), "every entity in the configured world frame");
    }

    fn cube_axes(cube: &serde_json::Value) -> (glam::DVec3, [glam::DVec3; 3]) {
        let p = &cube["pose"]["position"];
        let q = &cube["pose"]["orientation"];
        let f = |v: &serde_json::Value| v.as_f64().unwrap();
        let rotation = glam::DQuat::from_xyzw(f(&q["x"]), f(&q["y"]), f(&q["z"]), f(&q["w"]));
        let centre = glam::DVec3::new(f(&p["x"]), f(&p["y"]), f(&p["z"]));
        (centre, [glam::DVec3::X, glam::DVec3::Y, glam::DVec3::Z].map(|a| rotation * a))
    }

    #[test]
    fn cubes_are_the_oriented_boxes_turned_about_the_world_up_axis() {
        let yaw = 0.5f32;
        for up_axis in [UpAxis::Z, UpAxis::Y, UpAxis::NegY] {
            let mut n = node(3, NodeKind::Object, [0.0; 3], [2.0, 2.0, 2.0]);
            n.obb = OrientedBox { centre_m: [1.0, 1.5, 0.5], size_m: [1.2, 0.4, 0.9], yaw_rad: yaw };
            let graph = SceneGraph { version: 1, stamp_ns: 0, nodes: vec![n.clone()], edges: vec![] };
            let mut out = Vec::new();
            write_scene_update(&graph, up_axis, "world", &mut out);
            let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
            let cube = &v["entities"][0]["cubes"][0];
            assert_eq!(cube["size"]["x"], f64::from(1.2f32));
            let (centre, axes) = cube_axes(cube);
            assert_eq!(centre, glam::DVec3::from_array(n.obb.centre_m.map(f64::from)));
            // The cube's corners are the box's corners.
            let half = glam::DVec3::new(0.6, 0.2, 0.45);
            let corners = n.obb.corners(up_axis);
            let signs = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
            for (level, z) in [-1.0f64, 1.0].into_iter().enumerate() {
                for (i, (a, b)) in signs.iter().enumerate() {
                    let got = centre + axes[0] * (a * half.x) + axes[1] * (b * half.y) + axes[2] * (z * half.z);
                    let want = glam::DVec3::from_array(corners[level * 4 + i].map(f64::from));
                    assert!(got.distance(want) < 1e-5, "{up_axis:?} corner {}: {got} vs {want}", level * 4 + i);
                }
            }
            // The label sits above the box's top along up.
            let text = &v["entities"][0]["texts"][0]["pose"]["position"];
            let text =
                glam::DVec3::new(text["x"].as_f64().unwrap(), text["y"].as_f64().unwrap(), text["z"].as_f64().unwrap());
            assert!((text - centre).dot(axes[2]) > 0.45, "{up_axis:?}: label above the top");
        }
    }

    #[test]
    fn a_node_without_an_oriented_box_gets_its_axis_aligned_one() {
        let mut n = node(4, NodeKind::Part, [1.0, 2.0, 3.0], [1.5, 2.5, 4.0]);
        n.obb = OrientedBox::default();
        let graph = SceneGraph { version: 1, stamp_ns: 0, nodes: vec![n], edges: vec![] };
        let mut out = Vec::new();
        write_scene_update(&graph, UpAxis::Z, "world", &mut out);
        let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
        let cube = &v["entities"][0]["cubes"][0];
        assert_eq!(cube["pose"]["position"]["z"], 3.5);
        assert_eq!(cube["size"]["z"], 1.0);
        assert_eq!(cube["pose"]["orientation"]["w"], 1.0);
    }
}
