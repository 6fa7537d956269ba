//! # The 2D occupancy map: depth and poses → free and occupied floor cells
//!
//! A fixed-size square grid on the floor plane (`[occupancy]`: `size_m` side, `cell_size_m`
//! cells, centred on `centre_m` or, unset, on the first keyframe's camera position), allocated
//! once when the daemon starts; nothing grows afterwards ([`OccupancyGrid::memory_bytes`]).
//! Every keyframe is integrated on a thread of its own ([`service`]), never on the fusion
//! thread; the planner on top of it is [`nav`].
//!
//! ## Integration of one keyframe ([`OccupancyGrid::integrate`])
//!
//! 1. Every `pixel_stride`-th pixel in both directions (8: 80 × 60 rays for 640 × 480) with a
//!    depth is back-projected (`point_in_camera = ((u - cx) / fx · d, (v - cy) / fy · d, d)`) and
//!    moved into the world (`world_from_camera`). Its height above the floor is
//!    `h = up · point_in_world - floor_height_m`.
//! 2. A point within the obstacle band `[obstacle_min_height_m, obstacle_max_height_m]` is a
//!    **hit**: its cell gets evidence of occupancy. A point below the band is floor: its cell is
//!    free evidence. A point above the band (ceiling, top of a wardrobe) is left out altogether
//!    (it says nothing about the band below it). A ray longer than `max_range_m` is cut there
//!    and its end is not a hit.
//! 3. **Free space by ray casting**: the cells of the 2D Bresenham line from the camera's floor
//!    projection to the end cell (the end excluded when it is a hit) get evidence of freedom.
//! 4. Each cell changes at most once per keyframe (a hit wins over free), so the many rays near
//!    the camera do not count as many observations.
//! 5. The robot stands where the camera is: the cells within `navigation.robot_radius_m` of the
//!    camera's floor projection are made free (the camera does not see the floor under itself).
//!
//! Evidence is **log-odds**: `l += hit_log_odds` for a hit (0.85: p = 0.70), `l -= miss_log_odds`
//! for free (0.7: p = 0.33), clamped to `±max_log_odds`. Published cells are the probability
//! `p = 1 - 1 / (1 + e^l)` in percent, `-1` for a cell never updated
//! ([`op3dsg_ipc_types::occupancy_types`]); free ≤ 35 %, occupied ≥ 65 %, so one clear
//! observation makes a cell free and one hit makes it occupied, and a hit seen once, then seen
//! through twice (a person who walked away) is free again.
//!
//! Known limits: a 2D map of a 3D band: a ray that passes over a low obstacle (below the camera)
//! to the floor behind it counts the obstacle's cell as free at that keyframe; hits are stronger
//! than misses so an obstacle seen from several keyframes stays occupied, but a low, thin one
//! seen once may not. Overhangs above `obstacle_max_height_m` are ignored by design (set it to
//! the robot's height).
//!
//! ## Cost and memory
//!
//! Per keyframe: `(width / stride) · (height / stride)` rays of at most `max_range_m /
//! cell_size_m` cells (`op3dsg bench nav` prints p50/p99 per keyframe). Memory: 4 bytes of
//! log-odds and 4 of per-keyframe marks per cell (20 m at 5 cm: 400 × 400 cells, 1.25 MiB), plus
//! a fixed buffer of ray ends.

pub mod nav;
pub mod persist;
pub mod service;

use glam::{DVec3, Vec3};
use op3dsg_drivers::frame::Intrinsics;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{OCCUPANCY_MAX_SIDE_CELLS, OCCUPANCY_UNKNOWN, OccupancyHeader};
use serde::{Deserialize, Serialize};

use crate::config::UpAxis;

pub use nav::{Approach, NavigationConfig, Planner, Target};

/// `[occupancy]`: the 2D occupancy map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OccupancyConfig {
    /// Build the map and publish it on `<prefix>/occupancy`.
    pub enabled: bool,
    /// Side of a square cell, metres.
    pub cell_size_m: f32,
    /// Side of the square grid, metres (fixed at start; `size_m / cell_size_m` cells a side).
    pub size_m: f32,
    /// Centre of the grid on the floor plane (`[x, y]` with z up, `[x, z]` with y up), metres;
    /// unset: the first keyframe's camera position.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub centre_m: Option<[f32; 2]>,
    /// World coordinate of the floor along the up axis, metres.
    pub floor_height_m: f32,
    /// Lowest height above the floor that is an obstacle, metres (below: floor).
    pub obstacle_min_height_m: f32,
    /// Highest height above the floor that is an obstacle, metres (the robot's height; above:
    /// ignored).
    pub obstacle_max_height_m: f32,
    /// Rays are cut at this range, metres (depth beyond is too noisy to mark obstacles).
    pub max_range_m: f32,
    /// Every `pixel_stride`-th pixel in both directions is a ray.
    pub pixel_stride: u32,
    /// Log-odds added to a cell a ray ends in (a hit).
    pub hit_log_odds: f32,
    /// Log-odds taken from a cell a ray passes through.
    pub miss_log_odds: f32,
    /// Log-odds are clamped to `±max_log_odds` (how fast the map can change its mind).
    pub max_log_odds: f32,
    /// Keyframes waiting for the occupancy thread at most; more are dropped (counted in the
    /// published header), never waited for.
    pub queue_capacity: usize,
    /// How often the map is published on `<prefix>/occupancy` and handed to the query service,
    /// milliseconds.
    pub publish_period_ms: u64,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            cell_size_m: 0.05,
            size_m: 20.0,
            centre_m: None,
            floor_height_m: 0.0,
            obstacle_min_height_m: 0.05,
            obstacle_max_height_m: 1.5,
            max_range_m: 4.0,
            pixel_stride: 8,
            hit_log_odds: 0.85,
            miss_log_odds: 0.7,
            max_log_odds: 3.5,
            queue_capacity: 2,
            publish_period_ms: 1000,
        }
    }
}

