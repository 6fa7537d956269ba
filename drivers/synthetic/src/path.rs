//! A robot-like camera path: a Stretch-style head camera (1.1–1.3 m high) visits viewpoints
//! facing each wall, sweeps pan (±40°) and tilt (−45°..+10°) at each, and drives between them
//! at about 0.3 m/s along collision-free paths planned on a free-space grid. The path is a loop;
//! poses are smooth (eased motion, no jumps) and a pure function of the scene, seed and rate.

use glam::{DMat3, DQuat, DVec3, Vec2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::scene::Scene;
use super::{InstanceKind, RoomKind};
use op3dsg_drivers::pose::Isometry;

const CELL_M: f32 = 0.05;
/// Clearance kept from furniture and walls (robot footprint radius plus margin).
const CLEARANCE_M: f32 = 0.3;
const DRIVE_SPEED_MPS: f64 = 0.3;
const TURN_RATE_RADPS: f64 = 0.7;
const SWEEP_S: f64 = 5.0;
const PAN_RAD: f64 = 40.0 * std::f64::consts::PI / 180.0;
const TILT_MID_RAD: f64 = -17.5 * std::f64::consts::PI / 180.0;
const TILT_AMP_RAD: f64 = 27.5 * std::f64::consts::PI / 180.0;

/// One leg of the loop.
#[derive(Debug, Clone)]
enum Segment {
    /// Pan/tilt sweep standing at a viewpoint: pan `± pan_amp` around `yaw` once, tilt
    /// `tilt_mid ± tilt_amp` twice.
    Sweep { at: Vec2, yaw: f64, tilt_mid: f64, pan_amp: f64, tilt_amp: f64 },
    /// Drive along a polyline while turning from `yaw0` to `yaw1` (tilt `TILT_MID_RAD`), or,
    /// with `look_at`, while keeping that point in the image centre.
    Drive { points: Vec<Vec2>, cumulative: Vec<f64>, yaw0: f64, yaw1: f64, look_at: Option<DVec3> },
}

/// Viewpoints of the colour panel's path: distance from the panel's parts (metres) and angle
/// off the panel's normal (degrees), in visiting order.
const PANEL_VIEWS: [(f64, f64); 6] = [(0.55, 0.0), (0.8, -35.0), (1.3, -15.0), (2.1, 10.0), (1.2, 30.0), (0.7, 45.0)];
/// Pan and tilt amplitudes of the sweeps at the panel's viewpoints, degrees.
const PANEL_SWEEP_DEG: (f64, f64) = (12.0, 6.0);
/// Seconds of a sweep at one of the panel's viewpoints.
const PANEL_SWEEP_S: f64 = 3.0;

/// Poses along the robot-like loop.
#[derive(Debug, Clone)]
pub struct CameraPath {
    height_m: f64,
    segments: Vec<(u64, u64, Segment)>,
    frame_rate_hz: f64,
    period: u64,
}

/// Free-space occupancy grid of the room at robot height.
struct Grid {
    nx: usize,
    ny: usize,
    free: Vec<bool>,
}

impl Grid {
    fn new(scene: &Scene) -> Self {
        let (_, max) = scene.bounds();
        let nx = (max.x / CELL_M).ceil() as usize;
        let ny = (max.y / CELL_M).ceil() as usize;
        let boxes: Vec<(Vec2, Vec2)> = scene
            .instances()
            .iter()
            .filter(|i| i.box_min_m.z < 1.6)
            .map(|i| (i.box_min_m.truncate(), i.box_max_m.truncate()))
            .collect();
        let mut free = vec![false; nx * ny];
        for iy in 0..ny {
            for ix in 0..nx {
                let p = Self::centre_of(ix, iy);
                let inside = p.x >= CLEARANCE_M
                    && p.y >= CLEARANCE_M
                    && p.x <= max.x - CLEARANCE_M
                    && p.y <= max.y - CLEARANCE_M;
                let clear = boxes.iter().all(|(a, b)| {
                    let d = (*a - p).max(p - *b).max(Vec2::ZERO);
                    d.length() > CLEARANCE_M
                });
                free[iy * nx + ix] = inside && clear;
            }
        }
        Self { nx, ny, free }
    }

    fn centre_of(ix: usize, iy: usize) -> Vec2 {
        Vec2::new((ix as f32 + 0.5) * CELL_M, (iy as f32 + 0.5) * CELL_M)
    }

    fn cell_of(&self, p: Vec2) -> (usize, usize) {
        let ix = ((p.x / CELL_M) as isize).clamp(0, self.nx as isize - 1) as usize;
        let iy = ((p.y / CELL_M) as isize).clamp(0, self.ny as isize - 1) as usize;
        (ix, iy)
    }

    fn is_free(&self, p: Vec2) -> bool {
        let (ix, iy) = self.cell_of(p);
        self.free[iy * self.nx + ix]
    }

    fn neighbours(&self, c: usize) -> impl Iterator<Item = usize> + '_ {
        let (ix, iy) = ((c % self.nx) as isize, (c / self.nx) as isize);
        [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, -1), (-1, 1), (1, 1)].into_iter().filter_map(
            move |(dx, dy)| {
                let (x, y) = (ix + dx, iy + dy);
                if x < 0 || y < 0 || x >= self.nx as isize || y >= self.ny as isize {
                    return None;
                }
                let n = y as usize * self.nx + x as usize;
                // Diagonal moves must not cut corners.
                let ok = self.free[n]
                    && self.free[iy as usize * self.nx + x as usize]
                    && self.free[y as usize * self.nx + ix as usize];
                ok.then_some(n)
            },
        )
    }

    /// Breadth-first distances (in steps) from `start`; `u32::MAX` where unreachable.
    fn bfs(&self, start: usize) -> (Vec<u32>, Vec<usize>) {
        let mut dist = vec![u32::MAX; self.free.len()];
        let mut prev = vec![usize::MAX; self.free.len()];
        let mut queue = std::collections::VecDeque::new();
        dist[start] = 0;
        queue.push_back(start);
        while let Some(c) = queue.pop_front() {
            for n in self.neighbours(c) {
                if dist[n] == u32::MAX {
                    dist[n] = dist[c] + 1;
                    prev[n] = c;
                    queue.push_back(n);
                }
            }
        }
        (dist, prev)
    }

    /// Whether the straight segment stays in free space.
    fn line_free(&self, a: Vec2, b: Vec2) -> bool {
        let steps = ((b - a).length() / (CELL_M * 0.5)).ceil().max(1.0) as usize;
        (0..=steps).all(|k| self.is_free(a.lerp(b, k as f32 / steps as f32)))
    }

    /// Shortest grid path from `a` to `b`, shortened by line-of-sight; straight when no path.
    fn path(&self, a: Vec2, b: Vec2) -> Vec<Vec2> {
        let (ca, cb) = (self.index(a), self.index(b));
        let (_, prev) = self.bfs(ca);
        let mut cells = vec![cb];
        let mut c = cb;
        while c != ca {
            c = prev[c];
            if c == usize::MAX {
                return vec![a, b];
            }
            cells.push(c);
        }
        cells.reverse();
        let mut raw: Vec<Vec2> = cells.iter().map(|&c| Self::centre_of(c % self.nx, c / self.nx)).collect();
        raw[0] = a;
        if let Some(last) = raw.last_mut() {
            *last = b;
        }
        let mut out = vec![a];
        let mut k = 0;
        while k + 1 < raw.len() {
            let mut far = k + 1;
            for j in (k + 1..raw.len()).rev() {
                if self.line_free(raw[k], raw[j]) {
                    far = j;
                    break;
                }
            }
            out.push(raw[far]);
            k = far;
        }
        out
    }

    fn index(&self, p: Vec2) -> usize {
        let (ix, iy) = self.cell_of(p);
        iy * self.nx + ix
    }
}

fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    (a + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI
}

fn ease(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl CameraPath {
    /// Plans the loop for `scene` (deterministic in `scene`, `seed`, `frame_rate_hz`).
    pub fn new(scene: &Scene, seed: u64, frame_rate_hz: f64) -> Self {
        let rate = if frame_rate_hz.is_finite() && frame_rate_hz > 0.0 { frame_rate_hz } else { 30.0 };
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_CA4E_7A70_0001);
        let height_m = rng.random_range(1.1..1.3);
        let grid = Grid::new(scene);
        if scene.room() == RoomKind::ColourPanel {
            return Self::around_parts(scene, &grid, height_m, rate);
        }
        let (_, max) = scene.bounds();
        let room = Vec2::new(max.x, max.y);
        let centre = room * 0.5;

        // The largest free component: viewpoints must be reachable from each other.
        let mut component = vec![u32::MAX; grid.free.len()];
        let mut best = (0usize, usize::MAX);
        let mut label = 0u32;
        for c in 0..grid.free.len() {
            if !grid.free[c] || component[c] != u32::MAX {
                continue;
            }
            let (dist, _) = grid.bfs(c);
            let mut count = 0;
            for (k, d) in dist.iter().enumerate() {
                if *d != u32::MAX {
                    component[k] = label;
                    count += 1;
                }
            }
            if count > best.0 {
                best = (count, label as usize);
            }
            label += 1;
        }
        let main = best.1 as u32;

        // Viewpoints: one facing each wall (the pan sweep covers the whole wall), standing well back from it.
        let walls = [
            (Vec2::new(0.0, 0.0), Vec2::X, Vec2::Y, room.x),
            (Vec2::new(room.x, 0.0), Vec2::Y, Vec2::NEG_X, room.y),
            (Vec2::new(room.x, room.y), Vec2::NEG_X, Vec2::NEG_Y, room.x),
            (Vec2::new(0.0, room.y), Vec2::NEG_Y, Vec2::X, room.y),
        ];
        let mut views: Vec<(Vec2, f64)> = Vec::new();
        for (origin, along, inward, len) in walls {
            let across = if inward.x.abs() > 0.5 { room.x } else { room.y };
            {
                // Off-centre along the wall so that viewpoints spread around the room.
                let s = len * 0.35 + rng.random_range(-0.15..0.15);
                let target = origin + along * s;
                let back = (across * 0.45).clamp(1.4, 2.4) + rng.random_range(-0.1..0.1);
                let desired = target + inward * back;
                // Nearest free cell of the main component.
                let mut chosen: Option<(f32, Vec2)> = None;
                for (c, _) in component.iter().enumerate().filter(|(_, label)| **label == main) {
                    let p = Grid::centre_of(c % grid.nx, c / grid.nx);
                    let d = (p - desired).length_squared();
                    if chosen.is_none_or(|(bd, _)| d < bd) {
                        chosen = Some((d, p));
                    }
                }
                if let Some((_, at)) = chosen {
                    let look = target - at;
                    views.push((at, f64::from(look.y).atan2(f64::from(look.x))));
                }
            }
        }
        if views.is_empty() {
            views.push((centre, 0.0));
        }
        views.sort_by(|a, b| {
            let angle = |p: Vec2| (p.y - centre.y).atan2(p.x - centre.x);
            angle(a.0).total_cmp(&angle(b.0))
        });

        let mut segments = Vec::new();
        let mut start = 0u64;
        let frames = |seconds: f64| (seconds * rate).round().max(1.0) as u64;
        for k in 0..views.len() {
            let (at, yaw) = views[k];
            let sweep_frames = frames(SWEEP_S + rng.random_range(-0.5..0.5));
            let sweep = Segment::Sweep { at, yaw, tilt_mid: TILT_MID_RAD, pan_amp: PAN_RAD, tilt_amp: TILT_AMP_RAD };
            segments.push((start, sweep_frames, sweep));
            start += sweep_frames;
            let (next_at, next_yaw) = views[(k + 1) % views.len()];
            let points = grid.path(at, next_at);
            let mut cumulative = vec![0.0];
            for pair in points.windows(2) {
                let last = cumulative.last().copied().unwrap_or(0.0);
                cumulative.push(last + f64::from((pair[1] - pair[0]).length()));
            }
            let length = cumulative.last().copied().unwrap_or(0.0);
            let turn = wrap_angle(next_yaw - yaw).abs();
            let seconds = (length / DRIVE_SPEED_MPS).max(turn / TURN_RATE_RADPS).max(1.0);
            let drive_frames = frames(seconds);
            segments.push((
                start,
                drive_frames,
                Segment::Drive { points, cumulative, yaw0: yaw, yaw1: yaw + wrap_angle(next_yaw - yaw), look_at: None },
            ));
            start += drive_frames;
        }
        Self { height_m, segments, frame_rate_hz: rate, period: start.max(1) }
    }

    /// The colour panel's loop: stops at [`PANEL_VIEWS`] in front of the parts (the centre of
    /// their boxes; the panel faces the room centre), a small pan/tilt sweep aimed at the parts
    /// at each, and drives between them that keep the parts in the image centre.
    fn around_parts(scene: &Scene, grid: &Grid, height_m: f64, rate: f64) -> Self {
        let parts: Vec<_> = scene.instances().iter().filter(|i| i.kind == InstanceKind::Part).collect();
        let (lo, hi) = parts.iter().fold((glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.box_min_m), hi.max(p.box_max_m))
        });
        let (_, max) = scene.bounds();
        let target = if parts.is_empty() { max * 0.5 } else { (lo + hi) * 0.5 };
        let target_m = target.as_dvec3();
        // The panel's outward normal: towards the room centre, snapped to the nearest axis.
        let to_centre = (max * 0.5 - target).truncate();
        let normal = if to_centre.x.abs() > to_centre.y.abs() {
            Vec2::new(to_centre.x.signum(), 0.0)
        } else {
            Vec2::new(0.0, to_centre.y.signum())
        };
        let look = |at: Vec2| -> (f64, f64) {
            let d = target_m - DVec3::new(f64::from(at.x), f64::from(at.y), height_m);
            (d.y.atan2(d.x), d.z.atan2(d.truncate().length()))
        };
        let frames = |seconds: f64| (seconds * rate).round().max(1.0) as u64;
        let nearest_free = |desired: Vec2| -> Vec2 {
            if grid.is_free(desired) {
                return desired;
            }
            let mut best: Option<(f32, Vec2)> = None;
            for c in (0..grid.free.len()).filter(|c| grid.free[*c]) {
                let p = Grid::centre_of(c % grid.nx, c / grid.nx);
                let d = (p - desired).length_squared();
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, p));
                }
            }
            best.map_or(desired, |(_, p)| p)
        };
        let views: Vec<Vec2> = PANEL_VIEWS
            .iter()
            .map(|&(distance_m, angle_deg)| {
                let direction = glam::Mat2::from_angle(angle_deg.to_radians() as f32) * normal;
                nearest_free(target.truncate() + direction * distance_m as f32)
            })
            .collect();
        let mut segments = Vec::new();
        let mut start = 0u64;
        for (k, &at) in views.iter().enumerate() {
            let (yaw, tilt) = look(at);
            let sweep = Segment::Sweep {
                at,
                yaw,
                tilt_mid: tilt,
                pan_amp: PANEL_SWEEP_DEG.0.to_radians(),
                tilt_amp: PANEL_SWEEP_DEG.1.to_radians(),
            };
            let sweep_frames = frames(PANEL_SWEEP_S);
            segments.push((start, sweep_frames, sweep));
            start += sweep_frames;
            let next = views[(k + 1) % views.len()];
            let points = grid.path(at, next);
            let mut cumulative = vec![0.0];
            for pair in points.windows(2) {
                let last = cumulative.last().copied().unwrap_or(0.0);
                cumulative.push(last + f64::from((pair[1] - pair[0]).length()));
            }
            let length = cumulative.last().copied().unwrap_or(0.0);
            let drive_frames = frames((length / DRIVE_SPEED_MPS).max(1.0));
            let (next_yaw, _) = look(next);
            let drive = Segment::Drive {
                points,
                cumulative,
                yaw0: yaw,
                yaw1: yaw + wrap_angle(next_yaw - yaw),
                look_at: Some(target_m),
            };
            segments.push((start, drive_frames, drive));
            start += drive_frames;
        }
        Self { height_m, segments, frame_rate_hz: rate, period: start.max(1) }
    }

    /// Frames in one loop of the path.
    pub fn period_frames(&self) -> u64 {
        self.period
    }

    /// Camera height above the floor, metres.
    pub fn height_m(&self) -> f64 {
        self.height_m
    }

    /// `world_from_camera` (optical frame: x right, y down, z forward) at frame `frame_index`
    /// (wraps around the loop).
    pub fn pose_at(&self, frame_index: u64) -> Isometry {
        let k = frame_index % self.period;
        let idx = self.segments.partition_point(|(s, _, _)| *s <= k).saturating_sub(1);
        let Some((start, len, segment)) = self.segments.get(idx) else {
            return Isometry::IDENTITY;
        };
        let t = (k - start) as f64 / *len as f64;
        let (xy, yaw, tilt) = match segment {
            Segment::Sweep { at, yaw, tilt_mid, pan_amp, tilt_amp } => {
                let phase = std::f64::consts::TAU * t;
                let pan = pan_amp * phase.sin();
                let tilt = tilt_mid - tilt_amp * (2.0 * phase).sin();
                (*at, yaw + pan, tilt)
            }
            Segment::Drive { points, cumulative, yaw0, yaw1, look_at } => {
                let e = ease(t);
                let total = cumulative.last().copied().unwrap_or(0.0);
                let s = e * total;
                let j = cumulative.partition_point(|c| *c <= s).clamp(1, points.len().max(2) - 1);
                let xy = if points.len() < 2 {
                    points.first().copied().unwrap_or(Vec2::ZERO)
                } else {
                    let span = (cumulative[j] - cumulative[j - 1]).max(1e-9);
                    let u = ((s - cumulative[j - 1]) / span).clamp(0.0, 1.0);
                    points[j - 1].lerp(points[j], u as f32)
                };
                match look_at {
                    Some(target) => {
                        let d = *target - DVec3::new(f64::from(xy.x), f64::from(xy.y), self.height_m);
                        (xy, d.y.atan2(d.x), d.z.atan2(d.truncate().length()))
                    }
                    None => (xy, yaw0 + (yaw1 - yaw0) * e, TILT_MID_RAD),
                }
            }
        };
        let position = DVec3::new(f64::from(xy.x), f64::from(xy.y), self.height_m);
        Isometry::new(look_rotation(yaw, tilt), position)
    }

    /// The simulated time of frame `frame_index`, seconds.
    pub fn time_s(&self, frame_index: u64) -> f64 {
        frame_index as f64 / self.frame_rate_hz
    }
}

