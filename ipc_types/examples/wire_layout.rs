//! Prints the wire contract as the compiler lays it out, as JSON: for every wire type its type
//! name, size, alignment and each field's offset and size, plus the constants a client mirrors
//! (schema version, buffer sizes, vocabularies, QoS figures).
//!
//! `cargo run -p op3dsg-ipc-types --example wire_layout`
//!
//! The Python package's test (`ipc_types/python/tests/test_layout.py`) compares its ctypes
//! mirror with this output, so the mirror cannot drift from the Rust layout silently. Each type's
//! field list is checked to be complete at compile time (an exhaustive destructuring pattern), so
//! a field added in Rust fails this build until it is listed here.

use std::fmt::Write as _;

use op3dsg_ipc_types::services::{
    DEFAULT_GRAPH_SUBSCRIBER_BUFFER, DEFAULT_MAX_SUBSCRIBERS, DEFAULT_POSE_BUFFER, DEFAULT_PREFIX, EVENT_ID_MAX_VALUE,
    GRAPH_UPDATED_EVENT_ID, HISTORY_SIZE, MAX_PREFIX_LEN, POSE_MAX_PUBLISHERS, POSE_MAX_SUBSCRIBERS,
    QUATERNION_NORM_TOLERANCE, SAFE_OVERFLOW, SUBSCRIBER_MAX_BORROWED_SAMPLES,
};
use op3dsg_ipc_types::{
    AFFORDANCES, EDGE_BYTES, EXECUTION_PROVIDERS, Edge, FIXED_STAGES, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS,
    FUTURE_POSE_LIMIT_NS, GraphHeader, Health, LABEL_CAPACITY_BYTES, MAX_EDGES, MAX_MODELS, MAX_NODES, MAX_QUEUES,
    MAX_REMOTE_WORKERS, MAX_STAGES, MAX_WORKERS, ModelHealth, NAME_CAPACITY_BYTES, NO_NODE, NODE_BYTES, Node,
    PHRASE_CAPACITY_BYTES, PoseHealth, PoseStamped, QueueHealth, RECORDER_STATES, REFINER_ERRORS, REFINER_FORMATS,
    REFINER_REJECTIONS, REFINER_STATES, REMOTE_KEY_CAPACITY_BYTES, REMOTE_REJECTIONS, RecorderHealth, RefinerHealth,
    RemoteHealth, RemoteWorkerHealth, SCHEMA_VERSION, SNAPSHOT_STATES, SOURCE_KINDS, SPATIAL_RELATIONS, SnapshotHealth,
    StageHealth, TF_PATH_CAPACITY_BYTES, TfHealth, ZeroCopySend,
};

/// The JSON object of one type: `"Name": {"type_name", "size", "align", "fields": [...]}`.
/// The closure is never called: its exhaustive pattern makes the compiler check the field list.
macro_rules! layout {
    ($out:expr, $t:ident { $($field:ident),* $(,)? }) => {{
        let _every_field_listed = |value: $t| {
            let $t { $($field: _),* } = value;
        };
        let value = <$t>::default();
        let mut fields = Vec::new();
        $(
            fields.push(format!(
                "{{\"name\": \"{}\", \"offset\": {}, \"size\": {}}}",
                stringify!($field),
                core::mem::offset_of!($t, $field),
                core::mem::size_of_val(&value.$field),
            ));
        )*
        $out.push(format!(
            "\"{}\": {{\"type_name\": \"{}\", \"size\": {}, \"align\": {}, \"fields\": [{}]}}",
            stringify!($t),
            type_name::<$t>(),
            core::mem::size_of::<$t>(),
            core::mem::align_of::<$t>(),
            fields.join(", "),
        ));
    }};
}

/// The `#[type_name]` iceoryx2 matches across processes and languages.
#[allow(unsafe_code)]
fn type_name<T: ZeroCopySend>() -> &'static str {
    // SAFETY: `type_name` is an unsafe trait fn only because implementors must keep it stable;
    // calling it has no precondition.
    unsafe { <T as ZeroCopySend>::type_name() }
}

fn json_strings(items: &[&str]) -> String {
    let quoted: Vec<String> = items.iter().map(|s| format!("\"{s}\"")).collect();
    format!("[{}]", quoted.join(", "))
}

fn main() {
    let mut types = graph_layouts();
    types.extend(health_layouts());
    println!("{{\"types\": {{{}}}, \"constants\": {{{}}}}}", types.join(", "), constants());
}

