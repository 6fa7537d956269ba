//! Tests of the change script: what the source renders before and after each kind of change,
//! the ground truth of the final scene, and the refusals.

use glam::Vec3;

use super::*;
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::source::{FrameSource, SourceStatus};

fn small_intrinsics() -> Intrinsics {
    Intrinsics { width: 320, height: 240, fx: 307.5, fy: 307.5, cx: 160.0, cy: 120.0 }
}

/// Exact depth, small frames, endless: frame `f` and `f + period` share a pose.
fn config(room: RoomKind, seed: u64, changes: Vec<SceneChange>) -> SyntheticConfig {
    SyntheticConfig { room, seed, intrinsics: small_intrinsics(), depth_noise: None, changes, ..Default::default() }
}

/// A source rendered at chosen frames (skipping the others).
struct Cursor {
    source: SyntheticSource,
    truth: GroundTruth,
    next: u64,
    frame: Frame,
}

impl Cursor {
    fn new(config: &SyntheticConfig) -> Self {
        let source = SyntheticSource::new(config).unwrap();
        let truth = source.ground_truth();
        Self { source, truth, next: 0, frame: Frame::new(config.intrinsics) }
    }

    /// Frame `k` (at or after the last one rendered) and its instance ids.
    fn render(&mut self, k: u64) -> (Frame, Vec<u16>) {
        assert!(k >= self.next, "frames go forward");
        while self.next < k {
            self.source.skip_frame();
            self.next += 1;
        }
        assert_eq!(self.source.next_frame(&mut self.frame).unwrap(), SourceStatus::Frame);
        self.next += 1;
        let ids = self.truth.instance_ids.with_ids(&self.frame, <[u16]>::to_vec).unwrap();
        (self.frame.clone(), ids)
    }
}

fn count(ids: &[u16], wanted: &[u16]) -> usize {
    ids.iter().filter(|id| wanted.contains(id)).count()
}

/// The frame of lap 0 (every 20th) that shows the most pixels of `wanted` in `scene`, and how many.
fn best_view(scene: &Scene, path: &CameraPath, wanted: &[u16]) -> (u64, usize) {
    let k = small_intrinsics();
    let mut renderer = Renderer::new();
    let mut frame = Frame::new(k);
    let mut ids = Vec::new();
    let mut best = (0, 0);
    for f in (0..path.period_frames()).step_by(20) {
        renderer.render(scene, &path.pose_at(f), &k, None, &mut frame, Some(&mut ids));
        let n = count(&ids, wanted);
        if n > best.1 {
            best = (f, n);
        }
    }
    best
}

fn parts_of(scene: &Scene, id: u16) -> Vec<u16> {
    scene.instances().iter().filter(|i| i.parent == Some(id)).map(|i| i.id).collect()
}

/// Whether some object stands on `id` (an `on` edge to it).
fn carries(scene: &Scene, id: u16) -> bool {
    scene.edges().iter().any(|e| e.relation == "on" && e.target == id)
}

fn boxes_overlap(a: &InstanceInfo, min: Vec3, max: Vec3) -> bool {
    (a.box_max_m.min(max) - a.box_min_m.max(min)).cmpgt(Vec3::splat(1e-3)).all()
}

fn at_lap(lap: u64) -> SceneChange {
    SceneChange { at_lap: Some(lap), ..Default::default() }
}

/// Back-projects pixel `i` of `frame` (exact depth) into the world.
fn world_point(frame: &Frame, i: usize) -> Vec3 {
    let k = frame.intrinsics;
    let (col, row) = ((i % k.width as usize) as f32, (i / k.width as usize) as f32);
    let pose = frame.world_from_camera.unwrap();
    pose.transform_point_f32(k.point_in_camera(col, row, frame.depth_m(i)))
}