impl OccupancyConfig {
    /// Cells along one side.
    pub fn side_cells(&self) -> u32 {
        (self.size_m / self.cell_size_m).round() as u32
    }

    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let positive = |value: f32, field: &str| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(format!("{path}.{field}: must be a positive number of metres, got {value}"))
            }
        };
        positive(self.cell_size_m, "cell_size_m")?;
        positive(self.size_m, "size_m")?;
        positive(self.max_range_m, "max_range_m")?;
        if !(0.01..=1.0).contains(&self.cell_size_m) {
            return Err(format!("{path}.cell_size_m: must be within [0.01, 1] m, got {}", self.cell_size_m));
        }
        let side = self.side_cells();
        if !(8..=OCCUPANCY_MAX_SIDE_CELLS).contains(&side) {
            return Err(format!(
                "{path}.size_m: {} m / cell_size_m {} m = {side} cells a side; must be within [8, \
                 {OCCUPANCY_MAX_SIDE_CELLS}]",
                self.size_m, self.cell_size_m
            ));
        }
        if let Some(centre) = self.centre_m
            && !centre.iter().all(|c| c.is_finite())
        {
            return Err(format!("{path}.centre_m: must be finite, got {centre:?}"));
        }
        if !self.floor_height_m.is_finite() {
            return Err(format!("{path}.floor_height_m: must be finite, got {}", self.floor_height_m));
        }
        if !(self.obstacle_min_height_m.is_finite()
            && self.obstacle_max_height_m.is_finite()
            && self.obstacle_min_height_m >= 0.0
            && self.obstacle_min_height_m < self.obstacle_max_height_m)
        {
            return Err(format!(
                "{path}.obstacle_min_height_m: must be >= 0 and below obstacle_max_height_m, got {} and {}",
                self.obstacle_min_height_m, self.obstacle_max_height_m
            ));
        }
        if !(1..=64).contains(&self.pixel_stride) {
            return Err(format!("{path}.pixel_stride: must be within [1, 64], got {}", self.pixel_stride));
        }
        for (value, field) in [
            (self.hit_log_odds, "hit_log_odds"),
            (self.miss_log_odds, "miss_log_odds"),
            (self.max_log_odds, "max_log_odds"),
        ] {
            if !(value.is_finite() && value > 0.0 && value <= 20.0) {
                return Err(format!("{path}.{field}: must be within (0, 20], got {value}"));
            }
        }
        if !(1..=64).contains(&self.queue_capacity) {
            return Err(format!("{path}.queue_capacity: must be within [1, 64], got {}", self.queue_capacity));
        }
        if !(50..=60_000).contains(&self.publish_period_ms) {
            return Err(format!(
                "{path}.publish_period_ms: must be within [50, 60000], got {}",
                self.publish_period_ms
            ));
        }
        Ok(())
    }
}

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

    fn allocated_bytes(&self) -> usize {
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

        self.scan = self.scan.wrapping_add(1);
        if self.scan >= u32::MAX / 2 {
            // Once in 2^31 keyframes: forget the old marks (a cell stays "observed").
            for mark in &mut self.marks {
                *mark = u32::from(*mark != MARK_NONE);
            }
            self.scan = 1;
        }
        let hit_mark = self.scan * 2;
        let free_mark = hit_mark + 1;
        let geometry = self.geometry;
        let (camera_col, camera_row) = geometry.cell_of(camera.xy);
        let floor = self.config.floor_height_m;
        let (band_min, band_max) = (self.config.obstacle_min_height_m, self.config.obstacle_max_height_m);
        let max_range = f64::from(self.config.max_range_m);
        let up = self.up_vector();
        let units = f64::from(scan.depth_units_per_m.max(1e-6));
        let k = &scan.intrinsics;
        let stride = scan.stride.max(1) as f64;

        // 1-2: ray ends and hits.
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
        // 3-4: free cells along each ray, once per keyframe, hits excluded.
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
        // 5: the robot's footprint is free.
        let radius_cells = (self.robot_radius_m / geometry.cell_size_m).ceil() as i32;
        let radius2 = self.robot_radius_m * self.robot_radius_m;
        for dr in -radius_cells..=radius_cells {
            for dc in -radius_cells..=radius_cells {
                let (col, row) = (camera_col + dc, camera_row + dr);
                let centre = geometry.centre_of(col, row);
                let (dx, dy) = (centre[0] - camera.xy[0], centre[1] - camera.xy[1]);
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    fn intrinsics() -> Intrinsics {
        Intrinsics { width: 64, height: 48, fx: 40.0, fy: 40.0, cx: 32.0, cy: 24.0 }
    }

    /// A camera 1 m above the floor at the origin looking along +x (z up): camera z = world x,
    /// camera x = world -y, camera y = world -z.
    fn looking_along_x() -> Isometry {
        let rotation = DQuat::from_mat3(&glam::DMat3::from_cols(DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X));
        Isometry::new(rotation, DVec3::new(0.0, 0.0, 1.0))
    }

    #[test]
    fn bresenham_visits_every_cell_once_end_included() {
        let mut cells = Vec::new();
        bresenham(0, 0, 4, 2, |c, r| cells.push((c, r)));
        assert_eq!(cells.first(), Some(&(0, 0)));
        assert_eq!(cells.last(), Some(&(4, 2)));
        assert_eq!(cells.len(), 5);
        let mut back = Vec::new();
        bresenham(3, 3, 3, -1, |c, r| back.push((c, r)));
        assert_eq!(back, [(3, 3), (3, 2), (3, 1), (3, 0), (3, -1)]);
    }

    #[test]
    fn a_wall_ahead_is_occupied_and_the_floor_before_it_free() {
        // Depth of a wall 2 m ahead (x = 2) for pixels looking above the floor, the floor for
        // those that meet it first.
        let k = intrinsics();
        let pose = looking_along_x();
        let mut depth = vec![0u16; (k.width * k.height) as usize];
        for v in 0..k.height {
            let b = (v as f64 - f64::from(k.cy)) / f64::from(k.fy);
            for u in 0..k.width {
                // Ray direction in world: (1, -a, -b); floor at z = 0 is met at t = 1 / b.
                let t_wall = 2.02;
                let t = if b > 0.0 { (1.0 / b).min(t_wall) } else { t_wall };
                depth[(v * k.width + u) as usize] = (t * 1000.0) as u16;
            }
        }
        let config = OccupancyConfig { size_m: 6.0, centre_m: Some([0.0, 0.0]), pixel_stride: 2, ..Default::default() };
        let mut grid = OccupancyGrid::new(&config, UpAxis::Z, 0.2, &k);
        let mut scan = DepthScan::with_capacity(&k, config.pixel_stride);
        scan.fill(&depth, &k, 1000.0, &pose, 1);
        let memory = grid.allocated_bytes();
        grid.integrate(&scan);
        grid.integrate(&scan);
        assert_eq!(grid.allocated_bytes(), memory, "integration grows no buffer");
        assert_eq!(grid.memory_bytes(), memory);
        let g = grid.geometry();
        let at = |x: f32, y: f32| {
            let (c, r) = g.cell_of([x, y]);
            grid.cell_percent(g.index(c, r).unwrap())
        };
        assert!(at(2.02, 0.0) >= 65, "wall cell {}", at(2.02, 0.0));
        assert!((0..=35).contains(&at(1.0, 0.0)), "floor before the wall {}", at(1.0, 0.0));
        assert!((0..=35).contains(&at(0.0, 0.0)), "under the robot {}", at(0.0, 0.0));
        assert_eq!(at(-2.0, 0.0), OCCUPANCY_UNKNOWN, "behind the camera");
        assert_eq!(at(2.6, 0.0), OCCUPANCY_UNKNOWN, "behind the wall");
        let robot = grid.robot().unwrap();
        assert!(robot.yaw_rad.abs() < 1e-5 && robot.xy == [0.0, 0.0], "{robot:?}");
    }

    #[test]
    fn validation_names_the_field() {
        let bad = OccupancyConfig { cell_size_m: 0.0, ..Default::default() };
        assert!(bad.validate("occupancy").unwrap_err().starts_with("occupancy.cell_size_m"));
        let bad = OccupancyConfig { size_m: 500.0, ..Default::default() };
        assert!(bad.validate("occupancy").unwrap_err().starts_with("occupancy.size_m"));
        let bad = OccupancyConfig { obstacle_min_height_m: 2.0, ..Default::default() };
        assert!(bad.validate("occupancy").unwrap_err().contains("obstacle_min_height_m"));
        assert!(OccupancyConfig::default().validate("occupancy").is_ok());
    }
}
