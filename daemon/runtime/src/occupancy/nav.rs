//! Navigation targets on the occupancy map: where to stand to reach a node, and whether the
//! robot can get there.
//!
//! ## The approach pose of a node ([`Planner::approach`])
//!
//! - The node's **footprint** is its box projected on the floor plane. Candidate cells are the
//!   robot-free cells (below) whose centre is `[navigation.standoff_min_m,
//!   navigation.standoff_max_m]` from the footprint (0.4–0.8 m by default), so a long counter
//!   or a bed is approached along its side, not from its centre.
//! - A **part** is approached from the side it is on: the direction from its parent object's
//!   centre to the part's centre on the plane (a handle on a cabinet's front points out of the
//!   front). Only cells within `navigation.part_side_half_angle_deg` (60°) of that direction,
//!   seen from the part's centre, qualify. A part less than 2 cm from its parent's centre on the
//!   plane (a knob on top), or without a parent, has no side.
//! - **Robot-free** cells: free on the map (≤ 35 %) with no occupied cell (≥ 65 %) within
//!   `navigation.robot_radius_m` (the map inflated by the robot's radius). Unknown cells are
//!   never free.
//! - **Reachable**: connected to the robot's cell through robot-free cells, 8-connected,
//!   diagonal steps only between two robot-free side neighbours (no corner cutting). The
//!   connected set is flooded once per map and robot cell ([`Planner::prepare`]), so a query's
//!   16 hits cost one flood; the chosen cell's path is then found by **A\*** (octile distance
//!   heuristic, costs 1 and √2 cells), whose length the reply carries.
//! - Among reachable candidates the one nearest the preferred standoff `navigation.standoff_m`
//!   wins, ties broken by the straight distance to the robot. The pose faces the node's centre.
//! - None: [`ApproachStatus::NoFreeCell`] (no robot-free cell in the band, reachable or not) or
//!   [`ApproachStatus::Unreachable`] (some, none connected to the robot). Never a guess.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use op3dsg_ipc_types::{ApproachStatus, NodeKind, OCCUPANCY_FREE_MAX_PERCENT, OCCUPANCY_OCCUPIED_MIN_PERCENT};
use serde::{Deserialize, Serialize};

use super::{GridGeometry, RobotPose, to_plane};
use crate::graph::{GraphNode, SceneGraph};
use crate::world::UpAxis;

/// `[navigation]`: approach poses on the occupancy map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NavigationConfig {
    /// Preferred distance from the node's footprint to the approach position, metres.
    pub standoff_m: f32,
    /// Nearest accepted distance, metres.
    pub standoff_min_m: f32,
    /// Farthest accepted distance, metres.
    pub standoff_max_m: f32,
    /// Radius of the robot's footprint: the map is inflated by it, metres (Stretch 3: 0.17 m
    /// half-width; 0.2 with margin).
    pub robot_radius_m: f32,
    /// A part is approached from within this angle of the direction it faces, degrees.
    pub part_side_half_angle_deg: f32,
}

impl Default for NavigationConfig {
    fn default() -> Self {
        Self {
            standoff_m: 0.6,
            standoff_min_m: 0.4,
            standoff_max_m: 0.8,
            robot_radius_m: 0.2,
            part_side_half_angle_deg: 60.0,
        }
    }
}

impl NavigationConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let (min, preferred, max) = (self.standoff_min_m, self.standoff_m, self.standoff_max_m);
        for (value, field) in [(min, "standoff_min_m"), (preferred, "standoff_m"), (max, "standoff_max_m")] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("{path}.{field}: must be a distance >= 0 m, got {value}"));
            }
        }
        if min > preferred {
            return Err(format!("{path}.standoff_min_m: must be at most standoff_m ({preferred} m), got {min}"));
        }
        if preferred > max {
            return Err(format!("{path}.standoff_max_m: must be at least standoff_m ({preferred} m), got {max}"));
        }
        if max > 5.0 {
            return Err(format!("{path}.standoff_max_m: must be at most 5 m, got {max}"));
        }
        if !(self.robot_radius_m.is_finite() && (0.0..=2.0).contains(&self.robot_radius_m)) {
            return Err(format!("{path}.robot_radius_m: must be within [0, 2] m, got {}", self.robot_radius_m));
        }
        if !(self.part_side_half_angle_deg.is_finite() && (1.0..=180.0).contains(&self.part_side_half_angle_deg)) {
            return Err(format!(
                "{path}.part_side_half_angle_deg: must be within [1, 180], got {}",
                self.part_side_half_angle_deg
            ));
        }
        Ok(())
    }
}

