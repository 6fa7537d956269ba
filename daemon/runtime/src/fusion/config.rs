//! `[fusion]`: the map's method and the OP3DSG fusion's parameters.

use serde::{Deserialize, Serialize};

use super::colour::ColourParams;

/// The OP3DSG paper's part-aware fusion (`fusion.method`, the default).
pub const OP3DSG_FUSION: &str = "op3dsg";

fn default_method() -> String {
    OP3DSG_FUSION.to_owned()
}

/// `[fusion]`. Defaults (the built-in profile) follow the paper where it gives a value
/// (`w_p = 0.4`, `τ_S = 0.1`, `τ_V = 0.9`, colour weights `(0.2, 0.4, 0.4)`); the rest are this
/// project's choices, documented in [`super::multiview`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FusionConfig {
    /// Which fusion builds the map: `op3dsg` (the paper's, [`OP3DSG_FUSION`], configured by
    /// the keys below), or one registered with the composition's backends, which owns its
    /// section `[fusion.<name>]` (`conceptgraphs` in `op3dsgd`: ConceptGraphs' association and
    /// merging, the benchmark's peer; its maps are not saved in snapshots).
    #[serde(default = "default_method")]
    pub method: String,
    /// Back-project at least every n-th pixel of a mask in x and y (1 = every pixel); the
    /// smallest stride of the adaptive sampling.
    pub pixel_stride: u32,
    /// Adaptive sampling: about this many samples per voxel edge at the mask's median depth (the
    /// stride grows with nearness, up to 16); 0 = always `pixel_stride`.
    pub samples_per_voxel: u32,
    /// Depth outside [min_depth_m, max_depth_m] is ignored, metres.
    pub min_depth_m: f32,
    /// See `min_depth_m`.
    pub max_depth_m: f32,
    /// Object mask pixels closer than this to the mask border are not back-projected (flying
    /// pixels at depth edges), pixels.
    pub object_mask_erode_px: u32,
    /// The same for parts, pixels.
    pub part_mask_erode_px: u32,
    /// Object points further than this from the mask's median depth are dropped (mask bleed
    /// onto the background), metres.
    pub object_depth_band_m: f32,
    /// The same for parts, metres.
    pub part_depth_band_m: f32,
    /// Voxel size for object point clouds, metres.
    pub object_voxel_m: f32,
    /// Voxel size for part point clouds, metres.
    pub part_voxel_m: f32,
    /// Nearest-neighbour radius `δ` of the geometric similarity for objects, metres.
    pub object_nnr_radius_m: f32,
    /// The same for parts, metres.
    pub part_nnr_radius_m: f32,
    /// The nearest-neighbour ratio is computed on at most this many (evenly spread) points of
    /// a detection.
    pub nnr_max_points: usize,
    /// Points kept per node at most.
    pub max_points_per_node: usize,
    /// Detections with fewer valid points (after downsampling) are ignored.
    pub min_points: usize,
    /// A candidate node needs at least this geometric similarity `s^g` (the candidate must
    /// partially overlap in geometry), [0, 1].
    pub min_geometric_similarity: f32,
    /// An object joins its best candidate when `S^o = s^g + s^s` reaches this, [0, 2].
    pub object_match_threshold: f32,
    /// A part joins its best candidate when `S^p` reaches this, [0, 1.4].
    pub part_match_threshold: f32,
    /// `w_p` of `S^p = w_p (s^g + s^s) + (1 − w_p) s^c`, [0, 1].
    pub part_weight: f32,
    /// Use the colour-distribution feature for parts (false = the paper's ablation).
    pub colour_features: bool,
    /// Colour-distribution feature parameters.
    pub colour: ColourParams,
    /// Nodes seen fewer times are held back from publication until confirmed.
    pub min_observations: u32,
    /// Nodes whose mean detector score is lower are held back too (and pruned like other
    /// unconfirmed nodes), [0, 1].
    pub min_mean_score: f32,
    /// Unconfirmed nodes not seen for this many keyframes are removed (0 = never).
    pub prune_unconfirmed_after_keyframes: u32,
    /// Run maintenance (duplicate merge, outlier removal, pruning) every this many keyframes
    /// (0 = never).
    pub maintenance_every_keyframes: u32,
    /// Maintenance merges two nodes of one kind when the larger of their two nearest-neighbour
    /// ratios reaches this, [0, 1] ...
    pub merge_min_overlap: f32,
    /// ... their semantic similarity `s^s` reaches this, [0, 1] ...
    pub merge_min_semantic: f32,
    /// ... and, for parts whose colour features are both valid, `s^c` reaches this, [0.5, 1].
    pub merge_min_colour: f32,
    /// Outlier removal keeps a point with at least this many other points of its node within
    /// `outlier_radius_voxels` (0 = no outlier removal).
    pub outlier_min_neighbours: u32,
    /// Radius of the outlier test in voxels of the node's kind (downsampled neighbours sit about
    /// one voxel apart), (1, 16].
    pub outlier_radius_voxels: f32,
    /// Cell size of the spatial index over node boxes, metres.
    pub index_cell_m: f32,
    /// A part attaches to an object whose box, grown by this margin, contains the part centre,
    /// metres.
    pub part_attach_margin_m: f32,
    /// `[fusion.change]`: removed and moved nodes from each keyframe's depth.
    #[serde(default)]
    pub change: super::change::ChangeConfig,
}

