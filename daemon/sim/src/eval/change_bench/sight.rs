//! The first keyframe that sees a changed place: the renderer's exact depth of the scene as it
//! is at that keyframe, from the keyframe's true pose, at a quarter of the camera's resolution.

use glam::Vec3;
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;
use op3dsg_synthetic::{AppliedChange, ChangeKind, Renderer, SyntheticSource};

/// A point is in sight within this range, metres.
const SIGHT_RANGE_M: (f32, f32) = (0.3, 3.0);
/// The line of sight to a point is clear when the depth there is at least its range less this.
const CLEAR_M: f32 = 0.05;

/// Per changed place (index into `changes`, and whether it is the new place of a move or an
/// addition): the first keyframe (fusion's counter, 1-based: `poses[k - 1]`) at or after the
/// change's frame that sees it. Controls have no place.
pub(super) fn first_sights(
    source: &SyntheticSource,
    changes: &[AppliedChange],
    poses: &[(u64, Isometry)],
    intrinsics: &Intrinsics,
) -> Vec<(usize, bool, Option<u64>)> {
    let mut places: Vec<(usize, bool, (Vec3, Vec3), u64)> = Vec::new();
    for (i, c) in changes.iter().enumerate() {
        match c.kind {
            ChangeKind::Removed | ChangeKind::Moved => {
                if let Some(from) = c.from {
                    places.push((i, false, from, c.frame));
                }
                if let (ChangeKind::Moved, Some(to)) = (c.kind, c.to) {
                    places.push((i, true, to, c.frame));
                }
            }
            ChangeKind::Added => {
                if let Some(to) = c.to {
                    places.push((i, true, to, c.frame));
                }
            }
            _ => {}
        }
    }
    let mut found: Vec<Option<u64>> = vec![None; places.len()];
    let Some(earliest) = places.iter().map(|p| p.3).min() else { return Vec::new() };
    let small = quarter(intrinsics);
    let mut frame = Frame::new(small);
    let mut renderer = Renderer::new();
    for (k, (seq, pose)) in poses.iter().enumerate() {
        if *seq < earliest || found.iter().all(Option::is_some) {
            continue;
        }
        renderer.render(source.scene_at(*seq), pose, &small, None, &mut frame, None);
        let camera_from_world = pose.to_mat4().inverse();
        for (slot, place) in found.iter_mut().zip(&places) {
            if slot.is_none() && *seq >= place.3 && sees(&frame, &small, &camera_from_world, place.2) {
                *slot = Some(k as u64 + 1);
            }
        }
    }
    places.iter().zip(found).map(|(p, f)| (p.0, p.1, f)).collect()
}

fn quarter(k: &Intrinsics) -> Intrinsics {
    Intrinsics {
        width: (k.width / 4).max(1),
        height: (k.height / 4).max(1),
        fx: k.fx / 4.0,
        fy: k.fy / 4.0,
        cx: k.cx / 4.0,
        cy: k.cy / 4.0,
    }
}

/// Whether at least half of the box's 9 probe points are in sight in `frame`'s exact depth.
fn sees(frame: &Frame, k: &Intrinsics, camera_from_world: &glam::Mat4, (min, max): (Vec3, Vec3)) -> bool {
    let centre = (min + max) * 0.5;
    let mut points = [centre; 9];
    for (corner, point) in points[1..].iter_mut().enumerate() {
        let c = Vec3::new(
            if corner & 1 == 0 { min.x } else { max.x },
            if corner & 2 == 0 { min.y } else { max.y },
            if corner & 4 == 0 { min.z } else { max.z },
        );
        *point = c + (centre - c) * 0.25;
    }
    let in_sight = points
        .iter()
        .filter(|p| {
            let q = camera_from_world.transform_point3(**p);
            if q.z < SIGHT_RANGE_M.0 || q.z > SIGHT_RANGE_M.1 {
                return false;
            }
            let (u, v) = (k.fx * q.x / q.z + k.cx, k.fy * q.y / q.z + k.cy);
            if u < 0.0 || v < 0.0 || u >= k.width as f32 || v >= k.height as f32 {
                return false;
            }
            let depth = frame.depth_m(v as usize * k.width as usize + u as usize);
            depth > 0.0 && depth >= q.z - CLEAR_M
        })
        .count();
    in_sight * 2 >= points.len()
}