#[test]
fn a_removed_object_and_its_parts_vanish_and_reveal_what_is_behind() {
    let (room, seed) = (RoomKind::Kitchen, 1);
    let scene = Scene::generate(room, seed);
    let path = CameraPath::new(&scene, seed, 30.0);
    let period = path.period_frames();
    // The object with parts (and nothing on it) seen best in the first lap.
    let (k, view, _) = scene
        .instances()
        .iter()
        .filter(|i| i.kind == InstanceKind::Object && !parts_of(&scene, i.id).is_empty() && !carries(&scene, i.id))
        .map(|i| {
            let mut gone = parts_of(&scene, i.id);
            gone.push(i.id);
            let (f, n) = best_view(&scene, &path, &gone);
            (i.id, f, n)
        })
        .max_by_key(|c| c.2)
        .unwrap();
    let parts = parts_of(&scene, k);
    let mut gone = parts.clone();
    gone.push(k);
    let config = config(room, seed, vec![SceneChange { remove: Some(k), ..at_lap(1) }]);
    let mut cursor = Cursor::new(&config);
    let (before, before_ids) = cursor.render(view);
    assert!(count(&before_ids, &[k]) > 200, "instance {k} is visible at frame {view} before the change");
    let (after, after_ids) = cursor.render(view + period);
    assert_eq!(before.world_from_camera, after.world_from_camera);
    assert_eq!(count(&after_ids, &gone), 0, "{k} and its parts {parts:?} are gone after the change");
    let (mut farther, mut former) = (0, 0);
    for (i, id) in before_ids.iter().enumerate() {
        if gone.contains(id) {
            former += 1;
            assert!(after.depth[i] + 1 >= before.depth[i], "pixel {i}: something nearer where {k} was");
            farther += usize::from(after.depth[i] > before.depth[i] + 10);
        }
    }
    assert!(farther * 10 >= former * 9, "{farther} of {former} former pixels read what is behind");

    let truth = &cursor.truth;
    assert_eq!(truth.initial.as_ref(), Some(&scene));
    assert!(gone.iter().all(|id| !truth.scene.is_present(*id) && truth.scene.instance(*id).is_some()));
    assert_eq!(truth.scene.instances().len(), scene.instances().len(), "ids stay");
    let gt = truth.scene.ground_truth();
    gt.check().unwrap();
    assert!(gt.nodes.iter().all(|n| !gone.contains(&(n.id as u16))));
    assert_eq!(gt.nodes.len(), scene.instances().len() - gone.len());
    assert!(gt.edges.iter().all(|e| !gone.contains(&(e.source as u16)) && !gone.contains(&(e.target as u16))));
    assert_eq!(truth.scene.present_instances().count(), gt.nodes.len());
    let change = &truth.changes[0];
    assert_eq!((change.kind, change.instance, change.frame, &change.parts), (ChangeKind::Removed, k, period, &parts));
    assert!(change.from.is_some() && change.to.is_none());
    let final_scene = config.final_scene().unwrap();
    assert_eq!(final_scene, truth.scene);
}

/// The first (object with parts, object to put it on) pair whose move the source accepts and
/// shows in the second lap: the source, the pair and a frame of lap 1 that shows it.
fn accepted_move(room: RoomKind, seed: u64) -> Option<(SyntheticConfig, u16, u16)> {
    let scene = Scene::generate(room, seed);
    let objects: Vec<&InstanceInfo> = scene.instances().iter().filter(|i| i.kind == InstanceKind::Object).collect();
    let mut movable: Vec<&&InstanceInfo> = objects
        .iter()
        .filter(|i| !parts_of(&scene, i.id).is_empty() && !carries(&scene, i.id) && i.box_max_m.z - i.box_min_m.z < 0.6)
        .collect();
    movable.sort_by(|a, b| (a.box_max_m - a.box_min_m).length().total_cmp(&(b.box_max_m - b.box_min_m).length()));
    let mut surfaces: Vec<&&InstanceInfo> = objects.iter().filter(|i| i.box_max_m.z < 1.1).collect();
    let area = |i: &InstanceInfo| (i.box_max_m.x - i.box_min_m.x) * (i.box_max_m.y - i.box_min_m.y);
    surfaces.sort_by(|a, b| area(b).total_cmp(&area(a)));
    for k in &movable {
        for s in &surfaces {
            let change = SceneChange { move_instance: Some(k.id), onto: Some(s.id), ..at_lap(1) };
            let config = config(room, seed, vec![change]);
            if SyntheticSource::new(&config).is_ok() {
                return Some((config, k.id, s.id));
            }
        }
    }
    None
}

