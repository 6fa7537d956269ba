//! `[fusion.change]`: when the map believes a node is gone, moved, or new in a known place.

use serde::{Deserialize, Serialize};

/// `[fusion.change]`: negative evidence from each keyframe's depth and the rules that turn it
/// into removals and moves (see [`super`]). The defaults hold under the benchmark's `field`
/// preset (pose drift, depth noise, a detector that misses); `enabled = false` is the map that
/// only grows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChangeConfig {
    /// Look for removed and moved nodes at all.
    pub enabled: bool,
    /// Depth nearer than this gives no evidence, metres.
    pub min_range_m: f32,
    /// The range the depth is trusted at: a node point farther than this, or a pixel reading
    /// farther, gives no evidence, metres.
    pub max_range_m: f32,
    /// Points of a node's cloud tested per keyframe (evenly spread).
    pub samples_per_node: u32,
    /// A point's pixel and its neighbours this many pixels away (x, y, diagonals) are read;
    /// "free" needs all of them clearly behind, so a silhouette edge is not free.
    pub window_px: u32,
    /// Depth agrees with a point within `agree_m + agree_per_m2 · z²` (the sensor's noise
    /// grows with the square of the range), metres.
    pub agree_m: f32,
    /// See `agree_m`, metres per square metre.
    pub agree_per_m2: f32,
    /// A pixel is "free" (the line of sight passes through where the point was) when its depth
    /// is behind the point by more than `free_margin_m + free_margin_per_m2 · z²`, metres.
    pub free_margin_m: f32,
    /// See `free_margin_m`, metres per square metre.
    pub free_margin_per_m2: f32,
    /// A keyframe gives evidence on a node only when at least this many of its tested points
    /// are visible: seen or free (occluded points are not).
    pub min_visible_points: u32,
    /// An object gets a miss when at least this share of its visible points is free, [0.5, 1].
    pub free_fraction: f32,
    /// The same for a part (small and thin: a higher bar), [0.5, 1].
    pub part_free_fraction: f32,
    /// A node whose decided points agree with the depth at least this share clears its misses,
    /// [0, 1].
    pub seen_fraction: f32,
    /// Misses needed to remove a node (at least 2).
    pub misses_to_remove: u32,
    /// The misses that remove a node span at least this much time, seconds ...
    pub min_miss_separation_s: f32,
    /// ... and camera positions this far apart, metres, or view directions this far apart,
    /// degrees (`min_viewpoint_change_deg`).
    pub min_viewpoint_change_m: f32,
    /// See `min_viewpoint_change_m`, degrees.
    pub min_viewpoint_change_deg: f32,
    /// A detection of the node's label whose box overlaps where the node projects vetoes the
    /// miss: the object is still in view, the pose or the depth is off. Its box grows by this
    /// share of its size first, [0, 1].
    pub detection_veto_grow: f32,
    /// Removed nodes remembered (for "where did you last see it" and moves); oldest go first.
    pub history: u32,
    /// A node that appears within this long of the removal of a node of the same label and
    /// appearance, elsewhere, is that node moved (it keeps the old id), seconds (0: no moves).
    pub move_window_s: f32,
    /// ... "the same appearance": semantic similarity at least this, [0, 1] (nodes without
    /// features compare labels).
    pub move_min_semantic: f32,
    /// ... "elsewhere": centres at least this far apart, metres.
    pub move_min_distance_m: f32,
    /// A node first confirmed where a keyframe at least this much older already looked is
    /// logged as appeared (a new thing in a known place); nodes found while mapping new ground
    /// are not, seconds.
    pub appeared_after_s: f32,
}

impl Default for ChangeConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            min_range_m: 0.3,
            max_range_m: 3.0,
            samples_per_node: 48,
            window_px: 2,
            agree_m: 0.03,
            agree_per_m2: 0.01,
            free_margin_m: 0.12,
            free_margin_per_m2: 0.02,
            min_visible_points: 12,
            free_fraction: 0.7,
            part_free_fraction: 0.85,
            seen_fraction: 0.3,
            misses_to_remove: 2,
            min_miss_separation_s: 0.5,
            min_viewpoint_change_m: 0.15,
            min_viewpoint_change_deg: 10.0,
            detection_veto_grow: 0.25,
            history: 256,
            move_window_s: 600.0,
            move_min_semantic: 0.8,
            move_min_distance_m: 0.3,
            appeared_after_s: 10.0,
        }
    }
}

impl ChangeConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let lengths = [
            ("min_range_m", self.min_range_m, 0.0, 20.0),
            ("max_range_m", self.max_range_m, 0.0, 20.0),
            ("agree_m", self.agree_m, 0.0, 1.0),
            ("agree_per_m2", self.agree_per_m2, 0.0, 1.0),
            ("free_margin_m", self.free_margin_m, 0.0, 2.0),
            ("free_margin_per_m2", self.free_margin_per_m2, 0.0, 1.0),
            ("free_fraction", self.free_fraction, 0.5, 1.0),
            ("part_free_fraction", self.part_free_fraction, 0.5, 1.0),
            ("seen_fraction", self.seen_fraction, 0.0, 1.0),
            ("min_miss_separation_s", self.min_miss_separation_s, 0.0, 3600.0),
            ("min_viewpoint_change_m", self.min_viewpoint_change_m, 0.0, 10.0),
            ("min_viewpoint_change_deg", self.min_viewpoint_change_deg, 0.0, 180.0),
            ("detection_veto_grow", self.detection_veto_grow, 0.0, 1.0),
            ("move_window_s", self.move_window_s, 0.0, 1.0e6),
            ("move_min_semantic", self.move_min_semantic, 0.0, 1.0),
            ("move_min_distance_m", self.move_min_distance_m, 0.0, 100.0),
            ("appeared_after_s", self.appeared_after_s, 0.0, 1.0e6),
        ];
        for (name, v, lo, hi) in lengths {
            if !(lo..=hi).contains(&v) {
                return Err(format!("{path}.{name}: must be within [{lo}, {hi}], got {v}"));
            }
        }
        if self.max_range_m <= self.min_range_m {
            return Err(format!(
                "{path}.max_range_m: must be greater than min_range_m ({}), got {}",
                self.min_range_m, self.max_range_m
            ));
        }
        if self.free_margin_m <= self.agree_m {
            return Err(format!(
                "{path}.free_margin_m: must be greater than agree_m ({}): a point cannot be both seen and free, got {}",
                self.agree_m, self.free_margin_m
            ));
        }
        let ints = [
            ("samples_per_node", self.samples_per_node, 4, 4096),
            ("window_px", self.window_px, 0, 16),
            ("min_visible_points", self.min_visible_points, 1, 4096),
            ("misses_to_remove", self.misses_to_remove, 2, 1000),
            ("history", self.history, 0, 1_000_000),
        ];
        for (name, v, lo, hi) in ints {
            if !(lo..=hi).contains(&v) {
                return Err(format!("{path}.{name}: must be within [{lo}, {hi}], got {v}"));
            }
        }
        if self.min_visible_points > self.samples_per_node {
            return Err(format!(
                "{path}.min_visible_points: must be at most samples_per_node ({}), got {}",
                self.samples_per_node, self.min_visible_points
            ));
        }
        Ok(())
    }
}
