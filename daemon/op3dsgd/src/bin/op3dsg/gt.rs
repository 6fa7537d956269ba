//! `op3dsg gt`: the ground-truth scene graph of a synthetic room as graph JSON, whole or as a
//! given run saw it, after the change script of the profile's `[source.synthetic]` when it
//! has one.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use op3dsg_drivers::source::SourceError;
use op3dsg_synthetic::RoomKind;

use super::write_output;

/// The profile whose change script is applied, and the run a ground truth is written for.
pub(super) struct RunSeen {
    /// `--frames`: write the ground truth as a run of this many frames saw it.
    pub frames: Option<u64>,
    pub profile: Option<PathBuf>,
    pub overrides: Vec<String>,
}

impl RunSeen {
    /// Whether a profile is needed (a profile, `--set`s or `--frames`).
    fn uses_profile(&self) -> bool {
        self.frames.is_some() || self.profile.is_some() || !self.overrides.is_empty()
    }
}

/// Writes the ground truth of synthetic `room` with `seed` as graph JSON to `out` (or stdout):
/// with a profile (`run`), of the scene after its `[source.synthetic]` change script (applied
/// to `room` / `seed`, which override the profile's); with `run.frames`, each node carries the
/// keyframes of that run in which it was visible, and a line on standard error says how many
/// are scored.
pub(super) fn write_ground_truth(room: RoomKind, seed: u64, run: &RunSeen, out: Option<&Path>) -> Result<()> {
    if !run.uses_profile() {
        let gt = op3dsg_synthetic::Scene::generate(room, seed).ground_truth();
        return write_graph(&gt, out);
    }
    let loaded = op3dsg_sim::load_profile(run.profile.as_deref(), &run.overrides)
        .map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
    let mut synthetic = op3dsg_sim::backends::synthetic_config(&loaded.profile).map_err(|e| anyhow::anyhow!("{e}"))?;
    synthetic.room = room;
    synthetic.seed = seed;
    if let Some(frames) = run.frames {
        synthetic.frame_count = Some(frames);
    }
    let scene = synthetic.final_scene().map_err(|e| match e {
        SourceError::Config(message) => {
            anyhow::anyhow!("source.synthetic.{message} (the change script, on {} seed {seed})", room.as_str())
        }
        other => anyhow::anyhow!("source.synthetic: {other}"),
    })?;
    if !synthetic.changes.is_empty() {
        eprintln!(
            "{} seed {seed}: the ground truth after the {} changes of source.synthetic.changes ({} of {} instances present)",
            room.as_str(),
            synthetic.changes.len(),
            scene.present_instances().count(),
            scene.instances().len()
        );
    }
    let mut gt = scene.ground_truth();
    if let Some(frames) = run.frames {
        let (keyframes, seen) = op3dsg_sim::eval::coverage::seen_keyframes(&loaded.profile, room, seed, frames)
            .map_err(anyhow::Error::msg)?;
        let scored = op3dsg_sim::eval::coverage::mark_seen(&mut gt, &seen);
        eprintln!(
            "{} seed {seed}, {frames} frames ({keyframes} keyframes): {scored} of {} ground-truth nodes seen in at least 3 keyframes; op3dsg eval scores these",
            room.as_str(),
            gt.nodes.len()
        );
    }
    write_graph(&gt, out)
}

fn write_graph(gt: &op3dsg_drivers::graph_json::GraphJson, out: Option<&Path>) -> Result<()> {
    let mut text = serde_json::to_string_pretty(gt).context("serialising the ground truth JSON")?;
    text.push('\n');
    write_output(out, &text)
}