impl FusionConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let lengths = [
            ("min_depth_m", self.min_depth_m),
            ("object_voxel_m", self.object_voxel_m),
            ("part_voxel_m", self.part_voxel_m),
            ("object_nnr_radius_m", self.object_nnr_radius_m),
            ("part_nnr_radius_m", self.part_nnr_radius_m),
            ("object_depth_band_m", self.object_depth_band_m),
            ("part_depth_band_m", self.part_depth_band_m),
            ("index_cell_m", self.index_cell_m),
        ];
        for (name, v) in lengths {
            if !(v > 0.0 && v < 10.0) {
                return Err(format!("{path}.{name}: must be within (0, 10) metres, got {v}"));
            }
        }
        if self.max_depth_m <= self.min_depth_m {
            return Err(format!("{path}.max_depth_m: must be greater than min_depth_m, got {}", self.max_depth_m));
        }
        let small_ints = [
            ("pixel_stride", self.pixel_stride, 1, 16),
            ("samples_per_voxel", self.samples_per_voxel, 0, 16),
            ("object_mask_erode_px", self.object_mask_erode_px, 0, 16),
            ("part_mask_erode_px", self.part_mask_erode_px, 0, 16),
        ];
        for (name, v, lo, hi) in small_ints {
            if !(lo..=hi).contains(&v) {
                return Err(format!("{path}.{name}: must be within [{lo}, {hi}], got {v}"));
            }
        }
        let counts = [
            ("max_points_per_node", self.max_points_per_node, 16, 1_000_000),
            ("nnr_max_points", self.nnr_max_points, 8, 1_000_000),
            ("min_points", self.min_points, 1, 100_000),
        ];
        for (name, v, lo, hi) in counts {
            if !(lo..=hi).contains(&v) {
                return Err(format!("{path}.{name}: must be within [{lo}, {hi}], got {v}"));
            }
        }
        let ranges = [
            ("min_geometric_similarity", self.min_geometric_similarity, 0.0, 1.0),
            ("object_match_threshold", self.object_match_threshold, 0.0, 2.0),
            ("part_match_threshold", self.part_match_threshold, 0.0, 1.4),
            ("part_weight", self.part_weight, 0.0, 1.0),
            ("merge_min_overlap", self.merge_min_overlap, 0.0, 1.0),
            ("min_mean_score", self.min_mean_score, 0.0, 1.0),
            ("merge_min_semantic", self.merge_min_semantic, 0.0, 1.0),
            ("merge_min_colour", self.merge_min_colour, 0.5, 1.0),
            ("part_attach_margin_m", self.part_attach_margin_m, 0.0, 1.0),
            ("outlier_radius_voxels", self.outlier_radius_voxels, 1.0, 16.0),
        ];
        for (name, v, lo, hi) in ranges {
            if !(lo..=hi).contains(&v) {
                return Err(format!("{path}.{name}: must be within [{lo}, {hi}], got {v}"));
            }
        }
        for (name, r, voxel) in [
            ("object_nnr_radius_m", self.object_nnr_radius_m, self.object_voxel_m),
            ("part_nnr_radius_m", self.part_nnr_radius_m, self.part_voxel_m),
        ] {
            if r < voxel * 0.5 {
                return Err(format!(
                    "{path}.{name}: must be at least half the voxel size ({}), got {r}: smaller radii \
                     cannot find neighbours in a voxel-downsampled cloud",
                    voxel * 0.5
                ));
            }
        }
        self.colour.validate(&format!("{path}.colour"))?;
        self.change.validate(&format!("{path}.change"))
    }
}
