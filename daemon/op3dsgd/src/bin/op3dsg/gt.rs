//! `op3dsg gt`: the ground-truth scene graph of a synthetic room as graph JSON, whole or as a
//! given run saw it.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use op3dsg_synthetic::RoomKind;

use super::write_output;

/// The run a ground truth is written for (`--frames`).
pub(super) struct RunSeen {
    pub frames: u64,
    pub profile: Option<PathBuf>,
    pub overrides: Vec<String>,
}

/// Writes the ground truth of synthetic `room` with `seed` as graph JSON to `out` (or stdout);
/// with `run`, each node carries the keyframes of that run in which it was visible, and a line
/// on standard error says how many are scored.
pub(super) fn write_ground_truth(room: RoomKind, seed: u64, run: Option<&RunSeen>, out: Option<&Path>) -> Result<()> {
    let scene = op3dsg_synthetic::Scene::generate(room, seed);
    let mut gt = scene.ground_truth();
    if let Some(run) = run {
        let loaded = op3dsg_sim::load_profile(run.profile.as_deref(), &run.overrides)
            .map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
        let (keyframes, seen) = op3dsg_sim::eval::coverage::seen_keyframes(&loaded.profile, room, seed, run.frames)
            .map_err(anyhow::Error::msg)?;
        let scored = op3dsg_sim::eval::coverage::mark_seen(&mut gt, &seen);
        eprintln!(
            "{} seed {seed}, {} frames ({keyframes} keyframes): {scored} of {} ground-truth nodes seen in at least 3 keyframes; op3dsg eval scores these",
            room.as_str(),
            run.frames,
            gt.nodes.len()
        );
    }
    let mut text = serde_json::to_string_pretty(&gt).context("serialising the ground truth JSON")?;
    text.push('\n');
    write_output(out, &text)
}
