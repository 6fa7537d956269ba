//! The navigation check (`op3dsg bench nav`): approach poses the daemon's planner gives for every
//! object and part node of a mapped synthetic room, judged against the room's **ground-truth
//! geometry** (its walls and the boxes and cylinders it renders), never against the occupancy
//! map the planner used.
//!
//! Each room runs through the batch pipeline as `bench quality`'s full row does, with the
//! occupancy map integrated from every keyframe exactly as the daemon's occupancy thread does
//! ([`op3dsg_runtime::occupancy::OccupancyGrid`]). The robot's pose is the last keyframe's
//! camera. For every node of the final graph the planner
//! ([`op3dsg_runtime::occupancy::Planner`], the one the query service runs) gives an approach
//! pose or says why not; `fusion_match` pairs the node with its ground-truth instance.
//!
//! ## What "correct" means (each a column of the report)
//!
//! - **free**: the robot's disc (`navigation.robot_radius_m`) at the approach position lies
//!   inside the room and clear of every ground-truth primitive that reaches into the obstacle
//!   band (`occupancy.obstacle_min_height_m`..`obstacle_max_height_m` above the floor), with one
//!   map cell of tolerance ([`NavCriteria::free_tolerance_m`]: a 5 cm grid cannot place the disc
//!   closer than that).
//! - **in band**: the distance from the approach position to the ground-truth instance's
//!   footprint (its true box on the floor) is within `[standoff_min_m, standoff_max_m]` ±
//!   [`NavCriteria::standoff_tolerance_m`] (0.1 m: the reconstructed box the planner used differs
//!   from the true one by the reconstruction error).
//! - **facing**: the heading points at the true footprint (the heading ray meets it) or within
//!   [`NavCriteria::facing_tolerance_deg`] (20°) of the true centre.
//! - **on side** (parts): the approach position is on the side the true part faces, i.e. the
//!   dot product of (position − true part centre) and (true part centre − true parent centre) on
//!   the floor is positive (parts less than 2 cm from their parent's centre on the floor: any side).
//!
//! A node is **correct** when all of them hold. Shares are reported over matched nodes (nodes
//! `fusion_match` paired with a ground-truth instance), objects and parts apart; nodes without
//! a match are counted, and their approach poses checked for free space only.

use std::time::Instant;

use op3dsg_ipc_types::{ApproachStatus, NodeKind};
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::graph::GraphNode;
use op3dsg_runtime::occupancy::nav::MapView;
use op3dsg_runtime::occupancy::{Approach, NavigationConfig, Planner, Target};
use op3dsg_runtime::reasoner::ReasonerKind;
use op3dsg_synthetic::{InstanceInfo, RoomKind, Scene, Shape};
use serde::Serialize;

use super::fusion_match::{self, MatchCriteria};
use crate::batch::{self, VisibilityThresholds};

/// Tolerances of the ground-truth checks (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavCriteria {
    /// The robot's disc may come this much nearer an obstacle than its radius, metres.
    pub free_tolerance_m: f32,
    /// The standoff band is widened by this on both sides, metres.
    pub standoff_tolerance_m: f32,
    /// Largest angle between the heading and the direction to the true centre, degrees.
    pub facing_tolerance_deg: f32,
}

impl NavCriteria {
    /// The documented tolerances for a map of `cell_size_m` cells.
    pub fn for_cell(cell_size_m: f32) -> Self {
        Self { free_tolerance_m: cell_size_m, standoff_tolerance_m: 0.1, facing_tolerance_deg: 20.0 }
    }
}

/// One node's outcome.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NodeNav {
    /// Graph node id.
    pub node_id: u32,
    /// `object` or `part`.
    pub kind: &'static str,
    /// Its label.
    pub label: String,
    /// The ground-truth instance it matched (`None`: unmatched).
    pub truth_id: Option<u32>,
    /// The planner's answer (`ok`, `no_free_cell`, `unreachable`, `robot_not_on_map`).
    pub status: &'static str,
    /// Approach position, metres (with `ok`).
    pub xy_m: Option<[f32; 2]>,
    /// Heading, radians (with `ok`).
    pub yaw_rad: Option<f32>,
    /// A* path length, metres (with `ok`).
    pub path_m: Option<f32>,
    /// Clearance of the approach position in the true geometry, metres (with `ok`).
    pub clearance_m: Option<f32>,
    /// Distance to the true footprint, metres (with `ok`, matched).
    pub true_standoff_m: Option<f32>,
    /// Angle between the heading and the direction to the true centre, degrees (with `ok`, matched).
    pub facing_error_deg: Option<f32>,
    /// The checks (with `ok`; the last three for matched nodes only).
    pub free: Option<bool>,
    /// In the band.
    pub in_band: Option<bool>,
    /// Facing.
    pub facing: Option<bool>,
    /// On the part's side (parts).
    pub on_side: Option<bool>,
    /// All checks hold.
    pub correct: bool,
}

