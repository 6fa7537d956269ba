//! `foxglove.SceneUpdate` of a graph version: a cube per node at its gravity-aligned oriented box
//! (`obb`: centre, size along the box's own axes, turned by its yaw about the world's up axis;
//! objects blue-grey and translucent, parts orange), its label as a billboard text above the
//! box's top, and the edges as lines
//! between node centres: spatial edges grey, functional edges green, each kind one entity
//! (`edges/spatial`, `edges/functional`) so Foxglove's topic settings can hide one.
//!
//! [`node_shapes`] and [`edge_lines`] hold these decisions once, and [`scene_update`] makes them
//! the `foxglove` crate's generated type: the recorder writes it (protobuf), the live view
//! (`crate::live_view`) sends the same message.
//!
//! Each update first deletes every entity of the topic (`ALL`), so removed nodes disappear; the
//! scene at any time is exactly the graph version written last.

use foxglove::messages::{
    Color, CubePrimitive, Duration, FrameTransform, KeyValuePair, LinePrimitive, Point3, Pose, Quaternion, SceneEntity,
    SceneEntityDeletion, SceneUpdate, TextPrimitive, Vector3, line_primitive, scene_entity_deletion,
};
use op3dsg_drivers::mcap::messages::timestamp;
use op3dsg_drivers::pose::Isometry;
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
#[derive(Debug, Clone, Copy, PartialEq)]
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

fn colour(c: Colour) -> Option<Color> {
    Some(Color { r: f64::from(c.r), g: f64::from(c.g), b: f64::from(c.b), a: f64::from(c.a) })
}

/// A `foxglove.Pose` at `position` turned by `rotation`.
pub fn pose([x, y, z]: [f64; 3], rotation: glam::DQuat) -> Option<Pose> {
    let glam::DQuat { x: qx, y: qy, z: qz, w: qw } = rotation;
    Some(Pose { position: Some(Vector3 { x, y, z }), orientation: Some(Quaternion { x: qx, y: qy, z: qz, w: qw }) })
}

