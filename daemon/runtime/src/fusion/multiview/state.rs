//! The map's saved form ([`MapState`]): everything [`MultiViewFusion`] needs to go on fusing
//! after a restart as if it had never stopped (node ids, points, features, votes, the counters
//! pruning and maintenance read), and nothing it can rebuild (the point grids, the node index,
//! scratch buffers).

use glam::{IVec3, Vec3};
use op3dsg_ipc_types::NodeKind;
use serde::{Deserialize, Serialize};

use super::MultiViewFusion;
use super::node::Node;
use crate::fusion::change::{RemovedHistory, RemovedNode};
use crate::fusion::colour::{AB_BINS, CN_BINS, ColourFeature, OPP_BINS};

/// The fusion parameters a saved map depends on: points were voxel-downsampled and compared
/// with these, so a map saved under others cannot be continued.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapGeometry {
    /// `fusion.object_voxel_m`.
    pub object_voxel_m: f32,
    /// `fusion.part_voxel_m`.
    pub part_voxel_m: f32,
    /// `fusion.object_nnr_radius_m`.
    pub object_nnr_radius_m: f32,
    /// `fusion.part_nnr_radius_m`.
    pub part_nnr_radius_m: f32,
}

/// One saved node.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NodeState {
    /// Node id (published ids stay the same across a restart).
    pub id: u32,
    /// 0 object, 1 part ([`NodeKind`]).
    pub kind: u8,
    /// Voxel-downsampled points in the world frame, metres.
    pub points: Vec<[f32; 3]>,
    /// Voxel multiplier of the cloud (1, 2, 4, ...).
    pub voxel_scale: u32,
    /// Points before this index passed the last outlier test.
    pub checked_points: u32,
    /// Running mean of the semantic features (may be empty).
    pub semantic: Vec<f32>,
    /// Colour-distribution histograms (Colour Names, a*b*, opponent) and the valid-pixel count.
    pub colour: (Vec<f32>, Vec<f32>, Vec<f32>, u32),
    /// (index into [`MapState::labels`], count).
    pub votes: Vec<(u32, u32)>,
    /// Sum of detector scores.
    pub score_sum: f32,
    /// Detections fused.
    pub observation_count: u32,
    /// Keyframe counter when last seen.
    pub last_keyframe: u64,
    /// Stamp of the last keyframe that saw it, nanoseconds.
    pub last_seen_stamp_ns: u64,
}

/// The whole map of a [`MultiViewFusion`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapState {
    /// Parameters the points depend on.
    pub geometry: MapGeometry,
    /// Interned labels.
    pub labels: Vec<String>,
    /// Next node id to hand out.
    pub next_id: u32,
    /// Keyframes integrated so far.
    pub keyframes: u64,
    /// Every live node (confirmed or not), by id.
    pub nodes: Vec<NodeState>,
    /// The nodes' first sightings and the removed nodes (snapshot format 2; `None` in a
    /// format-1 file: the first sightings then read as the last ones).
    pub life: Option<MapLife>,
}

/// When each node was first seen, and the history of removed nodes (`[fusion.change]`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MapLife {
    /// (node id, first-seen stamp ns, fusion keyframe counter at first sight), by id.
    pub first_seen: Vec<(u32, u64, u64)>,
    /// Removed nodes, oldest first.
    pub removed: Vec<RemovedNode>,
}

impl MapState {
    /// (objects, parts) among the nodes.
    pub fn kind_counts(&self) -> (usize, usize) {
        let parts = self.nodes.iter().filter(|n| n.kind == NodeKind::Part as u8).count();
        (self.nodes.len() - parts, parts)
    }

    /// Points over all nodes.
    pub fn point_count(&self) -> usize {
        self.nodes.iter().map(|n| n.points.len()).sum()
    }
}

impl MultiViewFusion {
    pub(super) fn map_geometry(&self) -> MapGeometry {
        MapGeometry {
            object_voxel_m: self.config.object_voxel_m,
            part_voxel_m: self.config.part_voxel_m,
            object_nnr_radius_m: self.config.object_nnr_radius_m,
            part_nnr_radius_m: self.config.part_nnr_radius_m,
        }
    }

    pub(super) fn export(&self) -> MapState {
        let mut nodes: Vec<NodeState> = self
            .nodes
            .iter()
            .filter(|n| n.alive)
            .map(|n| NodeState {
                id: n.id,
                kind: n.kind as u8,
                points: n.cloud.points.iter().map(|p| p.to_array()).collect(),
                voxel_scale: n.cloud.scale.max(1),
                checked_points: n.cloud.checked.min(n.cloud.points.len()) as u32,
                semantic: n.semantic.clone(),
                colour: (n.colour.cn.to_vec(), n.colour.ab.to_vec(), n.colour.opp.to_vec(), n.colour.valid_pixels),
                votes: n.votes.clone(),
                score_sum: n.score_sum,
                observation_count: n.observation_count,
                last_keyframe: n.last_keyframe,
                last_seen_stamp_ns: n.last_seen_stamp_ns,
            })
            .collect();
        nodes.sort_unstable_by_key(|n| n.id);
        let mut first_seen: Vec<(u32, u64, u64)> =
            self.nodes.iter().filter(|n| n.alive).map(|n| (n.id, n.first_seen_stamp_ns, n.first_keyframe)).collect();
        first_seen.sort_unstable_by_key(|f| f.0);
        let life = MapLife { first_seen, removed: self.history.iter().cloned().collect() };
        MapState {
            geometry: self.map_geometry(),
            labels: self.labels.clone(),
            next_id: self.next_id,
            keyframes: self.keyframe,
            nodes,
            life: Some(life),
        }
    }