/// Counts of one kind in one room or over all.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct KindNav {
    /// Nodes of the graph.
    pub nodes: u32,
    /// Of those, matched to a ground-truth instance.
    pub matched: u32,
    /// Matched nodes with an approach pose.
    pub reachable: u32,
    /// Matched nodes whose approach pose passes every check.
    pub correct: u32,
    /// Matched: no free cell within the band.
    pub no_free_cell: u32,
    /// Matched: free cells in the band, none reachable.
    pub unreachable: u32,
    /// Matched: the robot's pose was not on a free cell.
    pub robot_not_on_map: u32,
    /// Matched, with a pose: not free in the true geometry.
    pub not_free: u32,
    /// Matched, with a pose: outside the band.
    pub out_of_band: u32,
    /// Matched, with a pose: not facing.
    pub not_facing: u32,
    /// Matched parts, with a pose: on the wrong side.
    pub wrong_side: u32,
    /// Unmatched nodes with a pose.
    pub unmatched_reachable: u32,
    /// Of those, free in the true geometry.
    pub unmatched_free: u32,
}

impl KindNav {
    fn add(&mut self, other: &KindNav) {
        self.nodes += other.nodes;
        self.matched += other.matched;
        self.reachable += other.reachable;
        self.correct += other.correct;
        self.no_free_cell += other.no_free_cell;
        self.unreachable += other.unreachable;
        self.robot_not_on_map += other.robot_not_on_map;
        self.not_free += other.not_free;
        self.out_of_band += other.out_of_band;
        self.not_facing += other.not_facing;
        self.wrong_side += other.wrong_side;
        self.unmatched_reachable += other.unmatched_reachable;
        self.unmatched_free += other.unmatched_free;
    }

    /// Share of matched nodes with an approach pose, percent.
    pub fn reachable_percent(&self) -> f64 {
        percent(self.reachable, self.matched)
    }

    /// Share of matched nodes whose pose is correct, percent.
    pub fn correct_percent(&self) -> f64 {
        percent(self.correct, self.matched)
    }

    /// Share of reachable matched nodes whose pose is correct, percent.
    pub fn correct_of_reachable_percent(&self) -> f64 {
        percent(self.correct, self.reachable)
    }
}

fn percent(value: u32, of: u32) -> f64 {
    if of == 0 { 0.0 } else { 100.0 * f64::from(value) / f64::from(of) }
}

/// One room.
#[derive(Debug, Clone, Serialize)]
pub struct RoomNav {
    /// Room.
    pub room: &'static str,
    /// Seed.
    pub seed: u64,
    /// Keyframes integrated into the map.
    pub keyframes: u64,
    /// The robot's pose the planner started from (last keyframe), metres / radians.
    pub robot_xy_m: [f32; 2],
    /// Objects.
    pub objects: KindNav,
    /// Parts.
    pub parts: KindNav,
    /// Every node.
    pub nodes: Vec<NodeNav>,
    /// Occupancy integration per keyframe (subsampling included), microseconds.
    pub integrate_us: Vec<u32>,
    /// Heap bytes of the occupancy grid.
    pub map_memory_bytes: usize,
    /// Heap bytes of the planner's buffers.
    pub planner_memory_bytes: usize,
    /// The planner's cost: inflation and flood of the map once, microseconds.
    pub prepare_us: u64,
    /// The planner's cost per node (approach + A*), p50 microseconds.
    pub approach_p50_us: f64,
}

