//! Maintenance of the map every `maintenance_every_keyframes` keyframes: duplicate merge,
//! outlier removal, pruning (see the module docs).

use glam::Vec3;
use op3dsg_ipc_types::NodeKind;

use super::MultiViewFusion;
use super::node::{Node, blend, boxes_touch, top_vote};
use crate::embedding::{dot, normalise};
use crate::fusion::FusionReport;
use crate::fusion::colour;

impl MultiViewFusion {
    /// Duplicate merge, outlier removal and pruning (see the module docs).
    pub(super) fn maintain(&mut self, report: &mut FusionReport) {
        let prune_after = u64::from(self.config.prune_unconfirmed_after_keyframes);
        // Pruning.
        if prune_after > 0 {
            for slot in 0..self.nodes.len() as u32 {
                let n = &self.nodes[slot as usize];
                if n.alive && !self.confirmed(n) && self.keyframe.saturating_sub(n.last_keyframe) >= prune_after {
                    self.remove_node(slot);
                    report.pruned += 1;
                }
            }
        }
        // Outlier removal.
        if self.config.outlier_min_neighbours > 0 {
            let need = self.config.outlier_min_neighbours;
            for slot in 0..self.nodes.len() {
                let n = &self.nodes[slot];
                if !n.alive || n.cloud.len() < 32 || n.cloud.checked == n.cloud.len() {
                    continue;
                }
                let g = self.geometry(n.kind);
                let node = &mut self.nodes[slot];
                let own = node.cloud.geometry(&g);
                let (radius, cell_m) = (own.voxel_m * self.config.outlier_radius_voxels, own.cell_m);
                let keep = &mut self.scratch.rebuild;
                keep.clear();
                // Only points added since the last test: older points only gain neighbours.
                let from = node.cloud.checked;
                let mut removed = false;
                keep.extend_from_slice(&node.cloud.points[..from]);
                for (i, p) in node.cloud.points.iter().enumerate().skip(from) {
                    if node.cloud.count_within(*p, radius, cell_m, i as u32, need) >= need {
                        keep.push(*p);
                    } else {
                        removed = true;
                    }
                }
                if removed && !keep.is_empty() {
                    std::mem::swap(&mut node.cloud.points, keep);
                    node.cloud.rebuild(&g, keep);
                    self.reindex(slot as u32);
                } else {
                    node.cloud.checked = node.cloud.len();
                }
            }
        }
        // Duplicate merge. A pair neither of whose nodes changed since the last run was already
        // checked, so only changed nodes are visited: the cost follows what the robot sees, not
        // the map's size. Most observations first, so small fragments fold into established
        // nodes.
        let mut order = std::mem::take(&mut self.scratch.order);
        order.clear();
        order.extend((0..self.nodes.len() as u32).filter(|&s| {
            let n = &self.nodes[s as usize];
            n.alive && n.dirty
        }));
        order.sort_unstable_by(|&a, &b| {
            let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
            nb.observation_count.cmp(&na.observation_count).then(na.id.cmp(&nb.id))
        });
        let mut candidates = std::mem::take(&mut self.scratch.candidates);
        for &a in &order {
            if !self.nodes[a as usize].alive {
                continue;
            }
            let node = &self.nodes[a as usize];
            let g = self.geometry(node.kind);
            let grow = Vec3::splat(g.radius_m);
            self.index.query(node.cloud.min - grow, node.cloud.max + grow, &mut candidates);
            for &b in &candidates {
                if b == a {
                    continue;
                }
                let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
                if !nb.alive || nb.kind != na.kind || !boxes_touch(na, nb, g.radius_m) {
                    continue;
                }
                // Survivor: more observations, then the older id.
                let (keep, gone) = if (nb.observation_count, std::cmp::Reverse(nb.id))
                    > (na.observation_count, std::cmp::Reverse(na.id))
                {
                    (b, a)
                } else {
                    (a, b)
                };
                if self.should_merge(keep, gone) {
                    self.merge_nodes(keep, gone);
                    report.maintenance_merged += 1;
                    if gone == a {
                        break;
                    }
                }
            }
        }
        self.scratch.candidates = candidates;
        for &slot in &order {
            self.nodes[slot as usize].dirty = false;
        }
        self.scratch.order = order;
    }

    /// The cheap tests (semantics, colour) first; the nearest-neighbour ratios last.
    fn should_merge(&self, a: u32, b: u32) -> bool {
        let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
        let semantic = if !na.semantic.is_empty() && na.semantic.len() == nb.semantic.len() {
            (dot(&na.semantic, &nb.semantic) + 1.0) * 0.5
        } else {
            let (la, _) = top_vote(&na.votes);
            if nb.has_label(la) { 1.0 } else { 0.0 }
        };
        if semantic < self.config.merge_min_semantic {
            return false;
        }
        if na.kind == NodeKind::Part
            && self.config.colour_features
            && let Some(s_c) = colour::colour_similarity(&na.colour, &nb.colour, &self.config.colour)
            && s_c < self.config.merge_min_colour
        {
            return false;
        }
        let g = self.geometry(na.kind);
        // A yes/no decision at a ratio of 0.5 needs far fewer samples than scoring does.
        let max_points = (self.config.nnr_max_points / 4).max(16);
        let overlap = nb.cloud.nnr(&na.cloud.points, &g, max_points);
        overlap >= self.config.merge_min_overlap
            || na.cloud.nnr(&nb.cloud.points, &g, max_points) >= self.config.merge_min_overlap
    }

    /// Folds node `gone` into node `keep`.
    fn merge_nodes(&mut self, keep: u32, gone: u32) {
        let (k, g_) = (keep as usize, gone as usize);
        let mut taken = std::mem::replace(&mut self.nodes[g_], Node::empty());
        let g = self.geometry(taken.kind);
        let cap = self.config.max_points_per_node;
        let node = &mut self.nodes[k];
        for &p in &taken.cloud.points {
            node.cloud.insert(p, &g, cap);
        }
        let (nk, ng) = (node.observation_count as f32, taken.observation_count as f32);
        if node.semantic.len() == taken.semantic.len() && !node.semantic.is_empty() {
            for (a, b) in node.semantic.iter_mut().zip(&taken.semantic) {
                *a = *a * nk + b * ng;
            }
            normalise(&mut node.semantic);
        } else if node.semantic.is_empty() {
            std::mem::swap(&mut node.semantic, &mut taken.semantic);
        }
        if taken.colour.is_valid() {
            if node.colour.is_valid() {
                let w = ng / (nk + ng);
                blend(&mut node.colour, &taken.colour, w, self.config.colour.ema_epsilon);
            } else {
                node.colour.clone_from(&taken.colour);
            }
        }
        for &(label, count) in &taken.votes {
            node.vote(label, count);
        }
        node.score_sum += taken.score_sum;
        node.observation_count += taken.observation_count;
        node.last_keyframe = node.last_keyframe.max(taken.last_keyframe);
        node.last_seen_stamp_ns = node.last_seen_stamp_ns.max(taken.last_seen_stamp_ns);
        node.first_seen_stamp_ns = node.first_seen_stamp_ns.min(taken.first_seen_stamp_ns);
        node.first_keyframe = node.first_keyframe.min(taken.first_keyframe);
        node.published |= taken.published;
        node.appeared |= taken.appeared;
        node.dirty = true;
        // Put the (dead) node back so its buffers are reused by the next new node.
        taken.alive = true;
        self.nodes[g_] = taken;
        self.remove_node(gone);
        self.reindex(keep);
    }
}
