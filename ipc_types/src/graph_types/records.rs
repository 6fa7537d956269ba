//! The records of a graph sample's payload: [`Node`] and [`Edge`], each laid out as its
//! `#[repr(C)]` struct, and their byte form (little-endian).

// The derive macros emit `unsafe impl ZeroCopySend`; that is the only unsafe code here.
#![allow(unsafe_code)]

use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

use super::vocabulary::{EdgeOrigin, NodeKind, affordance_origin};
use crate::text::fixed_str;

/// Bytes in a node label buffer (UTF-8, NUL padded).
pub const LABEL_CAPACITY_BYTES: usize = 48;
/// Bytes in a relation phrase buffer (UTF-8, NUL padded). The longest canonical phrase,
/// "rotate to adjust the setting or temperature", has 43 bytes.
pub const PHRASE_CAPACITY_BYTES: usize = 48;
/// Node id meaning "no node" (for example the parent of an object node).
pub const NO_NODE: u32 = u32::MAX;

/// One node of the scene graph (size 144 bytes, alignment 8, no implicit padding).
///
/// Byte offsets: `id` 0, `parent_id` 4, `kind` 8, `affordance_knowledge_bits` 10,
/// `observation_count` 12, `label` 16, `confidence` 64, `centre_m` 68, `box_min_m` 80,
/// `box_max_m` 92, `affordance_bits` 104, `affordance_llm_bits` 106, `obb_yaw_rad` 108,
/// `last_seen_stamp_ns` 112, `obb_centre_m` 120, `obb_size_m` 132.
///
/// Each affordance carries an origin like an edge ([`EdgeOrigin`], [`Node::affordance_origin`]):
/// its bit in `affordance_knowledge_bits` only: `knowledge`; in `affordance_llm_bits` only:
/// `llm`; in both: `knowledge+llm`; in neither: `geometry` (this daemon derives no affordance
/// from geometry alone, so it appears only for a publisher that sets `affordance_bits` without
/// the origin masks). Bits of the origin masks outside `affordance_bits` mean nothing.
///
/// Two boxes around the node's points: the axis-aligned `box_min_m`..`box_max_m`, and the
/// gravity-aligned oriented box (`obb_*`, schema 5): its third axis is the world's up axis (the
/// daemon profile's `world.up_axis`, +z on a robot), its first axis is the world's first
/// horizontal axis turned by `obb_yaw_rad` about up towards the second (for +z up: x turned
/// towards y), its second axis is `up × first`. With +z up the world corners are
/// `obb_centre_m + R_z(obb_yaw_rad) * (±sx/2, ±sy/2, ±sz/2)` for `obb_size_m = [sx, sy, sz]`.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault, bytemuck::Pod, bytemuck::Zeroable)]
#[type_name("op3dsg::Node")]
pub struct Node {
    /// Node id, stable while one daemon instance runs
    /// ([`GraphHeader::instance_id`](crate::GraphHeader::instance_id)) and across a restart that
    /// restored a map snapshot.
    pub id: u32,
    /// Id of the parent object of a part node, [`NO_NODE`] for objects and unattached parts.
    pub parent_id: u32,
    /// [`NodeKind`] as `u8`: 0 object, 1 part.
    pub kind: u8,
    /// Reserved, zero.
    pub reserved: u8,
    /// The bits of `affordance_bits` the offline knowledge reasoner gave (schema 7); with
    /// `affordance_llm_bits` they name each affordance's origin ([`Node::affordance_origin`]).
    pub affordance_knowledge_bits: u16,
    /// Number of keyframe detections fused into this node.
    pub observation_count: u32,
    /// Label (the winner of the node's label vote), UTF-8, NUL padded.
    pub label: [u8; LABEL_CAPACITY_BYTES],
    /// Confidence in [0, 1]: the winning label's share of the vote times the mean detector score.
    pub confidence: f32,
    /// Centre of the node's points, world frame, metres.
    pub centre_m: [f32; 3],
    /// Minimum corner of the axis-aligned box around the node's points, world frame, metres.
    pub box_min_m: [f32; 3],
    /// Maximum corner of the axis-aligned box, world frame, metres.
    pub box_max_m: [f32; 3],
    /// Bit set over [`AFFORDANCES`] (bit `i` = `AFFORDANCES[i]`).
    pub affordance_bits: u16,
    /// The bits of `affordance_bits` an LLM agent gave, after the verification gate (schema 7;
    /// see `affordance_knowledge_bits`).
    pub affordance_llm_bits: u16,
    /// Yaw of the oriented box about the world's up axis, radians in `(-pi/2, pi/2]` (see the
    /// type's docs; 0 when the box is axis-aligned).
    pub obb_yaw_rad: f32,
    /// Stamp of the last keyframe that observed this node, nanoseconds.
    pub last_seen_stamp_ns: u64,
    /// Centre of the oriented box, world frame, metres.
    pub obb_centre_m: [f32; 3],
    /// Extent of the oriented box along its first, second (horizontal) and third (up) axes,
    /// metres.
    pub obb_size_m: [f32; 3],
}

