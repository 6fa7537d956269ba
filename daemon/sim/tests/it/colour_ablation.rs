//! The colour-feature ablation on the `colour_panel` scene: part association with fusion's
//! colour features on and off (`op3dsg_sim::eval::ablation`). Prints both and asserts that
//! colour helps there: no more wrong merges across materials and no fewer matched parts with it,
//! and strictly better on at least one of the two.
//!
//! As in `fusion_quality.rs`, the camera runs at 10 Hz over one whole loop of its path (same
//! views, a third of the frames to render).

use op3dsg_runtime::config::Profile;
use op3dsg_sim::eval::ablation::{
    ablation_table, colour_panel_profile, fusion_with_colour, fusion_without_colour, run_colour_ablation,
};
use op3dsg_synthetic::{CameraPath, RoomKind, Scene};

const SEED: u64 = 1;
const FRAME_RATE_HZ: f64 = 10.0;

fn profile(frames: Option<u64>) -> Profile {
    let base = op3dsg_sim::load_profile(None, &[]).expect("base profile").profile;
    let loop_frames =
        CameraPath::new(&Scene::generate(RoomKind::ColourPanel, SEED), SEED, FRAME_RATE_HZ).period_frames();
    let mut profile = colour_panel_profile(&base, SEED, frames.unwrap_or(loop_frames)).expect("colour panel profile");
    op3dsg_sim::backends::edit_synthetic(&mut profile, |s| s.frame_rate_hz = FRAME_RATE_HZ)
        .expect("[source.synthetic] of the profile");
    profile
}

#[test]
fn colour_ablation_prints_part_association_with_colour_on_and_off() {
    let result = run_colour_ablation(&profile(None), &fusion_with_colour, &fusion_without_colour).expect("ablation");
    println!("colour_panel seed {SEED}, one path loop at {FRAME_RATE_HZ} Hz\n{}", ablation_table(&result));
    for side in [&result.with_colour, &result.without_colour] {
        assert!(side.run.scene.as_ref().is_some_and(|s| s.room() == RoomKind::ColourPanel));
        // All 18 parts are seen often enough to be scored, so the figures mean something.
        assert_eq!(side.parts().eligible, 18, "{:?}", side.parts());
    }
    assert_eq!(result.with_colour.run.keyframes, result.without_colour.run.keyframes);
    assert_eq!(result.with_colour.run.detected_keyframes, result.without_colour.run.detected_keyframes);
    let (on, off) = (result.with_colour.parts(), result.without_colour.parts());
    assert!(on.wrongly_merged_gt <= off.wrongly_merged_gt && on.matched >= off.matched, "colour made parts worse");
    assert!(
        on.wrongly_merged_gt < off.wrongly_merged_gt || on.matched > off.matched,
        "colour features made no difference on a scene built to need them"
    );
}

/// The same fusion on both sides gives the same figures: the harness compares like with like.
#[test]
fn equal_fusions_give_equal_sides() {
    let result = run_colour_ablation(&profile(Some(80)), &fusion_with_colour, &fusion_with_colour).expect("ablation");
    assert_eq!(result.with_colour.run.graph, result.without_colour.run.graph);
    assert_eq!(result.with_colour.report, result.without_colour.report);
    assert!(result.with_colour.parts().fused_nodes > 0);
}
