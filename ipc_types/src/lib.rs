//! # op3dsg wire contract and client
//!
//! This crate is all a planner, a navigation stack or a tool needs to talk to `op3dsgd` over
//! iceoryx2 shared memory. It depends on iceoryx2 alone and has two halves:
//!
//! - **Wire types** (the crate root): every type that travels is defined here, once. All are
//!   `#[repr(C)]`, plain data (no pointers, no heap), [`ZeroCopySend`] and carry a stable
//!   `#[type_name]`, so a C or Python client can mirror them field by field from this
//!   documentation alone (Python: a `ctypes.Structure` whose `type_name()` returns the name given
//!   below). [`services`] holds the service names, prefix rules and QoS both sides use.
//! - **Client** ([`client`], re-exported here): [`GraphSubscriber`] waits for the newest graph
//!   and lends it in place as a [`GraphView`] ([`GraphSubscriber::with_latest`], no copy) or
//!   copies it into an owned [`Graph`] with typed views ([`NodeView`], [`EdgeView`]);
//!   [`HealthSubscriber`] reads the daemon's [`Health`]; [`OccupancySubscriber`] its occupancy
//!   map; [`PosePublisher`] sends camera or base poses to the daemon; [`QueryClient`] asks it
//!   questions.
//!
//! ```no_run
//! use std::time::Duration;
//! use op3dsg_ipc_types::GraphSubscriber;
//!
//! # fn main() -> Result<(), op3dsg_ipc_types::ClientError> {
//! // Waits up to 30 s for the daemon to come up.
//! let mut graphs = GraphSubscriber::open_wait("op3dsg", "my-planner", Duration::from_secs(30))?;
//! let mut last_version = 0;
//! loop {
//!     graphs.wait_for_update(Duration::from_millis(500))?;
//!     // A graph of a restarted daemon (new instance id) counts as new whatever its version.
//!     let Some(graph) = graphs.latest_if_newer(last_version)? else { continue };
//!     if graph.restarted() {
//!         println!("op3dsgd restarted (instance {:#x}): re-check cached node ids", graph.instance_id());
//!     }
//!     last_version = graph.version();
//!     for handle in graph.find_by_label("cabinet handle") {
//!         let cabinet = handle.parent().map(|p| p.label()).unwrap_or("?");
//!         println!("handle {} of {cabinet} at {:?} m", handle.id(), handle.centre_m());
//!     }
//! }
//! # }
//! ```
//!
//! The same loop in place, for a planner that reads a few nodes of each new graph: the closure
//! gets a [`GraphView`] of the sample in shared memory and holds it only while it runs.
//!
//! ```no_run
//! # use std::time::Duration;
//! # let mut graphs = op3dsg_ipc_types::GraphSubscriber::open("op3dsg", "my-planner")?;
//! graphs.wait_for_update(Duration::from_millis(500))?;
//! graphs.with_latest(|graph| {
//!     for handle in graph.find_by_label("cabinet handle") {
//!         println!("handle {} of {:?} at {:?} m", handle.id(), handle.parent().map(|p| p.label()), handle.centre_m());
//!     }
//! })?;
//! # Ok::<(), op3dsg_ipc_types::ClientError>(())
//! ```
//!
//! Examples: `cargo run -p op3dsg-ipc-types --example planner -- --prefix op3dsg --versions 3`
//! prints each new graph version with every part and its parent object;
//! `cargo run -p op3dsg-ipc-types --example pose_publisher -- --seconds 10` sends a base driving a
//! circle at 10 Hz. `--example wire_layout` prints every wire type's size and field offsets as
//! JSON (the Python package's layout test compares its ctypes mirror with it); `--example
//! graph_bench` is the Rust side of `ipc_types/python/bench_latest.py`. The Python client,
//! `ipc_types/python/` (package `op3dsg`), reads the graph as numpy views of the sample.
//!
//! Conventions used by every type:
//! - Units are part of field names: `_m` metres, `_ns` nanoseconds, `_us` microseconds, `_hz`.
//! - Coordinates are in the world frame of the map, whose name every graph header carries
//!   ([`GraphHeader::world_frame`]: the profile's `world.frame_id`, `world` by default, `map` on
//!   the Stretch 3) (right-handed; which axis is up is the profile's `world.up_axis`, `+z` by
//!   default). Poses sent on `pose` are in that frame too.
//! - What the graph is of: [`GraphHeader::source_kind`] (and [`Health::source_kind`]) says
//!   whether the daemon reads a live camera, a replay or the synthetic rooms ([`SourceKind`]).
//! - Stamps are nanoseconds on the daemon's clock (`CLOCK_REALTIME` for live cameras, the
//!   recording's clock for replay, scene time for the synthetic source).
//! - Text is UTF-8 in a fixed buffer, padded with NUL bytes; a string that fills the buffer has no
//!   terminating NUL. Use [`fixed_str`] / [`write_fixed_str`] from Rust.
//! - Boolean-like fields are `u8` (0 or 1) so their size is the same in every language.
//!
//! ## Services (names under a configurable prefix, default `op3dsg`)
//!
//! | service                 | pattern           | payload            | QoS                                   |
//! |-------------------------|-------------------|--------------------|---------------------------------------|
//! | `<prefix>/graph`        | publish-subscribe | bytes + [`GraphHeader`] | history 1, safe overflow, borrow 1 |
//! | `<prefix>/graph_updated`| event             | event id 0         | notified after each graph sample      |
//! | `<prefix>/health`       | publish-subscribe | [`Health`]         | history 1, safe overflow              |
//! | `<prefix>/pose`         | publish-subscribe | [`PoseStamped`]    | input: the navigation stack publishes |
//! | `<prefix>/query`        | request-response  | [`QueryRequest`] → [`QueryResponse`] | one reply per request; hits with approach poses |
//! | `<prefix>/occupancy`    | publish-subscribe | `[i8]` cells + [`OccupancyHeader`] | history 1, about 1 Hz ([`occupancy_types`]) |
//!
//! The exact figures and who creates which service are in [`services`]. `pose` may be created
//! first by the navigation stack with iceoryx2's default QoS: the daemon opens it as it is.
//!
//! [`Health`] tells the whole story without a graph subscriber ([`HealthSubscriber`]): every
//! stage ([`MAX_STAGES`] = [`MAX_WORKERS`] + [`FIXED_STAGES`]), every queue, the pose input by
//! outcome ([`PoseHealth`]), frames without a pose, the execution provider each model runs on
//! ([`ModelHealth`], names in [`EXECUTION_PROVIDERS`]) and the LLM refiner.
//!
//! ## The graph sample
//!
//! `<prefix>/graph` is an iceoryx2 slice service: payload `[u8]`, user header [`GraphHeader`]
//! (type name `op3dsg::GraphHeader`). The payload is exactly
//! `node_count * NODE_BYTES + edge_count * EDGE_BYTES` bytes: the nodes (sorted by id), then the
//! edges, each record laid out as its struct ([`Node`], 144 bytes; [`Edge`], 64 bytes),
//! little-endian. So a sample costs what the graph holds: a 100-node graph is about 27 KB, not
//! the daemon's maximum (set by the profile's `ipc.max_nodes` / `ipc.max_edges`, default
//! [`MAX_NODES`] / [`MAX_EDGES`], about 4.3 MiB). A Python or C client reads the header, then views
//! the payload as `node_count` node records followed by `edge_count` edge records.
//!
//! **Restarts**: [`GraphHeader::instance_id`] is drawn anew (never 0) each time the daemon starts.
//! Versions only grow within one instance; a restarted daemon starts again at version 1. A
//! planner that sees an instance id other than the last one it saw must forget its version
//! bookkeeping (and cached node ids) and take the new graph. [`GraphSubscriber::latest_if_newer`]
//! does this, and [`Graph::restarted`] / [`GraphSubscriber::restarted`] say it happened.
//!
//! ```
//! use op3dsg_ipc_types::publish::GraphBuffer;
//! use op3dsg_ipc_types::{Graph, Node, SCHEMA_VERSION, ServiceNames, graph_payload_bytes};
//! let names = ServiceNames::new("op3dsg");
//! assert_eq!(names.graph, "op3dsg/graph");
//! // A sample holds what the graph holds: here 3 nodes, 432 bytes of payload.
//! let mut buffer = GraphBuffer::new();
//! buffer.header.schema_version = SCHEMA_VERSION;
//! buffer.header.node_capacity = 16_384;
//! buffer.nodes = (1..=3).map(|id| Node { id, kind: 0, ..Node::default() }).collect();
//! let message = buffer.encode();
//! assert_eq!(message.payload.len(), graph_payload_bytes(3, 0));
//! let graph = Graph::from_message(&message).expect("valid");
//! assert_eq!(graph.node_count(), 3);
//! ```

