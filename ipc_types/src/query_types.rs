//! The language query service `<prefix>/query` (iceoryx2 request-response): a planner sends a
//! need in words ([`QueryRequest`]) and gets the best-matching nodes of the current graph with
//! their scores and why they matched ([`QueryResponse`]).
//!
//! Both types are fixed-size and `#[repr(C)]`, copied in place into the loaned request and
//! response like every other op3dsg payload. Their layouts are new types, so the graph and
//! health schema ([`SCHEMA_VERSION`](crate::SCHEMA_VERSION)) is unchanged; each carries its own
//! [`QUERY_SCHEMA_VERSION`].
//!
//! | type | type name | bytes |
//! |---|---|---|
//! | [`QueryRequest`] | `op3dsg::QueryRequest` | 272 |
//! | [`QueryHit`] | (inside the response) | 192 (`approach_status` at 160) |
//! | [`QueryResponse`] | `op3dsg::QueryResponse` | 224 + 16 × 192 = 3296 (`message` at 64, `hits` at 224) |
//!
//! ## Schema versions
//!
//! - **2** (current): a request may name a node instead of a text ([`QueryRequest::node_id`],
//!   the text encoder is then not needed), and every hit carries a navigation target (the
//!   `approach_*` fields of [`QueryHit`], status [`ApproachStatus`]): a free cell of the daemon's
//!   occupancy map at the profile's standoff from the node, facing it, reachable from the robot's
//!   latest pose. Request 264 → 272 bytes (`node_id`, `reserved` appended), hit 160 → 192 bytes
//!   (the approach fields appended), response 2784 → 3296 bytes; every version-1 field keeps its
//!   offset inside its record.
//! - **1**: text requests, hits without approach poses.
//!
//! Across versions the payload sizes differ, so iceoryx2 refuses to open the service for a client
//! of the other version (payload type mismatch at open): rebuild the client. A same-sized request
//! with another `schema_version` gets [`QueryStatus::BadRequest`] naming `schema_version`.
//!
//! One request gets exactly one response. A request the daemon cannot take now (its bounded
//! request queue is full) gets a [`QueryStatus::Busy`] response at once, never silence.

mod bytes;

use iceoryx2::prelude::ZeroCopySend;

pub use bytes::{QUERY_HIT_BYTES, QUERY_REQUEST_BYTES, QUERY_RESPONSE_BYTES};

use crate::text::{fixed_str, write_fixed_str};
use crate::{LABEL_CAPACITY_BYTES, NO_NODE, NodeKind};

/// Version of the query request and response layouts.
pub const QUERY_SCHEMA_VERSION: u32 = 2;
/// Bytes of a query text (UTF-8, NUL padded); a longer text is refused.
pub const QUERY_TEXT_CAPACITY_BYTES: usize = 256;
/// Most hits one response carries (a larger `k` is answered with this many).
pub const QUERY_MAX_K: usize = 16;
/// Bytes of the text that matched best (label, "knob of the stove", an affordance or edge phrase).
pub const QUERY_MATCHED_TEXT_CAPACITY_BYTES: usize = 96;
/// Bytes of a response's message (the reason of an error or refusal).
pub const QUERY_MESSAGE_CAPACITY_BYTES: usize = 160;

/// A query: the need in words and how many nodes to return.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("op3dsg::QueryRequest")]
pub struct QueryRequest {
    /// [`QUERY_SCHEMA_VERSION`] of the sender.
    pub schema_version: u32,
    /// Nodes wanted, 1..=[`QUERY_MAX_K`] (0 is a bad request; more is cut to [`QUERY_MAX_K`]).
    pub k: u32,
    /// The need, UTF-8, NUL padded ("somewhere to wash my hands"); ignored (may be empty) when
    /// `node_id` names a node.
    pub text: [u8; QUERY_TEXT_CAPACITY_BYTES],
    /// [`NO_NODE`]: a text query. Any other value: the reply holds that node alone (score 1,
    /// matched `label`) with its approach pose, or [`QueryStatus::BadRequest`] naming `node_id`
    /// when the current graph has no such node. Needs no text encoder. Since schema 2.
    pub node_id: u32,
    /// Reserved, zero.
    pub reserved: u32,
}

impl Default for QueryRequest {
    fn default() -> Self {
        Self {
            schema_version: QUERY_SCHEMA_VERSION,
            k: 5,
            text: [0; QUERY_TEXT_CAPACITY_BYTES],
            node_id: NO_NODE,
            reserved: 0,
        }
    }
}

