//! The detections of a keyframe as `foxglove.ImageAnnotations` (a box outline per detection,
//! objects blue-grey and parts orange as in the scene, and a label with the detector's score),
//! and the nodes' points as `foxglove.PointCloud`.

use foxglove::bytes::Bytes;
use foxglove::messages::{
    Color, ImageAnnotations, KeyValuePair, PackedElementField, Point2, PointCloud, PointsAnnotation, TextAnnotation,
    packed_element_field::NumericType, points_annotation,
};
use op3dsg_drivers::mcap::messages::timestamp;
use op3dsg_ipc_types::NodeKind;

use super::scene::{Colour, OBJECT_COLOUR, PART_COLOUR, pose};
use crate::graph::NodePoint;

/// A detection as recorded: its box in the keyframe's image.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct DetectionBox {
    pub(crate) label: String,
    pub(crate) kind: NodeKind,
    pub(crate) score: f32,
    /// Left, top (inclusive), width, height, pixels.
    pub(crate) x0: u32,
    pub(crate) y0: u32,
    pub(crate) width: u32,
    pub(crate) height: u32,
}

fn colour(c: Colour, a: f32) -> Option<Color> {
    Some(Color { r: f64::from(c.r), g: f64::from(c.g), b: f64::from(c.b), a: f64::from(a) })
}

fn key_value(key: &str, value: String) -> KeyValuePair {
    KeyValuePair { key: key.to_owned(), value }
}

/// The `foxglove.ImageAnnotations` of a keyframe's detections.
pub(crate) fn detections(stamp_ns: u64, boxes: &[DetectionBox]) -> ImageAnnotations {
    let stamp = Some(timestamp(stamp_ns));
    let mut points = Vec::with_capacity(boxes.len());
    let mut texts = Vec::with_capacity(boxes.len());
    for d in boxes {
        let part = d.kind == NodeKind::Part;
        let c = if part { PART_COLOUR } else { OBJECT_COLOUR };
        // Pixel edges: the box covers columns x0 .. x0 + width - 1.
        let (x0, y0) = (f64::from(d.x0), f64::from(d.y0));
        let (x1, y1) = (x0 + f64::from(d.width), y0 + f64::from(d.height));
        points.push(PointsAnnotation {
            timestamp: stamp,
            r#type: points_annotation::Type::LineLoop as i32,
            points: vec![
                Point2 { x: x0, y: y0 },
                Point2 { x: x1, y: y0 },
                Point2 { x: x1, y: y1 },
                Point2 { x: x0, y: y1 },
            ],
            outline_color: colour(c, 1.0),
            outline_colors: Vec::new(),
            fill_color: colour(c, 0.0),
            thickness: if part { 1.5 } else { 2.5 },
            metadata: vec![
                key_value("label", d.label.clone()),
                key_value("kind", d.kind.as_str().to_owned()),
                key_value("score", d.score.to_string()),
            ],
        });
        texts.push(TextAnnotation {
            timestamp: stamp,
            position: Some(Point2 { x: x0, y: y0 }),
            text: format!("{} {:.2}", d.label, d.score),
            font_size: if part { 11.0 } else { 13.0 },
            text_color: Some(Color { r: 1.0, g: 1.0, b: 1.0, a: 1.0 }),
            background_color: colour(c, 0.7),
            ..TextAnnotation::default()
        });
    }
    ImageAnnotations {
        timestamp: stamp,
        circles: Vec::new(),
        points,
        texts,
        metadata: vec![key_value("detections", boxes.len().to_string())],
    }
}

/// Bytes per point of the cloud: x, y, z (float32), node_id (uint32), little-endian.
pub(crate) const POINT_STRIDE: usize = 16;

/// The `foxglove.PointCloud` of `points` (in the world frame, named `world_frame`); `scratch`
/// holds the packed points on the way.
pub(crate) fn node_points(stamp_ns: u64, points: &[NodePoint], world_frame: &str, scratch: &mut Vec<u8>) -> PointCloud {
    scratch.clear();
    scratch.reserve(points.len() * POINT_STRIDE);
    for p in points {
        for v in p.position_m {
            scratch.extend_from_slice(&v.to_le_bytes());
        }
        scratch.extend_from_slice(&p.node_id.to_le_bytes());
    }
    let field = |name: &str, offset: u32, ty: NumericType| PackedElementField {
        name: name.to_owned(),
        offset,
        r#type: ty as i32,
    };
    PointCloud {
        timestamp: Some(timestamp(stamp_ns)),
        frame_id: world_frame.to_owned(),
        pose: pose([0.0; 3], glam::DQuat::IDENTITY),
        point_stride: POINT_STRIDE as u32,
        fields: vec![
            field("x", 0, NumericType::Float32),
            field("y", 4, NumericType::Float32),
            field("z", 8, NumericType::Float32),
            field("node_id", 12, NumericType::Uint32),
        ],
        data: Bytes::copy_from_slice(scratch),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detections_are_box_outlines_with_labels_and_scores() {
        let boxes = [DetectionBox {
            label: "cabinet".to_owned(),
            kind: NodeKind::Object,
            score: 0.875,
            x0: 10,
            y0: 20,
            width: 30,
            height: 40,
        }];
        let v = detections(1_500_000_000, &boxes);
        let outline = &v.points[0];
        assert_eq!(outline.r#type, 2, "LINE_LOOP");
        assert_eq!(outline.points[2], Point2 { x: 40.0, y: 60.0 });
        assert_eq!(v.texts[0].text, "cabinet 0.88");
        assert_eq!(v.timestamp, Some(timestamp(1_500_000_000)));
    }

    #[test]
    fn node_points_pack_xyz_and_the_node_id() {
        let points = [NodePoint { node_id: 7, position_m: [1.0, -2.0, 0.5] }];
        let cloud = node_points(0, &points, "map", &mut Vec::new());
        assert_eq!(cloud.frame_id, "map", "the configured world frame");
        assert_eq!((cloud.fields[0].r#type, cloud.fields[3].r#type), (7, 5), "float32, uint32");
        let data = &cloud.data;
        assert_eq!(data.len(), POINT_STRIDE);
        assert_eq!(f32::from_le_bytes(data[4..8].try_into().unwrap()), -2.0);
        assert_eq!(u32::from_le_bytes(data[12..16].try_into().unwrap()), 7);
    }
}