/// The iceoryx2 this crate is built on, for a planner that attaches
/// [`GraphSubscriber::listener`] to its own `WaitSet` or sets iceoryx2's log level: using this
/// path keeps both on the same version.
pub use iceoryx2;
pub use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

pub mod access;
pub mod client;
mod graph_types;
mod health_types;
pub mod occupancy_types;
mod pose_types;
pub mod publish;
pub mod query_types;
pub mod remote;
pub mod services;
mod text;

pub use access::{IPC_ROOT_ENV, IpcRoot, RootError};
pub use client::{
    ClientError, EdgeRef, EdgeView, ErrorCause, Graph, GraphSubscriber, GraphView, HealthSubscriber, NodeRef, NodeView,
    OccupancyError, OccupancyMap, OccupancySubscriber, Operation, Pose, PosePublisher, QueryClient, QueryClientError,
    SnapshotError, UnknownAffordance, check_layout, check_message, check_occupancy,
};
pub use graph_types::{
    AFFORDANCES, EDGE_BYTES, Edge, EdgeKind, EdgeOrigin, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS, GraphHeader,
    GraphMessage, LABEL_CAPACITY_BYTES, MAX_EDGES, MAX_NODES, NO_NODE, NODE_BYTES, Node, NodeKind,
    PHRASE_CAPACITY_BYTES, SOURCE_KINDS, SPATIAL_RELATIONS, SourceKind, affordance_bits, affordance_names,
    affordance_origin, affordance_origins, graph_payload_bytes, relation_id, relation_phrase,
};
pub use health_types::{
    EXECUTION_PROVIDERS, FIXED_STAGES, FUTURE_POSE_LIMIT_NS, Health, MAX_MODELS, MAX_QUEUES, MAX_REMOTE_WORKERS,
    MAX_STAGES, MAX_WORKERS, ModelHealth, POSE_SOURCES, PoseHealth, QueueHealth, RECORDER_STATES, REFINER_ERRORS,
    REFINER_FORMATS, REFINER_REJECTIONS, REFINER_STATES, REMOTE_KEY_CAPACITY_BYTES, REMOTE_REJECTIONS, RecorderHealth,
    RefinerHealth, RemoteHealth, RemoteWorkerHealth, SNAPSHOT_STATES, SnapshotHealth, StageHealth,
    TF_PATH_CAPACITY_BYTES, TfHealth,
};
pub use occupancy_types::{
    OCCUPANCY_FREE_MAX_PERCENT, OCCUPANCY_MAX_SIDE_CELLS, OCCUPANCY_OCCUPIED_MIN_PERCENT, OCCUPANCY_SCHEMA_VERSION,
    OCCUPANCY_UNKNOWN, OccupancyHeader,
};
pub use pose_types::{PoseError, PoseKind, PoseStamped, check_pose};
pub use query_types::{
    ApproachStatus, QUERY_MAX_K, QUERY_SCHEMA_VERSION, QUERY_TEXT_CAPACITY_BYTES, QueryHit, QueryMatch, QueryRequest,
    QueryResponse, QueryStatus,
};
pub use services::{IpcService, PrefixError, ServiceKind, ServiceNames, validate_prefix};
pub use text::{fixed_str, without_source_locations, write_fixed_str};