#[test]
fn a_moved_object_and_its_parts_render_in_their_new_place_on_top_of_the_surface() {
    let (room, seed) = (RoomKind::Kitchen, 1);
    let (config, k, s) = accepted_move(room, seed).expect("an object with parts that fits on another");
    let mut cursor = Cursor::new(&config);
    let truth = cursor.truth.clone();
    let initial = truth.initial.clone().unwrap();
    let (old, new) = (initial.instance(k).unwrap(), truth.scene.instance(k).unwrap());
    let offset = new.box_min_m - old.box_min_m;
    assert!(offset.length() > 0.05, "{k} moved by {offset}");
    assert!(((new.box_max_m - new.box_min_m) - (old.box_max_m - old.box_min_m)).length() < 1e-4, "same size");
    let parts = parts_of(&initial, k);
    let mut moving = parts.clone();
    moving.push(k);
    for p in &parts {
        let (a, b) = (initial.instance(*p).unwrap(), truth.scene.instance(*p).unwrap());
        assert!((b.box_min_m - a.box_min_m - offset).length() < 1e-4, "part {p} moved with its object");
        assert!((b.box_max_m - a.box_max_m - offset).length() < 1e-4, "part {p} moved with its object");
    }
    // On top of s, inside its footprint, clear of everything else.
    let surface = truth.scene.instance(s).unwrap();
    let (lo, hi) = moving
        .iter()
        .map(|m| truth.scene.instance(*m).unwrap())
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), i| (lo.min(i.box_min_m), hi.max(i.box_max_m)));
    assert!((lo.z - surface.box_max_m.z).abs() < 1e-4, "rests on {s}: {} vs {}", lo.z, surface.box_max_m.z);
    assert!(lo.truncate().cmpge(surface.box_min_m.truncate() - 1e-4).all());
    assert!(hi.truncate().cmple(surface.box_max_m.truncate() + 1e-4).all());
    for other in truth.scene.present_instances().filter(|i| !moving.contains(&i.id)) {
        for m in &moving {
            let info = truth.scene.instance(*m).unwrap();
            assert!(
                !boxes_overlap(other, info.box_min_m, info.box_max_m),
                "{m} overlaps {} ({})",
                other.id,
                other.label
            );
        }
    }
    let gt = truth.scene.ground_truth();
    gt.check().unwrap();
    let spatial: Vec<_> = gt
        .edges
        .iter()
        .filter(|e| {
            e.kind == "spatial" && e.relation != "part of" && (e.source == u32::from(k) || e.target == u32::from(k))
        })
        .map(|e| (e.source, e.relation.as_str(), e.target))
        .collect();
    assert_eq!(spatial, [(u32::from(k), "on", u32::from(s))]);
    let change = &truth.changes[0];
    assert_eq!((change.kind, change.onto, &change.parts), (ChangeKind::Moved, Some(s), &parts));
    assert_eq!(change.to, Some((new.box_min_m, new.box_max_m)));

    // Its pixels lie in its new box (grown by 3 cm), each part's in the part's.
    let (view, n) = best_view(&truth.scene, cursor.source.path(), &[k]);
    assert!(n > 50, "{k} is seen in its new place ({n} pixels at best)");
    let period = cursor.source.path().period_frames();
    let (frame, ids) = cursor.render(view + period);
    let mut checked = 0;
    for (i, id) in ids.iter().enumerate().filter(|(_, id)| moving.contains(id)) {
        let info = truth.scene.instance(*id).unwrap();
        let p = world_point(&frame, i);
        let inside = (info.box_min_m - 0.03).cmple(p).all() && p.cmple(info.box_max_m + 0.03).all();
        assert!(inside, "pixel {i} of {id} at {p} is outside its new box {:?}", (info.box_min_m, info.box_max_m));
        checked += 1;
    }
    assert!(checked > 50);
    // Before the change the same view showed it elsewhere (or not at all).
    let mut before = Cursor::new(&config);
    let (frame, ids) = before.render(view);
    for (i, _) in ids.iter().enumerate().filter(|(_, id)| **id == k) {
        let p = world_point(&frame, i);
        assert!((old.box_min_m - 0.03).cmple(p).all() && p.cmple(old.box_max_m + 0.03).all());
    }
}

