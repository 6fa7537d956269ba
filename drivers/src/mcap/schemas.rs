//! The JSON schemas embedded in every recording, one per channel type.
//!
//! The `foxglove.*` ones describe the fields op3dsg writes with the names, types and required
//! fields of Foxglove's published JSON schemas (foxglove-sdk `schemas/jsonschema`, 2025
//! releases); Foxglove picks its panels by the schema *name*, so a file opens in Foxglove's
//! 3D, Image and Raw Messages panels. The `op3dsg.*` ones describe our own messages.

use serde_json::{Value, json};

/// Schema encoding of every channel.
pub const SCHEMA_ENCODING: &str = "jsonschema";
/// Message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "json";

/// `foxglove.RawImage`.
pub const RAW_IMAGE: &str = "foxglove.RawImage";
/// `foxglove.CompressedImage`.
pub const COMPRESSED_IMAGE: &str = "foxglove.CompressedImage";
/// `foxglove.CameraCalibration`.
pub const CAMERA_CALIBRATION: &str = "foxglove.CameraCalibration";
/// `foxglove.FrameTransform`.
pub const FRAME_TRANSFORM: &str = "foxglove.FrameTransform";
/// `foxglove.SceneUpdate`.
pub const SCENE_UPDATE: &str = "foxglove.SceneUpdate";
/// `foxglove.ImageAnnotations`.
pub const IMAGE_ANNOTATIONS: &str = "foxglove.ImageAnnotations";
/// `foxglove.PointCloud`.
pub const POINT_CLOUD: &str = "foxglove.PointCloud";
/// `op3dsg.Graph`: [`crate::graph_json`].
pub const GRAPH: &str = "op3dsg.Graph";
/// `op3dsg.Frame`: [`super::messages::FrameMeta`].
pub const FRAME: &str = "op3dsg.Frame";
/// `op3dsg.Health`.
pub const HEALTH: &str = "op3dsg.Health";
/// `op3dsg.InputPose`: [`super::messages::InputPose`].
pub const INPUT_POSE: &str = "op3dsg.InputPose";
/// `op3dsg.LlmExchange`: [`super::messages::LlmExchange`].
pub const LLM_EXCHANGE: &str = "op3dsg.LlmExchange";

/// The schema text of `name` (one of the constants above), `None` for another name.
pub fn schema_text(name: &str) -> Option<String> {
    let value = match name {
        RAW_IMAGE => raw_image(),
        COMPRESSED_IMAGE => compressed_image(),
        CAMERA_CALIBRATION => camera_calibration(),
        FRAME_TRANSFORM => frame_transform(),
        SCENE_UPDATE => scene_update(),
        IMAGE_ANNOTATIONS => image_annotations(),
        POINT_CLOUD => point_cloud(),
        GRAPH => graph(),
        FRAME => frame(),
        HEALTH => health(),
        INPUT_POSE => input_pose(),
        LLM_EXCHANGE => llm_exchange(),
        _ => return None,
    };
    Some(value.to_string())
}

fn object(title: &str, properties: Value, required: &[&str]) -> Value {
    json!({ "title": title, "type": "object", "properties": properties, "required": required })
}

fn time() -> Value {
    json!({
        "type": "object", "title": "time",
        "properties": {
            "sec": { "type": "integer", "minimum": 0 },
            "nsec": { "type": "integer", "minimum": 0, "maximum": 999_999_999 }
        },
        "required": ["sec", "nsec"]
    })
}

fn duration() -> Value {
    json!({
        "type": "object", "title": "duration",
        "properties": {
            "sec": { "type": "integer" },
            "nsec": { "type": "integer", "minimum": 0, "maximum": 999_999_999 }
        },
        "required": ["sec", "nsec"]
    })
}

fn numbers(title: &str, names: &[&str]) -> Value {
    let properties: serde_json::Map<String, Value> =
        names.iter().map(|n| ((*n).to_owned(), json!({ "type": "number" }))).collect();
    object(title, Value::Object(properties), names)
}

fn vector3() -> Value {
    numbers("foxglove.Vector3", &["x", "y", "z"])
}

fn point3() -> Value {
    numbers("foxglove.Point3", &["x", "y", "z"])
}

fn quaternion() -> Value {
    numbers("foxglove.Quaternion", &["x", "y", "z", "w"])
}

fn color() -> Value {
    numbers("foxglove.Color", &["r", "g", "b", "a"])
}

fn pose() -> Value {
    object("foxglove.Pose", json!({ "position": vector3(), "orientation": quaternion() }), &["position", "orientation"])
}

