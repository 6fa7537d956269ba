//! The contract checks of a received [`GraphSnapshot`] and [`SnapshotError`], the error that
//! names the field or entry that breaks it.

use crate::{EdgeKind, EdgeOrigin, GraphSnapshot, MAX_EDGES, MAX_NODES, NodeKind, SCHEMA_VERSION};

/// A snapshot that breaks the wire contract; names the offending field or entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SnapshotError {
    /// The publisher wrote another wire-contract version.
    SchemaVersion {
        /// Version in the sample.
        found: u32,
        /// [`SCHEMA_VERSION`].
        expected: u32,
    },
    /// A count in the header exceeds the array capacity.
    CountTooLarge {
        /// `node_count` or `edge_count`.
        field: &'static str,
        /// The count found.
        value: u32,
        /// The array capacity.
        capacity: usize,
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

/// Checks a snapshot against the contract: schema version, counts within capacity, every valid
/// node's kind and every valid edge's kind and origin.
pub fn check_snapshot(snapshot: &GraphSnapshot) -> Result<(), SnapshotError> {
    let header = &snapshot.header;
    if header.schema_version != SCHEMA_VERSION {
        return Err(SnapshotError::SchemaVersion { found: header.schema_version, expected: SCHEMA_VERSION });
    }
    if header.node_count as usize > MAX_NODES {
        return Err(SnapshotError::CountTooLarge {
            field: "node_count",
            value: header.node_count,
            capacity: MAX_NODES,
        });
    }
    if header.edge_count as usize > MAX_EDGES {
        return Err(SnapshotError::CountTooLarge {
            field: "edge_count",
            value: header.edge_count,
            capacity: MAX_EDGES,
        });
    }
    for (index, node) in snapshot.valid_nodes().iter().enumerate() {
        if NodeKind::from_u8(node.kind).is_none() {
            return Err(SnapshotError::UnknownNodeKind { index, value: node.kind });
        }
    }
    for (index, edge) in snapshot.valid_edges().iter().enumerate() {
        if EdgeKind::from_u8(edge.kind).is_none() {
            return Err(SnapshotError::UnknownEdgeKind { index, value: edge.kind });
        }
        if EdgeOrigin::from_u8(edge.origin).is_none() {
            return Err(SnapshotError::UnknownEdgeOrigin { index, value: edge.origin });
        }
    }
    Ok(())
}