#[test]
fn added_objects_get_new_ids_and_an_occluder_stands_between_its_target_and_the_room_centre() {
    let (room, seed) = (RoomKind::Kitchen, 1);
    let scene = Scene::generate(room, seed);
    let path = CameraPath::new(&scene, seed, 30.0);
    let max = scene.instances().len() as u16;
    let area = |i: &InstanceInfo| (i.box_max_m.x - i.box_min_m.x) * (i.box_max_m.y - i.box_min_m.y);
    let surface = scene
        .instances()
        .iter()
        .filter(|i| i.kind == InstanceKind::Object && i.box_max_m.z < 1.1)
        .max_by(|a, b| area(a).total_cmp(&area(b)))
        .unwrap();
    // Floor-standing objects, best seen first.
    let mut floor: Vec<(u16, usize)> = scene
        .instances()
        .iter()
        .filter(|i| i.kind == InstanceKind::Object && i.box_min_m.z < 0.02 && i.box_max_m.z < 1.5)
        .map(|i| (i.id, best_view(&scene, &path, &[i.id]).1))
        .collect();
    floor.sort_by_key(|c| std::cmp::Reverse(c.1));
    let add_box = SceneChange { add: Some("box".to_owned()), onto: Some(surface.id), ..at_lap(1) };
    let (config, target) = floor
        .iter()
        .map(|(t, _)| {
            let occluder = SceneChange { add: Some("screen".to_owned()), in_front_of: Some(*t), ..at_lap(1) };
            (config(room, seed, vec![add_box.clone(), occluder]), *t)
        })
        .find(|(config, _)| SyntheticSource::new(config).is_ok())
        .expect("an occluder in front of some floor-standing object");
    let mut cursor = Cursor::new(&config);
    let truth = cursor.truth.clone();
    let (added, occluder) = (max + 1, max + 2);
    assert_eq!(truth.scene.instances().len(), usize::from(max) + 2);
    let b = truth.scene.instance(added).unwrap();
    assert_eq!(
        (b.label.as_str(), b.kind, b.parent, b.material.as_str()),
        ("box", InstanceKind::Object, None, "cardboard")
    );
    assert!((b.box_min_m.z - surface.box_max_m.z).abs() < 1e-4);
    assert!(((b.box_max_m - b.box_min_m) - Vec3::new(0.3, 0.25, 0.2)).length() < 1e-4, "the default box size");
    assert!(b.box_min_m.truncate().cmpge(surface.box_min_m.truncate()).all());
    assert!(b.box_max_m.truncate().cmple(surface.box_max_m.truncate()).all());
    let o = truth.scene.instance(occluder).unwrap();
    assert_eq!((o.label.as_str(), o.kind), ("screen", InstanceKind::Object));
    let t = truth.scene.instance(target).unwrap();
    assert!(o.box_min_m.z.abs() < 1e-6, "stands on the floor");
    assert!(o.box_max_m.z >= t.box_max_m.z, "at least as tall as {target}");
    let centre = |i: &InstanceInfo| ((i.box_min_m + i.box_max_m) * 0.5).truncate();
    let room_centre = (truth.scene.bounds().1 * 0.5).truncate();
    assert!(centre(o).distance(room_centre) < centre(t).distance(room_centre), "between it and the centre");
    let gap = (o.box_min_m - t.box_max_m).max(t.box_min_m - o.box_max_m).truncate().max_element();
    assert!((0.29..=0.51).contains(&gap), "{gap} m in front of {target}");
    for other in truth.scene.present_instances().filter(|i| i.id != occluder && i.id != added) {
        assert!(!boxes_overlap(other, o.box_min_m, o.box_max_m) && !boxes_overlap(other, b.box_min_m, b.box_max_m));
    }
    let gt = truth.scene.ground_truth();
    gt.check().unwrap();
    assert!(
        gt.edges
            .iter()
            .any(|e| e.source == u32::from(added) && e.relation == "on" && e.target == u32::from(surface.id))
    );
    let kinds: Vec<_> = truth.changes.iter().map(|c| (c.kind, c.instance, c.target, c.onto)).collect();
    assert_eq!(
        kinds,
        [(ChangeKind::Added, added, None, Some(surface.id)), (ChangeKind::Occluder, occluder, Some(target), None)]
    );

    // Both appear after the change, never before; the occluder hides most of its target.
    let period = path.period_frames();
    let (mut target_before, mut target_after, mut seen_box, mut seen_occluder) = (0, 0, 0, 0);
    let views: Vec<u64> = (0..period).step_by(25).collect();
    let mut before = Cursor::new(&config);
    for &f in &views {
        let (_, ids) = before.render(f);
        assert_eq!(count(&ids, &[added, occluder]), 0);
        target_before += count(&ids, &[target]);
        let (_, ids) = cursor.render(f + period);
        target_after += count(&ids, &[target]);
        seen_box += count(&ids, &[added]);
        seen_occluder += count(&ids, &[occluder]);
    }
    assert!(seen_box > 0 && seen_occluder > 0, "box {seen_box} px, occluder {seen_occluder} px");
    assert!(target_after * 2 < target_before, "{target}: {target_before} px before, {target_after} after");
}

