//! The live view's messages, in the `foxglove` crate's generated types (protobuf on the wire):
//! the scene from the recorder's shapes ([`crate::record::scene`]), so a recording and the live
//! view look the same; the camera's transform; the occupancy map as a `foxglove.Grid`; the
//! downscaled images as `foxglove.RawImage`.

use foxglove::bytes::Bytes;
use foxglove::messages::{
    Color, CubePrimitive, FrameTransform, Grid, KeyValuePair, LinePrimitive, PackedElementField, Point3, Pose,
    Quaternion, RawImage, SceneEntity, SceneEntityDeletion, SceneUpdate, TextPrimitive, Timestamp, Vector2, Vector3,
    line_primitive, packed_element_field, scene_entity_deletion,
};
use op3dsg_drivers::pose::Isometry;

use crate::flow::LiveImages;
use crate::graph::SceneGraph;
use crate::occupancy::MapCopy;
use crate::record::scene::{Colour, LABEL_COLOUR, edge_lines, node_shapes};
use crate::world::UpAxis;

/// A stamp as Foxglove's `Timestamp` (seconds past 2106 saturate).
pub fn timestamp(stamp_ns: u64) -> Timestamp {
    let sec = u32::try_from(stamp_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (stamp_ns % 1_000_000_000) as u32)
}

fn colour(c: Colour) -> Option<Color> {
    Some(Color { r: f64::from(c.r), g: f64::from(c.g), b: f64::from(c.b), a: f64::from(c.a) })
}

fn pose([x, y, z]: [f64; 3], rotation: glam::DQuat) -> Option<Pose> {
    let glam::DQuat { x: qx, y: qy, z: qz, w: qw } = rotation;
    Some(Pose { position: Some(Vector3 { x, y, z }), orientation: Some(Quaternion { x: qx, y: qy, z: qz, w: qw }) })
}

