//! The occupancy grid: log-odds per cell from keyframes' depth, and its geometry.

use glam::DVec3;
use op3dsg_drivers::frame::Intrinsics;
use op3dsg_ipc_types::{OCCUPANCY_MAX_SIDE_CELLS, OCCUPANCY_UNKNOWN, OccupancyHeader};

use super::{DepthScan, OccupancyConfig, PlanePoint, RobotPose, to_plane};
use crate::world::UpAxis;

/// The grid's geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Cell side, metres.
    pub cell_size_m: f32,
    /// Plane coordinates of the low corner of cell (0, 0), metres.
    pub origin_m: [f32; 2],
}

impl GridGeometry {
    /// The cell holding plane point `xy` (may be outside the grid).
    #[inline]
    pub fn cell_of(&self, xy: [f32; 2]) -> (i32, i32) {
        (
            ((xy[0] - self.origin_m[0]) / self.cell_size_m).floor() as i32,
            ((xy[1] - self.origin_m[1]) / self.cell_size_m).floor() as i32,
        )
    }

    /// The centre of cell `(col, row)`.
    #[inline]
    pub fn centre_of(&self, col: i32, row: i32) -> [f32; 2] {
        [
            self.origin_m[0] + (col as f32 + 0.5) * self.cell_size_m,
            self.origin_m[1] + (row as f32 + 0.5) * self.cell_size_m,
        ]
    }

    /// The index of cell `(col, row)`, `None` outside the grid.
    #[inline]
    pub fn index(&self, col: i32, row: i32) -> Option<usize> {
        (col >= 0 && row >= 0 && (col as u32) < self.width && (row as u32) < self.height)
            .then(|| row as usize * self.width as usize + col as usize)
    }

    /// Cells.
    pub fn cell_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Evidence kept per keyframe for a cell: marks are `2 · scan` (hit) or `2 · scan + 1` (free).
const MARK_NONE: u32 = 0;

/// The occupancy grid (one writer: the occupancy thread, or the batch runner).
#[derive(Debug, Clone)]
pub struct OccupancyGrid {
    config: OccupancyConfig,
    up_axis: UpAxis,
    robot_radius_m: f32,
    geometry: GridGeometry,
    placed: bool,
    log_odds: Vec<f32>,
    marks: Vec<u32>,
    scan: u32,
    ends: Vec<(i32, i32, bool)>,
    hits: Vec<u32>,
    robot: Option<RobotPose>,
    keyframes: u64,
    stamp_ns: u64,
    memory_bytes: usize,
}

impl OccupancyGrid {
    /// A grid for `config` (validated), allocated now for keyframes of `intrinsics`' size; the
    /// robot footprint cleared around the camera has radius `robot_radius_m`.
    pub fn new(config: &OccupancyConfig, up_axis: UpAxis, robot_radius_m: f32, intrinsics: &Intrinsics) -> Self {
        let side = config.side_cells().clamp(8, OCCUPANCY_MAX_SIDE_CELLS);
        let geometry = GridGeometry { width: side, height: side, cell_size_m: config.cell_size_m, origin_m: [0.0; 2] };
        let stride = config.pixel_stride.max(1);
        let rays = intrinsics.width.div_ceil(stride) as usize * intrinsics.height.div_ceil(stride) as usize;
        let mut grid = Self {
            config: config.clone(),
            up_axis,
            robot_radius_m,
            geometry,
            placed: false,
            log_odds: vec![0.0; geometry.cell_count()],
            marks: vec![MARK_NONE; geometry.cell_count()],
            scan: 0,
            ends: Vec::with_capacity(rays),
            hits: Vec::with_capacity(rays),
            robot: None,
            keyframes: 0,
            stamp_ns: 0,
            memory_bytes: 0,
        };
        grid.memory_bytes = grid.allocated_bytes();
        if let Some(centre) = config.centre_m {
            grid.place(centre);
        }
        grid
    }