impl QueryRequest {
    /// A request for `text` and `k` nodes; `None` when the text does not fit
    /// [`QUERY_TEXT_CAPACITY_BYTES`].
    pub fn new(text: &str, k: u32) -> Option<Self> {
        let mut request = Self { k, ..Self::default() };
        write_fixed_str(&mut request.text, text).then_some(request)
    }

    /// A request for node `node_id` alone (its approach pose).
    pub fn for_node(node_id: u32) -> Self {
        Self { k: 1, node_id, ..Self::default() }
    }

    /// The node asked for, `None` for a text query.
    pub fn asked_node(&self) -> Option<u32> {
        (self.node_id != NO_NODE).then_some(self.node_id)
    }

    /// The text.
    pub fn text_str(&self) -> &str {
        fixed_str(&self.text)
    }
}

/// What a response says about its request.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QueryStatus {
    /// `hits` holds the top `hit_count` nodes, best first.
    Ok = 0,
    /// Refused: the daemon's request queue (`query.queue_capacity`) was full. Try again later.
    Busy = 1,
    /// The daemon runs without the text encoder (`text_encoder.enabled = false`), so it cannot
    /// score text; `message` says what to set.
    EncoderOff = 2,
    /// No graph has been published yet.
    NoGraph = 3,
    /// The request is malformed (schema, `k` = 0, empty text); `message` names the field.
    BadRequest = 4,
    /// The text encoder failed on this text; `message` has its error.
    EncoderFailed = 5,
    /// The daemon is stopping.
    ShuttingDown = 6,
}

impl QueryStatus {
    /// Decodes the wire value.
    pub fn from_u8(value: u8) -> Option<Self> {
        Some(match value {
            0 => Self::Ok,
            1 => Self::Busy,
            2 => Self::EncoderOff,
            3 => Self::NoGraph,
            4 => Self::BadRequest,
            5 => Self::EncoderFailed,
            6 => Self::ShuttingDown,
            _ => return None,
        })
    }

    /// Lower-case name ("ok", "busy", "encoder_off", ...).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Busy => "busy",
            Self::EncoderOff => "encoder_off",
            Self::NoGraph => "no_graph",
            Self::BadRequest => "bad_request",
            Self::EncoderFailed => "encoder_failed",
            Self::ShuttingDown => "shutting_down",
        }
    }
}

/// Which of a node's texts matched the query best (the "why" of a hit).
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum QueryMatch {
    /// The node's own label ("sink").
    Label = 0,
    /// The label with its parent object's ("knob of the stove"; parts only).
    ParentLabel = 1,
    /// One of the node's affordances as a phrase ("pull the fridge handle").
    Affordance = 2,
    /// The phrase of a functional edge the node takes part in, with the other end's label
    /// ("light switch: turn on or turn off the ceiling light").
    Functional = 3,
}

impl QueryMatch {
    /// Decodes the wire value.
    pub fn from_u8(value: u8) -> Option<Self> {
        Some(match value {
            0 => Self::Label,
            1 => Self::ParentLabel,
            2 => Self::Affordance,
            3 => Self::Functional,
            _ => return None,
        })
    }

    /// Lower-case name ("label", "parent_label", "affordance", "functional").
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Label => "label",
            Self::ParentLabel => "parent_label",
            Self::Affordance => "affordance",
            Self::Functional => "functional",
        }
    }
}

/// Whether a hit carries a navigation target ([`QueryHit::approach_status`]).
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ApproachStatus {
    /// The daemon builds no occupancy map (`occupancy.enabled = false`): no target computed.
    Off = 0,
    /// `approach_*` hold a free, reachable pose facing the node.
    Ok = 1,
    /// No free cell of the map lies within the standoff band around the node (for a part: on
    /// the side it faces).
    NoFreeCell = 2,
    /// Free cells lie within the band, but none is reachable from the robot's latest pose.
    Unreachable = 3,
    /// No occupancy map yet (no keyframe integrated).
    NoMap = 4,
    /// The robot's latest position is outside the map or not on a free cell.
    RobotNotOnMap = 5,
}

impl ApproachStatus {
    /// Decodes the wire value.
    pub fn from_u8(value: u8) -> Option<Self> {
        Some(match value {
            0 => Self::Off,
            1 => Self::Ok,
            2 => Self::NoFreeCell,
            3 => Self::Unreachable,
            4 => Self::NoMap,
            5 => Self::RobotNotOnMap,
            _ => return None,
        })
    }

