//! The schemas embedded in every recording, one per channel type.
//!
//! The `foxglove.*` channels are protobuf, their schemas the `foxglove` crate's generated
//! types and descriptors (Foxglove SDK, the schemas Foxglove publishes): one source of truth for
//! the recorder, the live view and the replay; Foxglove picks its panels by the schema *name*, so
//! a file opens in Foxglove's 3D, Image and Raw Messages panels. The `op3dsg.*` channels are our
//! own messages, JSON with the JSON schemas written here (no generated types exist for them).
//! Files written before the `foxglove.*` channels became protobuf hold them as JSON; the replay
//! reads both ([`super::messages`]).

use std::borrow::Cow;

use foxglove::Encode;
use foxglove::messages::{
    CameraCalibration, CompressedImage, FrameTransform, ImageAnnotations, PointCloud, RawImage, SceneUpdate,
};
use serde_json::{Value, json};

/// Schema encoding of the `op3dsg.*` channels (and of the `foxglove.*` ones in files written
/// before they became protobuf).
pub const SCHEMA_ENCODING: &str = "jsonschema";
/// Message encoding of the `op3dsg.*` channels (as [`SCHEMA_ENCODING`]).
pub const MESSAGE_ENCODING: &str = "json";
/// Schema and message encoding of the `foxglove.*` channels.
pub const PROTOBUF: &str = "protobuf";

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

/// What a channel of one schema declares in a recording.
#[derive(Debug, Clone)]
pub struct ChannelSchema {
    /// The schema's encoding (`protobuf` or `jsonschema`).
    pub encoding: &'static str,
    /// The schema: a serialised `FileDescriptorSet` (protobuf) or the JSON schema's text.
    pub data: Cow<'static, [u8]>,
    /// The channel's message encoding (`protobuf` or `json`).
    pub message_encoding: &'static str,
}

fn protobuf<T: Encode>() -> Option<ChannelSchema> {
    let schema = T::get_schema()?;
    Some(ChannelSchema { encoding: PROTOBUF, data: schema.data, message_encoding: PROTOBUF })
}

/// The schema the recorder writes for `name` (one of the constants above), `None` for another
/// name.
pub fn channel_schema(name: &str) -> Option<ChannelSchema> {
    match name {
        RAW_IMAGE => protobuf::<RawImage>(),
        COMPRESSED_IMAGE => protobuf::<CompressedImage>(),
        CAMERA_CALIBRATION => protobuf::<CameraCalibration>(),
        FRAME_TRANSFORM => protobuf::<FrameTransform>(),
        SCENE_UPDATE => protobuf::<SceneUpdate>(),
        IMAGE_ANNOTATIONS => protobuf::<ImageAnnotations>(),
        POINT_CLOUD => protobuf::<PointCloud>(),
        _ => schema_text(name).map(|text| ChannelSchema {
            encoding: SCHEMA_ENCODING,
            data: Cow::Owned(text.into_bytes()),
            message_encoding: MESSAGE_ENCODING,
        }),
    }
}

