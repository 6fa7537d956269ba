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
//! - **Client** ([`client`], re-exported here): [`GraphSubscriber`] waits for and copies the
//!   newest graph into an owned [`Graph`] with typed views ([`NodeView`], [`EdgeView`]);
//!   [`HealthSubscriber`] reads the daemon's [`Health`]; [`PosePublisher`] sends camera or base
//!   poses to the daemon.
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
//!     let Some(graph) = graphs.latest_if_newer(last_version)? else { continue };
//!     last_version = graph.version();
//!     for handle in graph.find_by_label("cabinet handle") {
//!         let cabinet = handle.parent().map(|p| p.label()).unwrap_or("?");
//!         println!("handle {} of {cabinet} at {:?} m", handle.id(), handle.centre_m());
//!     }
//! }
//! # }
//! ```
//!
//! Examples: `cargo run -p op3dsg-ipc-types --example planner -- --prefix op3dsg --versions 3`
//! prints each new graph version with every part and its parent object;
//! `cargo run -p op3dsg-ipc-types --example pose_publisher -- --seconds 10` sends a base driving a
//! circle at 10 Hz.
//!
//! Conventions used by every type:
//! - Units are part of field names: `_m` metres, `_ns` nanoseconds, `_us` microseconds, `_hz`.
//! - Coordinates are in the `world` frame of the map (right-handed; which axis is up is the
//!   profile's `world.up_axis`, `+z` by default).
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
//! | `<prefix>/graph`        | publish-subscribe | [`GraphSnapshot`]  | history 1, safe overflow, borrow 1    |
//! | `<prefix>/graph_updated`| event             | event id 0         | notified after each graph sample      |
//! | `<prefix>/health`       | publish-subscribe | [`Health`]         | history 1, safe overflow              |
//! | `<prefix>/pose`         | publish-subscribe | [`PoseStamped`]    | input: the navigation stack publishes |
//!
//! The exact figures and who creates which service are in [`services`]. `pose` may be created
//! first by the navigation stack with iceoryx2's default QoS: the daemon opens it as it is.
//!
//! [`Health`] tells the whole story without a graph subscriber ([`HealthSubscriber`]): every
//! stage ([`MAX_STAGES`] = [`MAX_WORKERS`] + [`FIXED_STAGES`]), every queue, the pose input by
//! outcome ([`PoseHealth`]), frames without a pose, the execution provider each model runs on
//! ([`ModelHealth`], names in [`EXECUTION_PROVIDERS`]) and the LLM refiner.
//!
//! ```
//! use op3dsg_ipc_types::{GraphSnapshot, ServiceNames};
//! let names = ServiceNames::new("op3dsg");
//! assert_eq!(names.graph, "op3dsg/graph");
//! // The snapshot is large and must be built in place (in shared memory), never on the stack.
//! assert!(core::mem::size_of::<GraphSnapshot>() > 1 << 20);
//! ```

/// The iceoryx2 this crate is built on, for a planner that attaches
/// [`GraphSubscriber::listener`] to its own `WaitSet` or sets iceoryx2's log level: using this
/// path keeps both on the same version.
pub use iceoryx2;
pub use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

pub mod client;
mod graph_types;
mod health_types;
mod pose_types;
pub mod publish;
pub mod services;
mod text;

pub use client::{
    ClientError, EdgeView, ErrorCause, Graph, GraphSubscriber, HealthSubscriber, NodeView, Operation, Pose,
    PosePublisher, SnapshotError, UnknownAffordance,
};
pub use graph_types::{
    AFFORDANCES, Edge, EdgeKind, EdgeOrigin, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS, GraphHeader,
    GraphSnapshot, LABEL_CAPACITY_BYTES, MAX_EDGES, MAX_NODES, NO_NODE, Node, NodeKind, PHRASE_CAPACITY_BYTES,
    SPATIAL_RELATIONS, affordance_bits, affordance_names, relation_id, relation_phrase,
};
pub use health_types::{
    EXECUTION_PROVIDERS, FIXED_STAGES, FUTURE_POSE_LIMIT_NS, Health, MAX_MODELS, MAX_QUEUES, MAX_STAGES, MAX_WORKERS,
    ModelHealth, PoseHealth, QueueHealth, REFINER_REJECTIONS, REFINER_STATES, RefinerHealth, StageHealth,
};
pub use pose_types::{PoseError, PoseKind, PoseStamped, check_pose};
pub use services::{IpcService, PrefixError, ServiceKind, ServiceNames, validate_prefix};
pub use text::{fixed_str, write_fixed_str};

/// Version of this wire contract. Bumped whenever a type's layout or meaning changes; a client
/// must check [`GraphHeader::schema_version`] and [`Health::schema_version`] before reading.
pub const SCHEMA_VERSION: u32 = 4;

/// Bytes in a frame id (`PoseStamped::frame_id`), a stage or a queue name.
pub const NAME_CAPACITY_BYTES: usize = 32;

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{align_of, size_of};

    #[test]
    fn layouts_are_the_documented_ones() {
        assert_eq!(size_of::<Node>(), 120);
        assert_eq!(align_of::<Node>(), 8);
        assert_eq!(size_of::<Edge>(), 64);
        assert_eq!(size_of::<GraphHeader>(), 56);
        assert_eq!(size_of::<PoseStamped>(), 104);
        assert_eq!(size_of::<StageHealth>(), 64);
        assert_eq!(size_of::<QueueHealth>(), 56);
        assert_eq!(size_of::<RefinerHealth>(), 128);
        assert_eq!(size_of::<PoseHealth>(), 96);
        assert_eq!(size_of::<ModelHealth>(), 40);
        assert_eq!(MAX_STAGES, 72);
        assert_eq!(size_of::<Health>(), 88 + MAX_STAGES * 64 + MAX_QUEUES * 56 + 128 + 96 + 8 + MAX_MODELS * 40);
        assert_eq!(size_of::<GraphSnapshot>(), 56 + MAX_NODES * size_of::<Node>() + MAX_EDGES * size_of::<Edge>());
    }

    #[test]
    #[allow(unsafe_code)]
    fn type_names_are_stable() {
        // SAFETY: `type_name` is an unsafe trait fn only because implementors must keep it stable.
        unsafe {
            assert_eq!(<Node as ZeroCopySend>::type_name(), "op3dsg::Node");
            assert_eq!(<GraphSnapshot as ZeroCopySend>::type_name(), "op3dsg::GraphSnapshot");
            assert_eq!(<Health as ZeroCopySend>::type_name(), "op3dsg::Health");
            assert_eq!(<RefinerHealth as ZeroCopySend>::type_name(), "op3dsg::RefinerHealth");
            assert_eq!(<PoseHealth as ZeroCopySend>::type_name(), "op3dsg::PoseHealth");
            assert_eq!(<ModelHealth as ZeroCopySend>::type_name(), "op3dsg::ModelHealth");
            assert_eq!(<PoseStamped as ZeroCopySend>::type_name(), "op3dsg::PoseStamped");
        }
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
}