    fn place(&mut self, centre: [f32; 2]) {
        let half = self.geometry.width as f32 * self.geometry.cell_size_m * 0.5;
        self.geometry.origin_m = [centre[0] - half, centre[1] - half];
        self.placed = true;
    }

    /// The grid's geometry (its origin is fixed by the first keyframe unless `centre_m` is set).
    pub fn geometry(&self) -> GridGeometry {
        self.geometry
    }

    /// The robot's latest pose (the newest keyframe's camera), `None` before the first.
    pub fn robot(&self) -> Option<RobotPose> {
        self.robot
    }

    /// Keyframes integrated.
    pub fn keyframes(&self) -> u64 {
        self.keyframes
    }

    /// Newest keyframe stamp integrated, nanoseconds.
    pub fn stamp_ns(&self) -> u64 {
        self.stamp_ns
    }

    /// Which axis is up.
    pub fn up_axis(&self) -> UpAxis {
        self.up_axis
    }

    /// The profile section the grid was made with.
    pub fn config(&self) -> &OccupancyConfig {
        &self.config
    }

    /// Heap bytes allocated at construction (fixed: integration never grows a buffer; a clone
    /// reports its original's figure).
    pub fn memory_bytes(&self) -> usize {
        self.memory_bytes
    }

    pub(super) fn allocated_bytes(&self) -> usize {
        self.log_odds.capacity() * size_of::<f32>()
            + self.marks.capacity() * size_of::<u32>()
            + self.ends.capacity() * size_of::<(i32, i32, bool)>()
            + self.hits.capacity() * size_of::<u32>()
    }

    /// Log-odds of cell `index`.
    pub fn log_odds(&self, index: usize) -> f32 {
        self.log_odds.get(index).copied().unwrap_or(0.0)
    }

    fn up_vector(&self) -> DVec3 {
        match self.up_axis {
            UpAxis::Z => DVec3::Z,
            UpAxis::Y => DVec3::Y,
            UpAxis::NegY => DVec3::NEG_Y,
        }
    }

    /// Integrates one keyframe's scan (see the module docs). Allocates nothing.
    pub fn integrate(&mut self, scan: &DepthScan) {
        let camera = self.move_robot(scan);
        let hit_mark = self.next_scan_mark();
        let (camera_col, camera_row) = self.geometry.cell_of(camera.xy);
        self.cast_rays(scan, hit_mark);
        self.clear_along_rays((camera_col, camera_row), hit_mark);
        self.clear_footprint(camera.xy, (camera_col, camera_row), hit_mark + 1);
    }

    /// The robot at the scan's camera (the grid placed around the first one); the camera's
    /// point on the plane.
    fn move_robot(&mut self, scan: &DepthScan) -> PlanePoint {
        let pose = &scan.world_from_camera;
        let camera = to_plane(self.up_axis, pose.translation.as_vec3());
        if !self.placed {
            self.place(camera.xy);
        }
        let forward = pose.transform_vector(DVec3::Z).as_vec3();
        let forward = to_plane(self.up_axis, forward);
        let yaw_rad = if forward.xy[0].abs() + forward.xy[1].abs() > 1e-6 {
            forward.xy[1].atan2(forward.xy[0])
        } else {
            self.robot.map_or(0.0, |r| r.yaw_rad)
        };
        self.robot = Some(RobotPose { xy: camera.xy, yaw_rad });
        self.keyframes += 1;
        self.stamp_ns = self.stamp_ns.max(scan.stamp_ns);
        camera
    }

    /// This keyframe's hit mark (its free mark is the next number).
    fn next_scan_mark(&mut self) -> u32 {
        self.scan = self.scan.wrapping_add(1);
        if self.scan >= u32::MAX / 2 {
            // Once in 2^31 keyframes: forget the old marks (a cell stays "observed").
            for mark in &mut self.marks {
                *mark = u32::from(*mark != MARK_NONE);
            }
            self.scan = 1;
        }
        self.scan * 2
    }

