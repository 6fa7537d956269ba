//! The ROS messages of `[ros2.out]`: the graph as a `visualization_msgs/MarkerArray` for RViz and
//! as JSON in a `std_msgs/String`, the occupancy map as a `nav_msgs/OccupancyGrid`.
//!
//! Markers, all in the world frame at the graph's stamp:
//!
//! | namespace | id | marker |
//! | --- | --- | --- |
//! | `objects` | node id | `CUBE` on the object's oriented box, blue-grey, translucent |
//! | `parts` | node id | `CUBE` on the part's box, orange |
//! | `labels` | node id | `TEXT_VIEW_FACING` above the box's top: the label |
//! | `edges` | 0 | `LINE_LIST` part → its object (part-of), orange |
//! | `edges` | 1 | `LINE_LIST` along each functional edge, green |
//!
//! The first array of a run starts with `DELETEALL` (markers of an earlier run go); after that a
//! node that left the graph gets `DELETE` for its box and label, and an edge list with no line
//! left gets `DELETE`, so RViz shows exactly the graph version sent last.

use std::collections::BTreeSet;

use op3dsg_ipc_types::{EdgeKind, NodeKind};
use op3dsg_ros2::msg::builtin_interfaces::Time;
use op3dsg_ros2::msg::geometry_msgs::{Point, Pose, Quaternion, Vector3};
use op3dsg_ros2::msg::nav_msgs::{MapMetaData, OccupancyGrid};
use op3dsg_ros2::msg::std_msgs::{self, ColorRGBA, Header};
use op3dsg_ros2::msg::visualization_msgs::{Marker, MarkerArray};

use crate::graph::{SceneGraph, colours};
use crate::occupancy::MapCopy;
use crate::world::UpAxis;

const fn rgba([r, g, b, a]: [f32; 4]) -> ColorRGBA {
    ColorRGBA { r, g, b, a }
}

/// Object boxes (the recorder's Foxglove colours, so both viewers look alike).
const OBJECT_COLOUR: ColorRGBA = rgba(colours::OBJECT);
/// Part boxes.
const PART_COLOUR: ColorRGBA = rgba(colours::PART);
/// Part-of lines (the Foxglove scene draws none: parts sit on their objects there).
const PART_OF_COLOUR: ColorRGBA = rgba([1.0, 0.7, 0.3, 0.9]);
/// Functional edges.
const FUNCTIONAL_COLOUR: ColorRGBA = rgba(colours::FUNCTIONAL_EDGE);
const TEXT_COLOUR: ColorRGBA = rgba([1.0; 4]);
/// Letter heights, metres.
const OBJECT_TEXT_M: f64 = 0.08;
const PART_TEXT_M: f64 = 0.05;
/// Line widths, metres.
const PART_OF_WIDTH_M: f64 = 0.008;
const FUNCTIONAL_WIDTH_M: f64 = 0.015;

/// Marker namespaces.
pub const NS_OBJECTS: &str = "objects";
/// Part boxes.
pub const NS_PARTS: &str = "parts";
/// Labels.
pub const NS_LABELS: &str = "labels";
/// Edge lists.
pub const NS_EDGES: &str = "edges";