    /// Checks `state` against this fusion's parameters and itself; the message says what does
    /// not fit.
    fn check(&self, state: &MapState) -> Result<(), String> {
        let g = self.map_geometry();
        let pairs = [
            ("object_voxel_m", state.geometry.object_voxel_m, g.object_voxel_m),
            ("part_voxel_m", state.geometry.part_voxel_m, g.part_voxel_m),
            ("object_nnr_radius_m", state.geometry.object_nnr_radius_m, g.object_nnr_radius_m),
            ("part_nnr_radius_m", state.geometry.part_nnr_radius_m, g.part_nnr_radius_m),
        ];
        for (name, saved, now) in pairs {
            if saved != now {
                return Err(format!("saved with fusion.{name} = {saved}, the profile has {now}"));
            }
        }
        let mut ids = std::collections::BTreeSet::new();
        for n in &state.nodes {
            let node = format!("node {}", n.id);
            if n.id == 0 || n.id >= state.next_id || !ids.insert(n.id) {
                return Err(format!("{node}: id is 0, repeated or not below next_id {}", state.next_id));
            }
            if NodeKind::from_u8(n.kind).is_none() {
                return Err(format!("{node}: unknown kind {}", n.kind));
            }
            if n.points.is_empty() || n.points.iter().flatten().any(|v| !v.is_finite()) {
                return Err(format!("{node}: no points, or a point that is not finite"));
            }
            if !n.voxel_scale.is_power_of_two() || n.checked_points as usize > n.points.len() {
                return Err(format!(
                    "{node}: voxel scale {} or checked points {} out of range",
                    n.voxel_scale, n.checked_points
                ));
            }
            let (cn, ab, opp, _) = &n.colour;
            if (cn.len(), ab.len(), opp.len()) != (CN_BINS, AB_BINS, OPP_BINS) {
                return Err(format!(
                    "{node}: colour histograms of {}/{}/{} bins, expected {CN_BINS}/{AB_BINS}/{OPP_BINS}",
                    cn.len(),
                    ab.len(),
                    opp.len()
                ));
            }
            if n.votes.is_empty() || n.votes.iter().any(|&(label, _)| label as usize >= state.labels.len()) {
                return Err(format!("{node}: no votes, or a vote for a label not in the table"));
            }
            if n.observation_count == 0 || !n.score_sum.is_finite() || n.semantic.iter().any(|v| !v.is_finite()) {
                return Err(format!("{node}: no observations, or a score or feature that is not finite"));
            }
        }
        Ok(())
    }

    /// Replaces the map with `state` (after [`Self::check`]); the fusion goes on from there.
    pub(super) fn restore(&mut self, state: &MapState) -> Result<(), String> {
        self.check(state)?;
        let config = self.config.clone();
        *self = MultiViewFusion::new(config);
        self.labels = state.labels.clone();
        self.label_ids = state.labels.iter().enumerate().map(|(i, l)| (l.clone(), i as u32)).collect();
        self.next_id = state.next_id;
        self.keyframe = state.keyframes;
        let life = state.life.as_ref();
        if let Some(life) = life {
            self.history = RemovedHistory::restored(self.config.change.history as usize, &life.removed);
        }
        let first_seen =
            |id: u32| life.and_then(|l| l.first_seen.binary_search_by_key(&id, |f| f.0).ok().map(|i| l.first_seen[i]));
        for saved in &state.nodes {
            let slot = self.allocate_slot();
            let kind = NodeKind::from_u8(saved.kind).unwrap_or(NodeKind::Object);
            let g = self.geometry(kind);
            let node: &mut Node = &mut self.nodes[slot as usize];
            node.id = saved.id;
            node.kind = kind;
            node.alive = true;
            node.cloud.clear();
            node.cloud.scale = saved.voxel_scale;
            for p in &saved.points {
                // One point per voxel at this scale already: every point goes back in.
                node.cloud.insert(Vec3::from_array(*p), &g, usize::MAX);
            }
            node.cloud.checked = (saved.checked_points as usize).min(node.cloud.points.len());
            node.semantic.clone_from(&saved.semantic);
            let (cn, ab, opp, valid_pixels) = &saved.colour;
            let mut colour = ColourFeature { valid_pixels: *valid_pixels, ..ColourFeature::default() };
            colour.cn.copy_from_slice(cn);
            colour.ab.copy_from_slice(ab);
            colour.opp.copy_from_slice(opp);
            node.colour = colour;
            node.votes.clone_from(&saved.votes);
            node.score_sum = saved.score_sum;
            node.observation_count = saved.observation_count;
            node.last_keyframe = saved.last_keyframe;
            node.last_seen_stamp_ns = saved.last_seen_stamp_ns;
            let (_, first_stamp, first_keyframe) =
                first_seen(saved.id).unwrap_or((saved.id, saved.last_seen_stamp_ns, saved.last_keyframe));
            node.first_seen_stamp_ns = first_stamp;
            node.first_keyframe = first_keyframe;
            node.published = false;
            node.appeared = false;
            node.misses = Default::default();
            node.cells = (IVec3::ZERO, IVec3::NEG_ONE);
            // Let the next maintenance compare restored nodes with their neighbours once.
            node.dirty = true;
            self.alive += 1;
            self.reindex(slot);
        }
        // Restored confirmed nodes were published before the restart: no appearance, no move.
        for slot in 0..self.nodes.len() {
            let confirmed = self.nodes[slot].alive && self.confirmed(&self.nodes[slot]);
            self.nodes[slot].published = confirmed;
        }
        Ok(())
    }
}