    /// Steps 1-2: each ray's end cell, and the hit cells (marked once per keyframe).
    fn cast_rays(&mut self, scan: &DepthScan, hit_mark: u32) {
        let pose = &scan.world_from_camera;
        let geometry = self.geometry;
        let floor = self.config.floor_height_m;
        let (band_min, band_max) = (self.config.obstacle_min_height_m, self.config.obstacle_max_height_m);
        let max_range = f64::from(self.config.max_range_m);
        let up = self.up_vector();
        let units = f64::from(scan.depth_units_per_m.max(1e-6));
        let k = &scan.intrinsics;
        let stride = scan.stride.max(1) as f64;
        self.ends.clear();
        self.hits.clear();
        for row in 0..scan.rows as usize {
            let v = row as f64 * stride;
            let b = (v - f64::from(k.cy)) / f64::from(k.fy);
            for col in 0..scan.cols as usize {
                let raw = scan.depth[row * scan.cols as usize + col];
                if raw == 0 {
                    continue;
                }
                let depth_m = f64::from(raw) / units;
                let u = col as f64 * stride;
                let a = (u - f64::from(k.cx)) / f64::from(k.fx);
                let mut point_in_camera = DVec3::new(a * depth_m, b * depth_m, depth_m);
                let range = point_in_camera.length();
                let cut = range > max_range;
                if cut {
                    point_in_camera *= max_range / range;
                }
                let point_in_world = pose.transform_point(point_in_camera);
                let height = (point_in_world.dot(up) - f64::from(floor)) as f32;
                if height > band_max {
                    continue;
                }
                let hit = !cut && height >= band_min;
                let (col_e, row_e) = geometry.cell_of(to_plane(self.up_axis, point_in_world.as_vec3()).xy);
                if self.ends.len() == self.ends.capacity() {
                    break;
                }
                self.ends.push((col_e, row_e, hit));
                if hit
                    && let Some(index) = geometry.index(col_e, row_e)
                    && self.marks[index] != hit_mark
                {
                    self.marks[index] = hit_mark;
                    self.hits.push(index as u32);
                }
            }
        }
    }

    /// Steps 3-4: free cells along each ray from the camera's cell, once per keyframe, hits
    /// excluded; then the hits.
    fn clear_along_rays(&mut self, (camera_col, camera_row): (i32, i32), hit_mark: u32) {
        let free_mark = hit_mark + 1;
        let geometry = self.geometry;
        let miss = self.config.miss_log_odds;
        let clamp = self.config.max_log_odds;
        for &(col_e, row_e, hit) in &self.ends {
            bresenham(camera_col, camera_row, col_e, row_e, |col, row| {
                let at_end = col == col_e && row == row_e;
                if at_end && hit {
                    return;
                }
                if let Some(index) = geometry.index(col, row) {
                    let mark = &mut self.marks[index];
                    if *mark != hit_mark && *mark != free_mark {
                        *mark = free_mark;
                        self.log_odds[index] = (self.log_odds[index] - miss).max(-clamp);
                    }
                }
            });
        }
        let hit_add = self.config.hit_log_odds;
        for &index in &self.hits {
            let l = &mut self.log_odds[index as usize];
            *l = (*l + hit_add).min(clamp);
        }
    }

    /// Step 5: the robot's footprint around the camera is free.
    fn clear_footprint(&mut self, camera_xy: [f32; 2], (camera_col, camera_row): (i32, i32), free_mark: u32) {
        let geometry = self.geometry;
        let miss = self.config.miss_log_odds;
        let radius_cells = (self.robot_radius_m / geometry.cell_size_m).ceil() as i32;
        let radius2 = self.robot_radius_m * self.robot_radius_m;
        for dr in -radius_cells..=radius_cells {
            for dc in -radius_cells..=radius_cells {
                let (col, row) = (camera_col + dc, camera_row + dr);
                let centre = geometry.centre_of(col, row);
                let (dx, dy) = (centre[0] - camera_xy[0], centre[1] - camera_xy[1]);
                if dx * dx + dy * dy > radius2 {
                    continue;
                }
                if let Some(index) = geometry.index(col, row) {
                    self.log_odds[index] = self.log_odds[index].min(-miss);
                    if self.marks[index] == MARK_NONE {
                        self.marks[index] = free_mark;
                    }
                }
            }
        }
    }