/// The layouts of the graph sample's records and of the pose input.
fn graph_layouts() -> Vec<String> {
    let mut types = Vec::new();
    layout!(
        types,
        Node {
            id,
            parent_id,
            kind,
            reserved,
            affordance_knowledge_bits,
            observation_count,
            label,
            confidence,
            centre_m,
            box_min_m,
            box_max_m,
            affordance_bits,
            affordance_llm_bits,
            obb_yaw_rad,
            last_seen_stamp_ns,
            obb_centre_m,
            obb_size_m,
        }
    );
    layout!(types, Edge { source_id, target_id, kind, origin, relation_id, confidence, phrase });
    layout!(
        types,
        GraphHeader {
            schema_version,
            node_count,
            graph_version,
            instance_id,
            stamp_ns,
            publish_time_ns,
            edge_count,
            object_count,
            part_count,
            capacity_exceeded,
            source_kind,
            reserved,
            total_node_count,
            total_edge_count,
            node_capacity,
            edge_capacity,
            world_frame,
            reserved2,
        }
    );
    layout!(types, PoseStamped { stamp_ns, kind, reserved, translation_m, rotation_xyzw, frame_id });
    types
}

/// The layouts of the health record and of the records it holds.
fn health_layouts() -> Vec<String> {
    let mut types = Vec::new();
    layout!(types, StageHealth { name, processed, rate_hz, latency_p50_us, latency_p99_us, errors, reserved });
    layout!(types, QueueHealth { name, depth, capacity, dropped, pushed });
    layout!(
        types,
        RefinerHealth {
            state,
            breaker_open,
            last_error,
            response_format,
            last_latency_us,
            refreshes,
            calls,
            failures,
            timeouts,
            rate_limited,
            accepted,
            last_graph_version,
            rejections,
        }
    );
    layout!(
        types,
        PoseHealth {
            accepted,
            unknown_kind,
            non_finite,
            non_unit_quaternion,
            no_base_from_camera,
            out_of_order,
            stale,
            future,
            queue_full,
            no_transform_path,
            frame_not_found,
            extrapolation,
        }
    );
    layout!(types, ModelHealth { name, sessions, provider, requested_provider, reserved });
    layout!(
        types,
        RecorderHealth { state, reserved, files, messages_written, messages_dropped, bytes_written, cpu_ns }
    );
    layout!(
        types,
        SnapshotHealth {
            state,
            reserved,
            write_p99_us,
            restored_version,
            version,
            last_written_unix_ms,
            last_bytes,
            written,
            failures,
            skipped,
        }
    );
    layout!(
        types,
        Health {
            schema_version,
            stage_count,
            stamp_ns,
            uptime_ns,
            frames_captured,
            keyframes,
            frames_without_pose,
            detections_fused,
            graph_version,
            map_memory_bytes,
            map_node_count,
            queue_count,
            source_connected,
            source_kind,
            graph_subscribers,
            dead_nodes_cleaned,
            stages,
            queues,
            refiner,
            pose,
            model_count,
            pose_source,
            reserved_models,
            models,
            recorder,
            snapshot,
            world_frame,
            tf,
            remote,
        }
    );
    types.extend(tf_layout());
    types.extend(remote_layout());
    types
}

/// Remote detection's part of the health record.
fn remote_layout() -> Vec<String> {
    let mut types = Vec::new();
    layout!(
        types,
        RemoteWorkerHealth {
            key,
            requests,
            replies,
            timeouts,
            late,
            unreachable,
            rejections,
            bytes_out,
            bytes_in,
            round_trip_p50_us,
            round_trip_p99_us,
            in_flight,
            alive,
            reserved,
        }
    );
    layout!(
        types,
        RemoteHealth {
            active,
            fallback_active,
            worker_count,
            workers_not_reported,
            fallback_keyframes,
            fallback_switches,
            workers,
        }
    );
    types
}

/// The tf input's part of the health record.
fn tf_layout() -> Vec<String> {
    let mut types = Vec::new();
    layout!(
        types,
        TfHealth {
            path,
            lookup_stamp_ns,
            newest_data_ns,
            dynamic_messages,
            static_messages,
            transforms_refused,
            time_jumps,
            active,
            reserved,
        }
    );
    types
}

