//! A map that stays true when the home changes: what fusion does with the depth of every
//! keyframe besides fusing detections, and the events it reports.
//!
//! # Evidence, per keyframe
//!
//! Every confirmed node not fused in this keyframe whose points fall in the view, within the
//! trusted range (`min_range_m`..`max_range_m`), is tested at up to `samples_per_node` of its
//! points. Each point is projected into the keyframe's depth image and read there and at its
//! neighbours `window_px` away:
//!
//! - **seen**: a reading within `agree_m + agree_per_m2 · z²` of the point's range `z`;
//! - **occluded**: every reading nearer than that (something stands in front);
//! - **free**: every reading behind the point by more than `free_margin_m + free_margin_per_m2 · z²`
//!   (the line of sight passes through where the point was);
//! - **unknown**: no reading, a reading outside the trusted range, or readings that disagree
//!   among themselves (an edge).
//!
//! Occluded points are not visible. With at least `min_visible_points` visible points (seen or
//! free), a node whose free points are at least `free_fraction` of them (`part_free_fraction`
//! for parts) gets a **miss**, unless a detection of this keyframe with the node's label
//! overlaps where it projects at about its range (then the object is in view and the pose or
//! the depth is off). A node whose seen points reach `seen_fraction` of the visible ones clears
//! its misses, and so does fusing a detection into it. Occlusion and unknown give no evidence
//! either way. A node with a miss is **missing**: still published, marked so.
//!
//! # Removal
//!
//! `misses_to_remove` misses, the first and the last at least `min_miss_separation_s` apart and
//! from viewpoints `min_viewpoint_change_m` or `min_viewpoint_change_deg` apart, remove the
//! node. An object's parts (parts whose centre lies in its box grown by
//! `fusion.part_attach_margin_m`) go with it, except those this keyframe's depth sees where
//! they were (a wall outlet behind a kettle stays). A part also goes on its own free-space
//! evidence, never because a detector did not report it; its miss counts only when an object
//! around it is seen in place in the same keyframe (the map and the view line up there, so the
//! free space is no pose error), so a part with no object around it (a wall switch) is never
//! removed on its own. Removed nodes are kept in a bounded history
//! (`history`) with their place and times.
//!
//! # Appeared
//!
//! A node confirmed where the camera had already looked at least `appeared_after_s` earlier,
//! within the trusted range (the keyframe poses are kept, thinned), is new in the home: it is
//! logged as appeared, unless it is a move. Nodes found while mapping new ground are neither,
//! so the log of a static home stays empty.
//!
//! # Moves
//!
//! A removed node and a node that appeared (first seen after the removed one was last seen, at
//! least `move_min_distance_m` away, within `move_window_s`) are one object that moved when
//! they are alike: with semantic features on both, a similarity `(f_a · f_b + 1) / 2` of at
//! least `move_min_semantic` (synonyms share features, as in fusion); without, the same label.
//! The link is made when the old one is removed (the most similar appeared node, then the
//! nearest) or, when the new one is confirmed later, then (the newest removal it matches).
//! **Identity rule: a moved object keeps its old id**; the new node takes it, and the id the new
//! node had (`retired_id`; an earlier appeared event may have named it) is retired. The move is
//! logged from the old place to the new.
//!
//! # What it cannot see
//!
//! Depth sees surfaces. Glass and mirrors read the wrong depth (a mirror shows depth behind the
//! wall; a glass-fronted cabinet can read as free), objects inside a closed cabinet or drawer are
//! never in view, and a thing hidden behind a newer one stays "occluded" (no evidence) until the
//! robot sees past it.

mod config;

use std::collections::VecDeque;

pub use config::ChangeConfig;
use op3dsg_ipc_types::NodeKind;
use serde::{Deserialize, Serialize};

/// What happened to a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChangeKind {
    /// A node confirmed where the camera had looked before.
    Appeared,
    /// A node removed on free-space evidence (or with its object).
    Removed,
    /// A node that appeared elsewhere linked to a removed one; it keeps the removed one's id.
    Moved,
}

impl ChangeKind {
    /// `appeared`, `removed`, `moved`.
    pub fn as_str(self) -> &'static str {
        match self {
            ChangeKind::Appeared => "appeared",
            ChangeKind::Removed => "removed",
            ChangeKind::Moved => "moved",
        }
    }
}

/// One change of the map.
#[derive(Debug, Clone, PartialEq)]
pub struct ChangeEvent {
    /// What happened.
    pub kind: ChangeKind,
    /// The node's id (a moved node's id, which it keeps).
    pub node_id: u32,
    /// Object or part.
    pub node_kind: NodeKind,
    /// Its label.
    pub label: String,
    /// Removed and moved: where it was (its box's centre), world metres.
    pub from_m: Option<[f32; 3]>,
    /// Appeared and moved: where it is now, world metres.
    pub to_m: Option<[f32; 3]>,
    /// Moved: the id the node had at its new place before it was linked (retired).
    pub retired_id: Option<u32>,
    /// Removed: the object it went with (a part removed with its object).
    pub with_object: Option<u32>,
    /// Stamp of the keyframe that decided it, nanoseconds.
    pub stamp_ns: u64,
    /// Fusion's keyframe counter then.
    pub keyframe: u64,
    /// The graph version that first shows it (set by the publisher; 0 until then).
    pub graph_version: u64,
}

/// A removed node as the history keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RemovedNode {
    /// Its id.
    pub id: u32,
    /// 0 object, 1 part ([`NodeKind`]).
    pub kind: u8,
    /// Its label.
    pub label: String,
    /// Box centre, world metres.
    pub centre_m: [f32; 3],
    /// Box, world metres.
    pub box_min_m: [f32; 3],
    /// Box, world metres.
    pub box_max_m: [f32; 3],
    /// First and last seen, nanoseconds.
    pub first_seen_stamp_ns: u64,
    /// See `first_seen_stamp_ns`.
    pub last_seen_stamp_ns: u64,
    /// Fusion's keyframe counter when first and last seen (it goes on across restarts).
    pub first_keyframe: u64,
    /// See `first_keyframe`.
    pub last_keyframe: u64,
    /// When it was removed, nanoseconds.
    pub removed_stamp_ns: u64,
    /// Running mean of its semantic features (may be empty), for moves.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub semantic: Vec<f32>,
}

/// The bounded history of removed nodes, newest last.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RemovedHistory {
    capacity: usize,
    nodes: VecDeque<RemovedNode>,
}

impl RemovedHistory {
    /// An empty history of at most `capacity` nodes.
    pub fn new(capacity: usize) -> Self {
        Self { capacity, nodes: VecDeque::new() }
    }

    /// Remembers `node`, forgetting the oldest when full.
    pub fn push(&mut self, node: RemovedNode) {
        if self.capacity == 0 {
            return;
        }
        while self.nodes.len() >= self.capacity {
            self.nodes.pop_front();
        }
        self.nodes.push_back(node);
    }

    /// Takes the entry of `id` out (a moved node back in the map).
    pub fn take(&mut self, id: u32) -> Option<RemovedNode> {
        let i = self.nodes.iter().position(|n| n.id == id)?;
        self.nodes.remove(i)
    }

    /// Oldest first.
    pub fn iter(&self) -> impl DoubleEndedIterator<Item = &RemovedNode> {
        self.nodes.iter()
    }

    /// A history with this capacity holding the newest of `nodes`.
    pub fn restored(capacity: usize, nodes: &[RemovedNode]) -> Self {
        let mut h = Self::new(capacity);
        for n in nodes {
            h.push(n.clone());
        }
        h
    }
}
