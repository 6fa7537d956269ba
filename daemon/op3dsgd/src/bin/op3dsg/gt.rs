//! `op3dsg gt`: the ground-truth scene graph of a synthetic room as graph JSON.

use std::path::Path;

use anyhow::{Context, Result};
use op3dsg_synthetic::RoomKind;

use super::write_output;

/// Writes the ground truth of synthetic `room` with `seed` as graph JSON to `out` (or stdout).
pub(super) fn write_ground_truth(room: RoomKind, seed: u64, out: Option<&Path>) -> Result<()> {
    let scene = op3dsg_synthetic::Scene::generate(room, seed);
    let gt = scene.ground_truth();
    let mut text = serde_json::to_string_pretty(&gt).context("serialising the ground truth JSON")?;
    text.push('\n');
    write_output(out, &text)
}