/// What to approach, on the floor plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// The node's centre, metres.
    pub centre_m: [f32; 2],
    /// Low corner of its footprint, metres.
    pub footprint_min_m: [f32; 2],
    /// High corner of its footprint, metres.
    pub footprint_max_m: [f32; 2],
    /// Unit direction the approach must come from (parts), `None`: any side.
    pub side: Option<[f32; 2]>,
}

/// Parts nearer their parent's centre than this on the plane have no side, metres.
const MIN_SIDE_OFFSET_M: f32 = 0.02;

impl Target {
    /// The target of `node` of `graph` (a part's side from its parent's centre).
    pub fn of_node(graph: &SceneGraph, node: &GraphNode, up_axis: UpAxis) -> Self {
        let plane = |p: [f32; 3]| to_plane(up_axis, glam::Vec3::from_array(p)).xy;
        let (a, b) = (plane(node.box_min_m), plane(node.box_max_m));
        let centre = plane(node.centre_m);
        let side = (node.kind == NodeKind::Part)
            .then(|| node.parent_id.and_then(|id| graph.nodes.iter().find(|n| n.id == id)))
            .flatten()
            .and_then(|parent| {
                let p = plane(parent.centre_m);
                let (dx, dy) = (centre[0] - p[0], centre[1] - p[1]);
                let len = (dx * dx + dy * dy).sqrt();
                (len >= MIN_SIDE_OFFSET_M).then(|| [dx / len, dy / len])
            });
        Self {
            centre_m: centre,
            footprint_min_m: [a[0].min(b[0]), a[1].min(b[1])],
            footprint_max_m: [a[0].max(b[0]), a[1].max(b[1])],
            side,
        }
    }

    /// Distance from `p` to the footprint (0 inside), metres.
    pub fn distance_to_footprint(&self, p: [f32; 2]) -> f32 {
        let dx = (self.footprint_min_m[0] - p[0]).max(p[0] - self.footprint_max_m[0]).max(0.0);
        let dy = (self.footprint_min_m[1] - p[1]).max(p[1] - self.footprint_max_m[1]).max(0.0);
        (dx * dx + dy * dy).sqrt()
    }
}

/// An approach pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Approach {
    /// Where to stand (a cell centre), metres.
    pub xy_m: [f32; 2],
    /// Heading facing the node's centre, radians.
    pub yaw_rad: f32,
    /// Distance to the node's footprint, metres.
    pub standoff_m: f32,
    /// A* path length from the robot's cell, metres.
    pub path_m: f32,
}

/// A map as the planner reads it: geometry and published cells (-1 unknown, else percent).
#[derive(Debug, Clone, Copy)]
pub struct MapView<'a> {
    /// Geometry.
    pub geometry: GridGeometry,
    /// Cells, row-major.
    pub cells: &'a [i8],
}

/// The planner: robot-free cells, the robot's connected set, A* scratch; buffers sized once per
/// map size.
#[derive(Debug, Clone)]
pub struct Planner {
    config: NavigationConfig,
    geometry: Option<GridGeometry>,
    robot_free: Vec<bool>,
    reachable: Vec<bool>,
    stack: Vec<u32>,
    g_cost: Vec<f32>,
    visited: Vec<u32>,
    visit_stamp: u32,
    open: BinaryHeap<Reverse<(u32, u32)>>,
    robot_cell: Option<(i32, i32)>,
    robot_status: ApproachStatus,
    robot: RobotPose,
}