/// The constants a client mirrors, as the members of a JSON object.
fn constants() -> String {
    let mut constants = String::new();
    let mut constant = |name: &str, value: String| {
        let _ = write!(constants, "{}\"{name}\": {value}", if constants.is_empty() { "" } else { ", " });
    };
    constant("SCHEMA_VERSION", SCHEMA_VERSION.to_string());
    constant("NODE_BYTES", NODE_BYTES.to_string());
    constant("EDGE_BYTES", EDGE_BYTES.to_string());
    constant("LABEL_CAPACITY_BYTES", LABEL_CAPACITY_BYTES.to_string());
    constant("PHRASE_CAPACITY_BYTES", PHRASE_CAPACITY_BYTES.to_string());
    constant("NAME_CAPACITY_BYTES", NAME_CAPACITY_BYTES.to_string());
    constant("TF_PATH_CAPACITY_BYTES", TF_PATH_CAPACITY_BYTES.to_string());
    constant("REMOTE_KEY_CAPACITY_BYTES", REMOTE_KEY_CAPACITY_BYTES.to_string());
    constant("MAX_REMOTE_WORKERS", MAX_REMOTE_WORKERS.to_string());
    constant("MAX_NODES", MAX_NODES.to_string());
    constant("MAX_EDGES", MAX_EDGES.to_string());
    constant("NO_NODE", NO_NODE.to_string());
    constant("MAX_WORKERS", MAX_WORKERS.to_string());
    constant("FIXED_STAGES", FIXED_STAGES.to_string());
    constant("MAX_STAGES", MAX_STAGES.to_string());
    constant("MAX_QUEUES", MAX_QUEUES.to_string());
    constant("MAX_MODELS", MAX_MODELS.to_string());
    constant("FUTURE_POSE_LIMIT_NS", FUTURE_POSE_LIMIT_NS.to_string());
    constant("FUNCTIONAL_RELATION_BASE", FUNCTIONAL_RELATION_BASE.to_string());
    constant("AFFORDANCES", json_strings(&AFFORDANCES));
    constant("SPATIAL_RELATIONS", json_strings(&SPATIAL_RELATIONS));
    constant("FUNCTIONAL_RELATIONS", json_strings(&FUNCTIONAL_RELATIONS));
    constant("EXECUTION_PROVIDERS", json_strings(&EXECUTION_PROVIDERS));
    constant("REFINER_STATES", json_strings(&REFINER_STATES));
    constant("RECORDER_STATES", json_strings(&RECORDER_STATES));
    constant("SNAPSHOT_STATES", json_strings(&SNAPSHOT_STATES));
    constant("REFINER_ERRORS", json_strings(&REFINER_ERRORS));
    constant("REFINER_FORMATS", json_strings(&REFINER_FORMATS));
    constant("REFINER_REJECTIONS", json_strings(&REFINER_REJECTIONS));
    constant("REMOTE_REJECTIONS", json_strings(&REMOTE_REJECTIONS));
    constant("SOURCE_KINDS", json_strings(&SOURCE_KINDS));
    constant("DEFAULT_PREFIX", format!("\"{DEFAULT_PREFIX}\""));
    constant("MAX_PREFIX_LEN", MAX_PREFIX_LEN.to_string());
    constant("HISTORY_SIZE", HISTORY_SIZE.to_string());
    constant("SAFE_OVERFLOW", SAFE_OVERFLOW.to_string());
    constant("DEFAULT_MAX_SUBSCRIBERS", DEFAULT_MAX_SUBSCRIBERS.to_string());
    constant("DEFAULT_GRAPH_SUBSCRIBER_BUFFER", DEFAULT_GRAPH_SUBSCRIBER_BUFFER.to_string());
    constant("SUBSCRIBER_MAX_BORROWED_SAMPLES", SUBSCRIBER_MAX_BORROWED_SAMPLES.to_string());
    constant("GRAPH_UPDATED_EVENT_ID", GRAPH_UPDATED_EVENT_ID.to_string());
    constant("EVENT_ID_MAX_VALUE", EVENT_ID_MAX_VALUE.to_string());
    constant("DEFAULT_POSE_BUFFER", DEFAULT_POSE_BUFFER.to_string());
    constant("POSE_MAX_PUBLISHERS", POSE_MAX_PUBLISHERS.to_string());
    constant("POSE_MAX_SUBSCRIBERS", POSE_MAX_SUBSCRIBERS.to_string());
    constant("QUATERNION_NORM_TOLERANCE", format!("{QUATERNION_NORM_TOLERANCE:?}"));
    constants
}
