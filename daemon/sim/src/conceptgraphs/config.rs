//! `[fusion.conceptgraphs]`: ConceptGraphs' settings.

use serde::{Deserialize, Serialize};

/// ConceptGraphs' settings; the defaults are their `base_mapping.yaml` (see the module docs for
/// `merge_interval`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConceptGraphsConfig {
    /// `downsample_voxel_size`, metres: voxel of every cloud and the overlap distance.
    pub voxel_m: f32,
    /// `sim_threshold` of `match_method = "sim_sum"`.
    pub sim_threshold: f32,
    /// `phys_bias` of the aggregation.
    pub phys_bias: f32,
    /// `mask_area_threshold`, pixels.
    pub mask_area_threshold_px: usize,
    /// `mask_conf_threshold`.
    pub mask_conf_threshold: f32,
    /// `max_bbox_area_ratio` (2D box area over image area).
    pub max_bbox_area_ratio: f32,
    /// `skip_bg`: drop detections of the background classes (wall, floor, ceiling).
    pub skip_bg: bool,
    /// `min_points_threshold`: lifted points a detection needs (at least 4).
    pub min_points_threshold: usize,
    /// `obj_pcd_max_points` (0 = no cap).
    pub obj_pcd_max_points: usize,
    /// `dbscan_remove_noise`.
    pub dbscan_remove_noise: bool,
    /// `dbscan_eps`, metres.
    pub dbscan_eps_m: f32,
    /// `dbscan_min_points`.
    pub dbscan_min_points: usize,
    /// `obj_min_points`.
    pub obj_min_points: usize,
    /// `obj_min_detections`.
    pub obj_min_detections: u32,
    /// `merge_overlap_thresh` (negative = no merge).
    pub merge_overlap_thresh: f32,
    /// `merge_visual_sim_thresh`.
    pub merge_visual_sim_thresh: f32,
    /// `merge_text_sim_thresh`.
    pub merge_text_sim_thresh: f32,
    /// `denoise_interval`, keyframes (0 = never during the run).
    pub denoise_interval: u32,
    /// `filter_interval`, keyframes (0 = never during the run).
    pub filter_interval: u32,
    /// `merge_interval`, keyframes (0 = never during the run).
    pub merge_interval: u32,
    /// Run ConceptGraphs' association over objects and parts together (their class-agnostic
    /// way) instead of within each kind.
    pub associate_across_kinds: bool,
    /// Part → object attachment margin of the published graph, metres (as `fusion`'s).
    pub part_attach_margin_m: f32,
}

impl Default for ConceptGraphsConfig {
    fn default() -> Self {
        Self {
            voxel_m: 0.025,
            sim_threshold: 1.2,
            phys_bias: 0.0,
            mask_area_threshold_px: 25,
            mask_conf_threshold: 0.25,
            max_bbox_area_ratio: 0.5,
            skip_bg: true,
            min_points_threshold: 16,
            obj_pcd_max_points: 5000,
            dbscan_remove_noise: true,
            dbscan_eps_m: 0.1,
            dbscan_min_points: 10,
            obj_min_points: 0,
            obj_min_detections: 3,
            merge_overlap_thresh: 0.7,
            merge_visual_sim_thresh: 0.7,
            merge_text_sim_thresh: 0.7,
            denoise_interval: 20,
            filter_interval: 0,
            merge_interval: 20,
            associate_across_kinds: false,
            part_attach_margin_m: 0.05,
        }
    }
}

impl ConceptGraphsConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let within = [
            ("voxel_m", self.voxel_m, 0.001, 1.0),
            ("dbscan_eps_m", self.dbscan_eps_m, 0.001, 10.0),
            ("mask_conf_threshold", self.mask_conf_threshold, 0.0, 1.0),
            ("max_bbox_area_ratio", self.max_bbox_area_ratio, 0.0, 1.0),
            ("sim_threshold", self.sim_threshold, -2.0, 4.0),
            ("phys_bias", self.phys_bias, -10.0, 10.0),
            ("merge_visual_sim_thresh", self.merge_visual_sim_thresh, -1.0, 1.0),
            ("merge_text_sim_thresh", self.merge_text_sim_thresh, -1.0, 1.0),
            ("part_attach_margin_m", self.part_attach_margin_m, 0.0, 1.0),
        ];
        for (name, v, lo, hi) in within {
            if !(lo..=hi).contains(&v) {
                return Err(format!("{path}.{name}: must be within [{lo}, {hi}], got {v}"));
            }
        }
        if self.merge_overlap_thresh.is_nan() || self.merge_overlap_thresh > 1.0 {
            return Err(format!(
                "{path}.merge_overlap_thresh: must be at most 1 (negative: no merging), got {}",
                self.merge_overlap_thresh
            ));
        }
        if self.min_points_threshold < 4 {
            return Err(format!("{path}.min_points_threshold: must be at least 4, got {}", self.min_points_threshold));
        }
        Ok(())
    }
}