const SQRT2: f32 = std::f32::consts::SQRT_2;

impl Planner {
    /// A planner with `config` (validated); buffers come with the first map.
    pub fn new(config: &NavigationConfig) -> Self {
        Self {
            config: config.clone(),
            geometry: None,
            robot_free: Vec::new(),
            reachable: Vec::new(),
            stack: Vec::new(),
            g_cost: Vec::new(),
            visited: Vec::new(),
            visit_stamp: 0,
            open: BinaryHeap::new(),
            robot_cell: None,
            robot_status: ApproachStatus::NoMap,
            robot: RobotPose::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &NavigationConfig {
        &self.config
    }

    /// Heap bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.robot_free.capacity()
            + self.reachable.capacity()
            + self.stack.capacity() * 4
            + self.g_cost.capacity() * 4
            + self.visited.capacity() * 4
            + self.open.capacity() * 8
    }

    /// Inflates `map` by the robot's radius and floods the robot-free cells connected to
    /// `robot`'s cell. Afterwards [`Self::robot_status`] says whether the robot is on the map.
    pub fn prepare(&mut self, map: &MapView<'_>, robot: RobotPose) {
        let geometry = map.geometry;
        let n = geometry.cell_count();
        if self.geometry.map(|g| g.cell_count()) != Some(n) {
            self.robot_free = vec![false; n];
            self.reachable = vec![false; n];
            self.g_cost = vec![f32::INFINITY; n];
            self.visited = vec![0; n];
            self.stack = Vec::with_capacity(n);
            self.open = BinaryHeap::with_capacity(n);
        }
        self.geometry = Some(geometry);
        self.robot = robot;
        let (w, h) = (geometry.width as i32, geometry.height as i32);
        for (free, &cell) in self.robot_free.iter_mut().zip(map.cells) {
            *free = (0..=OCCUPANCY_FREE_MAX_PERCENT).contains(&cell);
        }
        // Inflation: every occupied cell blocks the disc of the robot's radius around it.
        let radius_cells = (self.config.robot_radius_m / geometry.cell_size_m).ceil() as i32;
        let radius2 = (self.config.robot_radius_m / geometry.cell_size_m).powi(2);
        for row in 0..h {
            for col in 0..w {
                let index = (row * w + col) as usize;
                if map.cells[index] < OCCUPANCY_OCCUPIED_MIN_PERCENT {
                    continue;
                }
                for dr in -radius_cells..=radius_cells {
                    for dc in -radius_cells..=radius_cells {
                        if (dr * dr + dc * dc) as f32 > radius2 {
                            continue;
                        }
                        if let Some(i) = geometry.index(col + dc, row + dr) {
                            self.robot_free[i] = false;
                        }
                    }
                }
            }
        }
        // The robot's cell, or the nearest robot-free cell within its radius.
        self.reachable.fill(false);
        let (rc, rr) = geometry.cell_of(robot.xy);
        self.robot_cell = None;
        let mut best: Option<(i32, (i32, i32))> = None;
        for dr in -radius_cells..=radius_cells {
            for dc in -radius_cells..=radius_cells {
                let d2 = dr * dr + dc * dc;
                if d2 as f32 > radius2.max(1.0) {
                    continue;
                }
                if let Some(i) = geometry.index(rc + dc, rr + dr)
                    && self.robot_free[i]
                    && best.is_none_or(|(b, _)| d2 < b)
                {
                    best = Some((d2, (rc + dc, rr + dr)));
                }
            }
        }
        let Some((_, start)) = best else {
            self.robot_status = ApproachStatus::RobotNotOnMap;
            return;
        };
        self.robot_cell = Some(start);
        self.robot_status = ApproachStatus::Ok;
        // Flood the connected robot-free cells (same moves as A*).
        self.stack.clear();
        if let Some(i) = geometry.index(start.0, start.1) {
            self.reachable[i] = true;
            self.stack.push(i as u32);
        }
        while let Some(i) = self.stack.pop() {
            let (col, row) = ((i as i32) % w, (i as i32) / w);
            for (dc, dr) in NEIGHBOURS {
                if let Some(j) = self.step(col, row, dc, dr)
                    && !self.reachable[j]
                {
                    self.reachable[j] = true;
                    self.stack.push(j as u32);
                }
            }
        }
    }

    /// Whether the robot is on the prepared map (`Ok`), or why not.
    pub fn robot_status(&self) -> ApproachStatus {
        self.robot_status
    }

    /// The neighbour `(col + dc, row + dr)` if the move is allowed (robot-free, no corner cut).
    #[inline]
    fn step(&self, col: i32, row: i32, dc: i32, dr: i32) -> Option<usize> {
        let geometry = self.geometry?;
        let j = geometry.index(col + dc, row + dr)?;
        if !self.robot_free[j] {
            return None;
        }
        if dc != 0 && dr != 0 {
            let a = geometry.index(col + dc, row)?;
            let b = geometry.index(col, row + dr)?;
            if !(self.robot_free[a] && self.robot_free[b]) {
                return None;
            }
        }
        Some(j)
    }

    /// Whether cell `(col, row)` is robot-free on the prepared map.
    pub fn is_robot_free(&self, col: i32, row: i32) -> bool {
        self.geometry.and_then(|g| g.index(col, row)).is_some_and(|i| self.robot_free[i])
    }

    /// The approach pose of `target` on the prepared map (see the module docs).
    pub fn approach(&mut self, target: &Target) -> Result<Approach, ApproachStatus> {
        let Some(geometry) = self.geometry else { return Err(ApproachStatus::NoMap) };
        if self.robot_status != ApproachStatus::Ok {
            return Err(self.robot_status);
        }
        let Some(start) = self.robot_cell else { return Err(ApproachStatus::RobotNotOnMap) };
        let (min, max, preferred) = (self.config.standoff_min_m, self.config.standoff_max_m, self.config.standoff_m);
        let cos_side = self.config.part_side_half_angle_deg.to_radians().cos();
        let (c0, r0) = geometry.cell_of([target.footprint_min_m[0] - max, target.footprint_min_m[1] - max]);
        let (c1, r1) = geometry.cell_of([target.footprint_max_m[0] + max, target.footprint_max_m[1] + max]);
        let (w, h) = (geometry.width as i32, geometry.height as i32);
        let mut any_free = false;
        let mut best: Option<(f32, f32, i32, i32, f32)> = None;
        for row in r0.max(0)..=r1.min(h - 1) {
            for col in c0.max(0)..=c1.min(w - 1) {
                let index = (row * w + col) as usize;
                if !self.robot_free[index] {
                    continue;
                }
                let p = geometry.centre_of(col, row);
                let standoff = target.distance_to_footprint(p);
                if standoff < min || standoff > max {
                    continue;
                }
                if let Some(side) = target.side {
                    let (dx, dy) = (p[0] - target.centre_m[0], p[1] - target.centre_m[1]);
                    let len = (dx * dx + dy * dy).sqrt().max(1e-6);
                    if (dx * side[0] + dy * side[1]) / len < cos_side {
                        continue;
                    }
                }
                any_free = true;
                if !self.reachable[index] {
                    continue;
                }
                let key = (standoff - preferred).abs();
                let to_robot = (p[0] - self.robot.xy[0]).hypot(p[1] - self.robot.xy[1]);
                if best.is_none_or(|(k, d, ..)| key < k - 1e-6 || (key <= k + 1e-6 && to_robot < d)) {
                    best = Some((key, to_robot, col, row, standoff));
                }
            }
        }
        let Some((_, _, col, row, standoff_m)) = best else {
            return Err(if any_free { ApproachStatus::Unreachable } else { ApproachStatus::NoFreeCell });
        };
        let path_cells = self.astar(start, (col, row)).ok_or(ApproachStatus::Unreachable)?;
        let xy_m = geometry.centre_of(col, row);
        let yaw_rad = (target.centre_m[1] - xy_m[1]).atan2(target.centre_m[0] - xy_m[0]);
        Ok(Approach { xy_m, yaw_rad, standoff_m, path_m: path_cells * geometry.cell_size_m })
    }

    /// A* over robot-free cells from `start` to `goal`: the path length in cells, `None` when
    /// there is none.
    pub fn astar(&mut self, start: (i32, i32), goal: (i32, i32)) -> Option<f32> {
        let geometry = self.geometry?;
        let w = geometry.width as i32;
        let start_i = geometry.index(start.0, start.1)?;
        let goal_i = geometry.index(goal.0, goal.1)?;
        if !(self.robot_free[start_i] && self.robot_free[goal_i]) {
            return None;
        }
        self.visit_stamp = self.visit_stamp.wrapping_add(1);
        if self.visit_stamp == 0 {
            self.visited.fill(0);
            self.visit_stamp = 1;
        }
        let stamp = self.visit_stamp;
        let heuristic = |c: i32, r: i32| {
            let (dx, dy) = ((c - goal.0).abs() as f32, (r - goal.1).abs() as f32);
            dx.max(dy) + (SQRT2 - 1.0) * dx.min(dy)
        };
        // Costs as fixed-point keys (1/1024 cell) so the heap orders integers.
        let key = |f: f32| (f * 1024.0) as u32;
        self.open.clear();
        self.g_cost[start_i] = 0.0;
        self.visited[start_i] = stamp;
        self.open.push(Reverse((key(heuristic(start.0, start.1)), start_i as u32)));
        while let Some(Reverse((_, i))) = self.open.pop() {
            let i = i as usize;
            if i == goal_i {
                return Some(self.g_cost[i]);
            }
            let (col, row) = ((i as i32) % w, (i as i32) / w);
            let g = self.g_cost[i];
            for (dc, dr) in NEIGHBOURS {
                let Some(j) = self.step(col, row, dc, dr) else { continue };
                let cost = g + if dc != 0 && dr != 0 { SQRT2 } else { 1.0 };
                if self.visited[j] != stamp || cost < self.g_cost[j] - 1e-6 {
                    self.visited[j] = stamp;
                    self.g_cost[j] = cost;
                    self.open.push(Reverse((key(cost + heuristic(col + dc, row + dr)), j as u32)));
                }
            }
        }
        None
    }
}

const NEIGHBOURS: [(i32, i32); 8] = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)];

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4 m × 4 m free room (5 cm cells) with a wall of `wall` cells at x = 2 m, robot at (0.5, 2).
    fn room(wall_gap: bool) -> (GridGeometry, Vec<i8>) {
        let geometry = GridGeometry { width: 80, height: 80, cell_size_m: 0.05, origin_m: [0.0, 0.0] };
        let mut cells = vec![0i8; geometry.cell_count()];
        for row in 0..80 {
            for col in 0..80 {
                let border = row == 0 || col == 0 || row == 79 || col == 79;
                let wall = col == 40 && !(wall_gap && (10..20).contains(&row));
                if border || wall {
                    cells[row * 80 + col] = 100;
                }
            }
        }
        (geometry, cells)
    }

    fn box_target(x: f32, y: f32, side: Option<[f32; 2]>) -> Target {
        Target { centre_m: [x, y], footprint_min_m: [x - 0.1, y - 0.1], footprint_max_m: [x + 0.1, y + 0.1], side }
    }

    #[test]
    fn approach_is_free_in_band_facing_and_reachable() {
        let (geometry, cells) = room(true);
        let mut planner = Planner::new(&NavigationConfig::default());
        planner.prepare(&MapView { geometry, cells: &cells }, RobotPose { xy: [0.5, 2.0], yaw_rad: 0.0 });
        assert_eq!(planner.robot_status(), ApproachStatus::Ok);
        // A box beyond the wall: reachable through the gap (rows 10..20 = y 0.5..1.0 m).
        let target = box_target(3.0, 3.0, None);
        let approach = planner.approach(&target).unwrap();
        let standoff = target.distance_to_footprint(approach.xy_m);
        assert!((0.4..=0.8).contains(&standoff), "{approach:?}");
        assert!((standoff - 0.6).abs() < 0.05, "{approach:?}");
        let (c, r) = geometry.cell_of(approach.xy_m);
        assert!(planner.is_robot_free(c, r));
        let facing = (3.0 - approach.xy_m[1]).atan2(3.0 - approach.xy_m[0]);
        assert!((facing - approach.yaw_rad).abs() < 1e-5);
        // Through the gap: much longer than the straight line.
        let straight = (approach.xy_m[0] - 0.5).hypot(approach.xy_m[1] - 2.0);
        assert!(approach.path_m > straight + 0.5, "{approach:?} straight {straight}");
    }

    #[test]
    fn a_closed_wall_makes_it_unreachable_and_a_part_keeps_its_side() {
        let (geometry, cells) = room(false);
        let mut planner = Planner::new(&NavigationConfig::default());
        planner.prepare(&MapView { geometry, cells: &cells }, RobotPose { xy: [0.5, 2.0], yaw_rad: 0.0 });
        assert_eq!(planner.approach(&box_target(3.0, 3.0, None)), Err(ApproachStatus::Unreachable));
        // A part facing -x is approached from -x.
        let near = planner.approach(&box_target(1.0, 2.0, Some([-1.0, 0.0]))).unwrap();
        assert!(near.xy_m[0] < 1.0, "approached from -x: {near:?}");
        // A part facing +x just before the wall: its side's band cells lie beyond the wall.
        assert_eq!(planner.approach(&box_target(1.85, 2.0, Some([1.0, 0.0]))), Err(ApproachStatus::Unreachable));
        // A part facing -x at the room's border: its side's band is off the map.
        assert_eq!(planner.approach(&box_target(0.2, 2.0, Some([-1.0, 0.0]))), Err(ApproachStatus::NoFreeCell));
        // The robot inside the wall.
        planner.prepare(&MapView { geometry, cells: &cells }, RobotPose { xy: [2.02, 2.0], yaw_rad: 0.0 });
        assert_eq!(planner.robot_status(), ApproachStatus::RobotNotOnMap);
        assert_eq!(planner.approach(&box_target(1.0, 2.0, None)), Err(ApproachStatus::RobotNotOnMap));
    }

    #[test]
    fn astar_length_is_octile_on_open_ground() {
        let geometry = GridGeometry { width: 20, height: 20, cell_size_m: 0.1, origin_m: [0.0, 0.0] };
        let cells = vec![0i8; geometry.cell_count()];
        let mut planner = Planner::new(&NavigationConfig { robot_radius_m: 0.0, ..Default::default() });
        planner.prepare(&MapView { geometry, cells: &cells }, RobotPose { xy: [0.05, 0.05], yaw_rad: 0.0 });
        let length = planner.astar((0, 0), (10, 4)).unwrap();
        assert!((length - (6.0 + 4.0 * SQRT2)).abs() < 1e-4, "{length}");
    }

    #[test]
    fn validation_names_the_field() {
        let bad = NavigationConfig { standoff_min_m: 0.9, ..Default::default() };
        assert!(bad.validate("navigation").unwrap_err().starts_with("navigation.standoff_min_m"));
        let bad = NavigationConfig { standoff_max_m: 0.5, ..Default::default() };
        assert!(bad.validate("navigation").unwrap_err().starts_with("navigation.standoff_max_m"));
        let bad = NavigationConfig { robot_radius_m: -1.0, ..Default::default() };
        assert!(bad.validate("navigation").unwrap_err().starts_with("navigation.robot_radius_m"));
        assert!(NavigationConfig::default().validate("navigation").is_ok());
    }
}