    /// Lower-case name ("off", "ok", "no_free_cell", "unreachable", "no_map", "robot_not_on_map").
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::Ok => "ok",
            Self::NoFreeCell => "no_free_cell",
            Self::Unreachable => "unreachable",
            Self::NoMap => "no_map",
            Self::RobotNotOnMap => "robot_not_on_map",
        }
    }

    /// A sentence for people ("no free cell within the standoff band", ...).
    pub fn explain(self) -> &'static str {
        match self {
            Self::Off => "the daemon builds no occupancy map (occupancy.enabled = false)",
            Self::Ok => "approach pose found",
            Self::NoFreeCell => "no free cell within the standoff band",
            Self::Unreachable => "unreachable from the robot's pose",
            Self::NoMap => "no occupancy map yet (no keyframe integrated)",
            Self::RobotNotOnMap => "the robot's latest position is not on a free cell of the map",
        }
    }
}

/// One node of a response.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("op3dsg::QueryHit")]
pub struct QueryHit {
    /// Node id in the graph of [`QueryResponse::graph_version`].
    pub node_id: u32,
    /// Its parent object's id, [`NO_NODE`] for objects and unattached parts.
    pub parent_id: u32,
    /// [`NodeKind`] as `u8`: 0 object, 1 part.
    pub kind: u8,
    /// [`QueryMatch`] as `u8`: which text matched best.
    pub matched: u8,
    /// Reserved, zero.
    pub reserved: [u8; 2],
    /// Score: the cosine similarity of the query and `matched_text` (see the daemon's
    /// `query` module for the formula), in [-1, 1].
    pub score: f32,
    /// The node's label, UTF-8, NUL padded.
    pub label: [u8; LABEL_CAPACITY_BYTES],
    /// The text that matched best, UTF-8, NUL padded.
    pub matched_text: [u8; QUERY_MATCHED_TEXT_CAPACITY_BYTES],
    /// [`ApproachStatus`] as `u8`; the `approach_*` values below hold only with `Ok` (1).
    /// Since schema 2.
    pub approach_status: u8,
    /// Reserved, zero.
    pub reserved2: [u8; 3],
    /// Where to stand: the approach cell's centre on the floor plane, first axis (see
    /// [`occupancy_types`](crate::occupancy_types) for the plane's axes), metres.
    pub approach_x_m: f32,
    /// The same, second axis, metres.
    pub approach_y_m: f32,
    /// Heading that faces the node's centre from there, `atan2(second, first)`, radians.
    pub approach_yaw_rad: f32,
    /// Distance from the approach position to the node's footprint (its box on the floor
    /// plane), metres: within `[navigation.standoff_min_m, navigation.standoff_max_m]`.
    pub approach_standoff_m: f32,
    /// Length of the A* path from the robot's latest position to the approach position on the
    /// occupancy map, metres.
    pub approach_path_m: f32,
    /// Reserved, zero.
    pub reserved3: [u32; 2],
}

impl Default for QueryHit {
    fn default() -> Self {
        Self {
            node_id: NO_NODE,
            parent_id: NO_NODE,
            kind: 0,
            matched: 0,
            reserved: [0; 2],
            score: 0.0,
            label: [0; LABEL_CAPACITY_BYTES],
            matched_text: [0; QUERY_MATCHED_TEXT_CAPACITY_BYTES],
            approach_status: ApproachStatus::Off as u8,
            reserved2: [0; 3],
            approach_x_m: 0.0,
            approach_y_m: 0.0,
            approach_yaw_rad: 0.0,
            approach_standoff_m: 0.0,
            approach_path_m: 0.0,
            reserved3: [0; 2],
        }
    }
}

impl QueryHit {
    /// The label as text.
    pub fn label_str(&self) -> &str {
        fixed_str(&self.label)
    }
    /// The matched text.
    pub fn matched_text_str(&self) -> &str {
        fixed_str(&self.matched_text)
    }
    /// The node kind, `None` for an unknown value.
    pub fn node_kind(&self) -> Option<NodeKind> {
        NodeKind::from_u8(self.kind)
    }
    /// What matched, `None` for an unknown value.
    pub fn query_match(&self) -> Option<QueryMatch> {
        QueryMatch::from_u8(self.matched)
    }
    /// The approach status, `None` for an unknown value.
    pub fn approach(&self) -> Option<ApproachStatus> {
        ApproachStatus::from_u8(self.approach_status)
    }
}