    /// The map's saved form ([`persist`]): geometry, robot, counters, every cell's log-odds and
    /// whether it was observed; appended to `out`.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        let g = &self.geometry;
        out.extend_from_slice(&g.width.to_le_bytes());
        out.extend_from_slice(&g.height.to_le_bytes());
        out.extend_from_slice(&g.cell_size_m.to_le_bytes());
        out.extend_from_slice(&g.origin_m[0].to_le_bytes());
        out.extend_from_slice(&g.origin_m[1].to_le_bytes());
        out.extend_from_slice(&self.keyframes.to_le_bytes());
        out.extend_from_slice(&self.stamp_ns.to_le_bytes());
        let robot = self.robot.unwrap_or_default();
        out.push(u8::from(self.robot.is_some()));
        for v in [robot.xy[0], robot.xy[1], robot.yaw_rad] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for l in &self.log_odds {
            out.extend_from_slice(&l.to_le_bytes());
        }
        for chunk in self.marks.chunks(8) {
            out.push(chunk.iter().enumerate().fold(0u8, |b, (i, m)| b | (u8::from(*m != MARK_NONE) << i)));
        }
    }

    /// Restores a map written by [`Self::encode_into`]; the geometry (cells a side, cell size and,
    /// with `centre_m` set, the origin) must be this grid's. Nothing changes on an error, which
    /// names what differs.
    pub fn restore_from(&mut self, bytes: &[u8]) -> Result<(), String> {
        let mut at = 0usize;
        let mut take = |n: usize| -> Result<&[u8], String> {
            let slice = bytes.get(at..at + n).ok_or_else(|| format!("truncated at byte {at}"))?;
            at += n;
            Ok(slice)
        };
        let u32_of = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let f32_of = |b: &[u8]| f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let u64_of = |b: &[u8]| {
            let mut a = [0u8; 8];
            a.copy_from_slice(b);
            u64::from_le_bytes(a)
        };
        let (width, height) = (u32_of(take(4)?), u32_of(take(4)?));
        let cell_size_m = f32_of(take(4)?);
        let origin_m = [f32_of(take(4)?), f32_of(take(4)?)];
        let g = self.geometry;
        if (width, height) != (g.width, g.height) || (cell_size_m - g.cell_size_m).abs() > 1e-6 {
            return Err(format!(
                "saved grid is {width} x {height} cells of {cell_size_m} m, the profile's {} x {} of {} m                  (occupancy.size_m, occupancy.cell_size_m)",
                g.width, g.height, g.cell_size_m
            ));
        }
        if self.placed && (origin_m[0] - g.origin_m[0]).abs().max((origin_m[1] - g.origin_m[1]).abs()) > 1e-4 {
            return Err(format!(
                "saved grid's origin {origin_m:?} is not the one occupancy.centre_m gives ({:?})",
                g.origin_m
            ));
        }
        let keyframes = u64_of(take(8)?);
        let stamp_ns = u64_of(take(8)?);
        let robot_valid = take(1)?[0] == 1;
        let robot = RobotPose { xy: [f32_of(take(4)?), f32_of(take(4)?)], yaw_rad: f32_of(take(4)?) };
        let n = g.cell_count();
        let log_odds = take(n * 4)?;
        let observed = take(n.div_ceil(8))?;
        if at != bytes.len() {
            return Err(format!("{} bytes after the cells", bytes.len() - at));
        }
        let clamp = self.config.max_log_odds;
        for (i, l) in self.log_odds.iter_mut().enumerate() {
            let v = f32_of(&log_odds[i * 4..i * 4 + 4]);
            *l = if v.is_finite() { v.clamp(-clamp, clamp) } else { 0.0 };
        }
        for (i, m) in self.marks.iter_mut().enumerate() {
            *m = u32::from(observed[i / 8] >> (i % 8) & 1 == 1);
        }
        self.geometry.origin_m = origin_m;
        self.placed = true;
        self.keyframes = keyframes;
        self.stamp_ns = stamp_ns;
        self.robot = robot_valid.then_some(robot);
        self.scan = 0;
        Ok(())
    }