fn raw_image() -> Value {
    let mut schema = object(
        RAW_IMAGE,
        json!({
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "width": { "type": "integer", "minimum": 0 },
            "height": { "type": "integer", "minimum": 0 },
            "encoding": { "type": "string", "description": "rgb8, 16UC1, mono16, ..." },
            "step": { "type": "integer", "minimum": 0, "description": "Byte length of a row" },
            "data": { "type": "string", "contentEncoding": "base64" }
        }),
        &["timestamp", "frame_id", "width", "height", "encoding", "step", "data"],
    );
    schema["description"] = json!("A raw image");
    schema
}

fn compressed_image() -> Value {
    let mut schema = object(
        COMPRESSED_IMAGE,
        json!({
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "data": { "type": "string", "contentEncoding": "base64" },
            "format": { "type": "string", "description": "jpeg or png" }
        }),
        &["timestamp", "frame_id", "data", "format"],
    );
    schema["description"] = json!("A compressed image");
    schema
}

fn camera_calibration() -> Value {
    let matrix = |n: usize| json!({ "type": "array", "items": { "type": "number" }, "minItems": n, "maxItems": n });
    object(
        CAMERA_CALIBRATION,
        json!({
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "width": { "type": "integer", "minimum": 0 },
            "height": { "type": "integer", "minimum": 0 },
            "distortion_model": { "type": "string" },
            "D": { "type": "array", "items": { "type": "number" } },
            "K": matrix(9),
            "R": matrix(9),
            "P": matrix(12)
        }),
        &["timestamp", "frame_id", "width", "height", "distortion_model", "D", "K", "R", "P"],
    )
}

