//! The 2D occupancy map the daemon builds from depth and poses, as it travels on
//! `<prefix>/occupancy` (publish-subscribe, about once a second; see [`services`](crate::services)).
//!
//! A sample is an iceoryx2 slice service: payload `[i8]` (one value per cell), user header
//! [`OccupancyHeader`] (type name `op3dsg::OccupancyHeader`, 112 bytes). The payload holds
//! exactly `width_cells * height_cells` values, row-major: cell `(col, row)` is at
//! `row * width_cells + col`.
//!
//! Cell values follow ROS `nav_msgs/OccupancyGrid`: [`OCCUPANCY_UNKNOWN`] (-1) for a cell never
//! observed, else the occupancy probability in percent, 0 (certainly free) to 100 (certainly
//! occupied). The daemon's own planner treats `<= OCCUPANCY_FREE_MAX_PERCENT` as free and
//! `>= OCCUPANCY_OCCUPIED_MIN_PERCENT` as occupied (the rest like unknown).
//!
//! The grid lies on the floor plane. With `world.up_axis = "z"` (default) column `col` spans
//! world `x` in `[origin_x_m + col * cell_size_m, origin_x_m + (col + 1) * cell_size_m)` and row
//! `row` spans world `y` likewise from `origin_y_m`; with `"y"` up the plane's first axis is world
//! `x` and its second world `z`. Yaws are `atan2(second, first)` in that plane, radians.

use iceoryx2::prelude::ZeroCopySend;

/// Version of [`OccupancyHeader`] and the cell encoding.
pub const OCCUPANCY_SCHEMA_VERSION: u32 = 1;
/// Cell value of a cell never observed.
pub const OCCUPANCY_UNKNOWN: i8 = -1;
/// Cells at or below this probability (percent) are free for the daemon's planner.
pub const OCCUPANCY_FREE_MAX_PERCENT: i8 = 35;
/// Cells at or above this probability (percent) are obstacles for the daemon's planner.
pub const OCCUPANCY_OCCUPIED_MIN_PERCENT: i8 = 65;
/// The most cells along one side of the grid a profile may ask for (`occupancy.size_m /
/// occupancy.cell_size_m`).
pub const OCCUPANCY_MAX_SIDE_CELLS: u32 = 2048;

/// The header of one occupancy sample; the cells are the payload.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("op3dsg::OccupancyHeader")]
pub struct OccupancyHeader {
    /// [`OCCUPANCY_SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Cells per row (along the plane's first axis).
    pub width_cells: u32,
    /// Rows (along the plane's second axis).
    pub height_cells: u32,
    /// Side of one square cell, metres.
    pub cell_size_m: f32,
    /// Plane coordinate of the grid's first-axis edge (cell column 0's low side), metres.
    pub origin_x_m: f32,
    /// Plane coordinate of the grid's second-axis edge (cell row 0's low side), metres.
    pub origin_y_m: f32,
    /// World coordinate of the floor along the up axis (`occupancy.floor_height_m`), metres.
    pub floor_height_m: f32,
    /// Obstacle band above the floor: lowest height that counts, metres.
    pub obstacle_min_height_m: f32,
    /// Obstacle band above the floor: highest height that counts, metres.
    pub obstacle_max_height_m: f32,
    /// `0`: +z up, `1`: +y up, `2`: -y up (`world.up_axis`).
    pub up_axis: u8,
    /// `1` when `robot_*` hold the robot's latest pose (a keyframe was integrated).
    pub robot_pose_valid: u8,
    /// Reserved, zero.
    pub reserved: [u8; 2],
    /// The occupancy publisher's instance, drawn when the daemon starts (not the graph's
    /// [`GraphHeader::instance_id`](crate::GraphHeader::instance_id)): a new value means a restart.
    pub instance_id: u64,
    /// Stamp of the newest keyframe integrated, on the frames' clock, nanoseconds.
    pub stamp_ns: u64,
    /// Wall-clock time of the send (`CLOCK_REALTIME`), nanoseconds.
    pub publish_time_ns: u64,
    /// Keyframes integrated since the daemon started.
    pub keyframes_integrated: u64,
    /// Keyframes not integrated because the occupancy queue was full (`occupancy.queue_capacity`).
    pub keyframes_dropped: u64,
    /// The robot's latest position on the plane (the camera's floor projection), first axis, metres.
    pub robot_x_m: f32,
    /// The robot's latest position, second axis, metres.
    pub robot_y_m: f32,
    /// The camera's heading on the plane (its optical axis projected), radians.
    pub robot_yaw_rad: f32,
    /// Median integration cost of one keyframe since the last sample, microseconds.
    pub integrate_p50_us: u32,
    /// 99th percentile of the same, microseconds.
    pub integrate_p99_us: u32,
    /// Cells now at or below [`OCCUPANCY_FREE_MAX_PERCENT`].
    pub free_cells: u32,
    /// Cells now at or above [`OCCUPANCY_OCCUPIED_MIN_PERCENT`].
    pub occupied_cells: u32,
    /// Reserved, zero.
    pub reserved2: u32,
}

impl OccupancyHeader {
    /// Cells of the payload (`width_cells * height_cells`).
    pub fn cell_count(&self) -> usize {
        self.width_cells as usize * self.height_cells as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{offset_of, size_of};

    #[test]
    fn layout_is_the_documented_one() {
        assert_eq!(size_of::<OccupancyHeader>(), 112);
        assert_eq!(offset_of!(OccupancyHeader, up_axis), 36);
        assert_eq!(offset_of!(OccupancyHeader, instance_id), 40);
        assert_eq!(offset_of!(OccupancyHeader, robot_x_m), 80);
        assert_eq!(offset_of!(OccupancyHeader, reserved2), 108);
    }

    #[test]
    #[allow(unsafe_code)]
    fn type_name_is_stable() {
        // SAFETY: `type_name` is an unsafe trait fn only because implementors must keep it stable.
        unsafe {
            assert_eq!(<OccupancyHeader as ZeroCopySend>::type_name(), "op3dsg::OccupancyHeader");
        }
    }
}