    /// Cell `index` as published: -1 unknown, else the occupancy probability in percent.
    #[inline]
    pub fn cell_percent(&self, index: usize) -> i8 {
        if self.marks[index] == MARK_NONE {
            return OCCUPANCY_UNKNOWN;
        }
        let p = 1.0 - 1.0 / (1.0 + self.log_odds[index].exp());
        (p * 100.0).round().clamp(0.0, 100.0) as i8
    }

    /// Writes every cell (as [`Self::cell_percent`]) into `out` (`cell_count` long); returns the
    /// free and occupied cell counts.
    pub fn write_cells(&self, out: &mut [i8]) -> (u32, u32) {
        let (mut free, mut occupied) = (0u32, 0u32);
        for (index, slot) in out.iter_mut().enumerate().take(self.geometry.cell_count()) {
            let value = self.cell_percent(index);
            *slot = value;
            if (0..=op3dsg_ipc_types::OCCUPANCY_FREE_MAX_PERCENT).contains(&value) {
                free += 1;
            } else if value >= op3dsg_ipc_types::OCCUPANCY_OCCUPIED_MIN_PERCENT {
                occupied += 1;
            }
        }
        (free, occupied)
    }

    /// The published header (without the per-period figures, which the caller fills).
    pub fn header(&self) -> OccupancyHeader {
        let robot = self.robot.unwrap_or_default();
        OccupancyHeader {
            schema_version: op3dsg_ipc_types::OCCUPANCY_SCHEMA_VERSION,
            width_cells: self.geometry.width,
            height_cells: self.geometry.height,
            cell_size_m: self.geometry.cell_size_m,
            origin_x_m: self.geometry.origin_m[0],
            origin_y_m: self.geometry.origin_m[1],
            floor_height_m: self.config.floor_height_m,
            obstacle_min_height_m: self.config.obstacle_min_height_m,
            obstacle_max_height_m: self.config.obstacle_max_height_m,
            up_axis: match self.up_axis {
                UpAxis::Z => 0,
                UpAxis::Y => 1,
                UpAxis::NegY => 2,
            },
            robot_pose_valid: u8::from(self.robot.is_some()),
            stamp_ns: self.stamp_ns,
            keyframes_integrated: self.keyframes,
            robot_x_m: robot.xy[0],
            robot_y_m: robot.xy[1],
            robot_yaw_rad: robot.yaw_rad,
            ..OccupancyHeader::default()
        }
    }
}

/// Visits the cells of the 2D Bresenham line from `(c0, r0)` to `(c1, r1)`, both included.
#[inline]
pub fn bresenham(c0: i32, r0: i32, c1: i32, r1: i32, mut visit: impl FnMut(i32, i32)) {
    let (dx, dy) = ((c1 - c0).abs(), -(r1 - r0).abs());
    let (sx, sy) = (if c0 < c1 { 1 } else { -1 }, if r0 < r1 { 1 } else { -1 });
    let (mut c, mut r, mut err) = (c0, r0, dx + dy);
    loop {
        visit(c, r);
        if c == c1 && r == r1 {
            break;
        }
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            c += sx;
        }
        if e2 <= dx {
            err += dx;
            r += sy;
        }
    }
}