/// Version of this wire contract. Bumped whenever a type's layout or meaning changes; a client
/// must check [`GraphHeader::schema_version`] and [`Health::schema_version`] before reading.
///
/// 4: the graph is a slice sample sized to the graph (bytes + [`GraphHeader`] user header) instead
/// of a fixed `GraphSnapshot`; the header gained `instance_id`, `node_capacity`, `edge_capacity`.
///
/// 5: [`Node`] grew from 120 to 144 bytes with its gravity-aligned oriented box: `obb_yaw_rad`
/// at offset 108 (where 4 reserved bytes were; `reserved2` is 2 bytes now), `obb_centre_m` at 120
/// and `obb_size_m` at 132, after `last_seen_stamp_ns`; every other offset is unchanged.
///
/// 6: [`Health`] gained `snapshot` ([`SnapshotHealth`], 64 bytes) after `recorder`, and
/// [`RefinerHealth`]'s last reserved byte became `response_format` ([`REFINER_FORMATS`]); the
/// graph's layout is unchanged.
///
/// 7: every affordance carries an origin like an edge: [`Node`]'s reserved bytes 10..12 became
/// `affordance_knowledge_bits` and `reserved2` (106..108) `affordance_llm_bits`; sizes and every
/// other offset are unchanged (`reserved` is the one byte at 9).
///
/// 8: [`Health`]'s reserved bytes after `source_connected` became `graph_subscribers` (u16) and
/// `dead_nodes_cleaned` (u32), with one reserved byte before them; its size and every other
/// offset are unchanged, and so is the graph's layout.
///
/// 9: what the graph is of. [`GraphHeader`] grew from 80 to 112 bytes: its first reserved byte
/// (offset 53) became `source_kind` ([`SourceKind`]: live camera, replay, synthetic, unknown;
/// `reserved` is the 2 bytes at 54), and after `edge_capacity` come `world_frame` (32 bytes at
/// 72: the frame the coordinates are in, the profile's `world.frame_id`) and an 8-byte
/// `reserved2` at 104 (was 4 bytes at 72); every other offset is unchanged. [`Health`]'s
/// reserved byte after `source_connected` became `source_kind`, and `world_frame` (32 bytes)
/// was appended after `snapshot`; every other offset is unchanged.
///
/// 10: [`Health`] grew by [`TfHealth`] (256 bytes) after `world_frame`: the tf input's last
/// chain, its stamp and data age, and its message counters. The graph's layout is unchanged.
///
/// 11: [`Health`] grew by [`RemoteHealth`] (1,752 bytes) after `tf`: remote detection's fallback
/// and its workers' requests, replies, timeouts, rejections by reason, bytes and round trips.
/// The graph's layout is unchanged.
///
/// 12: [`Health`]'s `reserved_models` (u32 after `model_count`) became `pose_source` (u8: where
/// the keyframe gate takes poses from, [`POSE_SOURCES`]) and 3 reserved bytes; its size and
/// every offset are unchanged, and so is the graph's layout.
pub const SCHEMA_VERSION: u32 = 12;