/// The `foxglove.SceneUpdate` of `graph`: every entity deleted first (removed nodes go), then a
/// cube and a label per node and the edges as two line lists; every entity in `world_frame`.
pub fn scene_update(graph: &SceneGraph, up_axis: UpAxis, world_frame: &str) -> SceneUpdate {
    let stamp = Some(timestamp(graph.stamp_ns));
    let entity = |id: String, metadata: Vec<KeyValuePair>| SceneEntity {
        timestamp: stamp,
        frame_id: world_frame.to_owned(),
        id,
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

/// The occupancy map as a `foxglove.Grid` in `world_frame`: one `int8` field `occupancy` per
/// cell (-1 unknown, else 0 free to 100 occupied), row-major, row 0 at the origin; the grid's
/// corner on the floor, its rows and columns along the world's horizontal axes.
pub fn occupancy_grid(map: &MapCopy, world_frame: &str) -> Grid {
    let h = &map.header;
    let (corner, rotation) = map.corner_pose();
    let cell = f64::from(h.cell_size_m);
    Grid {
        timestamp: Some(timestamp(h.stamp_ns)),
        frame_id: world_frame.to_owned(),
        pose: pose(corner.to_array(), rotation),
        column_count: h.width_cells,
        cell_size: Some(Vector2 { x: cell, y: cell }),
        row_stride: h.width_cells,
        cell_stride: 1,
        fields: vec![PackedElementField {
            name: "occupancy".to_owned(),
            offset: 0,
            r#type: packed_element_field::NumericType::Int8 as i32,
        }],
        data: Bytes::copy_from_slice(bytemuck::cast_slice(&map.cells)),
    }
}

/// The downscaled colour (`rgb8`) and depth (`16UC1`, the frame's depth units) as
/// `foxglove.RawImage`s in `camera_frame`; `None` for an image the frame did not have.
pub fn raw_images(images: &LiveImages, camera_frame: &str) -> (Option<RawImage>, Option<RawImage>) {
    let image = |encoding: &str, bytes_per_pixel: u32, data: &[u8]| RawImage {
        timestamp: Some(timestamp(images.stamp_ns)),
        frame_id: camera_frame.to_owned(),
        width: images.width,
        height: images.height,
        encoding: encoding.to_owned(),
        step: images.width * bytes_per_pixel,
        data: Bytes::copy_from_slice(data),
    };
    let colour = (!images.rgb.is_empty()).then(|| image("rgb8", 3, &images.rgb));
    let depth = (!images.depth.is_empty()).then(|| image("16UC1", 2, bytemuck::cast_slice(&images.depth)));
    (colour, depth)
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};

    use super::*;
    use crate::graph::{GraphEdge, GraphNode};
    use crate::world::OrientedBox;

    fn node(id: u32, kind: NodeKind, min: [f32; 3], max: [f32; 3]) -> GraphNode {
        GraphNode {
            id,
            kind,
            label: format!("n{id}"),
            centre_m: [0, 1, 2].map(|i| (min[i] + max[i]) / 2.0),
            box_min_m: min,
            box_max_m: max,
            obb: OrientedBox::axis_aligned(min, max, UpAxis::Z),
            ..Default::default()
        }
    }

    /// The live scene carries the recorder's numbers: cube by cube, label by label, line by line.
    #[test]
    fn the_live_scene_is_the_recorded_scene() {
        let graph = SceneGraph {
            version: 9,
            stamp_ns: 3_000_000_007,
            nodes: vec![
                node(1, NodeKind::Object, [0.0, 0.0, 0.0], [1.0, 2.0, 0.5]),
                node(2, NodeKind::Part, [0.9, 0.1, 0.2], [1.0, 0.3, 0.3]),
            ],
            edges: vec![GraphEdge {
                source_id: 2,
                target_id: 1,
                kind: EdgeKind::Functional,
                relation_id: 0,
                confidence: 1.0,
                origin: EdgeOrigin::Knowledge,
            }],
        };
        let live = scene_update(&graph, UpAxis::Z, "map");
        let mut json = Vec::new();
        crate::record::scene::write_scene_update(&graph, UpAxis::Z, "map", &mut json);
        let recorded: serde_json::Value = serde_json::from_slice(&json).unwrap();
        assert_eq!(live.deletions[0].r#type, 1);
        assert_eq!(live.entities.len(), recorded["entities"].as_array().unwrap().len());
        for (e, r) in live.entities.iter().zip(recorded["entities"].as_array().unwrap()) {
            assert_eq!(e.id, r["id"].as_str().unwrap());
            assert_eq!(e.frame_id, "map");
            assert_eq!(e.timestamp.unwrap().nsec(), 7);
            for (c, rc) in e.cubes.iter().zip(r["cubes"].as_array().unwrap()) {
                let p = c.pose.unwrap().position.unwrap();
                assert_eq!([p.x, p.y, p.z], ["x", "y", "z"].map(|k| rc["pose"]["position"][k].as_f64().unwrap()));
                let s = c.size.unwrap();
                assert_eq!([s.x, s.y, s.z], ["x", "y", "z"].map(|k| rc["size"][k].as_f64().unwrap()));
                // The recorder writes the colours as f32.
                assert_eq!(c.color.unwrap().a as f32, rc["color"]["a"].as_f64().unwrap() as f32);
            }
            for (t, rt) in e.texts.iter().zip(r["texts"].as_array().unwrap()) {
                assert_eq!(t.text, rt["text"].as_str().unwrap());
            }
            assert_eq!(e.lines.len(), r["lines"].as_array().unwrap().len());
            for (l, rl) in e.lines.iter().zip(r["lines"].as_array().unwrap()) {
                assert_eq!(l.points.len(), rl["points"].as_array().unwrap().len());
                assert_eq!(l.r#type, 2);
            }
        }
        assert_ne!(live.entities[0].cubes[0].color, live.entities[1].cubes[0].color, "parts apart");
    }

    #[test]
    fn the_camera_transform_is_world_to_camera() {
        let pose =
            Isometry { rotation: glam::DQuat::from_rotation_z(0.5), translation: glam::DVec3::new(1.0, 2.0, 3.0) };
        let t = frame_transform(5, &pose, "map", "camera");
        assert_eq!((t.parent_frame_id.as_str(), t.child_frame_id.as_str()), ("map", "camera"));
        assert_eq!(t.translation.unwrap().z, 3.0);
        assert!((t.rotation.unwrap().w - pose.rotation.w).abs() < 1e-12);
    }
}