impl Default for Node {
    fn default() -> Self {
        Self {
            id: NO_NODE,
            parent_id: NO_NODE,
            kind: 0,
            reserved: 0,
            affordance_knowledge_bits: 0,
            observation_count: 0,
            label: [0; LABEL_CAPACITY_BYTES],
            confidence: 0.0,
            centre_m: [0.0; 3],
            box_min_m: [0.0; 3],
            box_max_m: [0.0; 3],
            affordance_bits: 0,
            affordance_llm_bits: 0,
            obb_yaw_rad: 0.0,
            last_seen_stamp_ns: 0,
            obb_centre_m: [0.0; 3],
            obb_size_m: [0.0; 3],
        }
    }
}

impl Node {
    /// The label as text.
    pub fn label_str(&self) -> &str {
        fixed_str(&self.label)
    }
    /// The decoded kind (an unknown wire value reads as `None`).
    pub fn node_kind(&self) -> Option<NodeKind> {
        NodeKind::from_u8(self.kind)
    }
    /// Where the affordance `AFFORDANCES[index]` came from; `None` when the node does not have
    /// it (see the type's docs).
    pub fn affordance_origin(&self, index: usize) -> Option<EdgeOrigin> {
        affordance_origin(self.affordance_bits, self.affordance_knowledge_bits, self.affordance_llm_bits, index)
    }
}

/// One directed edge of the scene graph (size 64 bytes, alignment 4).
///
/// Direction: `source` relates to `target` as the phrase says, e.g. handle `part of` cabinet,
/// remote `remote to control` TV, cup `on` table.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault, bytemuck::Pod, bytemuck::Zeroable)]
#[type_name("op3dsg::Edge")]
pub struct Edge {
    /// Source node id.
    pub source_id: u32,
    /// Target node id.
    pub target_id: u32,
    /// [`EdgeKind`] as `u8`: 0 spatial, 1 functional.
    pub kind: u8,
    /// [`EdgeOrigin`] as `u8`: 0 geometry, 1 knowledge, 2 llm, 3 knowledge+llm.
    pub origin: u8,
    /// Canonical relation id: index into [`SPATIAL_RELATIONS`] for spatial edges,
    /// [`FUNCTIONAL_RELATION_BASE`] + index into [`FUNCTIONAL_RELATIONS`] for functional ones.
    pub relation_id: u16,
    /// Confidence in [0, 1].
    pub confidence: f32,
    /// The canonical phrase of `relation_id`, UTF-8, NUL padded (redundant, for readers without
    /// the tables).
    pub phrase: [u8; PHRASE_CAPACITY_BYTES],
}

impl Default for Edge {
    fn default() -> Self {
        Self {
            source_id: NO_NODE,
            target_id: NO_NODE,
            kind: 0,
            origin: 0,
            relation_id: 0,
            confidence: 0.0,
            phrase: [0; PHRASE_CAPACITY_BYTES],
        }
    }
}

impl Edge {
    /// The phrase as text.
    pub fn phrase_str(&self) -> &str {
        fixed_str(&self.phrase)
    }
}

/// Bytes of one node in the graph payload: [`Node`]'s layout, little-endian.
pub const NODE_BYTES: usize = 144;
/// Bytes of one edge in the graph payload: [`Edge`]'s layout, little-endian.
pub const EDGE_BYTES: usize = 64;

impl Node {
    /// Writes this node's [`NODE_BYTES`] bytes (the struct's field offsets, little-endian) into
    /// `b`, every byte of it; the inverse of [`Node::from_bytes`].
    pub fn write_bytes(&self, b: &mut [u8; NODE_BYTES]) {
        #[cfg(target_endian = "little")]
        b.copy_from_slice(bytemuck::bytes_of(self));
        #[cfg(not(target_endian = "little"))]
        self.write_fields(b);
    }

