//! What the map is made from: points on the floor plane, the robot's pose on it, and each
//! keyframe's subsampled depth.

use glam::Vec3;
use op3dsg_drivers::frame::Intrinsics;
use op3dsg_drivers::pose::Isometry;

use crate::world::UpAxis;

/// A point of the world on the floor plane and its height above the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanePoint {
    /// Plane coordinates (world `x, y` with z up, `x, z` with y up), metres.
    pub xy: [f32; 2],
    /// Height along the up axis (world coordinate, not above the floor), metres.
    pub up: f32,
}

/// World → floor plane for `up_axis` (`x, y` with z up; `x, z` with y or -y up).
pub fn to_plane(up_axis: UpAxis, point: Vec3) -> PlanePoint {
    match up_axis {
        UpAxis::Z => PlanePoint { xy: [point.x, point.y], up: point.z },
        UpAxis::Y => PlanePoint { xy: [point.x, point.z], up: point.y },
        UpAxis::NegY => PlanePoint { xy: [point.x, point.z], up: -point.y },
    }
}

/// The robot's pose on the plane.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RobotPose {
    /// Position, metres.
    pub xy: [f32; 2],
    /// Heading (the camera's optical axis projected), radians.
    pub yaw_rad: f32,
}

/// One keyframe's depth for the map, already subsampled: `depth[row * cols + col]` is the
/// depth of pixel `(col * stride, row * stride)`.
#[derive(Debug, Clone)]
pub struct DepthScan {
    /// Subsampled depth, sensor units (0 = none).
    pub depth: Vec<u16>,
    /// Samples per row.
    pub cols: u32,
    /// Rows.
    pub rows: u32,
    /// The stride the samples were taken with.
    pub stride: u32,
    /// Intrinsics of the full image.
    pub intrinsics: Intrinsics,
    /// Depth units per metre.
    pub depth_units_per_m: f32,
    /// `world_from_camera` of the keyframe.
    pub world_from_camera: Isometry,
    /// The keyframe's stamp, nanoseconds.
    pub stamp_ns: u64,
}

impl DepthScan {
    /// An empty scan with room for `intrinsics`' image at `stride` (allocated once).
    pub fn with_capacity(intrinsics: &Intrinsics, stride: u32) -> Self {
        let (cols, rows) = Self::samples(intrinsics, stride);
        Self {
            depth: Vec::with_capacity(cols as usize * rows as usize),
            cols: 0,
            rows: 0,
            stride: stride.max(1),
            intrinsics: *intrinsics,
            depth_units_per_m: 1000.0,
            world_from_camera: Isometry::IDENTITY,
            stamp_ns: 0,
        }
    }

    fn samples(intrinsics: &Intrinsics, stride: u32) -> (u32, u32) {
        let stride = stride.max(1);
        (intrinsics.width.div_ceil(stride), intrinsics.height.div_ceil(stride))
    }

    /// Fills the scan from a full-resolution depth image (reuses the buffer).
    pub fn fill(
        &mut self,
        depth: &[u16],
        intrinsics: &Intrinsics,
        depth_units_per_m: f32,
        world_from_camera: &Isometry,
        stamp_ns: u64,
    ) {
        let stride = self.stride.max(1);
        let (cols, rows) = Self::samples(intrinsics, stride);
        let width = intrinsics.width as usize;
        self.depth.clear();
        for row in 0..rows as usize {
            let start = row * stride as usize * width;
            let Some(line) = depth.get(start..start + width) else { break };
            self.depth.extend(line.iter().step_by(stride as usize));
        }
        self.cols = cols;
        self.rows = (self.depth.len() / cols.max(1) as usize) as u32;
        self.intrinsics = *intrinsics;
        self.depth_units_per_m = depth_units_per_m;
        self.world_from_camera = *world_from_camera;
        self.stamp_ns = stamp_ns;
    }
}
