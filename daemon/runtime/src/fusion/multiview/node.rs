//! One node of the map: its points, features, label votes and bookkeeping, and the small rules
//! that compare or blend two nodes.

use glam::{IVec3, Vec3};
use op3dsg_ipc_types::NodeKind;

use super::cloud::{NONE, PointCloud};
use crate::fusion::colour::ColourFeature;

/// One node of the map.
#[derive(Debug, Clone)]
pub(super) struct Node {
    pub(super) id: u32,
    pub(super) kind: NodeKind,
    pub(super) alive: bool,
    pub(super) cloud: PointCloud,
    /// Running mean of the semantic features, L2-normalised; empty when none was given.
    pub(super) semantic: Vec<f32>,
    pub(super) colour: ColourFeature,
    /// (label id, count).
    pub(super) votes: Vec<(u32, u32)>,
    pub(super) score_sum: f32,
    pub(super) observation_count: u32,
    pub(super) last_keyframe: u64,
    pub(super) last_seen_stamp_ns: u64,
    /// Stamp and keyframe counter of its first detection.
    pub(super) first_seen_stamp_ns: u64,
    pub(super) first_keyframe: u64,
    /// Confirmed once (published; the change rules apply from then on).
    pub(super) published: bool,
    /// Confirmed where the camera had looked before (logged as appeared; a move may link it).
    pub(super) appeared: bool,
    /// The current run of misses (`[fusion.change]`); a node with one is missing.
    pub(super) misses: super::evidence::Misses,
    /// Index cells the node is registered in (inclusive range).
    pub(super) cells: (IVec3, IVec3),
    /// Changed since the last maintenance.
    pub(super) dirty: bool,
}

impl Node {
    pub(super) fn empty() -> Self {
        Self {
            id: 0,
            kind: NodeKind::Object,
            alive: false,
            cloud: PointCloud::default(),
            semantic: Vec::new(),
            colour: ColourFeature::default(),
            votes: Vec::new(),
            score_sum: 0.0,
            observation_count: 0,
            last_keyframe: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            first_keyframe: 0,
            published: false,
            appeared: false,
            misses: Default::default(),
            cells: (IVec3::ZERO, IVec3::NEG_ONE),
            dirty: false,
        }
    }

    pub(super) fn vote(&mut self, label: u32, count: u32) {
        match self.votes.iter_mut().find(|(l, _)| *l == label) {
            Some((_, c)) => *c += count,
            None => self.votes.push((label, count)),
        }
    }

    pub(super) fn has_label(&self, label: u32) -> bool {
        self.votes.iter().any(|(l, _)| *l == label)
    }

    pub(super) fn heap_bytes(&self) -> usize {
        self.cloud.heap_bytes()
            + self.semantic.capacity() * size_of::<f32>()
            + self.votes.capacity() * size_of::<(u32, u32)>()
    }
}

pub(super) fn boxes_touch(a: &Node, b: &Node, grow: f32) -> bool {
    let g = Vec3::splat(grow);
    !(a.cloud.max.cmplt(b.cloud.min - g).any() || a.cloud.min.cmpgt(b.cloud.max + g).any())
}

pub(super) fn top_vote(votes: &[(u32, u32)]) -> (u32, u32) {
    votes.iter().copied().max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0))).unwrap_or((NONE, 0))
}

/// `a ← (1 − w) a + w b`, each histogram L1-renormalised with `ε`.
pub(super) fn blend(a: &mut ColourFeature, b: &ColourFeature, w: f32, epsilon: f32) {
    pub(super) fn mix(x: &mut [f32], y: &[f32], w: f32, epsilon: f32) {
        let mut sum = 0.0;
        for (p, q) in x.iter_mut().zip(y) {
            *p = (1.0 - w) * *p + w * q;
            sum += *p;
        }
        for p in x.iter_mut() {
            *p /= sum + epsilon;
        }
    }
    mix(&mut a.cn, &b.cn, w, epsilon);
    mix(&mut a.ab, &b.ab, w, epsilon);
    mix(&mut a.opp, &b.opp, w, epsilon);
    a.valid_pixels = a.valid_pixels.saturating_add(b.valid_pixels);
}
