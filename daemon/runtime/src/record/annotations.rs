//! The detections of a keyframe as `foxglove.ImageAnnotations` (a box outline per detection,
//! objects blue-grey and parts orange as in the scene, and a label with the detector's score),
//! and the nodes' points as `foxglove.PointCloud`.

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use op3dsg_drivers::mcap::messages::Time;
use op3dsg_ipc_types::NodeKind;
use serde_json::json;

use super::scene::{Colour, OBJECT_COLOUR, PART_COLOUR};
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

fn colour(c: Colour, a: f32) -> serde_json::Value {
    json!({ "r": c.r, "g": c.g, "b": c.b, "a": a })
}

/// Writes the `foxglove.ImageAnnotations` JSON of a keyframe's detections into `out`.
pub(crate) fn write_detections(stamp_ns: u64, boxes: &[DetectionBox], out: &mut Vec<u8>) {
    out.clear();
    let timestamp = Time::from_ns(stamp_ns);
    let mut points = Vec::with_capacity(boxes.len());
    let mut texts = Vec::with_capacity(boxes.len());
    for d in boxes {
        let part = d.kind == NodeKind::Part;
        let c = if part { PART_COLOUR } else { OBJECT_COLOUR };
        // Pixel edges: the box covers columns x0 .. x0 + width - 1.
        let (x0, y0) = (f64::from(d.x0), f64::from(d.y0));
        let (x1, y1) = (x0 + f64::from(d.width), y0 + f64::from(d.height));
        let metadata = json!([
            { "key": "label", "value": d.label },
            { "key": "kind", "value": d.kind.as_str() },
            { "key": "score", "value": d.score.to_string() },
        ]);
        points.push(json!({
            "timestamp": timestamp,
            "type": 2, // LINE_LOOP
            "points": [{ "x": x0, "y": y0 }, { "x": x1, "y": y0 }, { "x": x1, "y": y1 }, { "x": x0, "y": y1 }],
            "outline_color": colour(c, 1.0),
            "outline_colors": [],
            "fill_color": colour(c, 0.0),
            "thickness": if part { 1.5 } else { 2.5 },
            "metadata": metadata,
        }));
        texts.push(json!({
            "timestamp": timestamp,
            "position": { "x": x0, "y": y0 },
            "text": format!("{} {:.2}", d.label, d.score),
            "font_size": if part { 11.0 } else { 13.0 },
            "text_color": { "r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0 },
            "background_color": colour(c, 0.7),
        }));
    }
    let value = json!({
        "timestamp": timestamp,
        "circles": [],
        "points": points,
        "texts": texts,
        "metadata": [{ "key": "detections", "value": boxes.len().to_string() }],
    });
    // Serialising a Value into a Vec cannot fail.
    let _ = serde_json::to_writer(out, &value);
}

/// Bytes per point of the cloud: x, y, z (float32), node_id (uint32), little-endian.
pub(crate) const POINT_STRIDE: usize = 16;

/// Writes the `foxglove.PointCloud` JSON of `points` (in the world frame, named `world_frame`)
/// into `out`; `scratch` holds the packed points.
pub(crate) fn write_node_points(
    stamp_ns: u64,
    points: &[NodePoint],
    world_frame: &str,
    scratch: &mut Vec<u8>,
    out: &mut Vec<u8>,
) {
    out.clear();
    scratch.clear();
    scratch.reserve(points.len() * POINT_STRIDE);
    for p in points {
        for v in p.position_m {
            scratch.extend_from_slice(&v.to_le_bytes());
        }
        scratch.extend_from_slice(&p.node_id.to_le_bytes());
    }
    let value = json!({
        "timestamp": Time::from_ns(stamp_ns),
        "frame_id": world_frame,
        "pose": { "position": { "x": 0.0, "y": 0.0, "z": 0.0 }, "orientation": { "x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0 } },
        "point_stride": POINT_STRIDE,
        "fields": [
            { "name": "x", "offset": 0, "type": 7 },
            { "name": "y", "offset": 4, "type": 7 },
            { "name": "z", "offset": 8, "type": 7 },
            { "name": "node_id", "offset": 12, "type": 5 },
        ],
        "data": STANDARD.encode(&scratch[..]),
    });
    let _ = serde_json::to_writer(out, &value);
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
        let mut out = Vec::new();
        write_detections(1_500_000_000, &boxes, &mut out);
        let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
        let outline = &v["points"][0];
        assert_eq!(outline["type"], 2);
        assert_eq!(outline["points"][2], json!({ "x": 40.0, "y": 60.0 }));
        assert_eq!(v["texts"][0]["text"], "cabinet 0.88");
        assert_eq!(v["timestamp"], json!({ "sec": 1, "nsec": 500_000_000 }));
    }

    #[test]
    fn node_points_pack_xyz_and_the_node_id() {
        let points = [NodePoint { node_id: 7, position_m: [1.0, -2.0, 0.5] }];
        let (mut scratch, mut out) = (Vec::new(), Vec::new());
        write_node_points(0, &points, "map", &mut scratch, &mut out);
        let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(v["frame_id"], "map", "the configured world frame");
        let data = STANDARD.decode(v["data"].as_str().unwrap()).unwrap();
        assert_eq!(data.len(), POINT_STRIDE);
        assert_eq!(f32::from_le_bytes(data[4..8].try_into().unwrap()), -2.0);
        assert_eq!(u32::from_le_bytes(data[12..16].try_into().unwrap()), 7);
    }
}
