//! Multi-view fusion: detections of each keyframe become 3D nodes of one map.
//!
//! The fusion thread is the only owner of the map ([`Fusion`]); other threads see it only
//! through the [`crate::graph::SceneGraph`] snapshots it builds.

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use serde::{Deserialize, Serialize};

use crate::graph::SceneGraph;
use crate::perception::Detection;

pub mod colour;
pub mod simple;

/// `[fusion]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FusionConfig {
    /// Back-project every n-th pixel of a mask in x and y (1 = every pixel).
    pub pixel_stride: u32,
    /// Depth outside [min_depth_m, max_depth_m] is ignored, metres.
    pub min_depth_m: f32,
    /// See `min_depth_m`.
    pub max_depth_m: f32,
    /// Object points further than this from the mask's median depth are dropped (mask bleed
    /// onto the background), metres.
    pub object_depth_band_m: f32,
    /// The same for parts, metres.
    pub part_depth_band_m: f32,
    /// Voxel size for object point clouds, metres.
    pub object_voxel_m: f32,
    /// Voxel size for part point clouds, metres.
    pub part_voxel_m: f32,
    /// Points kept per node at most.
    pub max_points_per_node: usize,
    /// Detections with fewer valid points are ignored.
    pub min_points: usize,
    /// A detection joins the best node of its kind when at least this fraction of its points
    /// lie inside the node's box grown by one voxel; otherwise it starts a new node.
    pub min_overlap: f32,
    /// Nodes seen fewer times are held back from publication until confirmed.
    pub min_observations: u32,
    /// A part attaches to an object whose box, grown by this margin, contains the part centre,
    /// metres.
    pub part_attach_margin_m: f32,
}

impl FusionConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let positive = [
            ("min_depth_m", self.min_depth_m),
            ("object_voxel_m", self.object_voxel_m),
            ("part_voxel_m", self.part_voxel_m),
            ("object_depth_band_m", self.object_depth_band_m),
            ("part_depth_band_m", self.part_depth_band_m),
        ];
        for (name, v) in positive {
            if !(v > 0.0 && v < 10.0) {
                return Err(format!("{path}.{name}: must be within (0, 10) metres, got {v}"));
            }
        }
        if self.max_depth_m <= self.min_depth_m {
            return Err(format!("{path}.max_depth_m: must be greater than min_depth_m, got {}", self.max_depth_m));
        }
        if !(1..=16).contains(&self.pixel_stride) {
            return Err(format!("{path}.pixel_stride: must be within [1, 16], got {}", self.pixel_stride));
        }
        if !(16..=1_000_000).contains(&self.max_points_per_node) {
            return Err(format!(
                "{path}.max_points_per_node: must be within [16, 1000000], got {}",
                self.max_points_per_node
            ));
        }
        if !(0.0..=1.0).contains(&self.min_overlap) {
            return Err(format!("{path}.min_overlap: must be within [0, 1], got {}", self.min_overlap));
        }
        if !(0.0..1.0).contains(&self.part_attach_margin_m) {
            return Err(format!(
                "{path}.part_attach_margin_m: must be within [0, 1) metres, got {}",
                self.part_attach_margin_m
            ));
        }
        Ok(())
    }
}

/// What one keyframe did to the map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FusionReport {
    /// Detections merged into existing nodes.
    pub merged: u32,
    /// New nodes created.
    pub created: u32,
    /// Detections ignored (too few valid points).
    pub ignored: u32,
}

/// A map that fuses keyframe detections.
pub trait Fusion: Send {
    /// Fuses the detections of one keyframe taken at `world_from_camera`.
    fn integrate(&mut self, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> FusionReport;

    /// Fills `out` with the confirmed nodes and their geometric edges (version and stamp are
    /// set by the caller).
    fn build_graph(&self, out: &mut SceneGraph);

    /// Nodes in the map, confirmed or not.
    fn node_count(&self) -> usize;
}