/// The answer to one [`QueryRequest`].
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("op3dsg::QueryResponse")]
pub struct QueryResponse {
    /// [`QUERY_SCHEMA_VERSION`] of the daemon.
    pub schema_version: u32,
    /// [`QueryStatus`] as `u8`.
    pub status: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
    /// Version of the graph the hits were taken from (0 when none).
    pub graph_version: u64,
    /// The daemon instance ([`GraphHeader::instance_id`](crate::GraphHeader::instance_id)) of that graph.
    pub instance_id: u64,
    /// Valid entries of `hits`.
    pub hit_count: u32,
    /// The daemon's request queue capacity (`query.queue_capacity`).
    pub queue_capacity: u32,
    /// Requests answered with [`QueryStatus::Ok`] since the daemon started (this one included).
    pub served_count: u64,
    /// Requests refused with [`QueryStatus::Busy`] since the daemon started.
    pub refused_count: u64,
    /// Microseconds the text encoder took for the query text.
    pub encode_us: u32,
    /// Microseconds the scoring over the graph took.
    pub score_us: u32,
    /// Nodes scored.
    pub scored_node_count: u32,
    /// Reserved, zero.
    pub reserved2: u32,
    /// Why the request failed or was refused (empty for [`QueryStatus::Ok`]), UTF-8, NUL padded.
    pub message: [u8; QUERY_MESSAGE_CAPACITY_BYTES],
    /// The top `hit_count` nodes, best first.
    pub hits: [QueryHit; QUERY_MAX_K],
}

impl Default for QueryResponse {
    fn default() -> Self {
        Self {
            schema_version: QUERY_SCHEMA_VERSION,
            status: QueryStatus::Ok as u8,
            reserved: [0; 3],
            graph_version: 0,
            instance_id: 0,
            hit_count: 0,
            queue_capacity: 0,
            served_count: 0,
            refused_count: 0,
            encode_us: 0,
            score_us: 0,
            scored_node_count: 0,
            reserved2: 0,
            message: [0; QUERY_MESSAGE_CAPACITY_BYTES],
            hits: [QueryHit::default(); QUERY_MAX_K],
        }
    }
}

impl QueryResponse {
    /// A response with `status` and `message` and no hits.
    pub fn failure(status: QueryStatus, message: &str) -> Self {
        let mut response = Self { status: status as u8, ..Self::default() };
        write_fixed_str(&mut response.message, message);
        response
    }
    /// The status, `None` for an unknown value.
    pub fn query_status(&self) -> Option<QueryStatus> {
        QueryStatus::from_u8(self.status)
    }
    /// The message.
    pub fn message_str(&self) -> &str {
        fixed_str(&self.message)
    }
    /// The valid hits, best first.
    pub fn hits(&self) -> &[QueryHit] {
        &self.hits[..(self.hit_count as usize).min(QUERY_MAX_K)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{offset_of, size_of};

    #[test]
    fn layouts_are_the_documented_ones() {
        assert_eq!(size_of::<QueryRequest>(), 272);
        assert_eq!(offset_of!(QueryRequest, text), 8);
        assert_eq!(offset_of!(QueryRequest, node_id), 264);
        assert_eq!(size_of::<QueryHit>(), 192);
        assert_eq!(offset_of!(QueryHit, label), 16);
        assert_eq!(offset_of!(QueryHit, matched_text), 64);
        assert_eq!(offset_of!(QueryHit, approach_status), 160);
        assert_eq!(offset_of!(QueryHit, approach_x_m), 164);
        assert_eq!(offset_of!(QueryHit, approach_path_m), 180);
        assert_eq!(offset_of!(QueryResponse, message), 64);
        assert_eq!(offset_of!(QueryResponse, hits), 224);
        assert_eq!(size_of::<QueryResponse>(), 224 + QUERY_MAX_K * 192);
    }

    #[test]
    #[allow(unsafe_code)]
    fn type_names_are_stable() {
        // SAFETY: `type_name` is an unsafe trait fn only because implementors must keep it stable.
        unsafe {
            assert_eq!(<QueryRequest as ZeroCopySend>::type_name(), "op3dsg::QueryRequest");
            assert_eq!(<QueryResponse as ZeroCopySend>::type_name(), "op3dsg::QueryResponse");
        }
    }

    #[test]
    fn requests_refuse_text_that_does_not_fit() {
        let request = QueryRequest::new("somewhere to wash my hands", 3).expect("fits");
        assert_eq!((request.text_str(), request.k), ("somewhere to wash my hands", 3));
        assert!(QueryRequest::new(&"x".repeat(QUERY_TEXT_CAPACITY_BYTES + 1), 3).is_none());
        for value in 0..=7 {
            if let Some(status) = QueryStatus::from_u8(value) {
                assert_eq!(status as u8, value);
            }
            if let Some(status) = ApproachStatus::from_u8(value) {
                assert_eq!(status as u8, value);
            }
        }
        let by_id = QueryRequest::for_node(7);
        assert_eq!((by_id.asked_node(), QueryRequest::default().asked_node()), (Some(7), None));
        let failure = QueryResponse::failure(QueryStatus::Busy, "queue full");
        assert_eq!(
            (failure.query_status(), failure.message_str(), failure.hits().len()),
            (Some(QueryStatus::Busy), "queue full", 0)
        );
    }
}