#[test]
fn hide_depth_blanks_the_depth_of_its_instance_only() {
    let (room, seed) = (RoomKind::Kitchen, 2);
    let scene = Scene::generate(room, seed);
    let path = CameraPath::new(&scene, seed, 30.0);
    let (target, view, n) = scene
        .instances()
        .iter()
        .filter(|i| i.kind == InstanceKind::Object)
        .map(|i| {
            let (f, n) = best_view(&scene, &path, &[i.id]);
            (i.id, f, n)
        })
        .max_by_key(|c| c.2)
        .unwrap();
    assert!(n > 500);
    let config = config(room, seed, vec![SceneChange { hide_depth: Some(target), ..at_lap(1) }]);
    let mut cursor = Cursor::new(&config);
    let (before, before_ids) = cursor.render(view);
    let (after, after_ids) = cursor.render(view + path.period_frames());
    assert_eq!(before_ids, after_ids, "instance ids unchanged");
    assert_eq!(before.rgb, after.rgb, "colour unchanged");
    for (i, id) in after_ids.iter().enumerate() {
        if *id == target {
            assert!(before.depth[i] > 0);
            assert_eq!(after.depth[i], 0, "pixel {i} of {target} has depth");
        } else {
            assert_eq!(after.depth[i], before.depth[i], "pixel {i} of {id} changed");
        }
    }
    let truth = &cursor.truth;
    assert_eq!(truth.scene.depthless(), [target]);
    assert_eq!(truth.scene.ground_truth(), scene.ground_truth(), "the object itself is unchanged");
    assert_eq!(truth.changes[0].kind, ChangeKind::DepthHole);
    assert_eq!(truth.changes[0].target, Some(target));
}

#[test]
fn far_depth_is_garbage_beyond_the_range_and_untouched_within() {
    let (room, seed) = (RoomKind::LivingRoom, 1);
    let range = 2.5;
    // The view of the first lap with the most depth beyond the range.
    let scene = Scene::generate(room, seed);
    let path = CameraPath::new(&scene, seed, 30.0);
    let (k, mut renderer, mut frame) = (small_intrinsics(), Renderer::new(), Frame::new(small_intrinsics()));
    let view = (0..path.period_frames())
        .step_by(20)
        .max_by_key(|f| {
            renderer.render(&scene, &path.pose_at(*f), &k, None, &mut frame, None);
            (0..frame.depth.len()).filter(|i| frame.depth_m(*i) > range).count()
        })
        .unwrap();
    let config = config(room, seed, vec![SceneChange { degrade_depth_beyond_m: Some(range), ..at_lap(1) }]);
    let mut cursor = Cursor::new(&config);
    let (before, _) = cursor.render(view);
    let period = cursor.source.path().period_frames();
    let (after, _) = cursor.render(view + period);
    let (mut far, mut error_m, mut outliers) = (0usize, 0.0f64, 0usize);
    for i in 0..before.depth.len() {
        let z = before.depth_m(i);
        // Depth is quantised to millimetres: leave out the millimetre at the range.
        if z < range - 0.001 {
            assert_eq!(after.depth[i], before.depth[i], "pixel {i} at {z} m changed");
        } else if z > range + 0.001 && after.depth[i] > 0 {
            far += 1;
            let e = after.depth_m(i) - z;
            error_m += f64::from(e.abs());
            outliers += usize::from(e > 0.3);
        }
    }
    assert!(far > 1000, "{far} pixels beyond {range} m");
    let mean = error_m / far as f64;
    assert!(mean > 0.2, "mean error beyond the range {mean} m");
    assert!(outliers * 5 > far, "{outliers} of {far} read far too far");
    // Deterministic: the same frame renders the same garbage; the same view a lap later other garbage.
    let mut again = Cursor::new(&config);
    assert_eq!(again.render(view + period).0.depth, after.depth);
    assert_ne!(again.render(view + 2 * period).0.depth, after.depth);
    let change = &cursor.truth.changes[0];
    assert_eq!(
        (change.kind, change.instance, change.range_m, change.frame),
        (ChangeKind::FarDepth, 0, Some(range), period)
    );
}

