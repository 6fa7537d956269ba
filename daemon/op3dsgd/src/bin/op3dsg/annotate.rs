//! `op3dsg annotate`: ground truth for a recorded RGB-D sequence from hand-drawn 2D boxes,
//! lifted to world-frame 3D boxes with the recording's depth and poses
//! (`op3dsg_sim::annotate`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use op3dsg_sim::annotate::{Annotation, lift, preview, summary};

/// Reads the annotation, lifts it on the recording (`sequence`, else the file's own
/// `sequence`), prints the summary on standard error, writes the graph JSON to `out` (or
/// standard output) and, with `preview_dir`, the preview PNGs.
pub(super) fn annotate(
    annotation_path: &Path,
    sequence: Option<&Path>,
    out: Option<&Path>,
    preview_dir: Option<&Path>,
) -> Result<()> {
    let annotation = Annotation::read(annotation_path).map_err(anyhow::Error::msg)?;
    let sequence: PathBuf = match sequence {
        Some(path) => path.to_path_buf(),
        None => annotation.sequence_dir(annotation_path).with_context(|| {
            format!("{}: no `sequence` in the file, and no --sequence given", annotation_path.display())
        })?,
    };
    let lifted = lift(&annotation, annotation_path, &sequence).map_err(anyhow::Error::msg)?;
    eprint!("{}", summary(&annotation, &lifted));
    if let Some(dir) = preview_dir {
        let written = preview(&annotation, &sequence, dir).map_err(|e| anyhow::anyhow!("--preview: {e}"))?;
        eprintln!("preview: {} frames in {}", written.len(), dir.display());
    }
    let mut text = serde_json::to_string_pretty(&lifted.graph).context("serialising the ground truth JSON")?;
    text.push('\n');
    super::write_output(out, &text)
}