/// The whole report.
#[derive(Debug, Clone, Serialize)]
pub struct NavReport {
    /// Tolerances.
    pub criteria: NavCriteria,
    /// `[navigation]` used.
    pub standoff_band_m: [f32; 2],
    /// `navigation.robot_radius_m`.
    pub robot_radius_m: f32,
    /// Per room.
    pub rooms: Vec<RoomNav>,
    /// Objects over all rooms.
    pub objects: KindNav,
    /// Parts over all rooms.
    pub parts: KindNav,
    /// Occupancy integration per keyframe over all rooms, p50 microseconds.
    pub integrate_p50_us: f64,
    /// The same, p99.
    pub integrate_p99_us: f64,
    /// Occupancy grid memory (each room's grid is the same size), bytes.
    pub map_memory_bytes: usize,
    /// Occupancy grid cells.
    pub map_cells: usize,
}

/// Primitives that reach into the obstacle band (z up: the synthetic world).
fn obstacles(scene: &Scene, band: [f32; 2]) -> Vec<Shape> {
    scene
        .primitives()
        .iter()
        .map(|p| p.shape)
        .filter(|shape| {
            let (min, max) = shape.aabb();
            min.z < band[1] && max.z > band[0]
        })
        .collect()
}

/// Distance on the floor from `p` to `shape`'s footprint (vertical cylinders: a disc; everything
/// else: its box), metres; 0 inside.
fn footprint_distance(shape: &Shape, p: [f32; 2]) -> f32 {
    match *shape {
        Shape::Cylinder { axis: op3dsg_synthetic::Axis::Z, centre, radius, .. } => {
            ((p[0] - centre.x).hypot(p[1] - centre.y) - radius).max(0.0)
        }
        _ => {
            let (min, max) = shape.aabb();
            rect_distance([min.x, min.y], [max.x, max.y], p)
        }
    }
}

fn rect_distance(min: [f32; 2], max: [f32; 2], p: [f32; 2]) -> f32 {
    let dx = (min[0] - p[0]).max(p[0] - max[0]).max(0.0);
    let dy = (min[1] - p[1]).max(p[1] - max[1]).max(0.0);
    dx.hypot(dy)
}