/// What was drawn by the arrays sent so far: the boxes and labels to delete when their node
/// leaves, the edge lists to delete when they empty.
#[derive(Debug, Default)]
pub struct MarkerState {
    sent_any: bool,
    /// (namespace, id) of the boxes and labels shown.
    shown: BTreeSet<(&'static str, i32)>,
    /// Edge lists shown (ids 0 and 1).
    edges_shown: [bool; 2],
}

fn point(p: [f64; 3]) -> Point {
    Point { x: p[0], y: p[1], z: p[2] }
}

fn pose(position: [f64; 3], rotation: glam::DQuat) -> Pose {
    let glam::DQuat { x, y, z, w } = rotation;
    Pose { position: point(position), orientation: Quaternion { x, y, z, w } }
}

/// A marker of `ns` and `id` in `frame` at `stamp`, identity pose.
fn marker(header: &Header, ns: &str, id: i32, kind: i32, action: i32) -> Marker {
    Marker {
        header: header.clone(),
        ns: ns.to_owned(),
        id,
        kind,
        action,
        pose: pose([0.0; 3], glam::DQuat::IDENTITY),
        scale: Vector3 { x: 1.0, y: 1.0, z: 1.0 },
        ..Marker::default()
    }
}

/// Marker ids are `int32`; node ids above `i32::MAX` wrap (none in practice: ids count up).
fn marker_id(node_id: u32) -> i32 {
    node_id as i32
}

/// The `MarkerArray` of `graph` in `frame` (module docs); `state` remembers what is shown.
pub fn marker_array(graph: &SceneGraph, up_axis: UpAxis, frame: &str, state: &mut MarkerState) -> MarkerArray {
    let header = Header { stamp: Time::from_ns(graph.stamp_ns), frame_id: frame.to_owned() };
    let mut markers = Vec::with_capacity(graph.nodes.len() * 2 + 3);
    if !state.sent_any {
        markers.push(marker(&header, "", 0, Marker::CUBE, Marker::DELETEALL));
        state.sent_any = true;
    }
    let mut shown = BTreeSet::new();
    for node in &graph.nodes {
        let obb = node.display_box(up_axis);
        let (rotation, up) = obb.rotation(up_axis);
        let centre = obb.centre_m.map(f64::from);
        let [sx, sy, sz] = obb.size_m.map(|v| f64::from(v).max(0.001));
        let part = node.kind == NodeKind::Part;
        let ns = if part { NS_PARTS } else { NS_OBJECTS };
        let id = marker_id(node.id);
        let mut cube = marker(&header, ns, id, Marker::CUBE, Marker::ADD);
        cube.pose = pose(centre, rotation);
        cube.scale = Vector3 { x: sx, y: sy, z: sz };
        cube.color = if part { PART_COLOUR } else { OBJECT_COLOUR };
        markers.push(cube);
        let height = if part { PART_TEXT_M } else { OBJECT_TEXT_M };
        let top = glam::DVec3::from_array(centre) + up * (sz / 2.0 + height);
        let mut label = marker(&header, NS_LABELS, id, Marker::TEXT_VIEW_FACING, Marker::ADD);
        label.pose = pose(top.to_array(), glam::DQuat::IDENTITY);
        label.scale = Vector3 { x: 0.0, y: 0.0, z: height };
        label.color = TEXT_COLOUR;
        label.text = node.label.clone();
        markers.push(label);
        shown.insert((ns, id));
        shown.insert((NS_LABELS, id));
    }
    for &(ns, id) in state.shown.difference(&shown) {
        markers.push(marker(&header, ns, id, Marker::CUBE, Marker::DELETE));
    }
    state.shown = shown;
    let centre_of = |id: u32| {
        graph.nodes.binary_search_by_key(&id, |n| n.id).ok().map(|i| point(graph.nodes[i].centre_m.map(f64::from)))
    };
    let part_of: Vec<Point> = graph
        .nodes
        .iter()
        .filter(|n| n.kind == NodeKind::Part)
        .filter_map(|n| Some([centre_of(n.id)?, centre_of(n.parent_id?)?]))
        .flatten()
        .collect();
    let functional: Vec<Point> = graph
        .edges
        .iter()
        .filter(|e| e.kind == EdgeKind::Functional)
        .filter_map(|e| Some([centre_of(e.source_id)?, centre_of(e.target_id)?]))
        .flatten()
        .collect();
    for (id, points, colour, width) in
        [(0, part_of, PART_OF_COLOUR, PART_OF_WIDTH_M), (1, functional, FUNCTIONAL_COLOUR, FUNCTIONAL_WIDTH_M)]
    {
        let slot = &mut state.edges_shown[id as usize];
        if points.is_empty() {
            if std::mem::take(slot) {
                markers.push(marker(&header, NS_EDGES, id, Marker::LINE_LIST, Marker::DELETE));
            }
            continue;
        }
        let mut lines = marker(&header, NS_EDGES, id, Marker::LINE_LIST, Marker::ADD);
        lines.scale = Vector3 { x: width, y: 0.0, z: 0.0 };
        lines.color = colour;
        lines.points = points;
        markers.push(lines);
        *slot = true;
    }
    MarkerArray { markers }
}

/// The map as a `nav_msgs/OccupancyGrid` in `frame`: the same cells (-1 unknown, else 0 free to
/// 100 occupied, row-major, row 0 at the origin), the origin at the grid's corner on the floor,
/// turned so the grid's rows and columns run along the world's horizontal axes.
pub fn occupancy_grid(map: &MapCopy, frame: &str) -> OccupancyGrid {
    let h = &map.header;
    let (corner, rotation) = map.corner_pose();
    let stamp = Time::from_ns(h.stamp_ns);
    OccupancyGrid {
        header: Header { stamp, frame_id: frame.to_owned() },
        info: MapMetaData {
            map_load_time: stamp,
            resolution: h.cell_size_m,
            width: h.width_cells,
            height: h.height_cells,
            origin: pose(corner.to_array(), rotation),
        },
        data: map.cells.clone(),
    }
}

/// The graph as JSON (`op3dsg dump --json`'s form) in a `std_msgs/String`.
pub fn graph_json(graph: &SceneGraph, source: &str) -> std_msgs::String {
    std_msgs::String { data: serde_json::to_string(&graph.to_json(source)).unwrap_or_default() }
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::EdgeOrigin;

    use super::*;
    use crate::graph::{GraphEdge, GraphNode};
    use crate::world::OrientedBox;

    fn node(id: u32, kind: NodeKind, parent_id: Option<u32>, min: [f32; 3], max: [f32; 3]) -> GraphNode {
        GraphNode {
            id,
            kind,
            parent_id,
            label: format!("n{id}"),
            confidence: 1.0,
            centre_m: [0, 1, 2].map(|i| (min[i] + max[i]) / 2.0),
            box_min_m: min,
            box_max_m: max,
            observation_count: 1,
            obb: OrientedBox::axis_aligned(min, max, UpAxis::Z),
            ..Default::default()
        }
    }

    fn graph(nodes: Vec<GraphNode>, functional: bool) -> SceneGraph {
        let edges = if functional {
            vec![GraphEdge {
                source_id: 2,
                target_id: 1,
                kind: EdgeKind::Functional,
                relation_id: 0,
                confidence: 1.0,
                origin: EdgeOrigin::Knowledge,
            }]
        } else {
            Vec::new()
        };
        SceneGraph { version: 3, stamp_ns: 5_000_000_007, nodes, edges }
    }

    fn find<'a>(array: &'a MarkerArray, ns: &str, id: i32) -> Vec<&'a Marker> {
        array.markers.iter().filter(|m| m.ns == ns && m.id == id).collect()
    }

    #[test]
    fn boxes_labels_and_lines_then_deletions_of_what_left() {
        let cabinet = node(1, NodeKind::Object, None, [0.0, 0.0, 0.0], [1.0, 0.5, 0.8]);
        let handle = node(2, NodeKind::Part, Some(1), [0.9, 0.2, 0.5], [1.0, 0.3, 0.6]);
        let mut state = MarkerState::default();
        let first = marker_array(&graph(vec![cabinet.clone(), handle], true), UpAxis::Z, "map", &mut state);
        assert_eq!(first.markers[0].action, Marker::DELETEALL, "a run starts clean");
        let cube = find(&first, NS_OBJECTS, 1)[0];
        assert_eq!((cube.kind, cube.action), (Marker::CUBE, Marker::ADD));
        let p = cube.pose.position;
        assert!((p.x - 0.5).abs() < 1e-6 && (p.y - 0.25).abs() < 1e-6 && (p.z - 0.4).abs() < 1e-6, "{p:?}");
        assert!((cube.scale.x - 1.0).abs() < 1e-6 && (cube.scale.y - 0.5).abs() < 1e-6);
        assert_eq!(cube.header.frame_id, "map");
        assert_eq!(cube.header.stamp, Time::from_ns(5_000_000_007));
        let part = find(&first, NS_PARTS, 2)[0];
        assert_eq!(part.color, PART_COLOUR, "parts coloured apart");
        let label = find(&first, NS_LABELS, 2)[0];
        assert_eq!((label.kind, label.text.as_str()), (Marker::TEXT_VIEW_FACING, "n2"));
        assert!(label.pose.position.z > 0.6, "above the part's top");
        let part_of = find(&first, NS_EDGES, 0)[0];
        assert_eq!((part_of.kind, part_of.points.len()), (Marker::LINE_LIST, 2));
        assert_eq!(find(&first, NS_EDGES, 1)[0].points.len(), 2, "the functional edge");

        // The handle leaves, and with it both lines.
        let second = marker_array(&graph(vec![cabinet], false), UpAxis::Z, "map", &mut state);
        assert!(second.markers.iter().all(|m| m.action != Marker::DELETEALL));
        for (ns, id) in [(NS_PARTS, 2), (NS_LABELS, 2), (NS_EDGES, 0), (NS_EDGES, 1)] {
            let found = find(&second, ns, id);
            assert_eq!(found.len(), 1, "{ns}/{id}");
            assert_eq!(found[0].action, Marker::DELETE, "{ns}/{id}");
        }
        assert_eq!(find(&second, NS_OBJECTS, 1)[0].action, Marker::ADD);
        // Nothing more to delete the next time.
        let third = marker_array(&graph(vec![], false), UpAxis::Z, "map", &mut state);
        let deleted: Vec<_> = third.markers.iter().map(|m| (m.ns.as_str(), m.id, m.action)).collect();
        assert_eq!(deleted, vec![(NS_LABELS, 1, Marker::DELETE), (NS_OBJECTS, 1, Marker::DELETE)]);
    }

    #[test]
    fn the_grid_lies_on_the_floor_along_the_world_axes() {
        let header = op3dsg_ipc_types::OccupancyHeader {
            width_cells: 3,
            height_cells: 2,
            cell_size_m: 0.05,
            origin_x_m: -1.0,
            origin_y_m: 2.0,
            floor_height_m: 0.1,
            up_axis: 1,
            stamp_ns: 42,
            ..Default::default()
        };
        let map = MapCopy {
            version: 1,
            geometry: crate::occupancy::GridGeometry { width: 3, height: 2, cell_size_m: 0.05, origin_m: [-1.0, 2.0] },
            cells: vec![-1, 0, 100, 50, 0, -1],
            robot: None,
            header,
        };
        let grid = occupancy_grid(&map, "map");
        assert_eq!((grid.info.width, grid.info.height, grid.info.resolution), (3, 2, 0.05));
        assert_eq!(grid.data, map.cells);
        // +y up: the plane's first axis is world z, the second world x, the floor at y = 0.1.
        let o = grid.info.origin;
        assert!((o.position.z + 1.0).abs() < 1e-6 && (o.position.x - 2.0).abs() < 1e-6, "{o:?}");
        assert!((o.position.y - 0.1).abs() < 1e-6, "{o:?}");
        let q = glam::DQuat::from_xyzw(o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w);
        assert!((q * glam::DVec3::X - glam::DVec3::Z).length() < 1e-9, "grid x along world z");
        assert!((q * glam::DVec3::Y - glam::DVec3::X).length() < 1e-9, "grid y along world x");
        assert_eq!(grid.header.stamp, Time::from_ns(42));
    }
}