/// The `foxglove.SceneUpdate` of `graph`: every entity deleted first (removed nodes go), then a
/// cube and a label per node and the edges as two line lists; `up_axis` is the world's
/// (`world.up_axis`), about which the boxes' yaw turns, and every entity is in the frame
/// `world_frame` (`world.frame_id`).
pub fn scene_update(graph: &SceneGraph, up_axis: UpAxis, world_frame: &str) -> SceneUpdate {
    let stamp = Some(timestamp(graph.stamp_ns));
    let entity = |id: String, metadata: Vec<KeyValuePair>| SceneEntity {
        timestamp: stamp,
        frame_id: world_frame.to_owned(),
        id,
        // Zero: the entity stays until the next update deletes it (said explicitly, as
        // Foxglove's schema requires the field).
        lifetime: Some(Duration::default()),
        metadata,
        ..SceneEntity::default()
    };
    let mut entities = Vec::with_capacity(graph.nodes.len() + 2);
    for shape in node_shapes(graph, up_axis) {
        let metadata =
            shape.metadata.into_iter().map(|(key, value)| KeyValuePair { key: key.to_owned(), value }).collect();
        let mut e = entity(shape.entity_id, metadata);
        let [x, y, z] = shape.size_m;
        e.cubes.push(CubePrimitive {
            pose: pose(shape.centre_m, shape.rotation),
            size: Some(Vector3 { x, y, z }),
            color: colour(shape.colour),
        });
        e.texts.push(TextPrimitive {
            pose: pose(shape.label_position_m, glam::DQuat::IDENTITY),
            billboard: true,
            font_size: shape.font_size,
            scale_invariant: true,
            color: colour(LABEL_COLOUR),
            text: shape.label,
        });
        entities.push(e);
    }
    for lines in edge_lines(graph) {
        let version = KeyValuePair { key: "graph_version".to_owned(), value: graph.version.to_string() };
        let mut e = entity(lines.entity_id.to_owned(), vec![version]);
        if !lines.points_m.is_empty() {
            e.lines.push(LinePrimitive {
                r#type: line_primitive::Type::LineList as i32,
                pose: pose([0.0; 3], glam::DQuat::IDENTITY),
                thickness: lines.thickness,
                scale_invariant: true,
                points: lines.points_m.into_iter().map(|[x, y, z]| Point3 { x, y, z }).collect(),
                color: colour(lines.colour),
                ..LinePrimitive::default()
            });
        }
        entities.push(e);
    }
    let all =
        SceneEntityDeletion { timestamp: stamp, r#type: scene_entity_deletion::Type::All as i32, id: String::new() };
    SceneUpdate { deletions: vec![all], entities }
}

/// `world_frame → camera_frame` at a keyframe.
pub fn frame_transform(
    stamp_ns: u64,
    world_from_camera: &Isometry,
    world_frame: &str,
    camera_frame: &str,
) -> FrameTransform {
    let t = world_from_camera.translation;
    let q = world_from_camera.rotation;
    FrameTransform {
        timestamp: Some(timestamp(stamp_ns)),
        parent_frame_id: world_frame.to_owned(),
        child_frame_id: camera_frame.to_owned(),
        translation: Some(Vector3 { x: t.x, y: t.y, z: t.z }),
        rotation: Some(Quaternion { x: q.x, y: q.y, z: q.z, w: q.w }),
    }
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
            first_seen_stamp_ns: 0,
            missing: false,
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
        let update = scene_update(&graph, UpAxis::Z, "map");
        assert_eq!(update.deletions[0].r#type, scene_entity_deletion::Type::All as i32);
        let entities = &update.entities;
        assert_eq!(entities.len(), 4);
        let cube = &entities[0].cubes[0];
        assert_eq!(cube.pose.unwrap().position.unwrap().y, 1.0);
        assert_eq!(cube.size.unwrap().z, 0.5);
        assert_ne!(entities[0].cubes[0].color, entities[1].cubes[0].color, "parts apart from objects");
        assert_eq!(entities[1].texts[0].text, "n2");
        let metadata =
            |i: usize, key: &str| entities[i].metadata.iter().find(|kv| kv.key == key).map(|kv| kv.value.as_str());
        assert_eq!(metadata(1, "affordances"), Some("hook_pull:knowledge+llm,pinch_pull:llm"));
        assert_eq!(metadata(0, "affordances"), None, "no affordances, no entry");
        assert_eq!(entities[2].id, "edges/spatial");
        assert_eq!(entities[2].lines[0].points.len(), 2);
        assert_eq!(entities[2].lines[0].r#type, line_primitive::Type::LineList as i32);
        assert_ne!(entities[2].lines[0].color, entities[3].lines[0].color);
        assert_eq!(entities[0].timestamp.unwrap().nsec(), 3);
        assert!(entities.iter().all(|e| e.frame_id == "map"), "every entity in the configured world frame");
    }

    fn cube_axes(cube: &CubePrimitive) -> (glam::DVec3, [glam::DVec3; 3]) {
        let pose = cube.pose.unwrap();
        let (p, q) = (pose.position.unwrap(), pose.orientation.unwrap());
        let rotation = glam::DQuat::from_xyzw(q.x, q.y, q.z, q.w);
        let centre = glam::DVec3::new(p.x, p.y, p.z);
        (centre, [glam::DVec3::X, glam::DVec3::Y, glam::DVec3::Z].map(|a| rotation * a))
    }

    #[test]
    fn cubes_are_the_oriented_boxes_turned_about_the_world_up_axis() {
        let yaw = 0.5f32;
        for up_axis in [UpAxis::Z, UpAxis::Y, UpAxis::NegY] {
            let mut n = node(3, NodeKind::Object, [0.0; 3], [2.0, 2.0, 2.0]);
            n.obb = OrientedBox { centre_m: [1.0, 1.5, 0.5], size_m: [1.2, 0.4, 0.9], yaw_rad: yaw };
            let graph = SceneGraph { version: 1, stamp_ns: 0, nodes: vec![n.clone()], edges: vec![] };
            let update = scene_update(&graph, up_axis, "world");
            let cube = &update.entities[0].cubes[0];
            assert_eq!(cube.size.unwrap().x, f64::from(1.2f32));
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
            let text = update.entities[0].texts[0].pose.unwrap().position.unwrap();
            let text = glam::DVec3::new(text.x, text.y, text.z);
            assert!((text - centre).dot(axes[2]) > 0.45, "{up_axis:?}: label above the top");
        }
    }

    #[test]
    fn a_node_without_an_oriented_box_gets_its_axis_aligned_one() {
        let mut n = node(4, NodeKind::Part, [1.0, 2.0, 3.0], [1.5, 2.5, 4.0]);
        n.obb = OrientedBox::default();
        let graph = SceneGraph { version: 1, stamp_ns: 0, nodes: vec![n], edges: vec![] };
        let update = scene_update(&graph, UpAxis::Z, "world");
        let cube = &update.entities[0].cubes[0];
        assert_eq!(cube.pose.unwrap().position.unwrap().z, 3.5);
        assert_eq!(cube.size.unwrap().z, 1.0);
        assert_eq!(cube.pose.unwrap().orientation.unwrap().w, 1.0);
    }

    #[test]
    fn the_camera_transform_is_world_to_camera() {
        let pose =
            Isometry { rotation: glam::DQuat::from_rotation_z(0.5), translation: glam::DVec3::new(1.0, 2.0, 3.0) };
        let t = frame_transform(5, &pose, "map", "camera");
        assert_eq!((t.parent_frame_id.as_str(), t.child_frame_id.as_str()), ("map", "camera"));
        assert_eq!(t.translation.unwrap().z, 3.0);
        assert_eq!(t.rotation.unwrap().w, pose.rotation.w, "the pose's own numbers");
    }
}
