//! What a run saw: per ground-truth node, the keyframes in which it was visible, so a ground
//! truth can be written for a given run (`op3dsg gt --frames N`) and scored the way
//! `op3dsg bench quality` scores (nodes seen in fewer than
//! [`MatchCriteria::min_visible_keyframes`] keyframes, 3, are not scored, nor their edges and
//! affordances).
//!
//! The run is the profile's synthetic camera path through its keyframe gate, with the
//! benchmark's visibility rule ([`VisibilityThresholds`]: 200 pixels of an object, 30 of a part
//! in a keyframe). Visibility depends on the camera path and the keyframe gate only, not on the
//! detector or fusion, so a ground truth written with the profile a daemon ran with (same room,
//! seed, frame count and `[keyframe]` section) covers what that daemon's run saw.

use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::reasoner::ReasonerKind;
use op3dsg_synthetic::RoomKind;

use super::fusion_match::MatchCriteria;
use crate::backends::{set_synthetic_config, synthetic_config};
use crate::batch::{self, VisibilityThresholds};

/// Keyframes of `base` on `room` / `seed` for `frames` frames, and per instance id (index 0
/// unused) the keyframes in which it was visible.
pub fn seen_keyframes(base: &Profile, room: RoomKind, seed: u64, frames: u64) -> Result<(u64, Vec<u32>), String> {
    let name = format!("{} seed {seed}", room.as_str());
    let mut profile = base.clone();
    let mut synthetic = synthetic_config(&profile).map_err(|e| format!("{name}: {e}"))?;
    synthetic.room = room;
    synthetic.seed = seed;
    synthetic.frame_count = Some(frames);
    set_synthetic_config(&mut profile, &synthetic);
    profile.run.max_frames = 0;
    // Visibility needs the camera path and the keyframe gate only; no reasoning.
    profile.reasoner.kind = ReasonerKind::None;
    let run = batch::run(&profile, &VisibilityThresholds::default()).map_err(|e| format!("{name}: {e}"))?;
    Ok((run.keyframes, run.visible_keyframes))
}

/// Writes `seen` (per instance id) into the ground truth's nodes; how many nodes are scored
/// (seen in at least the benchmark's minimum).
pub fn mark_seen(ground_truth: &mut GraphJson, seen: &[u32]) -> usize {
    for node in &mut ground_truth.nodes {
        node.seen_keyframes = Some(seen.get(node.id as usize).copied().unwrap_or(0));
    }
    ground_truth.nodes.iter().filter(|n| is_scored(n.seen_keyframes)).count()
}

/// Whether a ground-truth node with `seen_keyframes` is scored: always without the field, else
/// when seen in at least [`MatchCriteria::min_visible_keyframes`] keyframes.
pub fn is_scored(seen_keyframes: Option<u32>) -> bool {
    seen_keyframes.is_none_or(|k| k >= MatchCriteria::default().min_visible_keyframes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_sees_part_of_the_room_and_marks_it() {
        let base = crate::load_profile(None, &[]).expect("base profile").profile;
        let (keyframes, seen) = seen_keyframes(&base, RoomKind::Kitchen, 3, 90).expect("run");
        assert!(keyframes > 3, "{keyframes} keyframes");
        let mut gt = op3dsg_synthetic::Scene::generate(RoomKind::Kitchen, 3).ground_truth();
        let total = gt.nodes.len();
        let scored = mark_seen(&mut gt, &seen);
        // Three seconds of camera path see some of the kitchen, not all of it.
        assert!(scored > 0 && scored < total, "{scored} of {total} scored");
        assert!(gt.nodes.iter().all(|n| n.seen_keyframes.is_some_and(|k| k as u64 <= keyframes)));
        // A longer path sees at least as much of every node.
        let (_, longer) = seen_keyframes(&base, RoomKind::Kitchen, 3, 180).expect("longer run");
        assert!(seen.iter().zip(&longer).all(|(a, b)| a <= b));
        assert!(is_scored(None) && !is_scored(Some(2)) && is_scored(Some(3)));
    }
}