fn at_frame(frame: u64) -> SceneChange {
    SceneChange { at_frame: Some(frame), ..Default::default() }
}

#[test]
fn without_changes_or_before_them_the_source_renders_as_before() {
    let noisy =
        SyntheticConfig { room: RoomKind::Bedroom, seed: 3, intrinsics: small_intrinsics(), ..Default::default() };
    let scene = Scene::generate(RoomKind::Bedroom, 3);
    let late = SceneChange { remove: Some(1), ..at_frame(10) };
    let changed = SyntheticConfig { changes: vec![late], ..noisy.clone() };
    let (mut plain, mut script) = (Cursor::new(&noisy), Cursor::new(&changed));
    assert!(plain.truth.initial.is_none() && plain.truth.changes.is_empty());
    assert_eq!(plain.truth.scene, scene);
    assert_eq!(plain.source.epochs().len(), 1);
    assert_eq!(noisy.final_scene().unwrap(), scene);
    for k in [0, 3, 9] {
        let (a, ids_a) = plain.render(k);
        let (b, ids_b) = script.render(k);
        assert_eq!((a.rgb, a.depth, ids_a), (b.rgb, b.depth, ids_b), "frame {k}");
    }
    let (_, ids) = script.render(10);
    assert_eq!(count(&ids, &[1]), 0);
    assert!(script.source.scene_at(9) == &scene && script.source.scene_at(10) != &scene);
    // A change at frame 0 shows from the first frame; the generated room is still the initial one.
    let first = SyntheticConfig { changes: vec![SceneChange { hide_depth: Some(1), ..at_frame(0) }], ..noisy };
    let source = SyntheticSource::new(&first).unwrap();
    assert_eq!(source.scene_at(0).depthless(), [1]);
    assert_eq!(source.ground_truth().initial, Some(scene));
}