/// Bytes in a frame id (`PoseStamped::frame_id`), a stage or a queue name.
pub const NAME_CAPACITY_BYTES: usize = 32;

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{align_of, size_of};

    #[test]
    fn layouts_are_the_documented_ones() {
        assert_eq!(size_of::<Node>(), 144);
        assert_eq!(core::mem::offset_of!(Node, affordance_knowledge_bits), 10);
        assert_eq!(core::mem::offset_of!(Node, observation_count), 12);
        assert_eq!(core::mem::offset_of!(Node, affordance_llm_bits), 106);
        assert_eq!(core::mem::offset_of!(Node, obb_yaw_rad), 108);
        assert_eq!(core::mem::offset_of!(Node, last_seen_stamp_ns), 112);
        assert_eq!(core::mem::offset_of!(Node, obb_centre_m), 120);
        assert_eq!(core::mem::offset_of!(Node, obb_size_m), 132);
        assert_eq!(align_of::<Node>(), 8);
        assert_eq!(size_of::<Edge>(), 64);
        assert_eq!(size_of::<GraphHeader>(), 112);
        assert_eq!(align_of::<GraphHeader>(), 8);
        assert_eq!((NODE_BYTES, EDGE_BYTES), (size_of::<Node>(), size_of::<Edge>()));
        assert_eq!(size_of::<PoseStamped>(), 104);
        assert_eq!(size_of::<StageHealth>(), 64);
        assert_eq!(size_of::<QueueHealth>(), 56);
        assert_eq!(size_of::<RefinerHealth>(), 128);
        assert_eq!(size_of::<PoseHealth>(), 96);
        assert_eq!(size_of::<ModelHealth>(), 40);
        assert_eq!(MAX_STAGES, 72);
        assert_eq!(
            size_of::<Health>(),
            88 + MAX_STAGES * 64
                + MAX_QUEUES * 56
                + 128
                + 96
                + 8
                + MAX_MODELS * 40
                + 40
                + 64
                + NAME_CAPACITY_BYTES
                + 256
                + 1752
        );
        assert_eq!(core::mem::offset_of!(Health, source_kind), 81);
        assert_eq!(core::mem::offset_of!(Health, world_frame), size_of::<Health>() - NAME_CAPACITY_BYTES - 256 - 1752);
        assert_eq!(size_of::<TfHealth>(), 256);
        assert_eq!(core::mem::offset_of!(Health, tf), size_of::<Health>() - 256 - 1752);
        assert_eq!(size_of::<RemoteWorkerHealth>(), 216);
        assert_eq!(size_of::<RemoteHealth>(), 1752);
        assert_eq!(core::mem::offset_of!(Health, remote), size_of::<Health>() - 1752);
        assert_eq!(size_of::<SnapshotHealth>(), 64);
        assert_eq!(core::mem::offset_of!(GraphHeader, instance_id), 16);
        assert_eq!(core::mem::offset_of!(GraphHeader, capacity_exceeded), 52);
        assert_eq!(core::mem::offset_of!(GraphHeader, node_capacity), 64);
        assert_eq!(core::mem::offset_of!(GraphHeader, source_kind), 53);
        assert_eq!(core::mem::offset_of!(GraphHeader, reserved), 54);
        assert_eq!(core::mem::offset_of!(GraphHeader, world_frame), 72);
        assert_eq!(core::mem::offset_of!(GraphHeader, reserved2), 104);
    }

    #[test]
    #[allow(unsafe_code)]
    fn type_names_are_stable() {
        // SAFETY: `type_name` is an unsafe trait fn only because implementors must keep it stable.
        unsafe {
            assert_eq!(<Node as ZeroCopySend>::type_name(), "op3dsg::Node");
            assert_eq!(<GraphHeader as ZeroCopySend>::type_name(), "op3dsg::GraphHeader");
            assert_eq!(<Health as ZeroCopySend>::type_name(), "op3dsg::Health");
            assert_eq!(<RefinerHealth as ZeroCopySend>::type_name(), "op3dsg::RefinerHealth");
            assert_eq!(<PoseHealth as ZeroCopySend>::type_name(), "op3dsg::PoseHealth");
            assert_eq!(<ModelHealth as ZeroCopySend>::type_name(), "op3dsg::ModelHealth");
            assert_eq!(<SnapshotHealth as ZeroCopySend>::type_name(), "op3dsg::SnapshotHealth");
            assert_eq!(<PoseStamped as ZeroCopySend>::type_name(), "op3dsg::PoseStamped");
        }
    }

    #[test]
    fn records_round_trip_through_their_bytes_at_the_struct_offsets() {
        let mut node = Node { id: 7, parent_id: 3, kind: 1, observation_count: 9, ..Node::default() };
        write_fixed_str(&mut node.label, "cabinet handle");
        node.confidence = 0.5;
        node.centre_m = [1.0, 2.0, 3.0];
        node.box_min_m = [-1.0, -2.0, -3.0];
        node.box_max_m = [4.0, 5.0, 6.0];
        node.affordance_bits = 0b1001;
        node.affordance_knowledge_bits = 0b0001;
        node.affordance_llm_bits = 0b1001;
        node.last_seen_stamp_ns = 0x0102_0304_0506_0708;
        node.obb_yaw_rad = 0.25;
        node.obb_centre_m = [1.5, 1.5, 1.5];
        node.obb_size_m = [0.5, 0.75, 9.0];
        let mut bytes = Vec::new();
        node.append_bytes(&mut bytes);
        assert_eq!(bytes.len(), NODE_BYTES);
        let u32_at = |b: &[u8], o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        assert_eq!(u32_at(&bytes, core::mem::offset_of!(Node, parent_id)), 3);
        assert_eq!(bytes[core::mem::offset_of!(Node, kind)], 1);
        assert_eq!(f32::from_bits(u32_at(&bytes, core::mem::offset_of!(Node, box_max_m) + 8)), 6.0);
        assert_eq!(bytes[core::mem::offset_of!(Node, last_seen_stamp_ns)], 0x08);
        assert_eq!(f32::from_bits(u32_at(&bytes, core::mem::offset_of!(Node, obb_yaw_rad))), 0.25);
        assert_eq!(f32::from_bits(u32_at(&bytes, core::mem::offset_of!(Node, obb_size_m) + 8)), 9.0);
        let back = Node::from_bytes(&bytes.as_chunks::<NODE_BYTES>().0[0]);
        assert_eq!(
            (back.id, back.label_str(), back.box_max_m, back.last_seen_stamp_ns),
            (7, "cabinet handle", [4.0, 5.0, 6.0], node.last_seen_stamp_ns)
        );
        assert_eq!((back.affordance_bits, back.observation_count, back.confidence), (0b1001, 9, 0.5));
        assert_eq!(u16::from_le_bytes([bytes[10], bytes[11]]), 0b0001, "affordance_knowledge_bits at 10");
        assert_eq!(u16::from_le_bytes([bytes[106], bytes[107]]), 0b1001, "affordance_llm_bits at 106");
        assert_eq!((back.affordance_knowledge_bits, back.affordance_llm_bits), (0b0001, 0b1001));
        let origins: Vec<_> = affordance_origins(back.affordance_bits, 0b0001, 0b1001).collect();
        assert_eq!(origins, [("rotate", EdgeOrigin::KnowledgeAndLlm), ("hook_pull", EdgeOrigin::Llm)]);
        assert_eq!((back.obb_yaw_rad, back.obb_centre_m, back.obb_size_m), (0.25, [1.5; 3], [0.5, 0.75, 9.0]));

        let mut edge = Edge {
            source_id: 7,
            target_id: 3,
            kind: 1,
            origin: 2,
            relation_id: 105,
            confidence: 0.25,
            ..Edge::default()
        };
        write_fixed_str(&mut edge.phrase, "remote to control");
        bytes.clear();
        edge.append_bytes(&mut bytes);
        assert_eq!(bytes.len(), EDGE_BYTES);
        assert_eq!(bytes[core::mem::offset_of!(Edge, origin)], 2);
        let back = Edge::from_bytes(&bytes.as_chunks::<EDGE_BYTES>().0[0]);
        assert_eq!((back.source_id, back.target_id, back.kind, back.origin, back.relation_id), (7, 3, 1, 2, 105));
        assert_eq!((back.confidence, back.phrase_str()), (0.25, "remote to control"));
    }

    #[test]
    fn relation_ids_round_trip() {
        for phrase in SPATIAL_RELATIONS.iter().chain(FUNCTIONAL_RELATIONS.iter()) {
            let (_, id) = relation_id(phrase).unwrap();
            assert_eq!(relation_phrase(id), Some(*phrase));
            assert!(phrase.len() <= PHRASE_CAPACITY_BYTES);
        }
        assert_eq!(relation_id("part of"), Some((EdgeKind::Spatial, 0)));
        assert_eq!(relation_id("remote to control"), Some((EdgeKind::Functional, 105)));
        assert_eq!(relation_id("frobnicate"), None);
    }

    #[test]
    fn affordance_bits_round_trip() {
        let bits = affordance_bits(["hook_pull", "rotate"]).unwrap();
        assert_eq!(bits, 0b1001);
        assert_eq!(affordance_names(bits).collect::<Vec<_>>(), ["rotate", "hook_pull"]);
        assert_eq!(affordance_bits(["fly"]), Err("fly"));
    }

    #[test]
    fn each_affordance_origin_follows_from_the_two_masks() {
        let bits = affordance_bits(["rotate", "tip_push", "hook_pull", "pinch_pull"]).unwrap();
        let knowledge = affordance_bits(["rotate", "hook_pull", "unplug"]).unwrap();
        let llm = affordance_bits(["rotate", "pinch_pull", "plug_in"]).unwrap();
        assert_eq!(
            affordance_origins(bits, knowledge, llm).collect::<Vec<_>>(),
            [
                ("rotate", EdgeOrigin::KnowledgeAndLlm),
                ("tip_push", EdgeOrigin::Geometry),
                ("hook_pull", EdgeOrigin::Knowledge),
                ("pinch_pull", EdgeOrigin::Llm),
            ],
            "origin bits outside affordance_bits (unplug, plug_in) mean nothing"
        );
        assert_eq!(affordance_origin(bits, knowledge, llm, 7), None);
        assert_eq!(affordance_origin(u16::MAX, u16::MAX, 0, 9), None, "past the 9 canonical affordances");
        let node = Node { affordance_bits: bits, affordance_knowledge_bits: knowledge, ..Node::default() };
        assert_eq!(node.affordance_origin(4), Some(EdgeOrigin::Geometry));
        assert_eq!(node.affordance_origin(0), Some(EdgeOrigin::Knowledge));
    }
}
