use op3dsg_synthetic::{RoomKind, SyntheticConfig};

use super::*;

#[test]
fn every_room_gets_a_script_that_applies_with_changes_and_controls() {
    let (mut occluders, mut holes, mut scenes) = (0, 0, 0);
    for room in RoomKind::ALL {
        for seed in [1, 2] {
            let scene = Scene::generate(room, seed);
            let lap = op3dsg_synthetic::CameraPath::new(&scene, seed, 30.0).period_frames();
            let config = SyntheticConfig { room, seed, frame_count: Some(2 * lap), ..Default::default() };
            let script = scene_script(&config);
            let name = format!("{} seed {seed}", room.as_str());
            assert!(script.iter().all(|c| c.at_lap == Some(1)), "{name}: {script:?}");
            let removals = script.iter().filter(|c| c.remove.is_some()).count();
            assert!(removals >= 1, "{name}: no removal in {script:?}");
            assert!(script.iter().any(|c| c.move_instance.is_some()), "{name}: no move in {script:?}");
            // A small room may have no unchanged object left for a control.
            occluders += usize::from(script.iter().any(|c| c.in_front_of.is_some()));
            holes += usize::from(script.iter().any(|c| c.hide_depth.is_some()));
            scenes += 1;
            assert!(script.iter().any(|c| c.degrade_depth_beyond_m.is_some()), "{name}: no far depth in {script:?}");
            // The same room gives the same script, and the whole script applies.
            assert_eq!(scene_script(&config), script);
            let applied = SyntheticConfig { changes: script, ..config }.final_scene();
            assert!(applied.is_ok(), "{name}: {applied:?}");
        }
    }
    assert!(
        occluders * 4 >= scenes * 3 && holes * 4 >= scenes * 3,
        "{occluders} occluders, {holes} depth holes in {scenes}"
    );
}

#[test]
fn a_control_target_is_never_changed_by_the_same_script() {
    let scene = Scene::generate(RoomKind::Kitchen, 3);
    let lap = op3dsg_synthetic::CameraPath::new(&scene, 3, 30.0).period_frames();
    let config = SyntheticConfig { room: RoomKind::Kitchen, seed: 3, frame_count: Some(2 * lap), ..Default::default() };
    let script = scene_script(&config);
    let changed: Vec<u16> = script.iter().filter_map(|c| c.remove.or(c.move_instance).or(c.onto)).collect();
    for target in script.iter().filter_map(|c| c.in_front_of.or(c.hide_depth)) {
        assert!(!changed.contains(&target), "control target {target} is changed: {script:?}");
    }
}