/// Whether the ray from `p` along `yaw` meets the rectangle.
fn ray_hits_rect(p: [f32; 2], yaw: f32, min: [f32; 2], max: [f32; 2]) -> bool {
    let d = [yaw.cos(), yaw.sin()];
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for k in 0..2 {
        if d[k].abs() < 1e-9 {
            if p[k] < min[k] || p[k] > max[k] {
                return false;
            }
        } else {
            let (a, b) = ((min[k] - p[k]) / d[k], (max[k] - p[k]) / d[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
    }
    t0 <= t1
}

/// Clearance of `p` in the true geometry: distance to the walls and the nearest obstacle.
fn clearance(scene: &Scene, obstacles: &[Shape], p: [f32; 2]) -> f32 {
    let (_, size) = scene.bounds();
    let walls = p[0].min(size.x - p[0]).min(p[1]).min(size.y - p[1]);
    obstacles.iter().map(|s| footprint_distance(s, p)).fold(walls, f32::min)
}

fn angle_deg(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(std::f32::consts::TAU);
    d.min(std::f32::consts::TAU - d).to_degrees()
}

/// The band, facing and side checks of a pose at `p` with heading `yaw_rad` for the true
/// instance `info` (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Judged {
    /// Distance to the true footprint, metres.
    pub true_standoff_m: f32,
    /// Within the band (with tolerance).
    pub in_band: bool,
    /// Angle to the true centre, degrees.
    pub facing_error_deg: f32,
    /// Facing.
    pub facing: bool,
    /// On the part's side (`None` for objects and parts without a parent).
    pub on_side: Option<bool>,
}

/// Judges a pose against the true instance `info` of `scene`.
pub fn judge(
    scene: &Scene,
    info: &op3dsg_synthetic::InstanceInfo,
    p: [f32; 2],
    yaw_rad: f32,
    nav: &op3dsg_runtime::occupancy::NavigationConfig,
    checks: &NavCriteria,
) -> Judged {
    let (min, max) = ([info.box_min_m.x, info.box_min_m.y], [info.box_max_m.x, info.box_max_m.y]);
    let centre = [(min[0] + max[0]) * 0.5, (min[1] + max[1]) * 0.5];
    let standoff = rect_distance(min, max, p);
    let in_band = standoff >= nav.standoff_min_m - checks.standoff_tolerance_m
        && standoff <= nav.standoff_max_m + checks.standoff_tolerance_m;
    let error = angle_deg(yaw_rad, (centre[1] - p[1]).atan2(centre[0] - p[0]));
    let facing = error <= checks.facing_tolerance_deg || ray_hits_rect(p, yaw_rad, min, max);
    let on_side = info.parent.and_then(|id| scene.instance(id)).map(|parent| {
        let pc = (parent.box_min_m + parent.box_max_m) * 0.5;
        let dir = [centre[0] - pc.x, centre[1] - pc.y];
        if dir[0].hypot(dir[1]) < 0.02 {
            return true;
        }
        (p[0] - centre[0]) * dir[0] + (p[1] - centre[1]) * dir[1] > 0.0
    });
    Judged { true_standoff_m: standoff, in_band, facing_error_deg: error, facing, on_side }
}

/// Whether the robot's disc at `p` is free in `scene`'s true geometry (walls and every primitive
/// reaching into the obstacle band `band_m`, world heights), and its clearance.
pub fn free_in_truth(
    scene: &Scene,
    band_m: [f32; 2],
    robot_radius_m: f32,
    tolerance_m: f32,
    p: [f32; 2],
) -> (bool, f32) {
    let clear = clearance(scene, &obstacles(scene, band_m), p);
    (clear >= robot_radius_m - tolerance_m, clear)
}

/// Maps `room` (seed `seed`) with `base` and checks every node's approach pose.
pub fn room_nav(base: &Profile, room: RoomKind, seed: u64) -> Result<RoomNav, String> {
    let name = format!("{} seed {seed}", room.as_str());
    let (mut profile, _) = super::benchmark::scene_profile(base, room, seed)?;
    if !profile.occupancy.enabled {
        return Err(format!("{name}: the navigation check needs occupancy.enabled = true"));
    }
    // The reasoner adds relations and affordances, not geometry: the check does not need it.
    profile.reasoner.kind = ReasonerKind::None;
    let run = batch::run(&profile, &VisibilityThresholds::default()).map_err(|e| format!("{name}: {e}"))?;
    let scene = run.scene.clone().ok_or_else(|| format!("{name}: the source has no ground truth"))?;
    let grid = run.occupancy.as_ref().ok_or_else(|| format!("{name}: no occupancy map came back"))?;
    let robot = grid.robot().ok_or_else(|| format!("{name}: no keyframe was integrated"))?;
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let matched = fusion_match::match_run(&run, &criteria);
    let truth_of: std::collections::HashMap<u32, u32> =
        matched.fused.iter().filter_map(|f| f.matched.map(|gt| (f.id, gt))).collect();

    let geometry = grid.geometry();
    let mut cells = vec![0i8; geometry.cell_count()];
    grid.write_cells(&mut cells);
    let mut planner = Planner::new(&profile.navigation);
    let t = Instant::now();
    planner.prepare(&MapView { geometry, cells: &cells }, robot);
    let prepare_us = t.elapsed().as_micros() as u64;
    let truth = TruthChecks::new(&scene, &profile, NavCriteria::for_cell(geometry.cell_size_m));

    let (mut objects, mut parts) = (KindNav::default(), KindNav::default());
    let mut nodes = Vec::new();
    let mut approach_us = Vec::new();
    for node in &run.graph.nodes {
        let target = Target::of_node(&run.graph, node, profile.world.up_axis);
        let t = Instant::now();
        let result = planner.approach(&target);
        approach_us.push(t.elapsed().as_secs_f64() * 1e6);
        let counts = match node.kind {
            NodeKind::Object => &mut objects,
            NodeKind::Part => &mut parts,
        };
        nodes.push(truth.node(node, truth_of.get(&node.id).copied(), result, counts));
    }
    approach_us.sort_by(f64::total_cmp);
    Ok(RoomNav {
        room: room.as_str(),
        seed,
        keyframes: run.keyframes,
        robot_xy_m: robot.xy,
        objects,
        parts,
        nodes,
        integrate_us: run.occupancy_integrate_us.clone(),
        map_memory_bytes: grid.memory_bytes(),
        planner_memory_bytes: planner.memory_bytes(),
        prepare_us,
        approach_p50_us: approach_us.get(approach_us.len() / 2).copied().unwrap_or(0.0),
    })
}

/// What one room's approach poses are judged against: its true geometry, the profile's
/// `[navigation]` and the tolerances.
struct TruthChecks<'a> {
    scene: &'a Scene,
    /// The walls and things that reach into the obstacle band.
    obstacles: Vec<Shape>,
    nav: &'a NavigationConfig,
    criteria: NavCriteria,
}

impl<'a> TruthChecks<'a> {
    fn new(scene: &'a Scene, profile: &'a Profile, criteria: NavCriteria) -> Self {
        let occ = &profile.occupancy;
        let band = [occ.floor_height_m + occ.obstacle_min_height_m, occ.floor_height_m + occ.obstacle_max_height_m];
        Self { scene, obstacles: obstacles(scene, band), nav: &profile.navigation, criteria }
    }

    /// The outcome of the planner's `result` for `node`, matched to the ground-truth instance
    /// `truth_id` (`None`: unmatched), counted into `counts` (the node's kind).
    fn node(
        &self,
        node: &GraphNode,
        truth_id: Option<u32>,
        result: Result<Approach, ApproachStatus>,
        counts: &mut KindNav,
    ) -> NodeNav {
        let truth = truth_id.and_then(|id| u16::try_from(id).ok()).and_then(|id| self.scene.instance(id));
        counts.nodes += 1;
        counts.matched += u32::from(truth.is_some());
        let status = match result {
            Ok(_) => ApproachStatus::Ok.as_str(),
            Err(status) => status.as_str(),
        };
        let mut outcome = NodeNav::unjudged(node, truth_id, status);
        match (result, truth) {
            (Err(status), Some(_)) => match status {
                ApproachStatus::NoFreeCell => counts.no_free_cell += 1,
                ApproachStatus::Unreachable => counts.unreachable += 1,
                _ => counts.robot_not_on_map += 1,
            },
            (Err(_), None) => {}
            (Ok(approach), truth) => self.approach(&approach, truth, &mut outcome, counts),
        }
        outcome
    }

    /// Judges an approach pose into `outcome` and `counts`: free space always, the band, facing
    /// and side against the true instance `truth` when the node has one.
    fn approach(&self, approach: &Approach, truth: Option<&InstanceInfo>, outcome: &mut NodeNav, counts: &mut KindNav) {
        let p = approach.xy_m;
        let clear = clearance(self.scene, &self.obstacles, p);
        let free = clear >= self.nav.robot_radius_m - self.criteria.free_tolerance_m;
        outcome.xy_m = Some(p);
        outcome.yaw_rad = Some(approach.yaw_rad);
        outcome.path_m = Some(approach.path_m);
        outcome.clearance_m = Some(clear);
        outcome.free = Some(free);
        let Some(info) = truth else {
            counts.unmatched_reachable += 1;
            counts.unmatched_free += u32::from(free);
            return;
        };
        counts.reachable += 1;
        let judged = judge(self.scene, info, p, approach.yaw_rad, self.nav, &self.criteria);
        outcome.true_standoff_m = Some(judged.true_standoff_m);
        outcome.facing_error_deg = Some(judged.facing_error_deg);
        outcome.in_band = Some(judged.in_band);
        outcome.facing = Some(judged.facing);
        outcome.on_side = judged.on_side;
        counts.not_free += u32::from(!free);
        counts.out_of_band += u32::from(!judged.in_band);
        counts.not_facing += u32::from(!judged.facing);
        counts.wrong_side += u32::from(judged.on_side == Some(false));
        outcome.correct = free && judged.in_band && judged.facing && judged.on_side != Some(false);
        counts.correct += u32::from(outcome.correct);
    }
}

impl NodeNav {
    /// `node` with the planner's `status` and nothing judged yet.
    fn unjudged(node: &GraphNode, truth_id: Option<u32>, status: &'static str) -> Self {
        Self {
            node_id: node.id,
            kind: node.kind.as_str(),
            label: node.label.clone(),
            truth_id,
            status,
            xy_m: None,
            yaw_rad: None,
            path_m: None,
            clearance_m: None,
            true_standoff_m: None,
            facing_error_deg: None,
            free: None,
            in_band: None,
            facing: None,
            on_side: None,
            correct: false,
        }
    }
}

fn percentile(sorted: &[u32], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    f64::from(sorted[((sorted.len() - 1) as f64 * q).round() as usize])
}

/// The report over `rooms`.
pub fn report(profile: &Profile, rooms: Vec<RoomNav>) -> NavReport {
    let (mut objects, mut parts) = (KindNav::default(), KindNav::default());
    let mut integrate: Vec<u32> = Vec::new();
    for room in &rooms {
        objects.add(&room.objects);
        parts.add(&room.parts);
        integrate.extend(&room.integrate_us);
    }
    integrate.sort_unstable();
    let side = profile.occupancy.side_cells() as usize;
    NavReport {
        criteria: NavCriteria::for_cell(profile.occupancy.cell_size_m),
        standoff_band_m: [profile.navigation.standoff_min_m, profile.navigation.standoff_max_m],
        robot_radius_m: profile.navigation.robot_radius_m,
        map_memory_bytes: rooms.first().map_or(0, |r| r.map_memory_bytes),
        map_cells: side * side,
        rooms,
        objects,
        parts,
        integrate_p50_us: percentile(&integrate, 0.5),
        integrate_p99_us: percentile(&integrate, 0.99),
    }
}

/// The report as text.
pub fn text(report: &NavReport) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let c = &report.criteria;
    let _ = writeln!(
        out,
        "approach poses checked against the rooms' true geometry: standoff band {:.2}-{:.2} m (±{:.2}), robot radius \
         {:.2} m (-{:.2}), facing within {:.0}° of the true centre or at the true footprint",
        report.standoff_band_m[0],
        report.standoff_band_m[1],
        c.standoff_tolerance_m,
        report.robot_radius_m,
        c.free_tolerance_m,
        c.facing_tolerance_deg
    );
    let _ = writeln!(
        out,
        "{:<12} {:<7} {:>5} {:>7} {:>9} {:>7} {:>11} {:>9}  failures (no free cell / unreachable / robot off map / not \
         free / out of band / not facing / wrong side)",
        "room", "kind", "nodes", "matched", "reachable", "correct", "correct/reach", "unmatched"
    );
    let row = |out: &mut String, room: &str, kind: &str, k: &KindNav| {
        let _ = writeln!(
            out,
            "{:<12} {:<7} {:>5} {:>7} {:>8.1}% {:>6.1}% {:>12.1}% {:>4}/{:<4}  {} / {} / {} / {} / {} / {} / {}",
            room,
            kind,
            k.nodes,
            k.matched,
            k.reachable_percent(),
            k.correct_percent(),
            k.correct_of_reachable_percent(),
            k.unmatched_free,
            k.unmatched_reachable,
            k.no_free_cell,
            k.unreachable,
            k.robot_not_on_map,
            k.not_free,
            k.out_of_band,
            k.not_facing,
            k.wrong_side
        );
    };
    for room in &report.rooms {
        row(&mut out, room.room, "objects", &room.objects);
        row(&mut out, room.room, "parts", &room.parts);
    }
    row(&mut out, "all", "objects", &report.objects);
    row(&mut out, "all", "parts", &report.parts);
    let _ = writeln!(out, "(unmatched: nodes without a ground-truth match whose pose is free / that got a pose)");
    let keyframes: usize = report.rooms.iter().map(|r| r.integrate_us.len()).sum();
    let _ = writeln!(
        out,
        "occupancy integration per keyframe: p50 {:.0} us, p99 {:.0} us over {keyframes} keyframes; map {} cells, {:.2} \
         MiB",
        report.integrate_p50_us,
        report.integrate_p99_us,
        report.map_cells,
        report.map_memory_bytes as f64 / (1024.0 * 1024.0)
    );
    for room in &report.rooms {
        let _ = writeln!(
            out,
            "  {}: {} keyframes, planner prepare {} us, approach p50 {:.0} us per node, planner buffers {:.2} MiB",
            room.room,
            room.keyframes,
            room.prepare_us,
            room.approach_p50_us,
            room.planner_memory_bytes as f64 / (1024.0 * 1024.0)
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn geometry_helpers() {
        assert_eq!(rect_distance([0.0, 0.0], [1.0, 1.0], [0.5, 0.5]), 0.0);
        assert!((rect_distance([0.0, 0.0], [1.0, 1.0], [2.0, 1.0]) - 1.0).abs() < 1e-6);
        assert!(ray_hits_rect([-1.0, 0.5], 0.0, [0.0, 0.0], [1.0, 1.0]));
        assert!(!ray_hits_rect([-1.0, 0.5], std::f32::consts::PI, [0.0, 0.0], [1.0, 1.0]));
        assert!((angle_deg(3.1, -3.1) - (std::f32::consts::TAU - 6.2).to_degrees()).abs() < 1e-3);
        let post = Shape::Cylinder {
            axis: op3dsg_synthetic::Axis::Z,
            centre: Vec3::new(1.0, 1.0, 0.5),
            radius: 0.2,
            half_length: 0.5,
        };
        assert!((footprint_distance(&post, [1.5, 1.0]) - 0.3).abs() < 1e-6);
    }

    /// The checks catch wrong poses: inside furniture, too far, looking away, behind a part.
    #[test]
    fn the_ground_truth_checks_reject_wrong_poses() {
        let scene = Scene::generate(RoomKind::Kitchen, 1);
        let nav = op3dsg_runtime::occupancy::NavigationConfig::default();
        let checks = NavCriteria::for_cell(0.05);
        let band = [0.05, 1.5];
        let fridge = scene.instances().iter().find(|i| i.label == "fridge").expect("a fridge");
        let centre = [(fridge.box_min_m.x + fridge.box_max_m.x) * 0.5, (fridge.box_min_m.y + fridge.box_max_m.y) * 0.5];
        assert!(
            !free_in_truth(&scene, band, nav.robot_radius_m, checks.free_tolerance_m, centre).0,
            "inside the fridge"
        );
        assert!(
            !free_in_truth(&scene, band, nav.robot_radius_m, checks.free_tolerance_m, [0.05, 0.05]).0,
            "in a corner"
        );
        let handle = scene
            .instances()
            .iter()
            .find(|i| i.label == "fridge handle" && i.parent == Some(fridge.id))
            .expect("a fridge handle");
        let hc = [(handle.box_min_m.x + handle.box_max_m.x) * 0.5, (handle.box_min_m.y + handle.box_max_m.y) * 0.5];
        // 0.6 m in front of the handle (out of the fridge), facing it.
        let out = [hc[0] - centre[0], hc[1] - centre[1]];
        let len = out[0].hypot(out[1]);
        let front = [hc[0] + out[0] / len * 0.6, hc[1] + out[1] / len * 0.6];
        let facing = (hc[1] - front[1]).atan2(hc[0] - front[0]);
        let good = judge(&scene, handle, front, facing, &nav, &checks);
        assert!(good.in_band && good.facing && good.on_side == Some(true), "{good:?}");
        assert!(free_in_truth(&scene, band, nav.robot_radius_m, checks.free_tolerance_m, front).0, "in front is free");
        let away = judge(&scene, handle, front, facing + std::f32::consts::PI, &nav, &checks);
        assert!(!away.facing, "{away:?}");
        let far = [hc[0] + out[0] / len * 2.0, hc[1] + out[1] / len * 2.0];
        assert!(!judge(&scene, handle, far, facing, &nav, &checks).in_band, "2 m is out of the band");
        let behind = [hc[0] - out[0] / len * 0.6, hc[1] - out[1] / len * 0.6];
        assert_eq!(judge(&scene, handle, behind, facing, &nav, &checks).on_side, Some(false), "behind the handle");
    }

    /// The navigation check on every room (debug build, 300 frames a room): most matched nodes
    /// get a pose, and nearly every pose passes the ground-truth checks.
    #[test]
    fn approach_poses_pass_the_ground_truth_checks_in_every_room() {
        let loaded = crate::load_profile(None, &["source.synthetic.frame_count=300".to_owned()]).expect("profile");
        let mut rooms = Vec::new();
        for room in RoomKind::ALL {
            let nav = room_nav(&loaded.profile, room, 1).expect("room");
            assert!(nav.objects.matched >= 2, "{}: {:?}", nav.room, nav.objects);
            assert!(nav.objects.correct + nav.parts.correct >= 1, "{}: no correct approach pose", nav.room);
            assert!(!nav.integrate_us.is_empty() && nav.map_memory_bytes > 0);
            rooms.push(nav);
        }
        let report = report(&loaded.profile, rooms);
        let correct = report.objects.correct + report.parts.correct;
        let reachable = report.objects.reachable + report.parts.reachable;
        let matched = report.objects.matched + report.parts.matched;
        eprintln!("{}", text(&report));
        assert!(
            f64::from(reachable) >= 0.8 * f64::from(matched),
            "{reachable} of {matched} matched nodes got an approach pose"
        );
        assert!(
            f64::from(correct) >= 0.85 * f64::from(reachable),
            "{correct} of {reachable} approach poses pass the ground-truth checks"
        );
    }
}
