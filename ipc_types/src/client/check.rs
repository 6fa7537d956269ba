//! The contract checks of a received graph ([`GraphMessage`]) and [`SnapshotError`], the error
//! that names the field or entry that breaks it.
//!
//! Two halves: [`check_layout`] (the header against the payload's length: schema version,
//! counts within capacity, length matching the counts; constant time) and the record checks
//! (every node's kind, every edge's kind and origin; one pass). [`check_message`] runs both, as
//! the owned [`Graph`](crate::Graph) and the borrowed [`GraphView`](crate::GraphView) do before
//! reading a sample.

use crate::{EDGE_BYTES, EdgeKind, EdgeOrigin, GraphHeader, GraphMessage, NODE_BYTES, NodeKind, SCHEMA_VERSION};

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
    /// A sample given as one byte block is shorter than a [`GraphHeader`].
    HeaderSize {
        /// Bytes found.
        found: usize,
        /// `size_of::<GraphHeader>()` (112).
        expected: usize,
    },
    /// The header or the records do not start at an address their type's alignment allows, so
    /// they cannot be read in place.
    Misaligned {
        /// `header` or `payload`.
        field: &'static str,
        /// The address found.
        address: usize,
        /// The alignment needed (8).
        alignment: usize,
    },
    /// The records are read in place only on a little-endian machine (the wire's byte order).
    ByteOrder,
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
            Self::HeaderSize { found, expected } => {
                write!(f, "header: {found} bytes, but a GraphHeader has {expected}")
            }
            Self::Misaligned { field, address, alignment } => write!(
                f,
                "{field}: starts at address {address:#x}, not a multiple of {alignment} (its records' alignment), \
                 so it cannot be read in place"
            ),
            Self::ByteOrder => {
                write!(f, "records: read in place only on a little-endian machine (the wire's byte order)")
            }
        }
    }
}

impl std::error::Error for SnapshotError {}

/// Checks a graph sample against the contract: schema version, counts within the stated
/// capacity, payload length matching the counts ([`check_layout`]), every node's kind and every
/// edge's kind and origin.
pub fn check_message(message: &GraphMessage<'_>) -> Result<(), SnapshotError> {
    check_layout(message.header, message.payload.len())?;
    check_records(message)
}

/// The constant-time half of [`check_message`]: the header's schema version, its counts within
/// its capacities, and `payload_len` equal to what the counts need. Once it passes, the node and
/// edge records lie within the payload; nothing past `payload_len` is ever read. The arithmetic
/// cannot overflow (64-bit products of 32-bit counts).
pub fn check_layout(header: &GraphHeader, payload_len: usize) -> Result<(), SnapshotError> {
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
    let needed = u64::from(header.node_count) * NODE_BYTES as u64 + u64::from(header.edge_count) * EDGE_BYTES as u64;
    if payload_len as u64 != needed {
        return Err(SnapshotError::PayloadSize {
            found: payload_len,
            expected: usize::try_from(needed).unwrap_or(usize::MAX),
        });
    }
    Ok(())
}

/// The record half of [`check_message`], for a message whose layout passed [`check_layout`]:
/// one pass over the kind bytes (and origin bytes) of the records; the index of the first bad
/// one only on failure.
pub(crate) fn check_records(message: &GraphMessage<'_>) -> Result<(), SnapshotError> {
    // The kind byte of a node record (offset 8); kinds are 0 and 1.
    let nodes = message.node_records();
    if nodes.iter().fold(0u8, |bad, node| bad | (node[8] & !1)) != 0 {
        for (index, node) in nodes.iter().enumerate() {
            if NodeKind::from_u8(node[8]).is_none() {
                return Err(SnapshotError::UnknownNodeKind { index, value: node[8] });
            }
        }
    }
    // The kind and origin bytes of an edge record (offsets 8 and 9); kinds 0 and 1, origins 0..=3.
    let edges = message.edge_records();
    if edges.iter().fold(0u8, |bad, edge| bad | (edge[8] & !1) | (edge[9] & !3)) != 0 {
        for (index, edge) in edges.iter().enumerate() {
            if EdgeKind::from_u8(edge[8]).is_none() {
                return Err(SnapshotError::UnknownEdgeKind { index, value: edge[8] });
            }
            if EdgeOrigin::from_u8(edge[9]).is_none() {
                return Err(SnapshotError::UnknownEdgeOrigin { index, value: edge[9] });
            }
        }
    }
    Ok(())
}