fn frame_transform() -> Value {
    object(
        FRAME_TRANSFORM,
        json!({
            "timestamp": time(),
            "parent_frame_id": { "type": "string" },
            "child_frame_id": { "type": "string" },
            "translation": vector3(),
            "rotation": quaternion()
        }),
        &["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
    )
}

fn scene_update() -> Value {
    let cube = object(
        "foxglove.CubePrimitive",
        json!({ "pose": pose(), "size": vector3(), "color": color() }),
        &["pose", "size", "color"],
    );
    let line = object(
        "foxglove.LinePrimitive",
        json!({
            "type": { "title": "foxglove.LineType", "oneOf": [
                { "title": "LINE_STRIP", "const": 0 }, { "title": "LINE_LOOP", "const": 1 }, { "title": "LINE_LIST", "const": 2 }
            ] },
            "pose": pose(),
            "thickness": { "type": "number" },
            "scale_invariant": { "type": "boolean" },
            "points": { "type": "array", "items": point3() },
            "color": color(),
            "colors": { "type": "array", "items": color() },
            "indices": { "type": "array", "items": { "type": "integer", "minimum": 0 } }
        }),
        &["type", "pose", "thickness", "scale_invariant", "points", "color", "colors", "indices"],
    );
    let text = object(
        "foxglove.TextPrimitive",
        json!({
            "pose": pose(),
            "billboard": { "type": "boolean" },
            "font_size": { "type": "number" },
            "scale_invariant": { "type": "boolean" },
            "color": color(),
            "text": { "type": "string" }
        }),
        &["pose", "billboard", "font_size", "scale_invariant", "color", "text"],
    );
    let key_value = object(
        "foxglove.KeyValuePair",
        json!({ "key": { "type": "string" }, "value": { "type": "string" } }),
        &["key", "value"],
    );
    let array = |items: Value| json!({ "type": "array", "items": items });
    let entity = object(
        "foxglove.SceneEntity",
        json!({
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "id": { "type": "string" },
            "lifetime": duration(),
            "frame_locked": { "type": "boolean" },
            "metadata": array(key_value),
            "arrows": array(json!({ "type": "object" })),
            "cubes": array(cube),
            "spheres": array(json!({ "type": "object" })),
            "cylinders": array(json!({ "type": "object" })),
            "lines": array(line),
            "triangles": array(json!({ "type": "object" })),
            "texts": array(text),
            "models": array(json!({ "type": "object" }))
        }),
        &[
            "timestamp",
            "frame_id",
            "id",
            "lifetime",
            "frame_locked",
            "metadata",
            "arrows",
            "cubes",
            "spheres",
            "cylinders",
            "lines",
            "triangles",
            "texts",
            "models",
        ],
    );
    let deletion = object(
        "foxglove.SceneEntityDeletion",
        json!({
            "timestamp": time(),
            "type": { "title": "foxglove.SceneEntityDeletionType", "oneOf": [
                { "title": "MATCHING_ID", "const": 0 }, { "title": "ALL", "const": 1 }
            ] },
            "id": { "type": "string" }
        }),
        &["timestamp", "type", "id"],
    );
    object(SCENE_UPDATE, json!({ "deletions": array(deletion), "entities": array(entity) }), &["deletions", "entities"])
}

fn point2() -> Value {
    numbers("foxglove.Point2", &["x", "y"])
}

fn key_values() -> Value {
    let pair = object(
        "foxglove.KeyValuePair",
        json!({ "key": { "type": "string" }, "value": { "type": "string" } }),
        &["key", "value"],
    );
    json!({ "type": "array", "items": pair })
}

fn image_annotations() -> Value {
    let points = object(
        "foxglove.PointsAnnotation",
        json!({
            "timestamp": time(),
            "type": { "title": "foxglove.PointsAnnotationType", "oneOf": [
                { "title": "UNKNOWN", "const": 0 }, { "title": "POINTS", "const": 1 }, { "title": "LINE_LOOP", "const": 2 },
                { "title": "LINE_STRIP", "const": 3 }, { "title": "LINE_LIST", "const": 4 }
            ] },
            "points": { "type": "array", "items": point2() },
            "outline_color": color(),
            "outline_colors": { "type": "array", "items": color() },
            "fill_color": color(),
            "thickness": { "type": "number" },
            "metadata": key_values()
        }),
        &["timestamp", "type", "points", "outline_color", "outline_colors", "fill_color", "thickness"],
    );
    let text = object(
        "foxglove.TextAnnotation",
        json!({
            "timestamp": time(),
            "position": point2(),
            "text": { "type": "string" },
            "font_size": { "type": "number" },
            "text_color": color(),
            "background_color": color(),
            "metadata": key_values()
        }),
        &["timestamp", "position", "text", "font_size", "text_color", "background_color"],
    );
    object(
        IMAGE_ANNOTATIONS,
        json!({
            "timestamp": time(),
            "circles": { "type": "array", "items": { "type": "object" } },
            "points": { "type": "array", "items": points },
            "texts": { "type": "array", "items": text },
            "metadata": key_values()
        }),
        &["circles", "points", "texts"],
    )
}

fn point_cloud() -> Value {
    let field = object(
        "foxglove.PackedElementField",
        json!({
            "name": { "type": "string" },
            "offset": { "type": "integer", "minimum": 0 },
            "type": { "title": "foxglove.NumericType", "oneOf": [
                { "title": "UNKNOWN", "const": 0 }, { "title": "UINT8", "const": 1 }, { "title": "INT8", "const": 2 },
                { "title": "UINT16", "const": 3 }, { "title": "INT16", "const": 4 }, { "title": "UINT32", "const": 5 },
                { "title": "INT32", "const": 6 }, { "title": "FLOAT32", "const": 7 }, { "title": "FLOAT64", "const": 8 }
            ] }
        }),
        &["name", "offset", "type"],
    );
    object(
        POINT_CLOUD,
        json!({
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "pose": pose(),
            "point_stride": { "type": "integer", "minimum": 0 },
            "fields": { "type": "array", "items": field },
            "data": { "type": "string", "contentEncoding": "base64" }
        }),
        &["timestamp", "frame_id", "pose", "point_stride", "fields", "data"],
    )
}

fn graph() -> Value {
    let xyz = json!({ "type": "array", "items": { "type": "number" }, "minItems": 3, "maxItems": 3 });
    let node = object(
        "op3dsg.Node",
        json!({
            "id": { "type": "integer", "minimum": 0 },
            "label": { "type": "string" },
            "kind": { "enum": ["object", "part"] },
            "parent": { "type": ["integer", "null"] },
            "centre_m": xyz, "box_min_m": xyz, "box_max_m": xyz,
            "affordances": { "type": "array", "items": { "type": "string" } },
            "affordance_origins": {
                "type": "object",
                "additionalProperties": { "enum": ["geometry", "knowledge", "llm", "knowledge+llm"] }
            },
            "confidence": { "type": "number" },
            "observation_count": { "type": "integer", "minimum": 0 }
        }),
        &[
            "id",
            "label",
            "kind",
            "parent",
            "centre_m",
            "box_min_m",
            "box_max_m",
            "affordances",
            "confidence",
            "observation_count",
        ],
    );
    let edge = object(
        "op3dsg.Edge",
        json!({
            "source": { "type": "integer" }, "target": { "type": "integer" },
            "kind": { "enum": ["spatial", "functional"] },
            "relation": { "type": "string" },
            "confidence": { "type": "number" },
            "origin": { "type": "string" }
        }),
        &["source", "target", "kind", "relation", "confidence", "origin"],
    );
    let mut schema = object(
        GRAPH,
        json!({
            "schema": { "const": crate::graph_json::GRAPH_JSON_SCHEMA },
            "source": { "type": "string" },
            "graph_version": { "type": "integer", "minimum": 0 },
            "stamp_ns": { "type": "integer", "minimum": 0 },
            "nodes": { "type": "array", "items": node },
            "edges": { "type": "array", "items": edge }
        }),
        &["schema", "source", "graph_version", "stamp_ns", "nodes", "edges"],
    );
    schema["description"] = json!("op3dsg scene graph, one published version (drivers/src/graph_json.rs)");
    schema
}

fn frame() -> Value {
    let pose = object(
        "op3dsg.Isometry",
        json!({
            "translation_m": { "type": "array", "items": { "type": "number" }, "minItems": 3, "maxItems": 3 },
            "rotation_xyzw": { "type": "array", "items": { "type": "number" }, "minItems": 4, "maxItems": 4 }
        }),
        &["translation_m", "rotation_xyzw"],
    );
    object(
        FRAME,
        json!({
            "seq": { "type": "integer", "minimum": 0 },
            "stamp_ns": { "type": "integer", "minimum": 0 },
            "depth_units_per_m": { "type": "number" },
            "world_from_camera": { "oneOf": [pose, { "type": "null" }] }
        }),
        &["seq", "stamp_ns", "depth_units_per_m", "world_from_camera"],
    )
}

fn input_pose() -> Value {
    let mut schema = object(
        INPUT_POSE,
        json!({
            "stamp_ns": { "type": "integer", "minimum": 0 },
            "kind": { "enum": ["world_from_camera", "world_from_base"] },
            "frame_id": { "type": "string" },
            "translation_m": { "type": "array", "items": { "type": "number" }, "minItems": 3, "maxItems": 3 },
            "rotation_xyzw": { "type": "array", "items": { "type": "number" }, "minItems": 4, "maxItems": 4 }
        }),
        &["stamp_ns", "kind", "frame_id", "translation_m", "rotation_xyzw"],
    );
    schema["description"] = json!("a pose the daemon received on <prefix>/pose (pose.source = \"ipc\")");
    schema
}

fn llm_exchange() -> Value {
    let nullable_string = json!({ "type": ["string", "null"] });
    let message = object(
        "op3dsg.ChatMessage",
        json!({ "role": { "enum": ["system", "user"] }, "content": { "type": "string" } }),
        &["role", "content"],
    );
    let verdict = object(
        "op3dsg.LlmVerdict",
        json!({
            "parsed": { "type": "boolean" },
            "accepted": { "type": "integer", "minimum": 0 },
            "rejected": { "type": "object", "additionalProperties": { "type": "integer", "minimum": 1 } }
        }),
        &["parsed", "accepted", "rejected"],
    );
    let mut schema = object(
        LLM_EXCHANGE,
        json!({
            "graph_version": { "type": "integer", "minimum": 0 },
            "agent": { "enum": ["local_relations", "remote_relations", "affordances"] },
            "model": { "type": "string" },
            "messages": { "type": "array", "items": message },
            "attempts": { "type": "integer", "minimum": 0 },
            "latency_ms": { "type": "number", "minimum": 0 },
            "total_ms": { "type": "number", "minimum": 0 },
            "answer": nullable_string,
            "error": nullable_string,
            "verdict": { "oneOf": [verdict, { "type": "null" }] }
        }),
        &[
            "graph_version",
            "agent",
            "model",
            "messages",
            "attempts",
            "latency_ms",
            "total_ms",
            "answer",
            "error",
            "verdict",
        ],
    );
    schema["description"] = json!(
        "one call of an LLM agent of the refiner: prompt, answer, the gate's verdict; never the API key or a header"
    );
    schema
}

fn health() -> Value {
    let mut schema = object(
        HEALTH,
        json!({
            "stamp_ns": { "type": "integer" },
            "uptime_ns": { "type": "integer" },
            "frames_captured": { "type": "integer" },
            "keyframes": { "type": "integer" },
            "graph_version": { "type": "integer" },
            "map_node_count": { "type": "integer" },
            "source_kind": { "enum": ["unknown", "live_camera", "replay", "synthetic"] },
            "world_frame": { "type": "string" },
            "stages": { "type": "array", "items": { "type": "object" } },
            "queues": { "type": "array", "items": { "type": "object" } },
            "recorder": { "type": "object" }
        }),
        &["stamp_ns", "frames_captured", "keyframes", "graph_version", "stages", "queues", "recorder"],
    );
    schema["description"] = json!("op3dsg health record (ipc_types/src/health_types.rs), as JSON");
    schema
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_schema_is_json_titled_by_its_name() {
        for name in [
            RAW_IMAGE,
            CAMERA_CALIBRATION,
            FRAME_TRANSFORM,
            SCENE_UPDATE,
            IMAGE_ANNOTATIONS,
            POINT_CLOUD,
            GRAPH,
            FRAME,
            HEALTH,
            INPUT_POSE,
        ] {
            let text = schema_text(name).unwrap();
            let value: Value = serde_json::from_str(&text).unwrap();
            assert_eq!(value["title"], name);
        }
        assert!(schema_text("foxglove.Nope").is_none());
    }
}
