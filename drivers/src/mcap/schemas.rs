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