/// Rotation of the optical frame looking along heading `yaw` (about world z, from +x) and
/// elevation `tilt` (positive up).
pub fn look_rotation(yaw: f64, tilt: f64) -> DQuat {
    let forward = DVec3::new(yaw.cos() * tilt.cos(), yaw.sin() * tilt.cos(), tilt.sin());
    let right = DVec3::new(yaw.sin(), -yaw.cos(), 0.0);
    let down = forward.cross(right);
    DQuat::from_mat3(&DMat3::from_cols(right, down, forward))
}

/// Whether a world point is inside (or within `margin` of) any object's box.
pub fn inside_furniture(scene: &Scene, p: glam::Vec3, margin: f32) -> bool {
    scene
        .instances()
        .iter()
        .filter(|i| i.kind == InstanceKind::Object)
        .any(|i| (i.box_min_m - margin).cmple(p).all() && p.cmple(i.box_max_m + margin).all())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_rotation_axes() {
        let q = look_rotation(0.0, 0.0);
        assert!((q * DVec3::Z - DVec3::X).length() < 1e-9, "optical z looks along heading");
        assert!((q * DVec3::Y - DVec3::NEG_Z).length() < 1e-9, "optical y points down");
        assert!((q * DVec3::X - DVec3::NEG_Y).length() < 1e-9, "optical x points right");
    }

    #[test]
    fn path_is_smooth_and_loops() {
        let scene = Scene::generate(RoomKind::Kitchen, 4);
        let path = CameraPath::new(&scene, 4, 30.0);
        let period = path.period_frames();
        assert!((400..=2000).contains(&period), "period {period}");
        for k in 0..period {
            let a = path.pose_at(k);
            let b = path.pose_at(k + 1);
            let step = (a.translation - b.translation).length();
            let turn = a.rotation.angle_between(b.rotation);
            assert!(step < 0.03, "frame {k}: moved {step} m");
            assert!(turn < 0.06, "frame {k}: turned {turn} rad");
        }
        assert_eq!(path.pose_at(3), path.pose_at(3 + period));
    }
}