#[test]
fn changes_apply_in_frame_order_and_parse_from_their_keys() {
    let json = r#"[{"at_lap": 1, "move": 7, "onto": 3}, {"at_frame": 450, "remove": 12}]"#;
    let changes: Vec<SceneChange> = serde_json::from_str(json).unwrap();
    assert_eq!(
        changes[0],
        SceneChange { at_lap: Some(1), move_instance: Some(7), onto: Some(3), ..Default::default() }
    );
    assert_eq!(changes[1], SceneChange { at_frame: Some(450), remove: Some(12), ..Default::default() });
    let unknown = serde_json::from_str::<Vec<SceneChange>>(r#"[{"at_lap": 1, "remvoe": 12}]"#).unwrap_err();
    assert!(unknown.to_string().contains("unknown field `remvoe`"), "{unknown}");
    let round: SyntheticConfig =
        serde_json::from_str(&serde_json::to_string(&config(RoomKind::Kitchen, 1, changes.clone())).unwrap()).unwrap();
    assert_eq!(round.changes, changes);

    // Listed later, applied first: the removal at lap 1 comes before the hide at lap 2.
    let scene = Scene::generate(RoomKind::Kitchen, 1);
    let k = scene.instances().iter().find(|i| i.kind == InstanceKind::Object && !carries(&scene, i.id)).unwrap().id;
    let changes = vec![SceneChange { hide_depth: Some(k), ..at_lap(2) }, SceneChange { remove: Some(k), ..at_lap(1) }];
    let message = SyntheticSource::new(&config(RoomKind::Kitchen, 1, changes)).unwrap_err().to_string();
    assert!(message.starts_with("config: changes[0].hide_depth: "), "{message}");
    assert!(message.contains("removed by changes[1] at frame"), "{message}");
    let two = vec![SceneChange { remove: Some(k), ..at_lap(1) }, SceneChange { hide_depth: Some(1), ..at_frame(3) }];
    let source = SyntheticSource::new(&config(RoomKind::Kitchen, 1, two)).unwrap();
    let order: Vec<_> = source.ground_truth().changes.iter().map(|c| (c.index, c.kind)).collect();
    assert_eq!(order, [(1, ChangeKind::DepthHole), (0, ChangeKind::Removed)]);
    assert_eq!(source.epochs().len(), 3);
}

type Refusal<'a> = (Vec<SceneChange>, Option<u64>, &'a str, &'a str);

/// Each case's changes (on kitchen seed 1, with its frame count) are refused with a message
/// that starts with the key and says the detail; `final_scene` refuses them alike.
fn assert_refused(cases: Vec<Refusal<'_>>) {
    for (changes, frame_count, prefix, detail) in cases {
        let config = SyntheticConfig { frame_count, ..config(RoomKind::Kitchen, 1, changes.clone()) };
        let err = match SyntheticSource::new(&config) {
            Ok(_) => panic!("accepted {changes:?}"),
            Err(err) => err,
        };
        let op3dsg_drivers::source::SourceError::Config(message) = &err else { panic!("{err}") };
        assert!(message.starts_with(prefix), "{changes:?}: {message}");
        assert!(message.contains(detail), "{changes:?}: {message} (wanted {detail:?})");
        assert!(!message.contains("Some(") && !message.contains("SceneChange"), "no Debug dump: {message}");
        assert_eq!(config.final_scene().unwrap_err().to_string(), err.to_string());
    }
}

fn one(change: SceneChange) -> Vec<SceneChange> {
    vec![change]
}

#[test]
fn malformed_changes_are_refused_naming_their_key() {
    let c = one;
    assert_refused(vec![
        (c(SceneChange { remove: Some(1), ..Default::default() }), None, "changes[0].at_frame: ", "at_lap"),
        (c(SceneChange { remove: Some(1), at_frame: Some(1), ..at_lap(1) }), None, "changes[0].at_lap: ", "not both"),
        (c(at_lap(1)), None, "changes[0]: no action", "remove"),
        (
            c(SceneChange { remove: Some(1), hide_depth: Some(2), ..at_lap(1) }),
            None,
            "changes[0].hide_depth: ",
            "remove",
        ),
        (c(SceneChange { move_instance: Some(1), ..at_lap(1) }), None, "changes[0].move: ", "onto"),
        (c(SceneChange { add: Some("box".into()), ..at_lap(1) }), None, "changes[0].add: ", "in_front_of"),
        (
            c(SceneChange { add: Some("box".into()), onto: Some(1), in_front_of: Some(1), ..at_lap(1) }),
            None,
            "changes[0].add: ",
            "exactly one",
        ),
        (c(SceneChange { add: Some(" ".into()), onto: Some(1), ..at_lap(1) }), None, "changes[0].add: ", "label"),
        (c(SceneChange { remove: Some(1), onto: Some(2), ..at_lap(1) }), None, "changes[0].onto: ", "move or add"),
        (
            c(SceneChange { hide_depth: Some(1), in_front_of: Some(2), ..at_lap(1) }),
            None,
            "changes[0].in_front_of: ",
            "add",
        ),
        (c(SceneChange { remove: Some(1), size_m: Some([0.1; 3]), ..at_lap(1) }), None, "changes[0].size_m: ", "add"),
        (
            c(SceneChange { remove: Some(1), ..at_frame(100) }),
            Some(100),
            "changes[0].at_frame: ",
            "the last frame is 99",
        ),
        (c(SceneChange { remove: Some(1), ..at_lap(1) }), Some(100), "changes[0].at_lap: ", "the last frame is 99"),
        (c(SceneChange { remove: Some(1), ..at_lap(u64::MAX) }), None, "changes[0].at_lap: ", "beyond"),
        (
            c(SceneChange { add: Some("box".into()), onto: Some(1), size_m: Some([0.3, f32::NAN, 0.2]), ..at_lap(1) }),
            None,
            "changes[0].size_m: ",
            "NaN",
        ),
        (
            c(SceneChange { add: Some("box".into()), onto: Some(1), size_m: Some([0.3, -1.0, 0.2]), ..at_lap(1) }),
            None,
            "changes[0].size_m: ",
            "-1",
        ),
        (
            c(SceneChange { degrade_depth_beyond_m: Some(0.0), ..at_lap(1) }),
            None,
            "changes[0].degrade_depth_beyond_m: ",
            "positive",
        ),
        (
            c(SceneChange { degrade_depth_beyond_m: Some(f32::INFINITY), ..at_lap(1) }),
            None,
            "changes[0].degrade_depth_beyond_m: ",
            "inf",
        ),
    ]);
}

#[test]
fn changes_that_do_not_fit_the_room_are_refused_naming_their_key() {
    let (room, seed) = (RoomKind::Kitchen, 1);
    let scene = Scene::generate(room, seed);
    let max = scene.instances().len() as u16;
    let object_with_parts = |i: &&InstanceInfo| i.kind == InstanceKind::Object && !parts_of(&scene, i.id).is_empty();
    let cabinet = scene.instances().iter().find(|i| object_with_parts(i) && !carries(&scene, i.id)).unwrap();
    let own_part = parts_of(&scene, cabinet.id)[0];
    let other_part =
        scene.instances().iter().find(|i| i.kind == InstanceKind::Part && i.parent != Some(cabinet.id)).unwrap();
    let carrier = scene.edges().iter().find(|e| e.relation == "on").unwrap();
    let fridge = scene.instances().iter().find(|i| i.label == "fridge").unwrap().id;
    let kettle = scene.instances().iter().find(|i| i.label == "kettle").unwrap().id;
    let c = one;
    let move_its_object = format!("move its object, move = {}", cabinet.id);
    let id_range = format!("1 to {max}");
    assert_refused(vec![
        (
            c(SceneChange { remove: Some(max + 1), ..at_lap(1) }),
            None,
            "changes[0].remove: ",
            "op3dsg gt --room kitchen --seed 1",
        ),
        (c(SceneChange { remove: Some(0), ..at_lap(1) }), None, "changes[0].remove: ", &id_range),
        (c(SceneChange { hide_depth: Some(max + 5), ..at_lap(1) }), None, "changes[0].hide_depth: ", "no instance"),
        (
            c(SceneChange { move_instance: Some(own_part), onto: Some(fridge), ..at_lap(1) }),
            None,
            "changes[0].move: ",
            &move_its_object,
        ),
        (
            c(SceneChange { move_instance: Some(cabinet.id), onto: Some(cabinet.id), ..at_lap(1) }),
            None,
            "changes[0].onto: ",
            "itself",
        ),
        (
            c(SceneChange { move_instance: Some(cabinet.id), onto: Some(own_part), ..at_lap(1) }),
            None,
            "changes[0].onto: ",
            "the object being moved",
        ),
        (
            c(SceneChange { add: Some("mug".into()), onto: Some(other_part.id), ..at_lap(1) }),
            None,
            "changes[0].onto: ",
            "is a part",
        ),
        (
            c(SceneChange { move_instance: Some(fridge), onto: Some(kettle), ..at_lap(1) }),
            None,
            "changes[0].onto: ",
            "no room",
        ),
        (
            c(SceneChange {
                add: Some("wardrobe".into()),
                onto: Some(kettle),
                size_m: Some([2.0, 1.0, 2.0]),
                ..at_lap(1)
            }),
            None,
            "changes[0].onto: ",
            "smaller than",
        ),
        (c(SceneChange { remove: Some(carrier.target), ..at_lap(1) }), None, "changes[0].remove: ", "on it"),
        (
            vec![SceneChange { remove: Some(kettle), ..at_lap(1) }, SceneChange { remove: Some(kettle), ..at_lap(1) }],
            None,
            "changes[1].remove: ",
            "removed by changes[0]",
        ),
    ]);
    // Removing a part is allowed: the part alone goes.
    let config = config(room, seed, vec![SceneChange { remove: Some(own_part), ..at_lap(1) }]);
    let truth = SyntheticSource::new(&config).unwrap().ground_truth();
    assert!(!truth.scene.is_present(own_part) && truth.scene.is_present(cabinet.id));
    assert!(truth.changes[0].parts.is_empty());
}
