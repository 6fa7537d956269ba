//! The contract checks of a received graph ([`GraphMessage`]) and [`SnapshotError`], the error
//! that names the field or entry that breaks it.

use crate::{EDGE_BYTES, EdgeKind, EdgeOrigin, GraphMessage, NODE_BYTES, NodeKind, SCHEMA_VERSION};

/// A graph sample that breaks the wire contract; names the offending field or entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SnapshotError {
    /// The publisher wrote another wire-contract version.
    SchemaVersion {
        /// Version in the sample.
        found: u32,
        /// [`SCHEMA_VERSION`].
        expected: u32,
    },
    /// A count in the header exceeds the capacity the header states.
    CountTooLarge {
        /// `node_count` or `edge_count`.
        field: &'static str,
        /// The count found.
        value: u32,
        /// `node_capacity` or `edge_capacity`.
        capacity: usize,
    },
    /// The payload is not as long as the header's counts say.
    PayloadSize {
        /// Bytes in the sample.
        found: usize,
        /// `node_count * NODE_BYTES + edge_count * EDGE_BYTES`.
        expected: usize,
    },
    /// A node with an unknown kind value.
    UnknownNodeKind {
        /// Index in `nodes`.
        index: usize,
        /// Wire value.
        value: u8,
    },
    /// An edge with an unknown kind value.
    UnknownEdgeKind {
        /// Index in `edges`.
        index: usize,
        /// Wire value.
        value: u8,
    },
    /// An edge with an unknown origin value.
    UnknownEdgeOrigin {
        /// Index in `edges`.
        index: usize,
        /// Wire value.
        value: u8,
    },
}

impl core::fmt::Display for SnapshotError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::SchemaVersion { found, expected } => {
                write!(f, "header.schema_version: found {found}, this build reads {expected}")
            }
            Self::CountTooLarge { field, value, capacity } => {
                write!(f, "header.{field}: {value} exceeds the capacity {capacity}")
            }
            Self::PayloadSize { found, expected } => write!(
                f,
                "payload: {found} bytes, but the header's counts need {expected} ({NODE_BYTES} per node, {EDGE_BYTES} per edge)"
            ),
            Self::UnknownNodeKind { index, value } => {
                write!(f, "nodes[{index}].kind: unknown value {value} (0 object, 1 part)")
            }
            Self::UnknownEdgeKind { index, value } => {
                write!(f, "edges[{index}].kind: unknown value {value} (0 spatial, 1 functional)")
            }
            Self::UnknownEdgeOrigin { index, value } => {
                write!(f, "edges[{index}].origin: unknown value {value} (0..=3)")
            }
        }
    }
}

impl std::error::Error for SnapshotError {}

/// Checks a graph sample against the contract: schema version, counts within the stated
/// capacity, payload length matching the counts, every node's kind and every edge's kind and
/// origin.
pub fn check_message(message: &GraphMessage<'_>) -> Result<(), SnapshotError> {
    let header = message.header;
    if header.schema_version != SCHEMA_VERSION {
        return Err(SnapshotError::SchemaVersion { found: header.schema_version, expected: SCHEMA_VERSION });
    }
    if header.node_count > header.node_capacity {
        return Err(SnapshotError::CountTooLarge {
            field: "node_count",
            value: header.node_count,
            capacity: header.node_capacity as usize,
        });
    }
    if header.edge_count > header.edge_capacity {
        return Err(SnapshotError::CountTooLarge {
            field: "edge_count",
            value: header.edge_count,
            capacity: header.edge_capacity as usize,
        });
    }
    if message.payload.len() != header.payload_bytes() {
        return Err(SnapshotError::PayloadSize { found: message.payload.len(), expected: header.payload_bytes() });
    }
    for (index, node) in message.node_records().iter().enumerate() {
        // The kind byte of a node record (offset 8).
        if NodeKind::from_u8(node[8]).is_none() {
            return Err(SnapshotError::UnknownNodeKind { index, value: node[8] });
        }
    }
    for (index, edge) in message.edge_records().iter().enumerate() {
        // The kind and origin bytes of an edge record (offsets 8 and 9).
        if EdgeKind::from_u8(edge[8]).is_none() {
            return Err(SnapshotError::UnknownEdgeKind { index, value: edge[8] });
        }
        if EdgeOrigin::from_u8(edge[9]).is_none() {
            return Err(SnapshotError::UnknownEdgeOrigin { index, value: edge[9] });
        }
    }
    Ok(())
}