/// The JSON schema text of an `op3dsg.*` name (one of the constants above), `None` for another
/// name.
pub fn schema_text(name: &str) -> Option<String> {
    let value = match name {
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

/// `object` with fields that may be `null` (`nullable`: name and the schema of its non-null
/// value). Foxglove's JSON-schema reader takes one `type` per field and no `null`, so these
/// fields are described under `patternProperties` (each name anchored), which that reader
/// skips and every JSON Schema validator checks: the file's own schema still validates each
/// message, and Foxglove's panels see every other field typed.
fn object_with_nullable(title: &str, properties: Value, nullable: &[(&str, Value)], required: &[&str]) -> Value {
    let mut schema = object(title, properties, required);
    let patterns: serde_json::Map<String, Value> = nullable
        .iter()
        .map(|(name, value)| (format!("^{name}$"), json!({ "oneOf": [value, { "type": "null" }] })))
        .collect();
    schema["patternProperties"] = Value::Object(patterns);
    schema
}

/// A string out of `values`.
fn string_enum(values: &[&str]) -> Value {
    json!({ "type": "string", "enum": values })
}

/// A JSON object used as a map from any key to `value` (no fixed fields).
fn map_of(value: Value) -> Value {
    json!({ "type": "object", "properties": {}, "additionalProperties": value })
}

fn numbers(count: usize) -> Value {
    json!({ "type": "array", "items": { "type": "number" }, "minItems": count, "maxItems": count })
}

fn graph() -> Value {
    let xyz = numbers(3);
    let obb = object(
        "op3dsg.OrientedBox",
        json!({ "centre_m": xyz, "size_m": xyz, "yaw_rad": { "type": "number" } }),
        &["centre_m", "size_m", "yaw_rad"],
    );
    let node = object_with_nullable(
        "op3dsg.Node",
        json!({
            "id": { "type": "integer", "minimum": 0 },
            "label": { "type": "string" },
            "kind": string_enum(&["object", "part"]),
            "centre_m": xyz, "box_min_m": xyz, "box_max_m": xyz,
            "affordances": { "type": "array", "items": { "type": "string" } },
            "obb": obb,
            "affordance_origins": map_of(string_enum(&crate::graph_json::AFFORDANCE_ORIGINS)),
            "confidence": { "type": "number" },
            "observation_count": { "type": "integer", "minimum": 0 },
            "seen_keyframes": { "type": "integer", "minimum": 0 }
        }),
        &[("parent", json!({ "type": "integer", "minimum": 0 }))],
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
            "kind": string_enum(&["spatial", "functional"]),
            "relation": { "type": "string" },
            "confidence": { "type": "number" },
            "origin": { "type": "string" }
        }),
        &["source", "target", "kind", "relation", "confidence", "origin"],
    );
    let mut schema = object(
        GRAPH,
        json!({
            "schema": { "type": "string", "const": crate::graph_json::GRAPH_JSON_SCHEMA },
            "source": { "type": "string" },
            "graph_version": { "type": "integer", "minimum": 0 },
            "stamp_ns": { "type": "integer", "minimum": 0 },
            "source_kind": { "type": "string" },
            "world_frame": { "type": "string" },
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
        json!({ "translation_m": numbers(3), "rotation_xyzw": numbers(4) }),
        &["translation_m", "rotation_xyzw"],
    );
    object_with_nullable(
        FRAME,
        json!({
            "seq": { "type": "integer", "minimum": 0 },
            "stamp_ns": { "type": "integer", "minimum": 0 },
            "depth_units_per_m": { "type": "number" }
        }),
        &[("world_from_camera", pose)],
        &["seq", "stamp_ns", "depth_units_per_m", "world_from_camera"],
    )
}

fn input_pose() -> Value {
    let mut schema = object(
        INPUT_POSE,
        json!({
            "stamp_ns": { "type": "integer", "minimum": 0 },
            "kind": string_enum(&["world_from_camera", "world_from_base"]),
            "frame_id": { "type": "string" },
            "translation_m": numbers(3),
            "rotation_xyzw": numbers(4)
        }),
        &["stamp_ns", "kind", "frame_id", "translation_m", "rotation_xyzw"],
    );
    schema["description"] = json!("a pose the daemon received on <prefix>/pose (pose.source = \"ipc\")");
    schema
}

fn llm_exchange() -> Value {
    let message = object(
        "op3dsg.ChatMessage",
        json!({ "role": string_enum(&["system", "user"]), "content": { "type": "string" } }),
        &["role", "content"],
    );
    let verdict = object(
        "op3dsg.LlmVerdict",
        json!({
            "parsed": { "type": "boolean" },
            "accepted": { "type": "integer", "minimum": 0 },
            "rejected": map_of(json!({ "type": "integer", "minimum": 1 }))
        }),
        &["parsed", "accepted", "rejected"],
    );
    let mut schema = object_with_nullable(
        LLM_EXCHANGE,
        json!({
            "graph_version": { "type": "integer", "minimum": 0 },
            "agent": string_enum(&["local_relations", "remote_relations", "affordances"]),
            "model": { "type": "string" },
            "messages": { "type": "array", "items": message },
            "attempts": { "type": "integer", "minimum": 0 },
            "latency_ms": { "type": "number", "minimum": 0 },
            "total_ms": { "type": "number", "minimum": 0 }
        }),
        &[("answer", json!({ "type": "string" })), ("error", json!({ "type": "string" })), ("verdict", verdict)],
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
    let integer = || json!({ "type": "integer", "minimum": 0 });
    let stage = object(
        "op3dsg.StageHealth",
        json!({
            "name": { "type": "string" },
            "processed": integer(),
            "rate_hz": { "type": "number" },
            "latency_p50_us": integer(),
            "latency_p99_us": integer(),
            "errors": integer()
        }),
        &["name", "processed", "rate_hz", "latency_p50_us", "latency_p99_us", "errors"],
    );
    let queue = object(
        "op3dsg.QueueHealth",
        json!({
            "name": { "type": "string" },
            "depth": integer(),
            "capacity": integer(),
            "dropped": integer(),
            "pushed": integer()
        }),
        &["name", "depth", "capacity", "dropped", "pushed"],
    );
    let pose = object(
        "op3dsg.PoseHealth",
        json!({ "accepted": integer(), "stale": integer(), "queue_full": integer() }),
        &["accepted", "stale", "queue_full"],
    );
    let recorder = object(
        "op3dsg.RecorderHealth",
        json!({
            "state": { "type": "string" },
            "files": integer(),
            "messages_written": integer(),
            "messages_dropped": integer(),
            "bytes_written": integer(),
            "cpu_ns": integer()
        }),
        &["state", "files", "messages_written", "messages_dropped", "bytes_written", "cpu_ns"],
    );
    let mut schema = object(
        HEALTH,
        json!({
            "stamp_ns": integer(),
            "uptime_ns": integer(),
            "frames_captured": integer(),
            "keyframes": integer(),
            "frames_without_pose": integer(),
            "detections_fused": integer(),
            "graph_version": integer(),
            "map_node_count": integer(),
            "map_memory_bytes": integer(),
            "source_connected": { "type": "boolean" },
            "source_kind": string_enum(&["unknown", "live_camera", "replay", "synthetic"]),
            "world_frame": { "type": "string" },
            "graph_subscribers": integer(),
            "dead_nodes_cleaned": integer(),
            "stages": { "type": "array", "items": stage },
            "queues": { "type": "array", "items": queue },
            "pose": pose,
            "recorder": recorder
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
    fn every_op3dsg_schema_is_json_titled_by_its_name() {
        for name in [GRAPH, FRAME, HEALTH, INPUT_POSE, LLM_EXCHANGE] {
            let text = schema_text(name).unwrap();
            let value: Value = serde_json::from_str(&text).unwrap();
            assert_eq!(value["title"], name);
            let channel = channel_schema(name).unwrap();
            assert_eq!((channel.encoding, channel.message_encoding), (SCHEMA_ENCODING, MESSAGE_ENCODING));
            assert_eq!(&*channel.data, text.as_bytes());
        }
        assert!(schema_text(RAW_IMAGE).is_none(), "foxglove.* schemas are the foxglove crate's");
        assert!(channel_schema("foxglove.Nope").is_none());
    }

    /// The rules of Foxglove's JSON-schema reader (`parseJsonSchema` of Foxglove Studio and
    /// Lichtblick, which every JSON channel's schema goes through before a panel sees it): an
    /// object has `"type": "object"` and `properties`; each property is a `oneOf` of numeric
    /// `const`s or has one `type` of boolean, string, number, integer, object or array; an
    /// array's `items` has one of those types (no arrays of arrays). Errors name the path.
    fn foxglove_reads(schema: &Value, path: &str) -> Result<(), String> {
        if schema["type"] != "object" {
            return Err(format!("{path}: expected \"type\": \"object\""));
        }
        let properties = schema["properties"].as_object().ok_or_else(|| format!("{path}: no \"properties\""))?;
        for (name, field) in properties {
            let at = format!("{path}.{name}");
            if let Some(alternatives) = field["oneOf"].as_array() {
                if alternatives.iter().all(|a| a["const"].is_number()) {
                    continue;
                }
                return Err(format!("{at}: oneOf alternatives must be numeric consts"));
            }
            match field["type"].as_str() {
                Some("boolean" | "string" | "number" | "integer") => {}
                Some("object") => foxglove_reads(field, &at)?,
                Some("array") => match field["items"]["type"].as_str() {
                    Some("boolean" | "string" | "number" | "integer") => {}
                    Some("object") => foxglove_reads(&field["items"], &format!("{at}[]"))?,
                    other => return Err(format!("{at}: unsupported item type {other:?}")),
                },
                _ => return Err(format!("{at}: unsupported type {}", field["type"])),
            }
        }
        Ok(())
    }

    #[test]
    fn foxglove_reads_every_op3dsg_schema() {
        for name in [GRAPH, FRAME, HEALTH, INPUT_POSE, LLM_EXCHANGE] {
            let schema: Value = serde_json::from_str(&schema_text(name).unwrap()).unwrap();
            foxglove_reads(&schema, name).unwrap_or_else(|e| panic!("{e}"));
        }
    }

    #[test]
    fn the_reader_rules_refuse_what_foxglove_refuses() {
        let bad = [
            json!({ "type": "object", "properties": { "q": { "type": "object" } } }),
            json!({ "type": "object", "properties": { "k": { "enum": ["a", "b"] } } }),
            json!({ "type": "object", "properties": { "p": { "type": ["integer", "null"] } } }),
            json!({ "type": "object", "properties": { "v": { "oneOf": [{ "type": "object" }, { "type": "null" }] } } }),
            json!({ "type": "object", "properties": { "m": { "type": "array", "items": { "type": "array" } } } }),
            json!({ "type": "object", "properties": { "s": { "const": "x" } } }),
        ];
        for schema in bad {
            assert!(foxglove_reads(&schema, "t").is_err(), "{schema}");
        }
    }

    #[test]
    fn every_foxglove_schema_is_the_foxglove_crates_descriptor_of_that_name() {
        let names = [
            (RAW_IMAGE, RawImage::get_schema()),
            (COMPRESSED_IMAGE, CompressedImage::get_schema()),
            (CAMERA_CALIBRATION, CameraCalibration::get_schema()),
            (FRAME_TRANSFORM, FrameTransform::get_schema()),
            (SCENE_UPDATE, SceneUpdate::get_schema()),
            (IMAGE_ANNOTATIONS, ImageAnnotations::get_schema()),
            (POINT_CLOUD, PointCloud::get_schema()),
        ];
        for (name, schema) in names {
            let schema = schema.unwrap();
            assert_eq!(schema.name, name, "the generated type of {name}");
            let channel = channel_schema(name).unwrap();
            assert_eq!((channel.encoding, channel.message_encoding), (PROTOBUF, PROTOBUF), "{name}");
            assert_eq!(channel.data, schema.data, "{name}");
            assert!(!channel.data.is_empty(), "{name}: a FileDescriptorSet");
        }
    }
}