    /// [`Node::write_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    pub(super) fn write_fields(&self, b: &mut [u8; NODE_BYTES]) {
        b[0..4].copy_from_slice(&self.id.to_le_bytes());
        b[4..8].copy_from_slice(&self.parent_id.to_le_bytes());
        b[8] = self.kind;
        b[9] = self.reserved;
        b[10..12].copy_from_slice(&self.affordance_knowledge_bits.to_le_bytes());
        b[12..16].copy_from_slice(&self.observation_count.to_le_bytes());
        b[16..64].copy_from_slice(&self.label);
        b[64..68].copy_from_slice(&self.confidence.to_le_bytes());
        for (i, v) in self.centre_m.iter().chain(&self.box_min_m).chain(&self.box_max_m).enumerate() {
            b[68 + 4 * i..72 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        b[104..106].copy_from_slice(&self.affordance_bits.to_le_bytes());
        b[106..108].copy_from_slice(&self.affordance_llm_bits.to_le_bytes());
        b[108..112].copy_from_slice(&self.obb_yaw_rad.to_le_bytes());
        b[112..120].copy_from_slice(&self.last_seen_stamp_ns.to_le_bytes());
        for (i, v) in self.obb_centre_m.iter().chain(&self.obb_size_m).enumerate() {
            b[120 + 4 * i..124 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
    }

    /// Appends this node's [`NODE_BYTES`] bytes to `out` (see [`Node::write_bytes`]).
    pub fn append_bytes(&self, out: &mut Vec<u8>) {
        let mut b = [0u8; NODE_BYTES];
        self.write_bytes(&mut b);
        out.extend_from_slice(&b);
    }

    /// The node in `b` (laid out as [`Node::append_bytes`] writes it).
    pub fn from_bytes(b: &[u8; NODE_BYTES]) -> Self {
        #[cfg(target_endian = "little")]
        return bytemuck::pod_read_unaligned(b);
        #[cfg(not(target_endian = "little"))]
        Self::from_fields(b)
    }

    /// [`Node::from_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    pub(super) fn from_fields(b: &[u8; NODE_BYTES]) -> Self {
        let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let f32_at = |o: usize| f32::from_bits(u32_at(o));
        let vec3_at = |o: usize| [f32_at(o), f32_at(o + 4), f32_at(o + 8)];
        let mut label = [0u8; LABEL_CAPACITY_BYTES];
        label.copy_from_slice(&b[16..64]);
        let mut last_seen = [0u8; 8];
        last_seen.copy_from_slice(&b[112..120]);
        Self {
            id: u32_at(0),
            parent_id: u32_at(4),
            kind: b[8],
            reserved: b[9],
            affordance_knowledge_bits: u16::from_le_bytes([b[10], b[11]]),
            observation_count: u32_at(12),
            label,
            confidence: f32_at(64),
            centre_m: vec3_at(68),
            box_min_m: vec3_at(80),
            box_max_m: vec3_at(92),
            affordance_bits: u16::from_le_bytes([b[104], b[105]]),
            affordance_llm_bits: u16::from_le_bytes([b[106], b[107]]),
            obb_yaw_rad: f32_at(108),
            last_seen_stamp_ns: u64::from_le_bytes(last_seen),
            obb_centre_m: vec3_at(120),
            obb_size_m: vec3_at(132),
        }
    }
}

impl Edge {
    /// Writes this edge's [`EDGE_BYTES`] bytes (the struct's field offsets, little-endian) into
    /// `b`, every byte of it; the inverse of [`Edge::from_bytes`].
    pub fn write_bytes(&self, b: &mut [u8; EDGE_BYTES]) {
        #[cfg(target_endian = "little")]
        b.copy_from_slice(bytemuck::bytes_of(self));
        #[cfg(not(target_endian = "little"))]
        self.write_fields(b);
    }

    /// [`Edge::write_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    pub(super) fn write_fields(&self, b: &mut [u8; EDGE_BYTES]) {
        b[0..4].copy_from_slice(&self.source_id.to_le_bytes());
        b[4..8].copy_from_slice(&self.target_id.to_le_bytes());
        b[8] = self.kind;
        b[9] = self.origin;
        b[10..12].copy_from_slice(&self.relation_id.to_le_bytes());
        b[12..16].copy_from_slice(&self.confidence.to_le_bytes());
        b[16..64].copy_from_slice(&self.phrase);
    }

    /// Appends this edge's [`EDGE_BYTES`] bytes to `out` (see [`Edge::write_bytes`]).
    pub fn append_bytes(&self, out: &mut Vec<u8>) {
        let mut b = [0u8; EDGE_BYTES];
        self.write_bytes(&mut b);
        out.extend_from_slice(&b);
    }

    /// The edge in `b` (laid out as [`Edge::append_bytes`] writes it).
    pub fn from_bytes(b: &[u8; EDGE_BYTES]) -> Self {
        #[cfg(target_endian = "little")]
        return bytemuck::pod_read_unaligned(b);
        #[cfg(not(target_endian = "little"))]
        Self::from_fields(b)
    }

    /// [`Edge::from_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    pub(super) fn from_fields(b: &[u8; EDGE_BYTES]) -> Self {
        let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let mut phrase = [0u8; PHRASE_CAPACITY_BYTES];
        phrase.copy_from_slice(&b[16..64]);
        Self {
            source_id: u32_at(0),
            target_id: u32_at(4),
            kind: b[8],
            origin: b[9],
            relation_id: u16::from_le_bytes([b[10], b[11]]),
            confidence: f32::from_bits(u32_at(12)),
            phrase,
        }
    }
}
