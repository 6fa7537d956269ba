//! `op3dsg eval`: a predicted graph scored against a ground-truth graph with the benchmark's
//! protocol, and the text encoder it (and `bench quality`) ranks labels with.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use super::write_output;

/// Loads ONNX Runtime and the text encoder the profile points at.
pub(crate) fn load_text_encoder(
    profile_path: Option<&Path>,
) -> Result<op3dsg_runtime::onnx::text_encoder::TextEncoder> {
    use op3dsg_runtime::onnx::{OnnxRuntime, text_encoder::TextEncoder};
    let loaded = op3dsg_sim::load_profile(profile_path, &[]).map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
    let runtime = OnnxRuntime::init(&loaded.profile.onnx).context("loading ONNX Runtime for the text encoder")?;
    TextEncoder::new(&runtime, &loaded.profile.text_encoder).context("loading the text encoder")
}

/// `op3dsg eval`: one predicted graph against one ground truth.
pub(super) fn evaluate(
    pred_path: &Path,
    gt_path: &Path,
    vocabulary_paths: &[PathBuf],
    profile_path: Option<&Path>,
    json: Option<&Path>,
) -> Result<()> {
    use op3dsg_drivers::graph_json::GraphJson;
    use op3dsg_sim::eval::recall::{RecallEvaluator, Vocabulary, text_report};
    let read = |path: &Path| GraphJson::read(path).map_err(|e| anyhow::anyhow!("{e}"));
    let pred = read(pred_path)?;
    let gt = read(gt_path)?;
    let mut vocabulary = Vocabulary::from_ground_truths([&gt]);
    for path in vocabulary_paths {
        vocabulary.add_ground_truth(&read(path)?);
    }
    let mut encoder = load_text_encoder(profile_path)?;
    let mut evaluator = RecallEvaluator::new(&mut encoder, vocabulary);
    let report = evaluator
        .evaluate(&pred, &gt, None)
        .map_err(|e| anyhow::anyhow!("evaluating {} against {}: {e}", pred_path.display(), gt_path.display()))?;
    let mut text = format!(
        "{} ({} nodes, {} edges) against {} ({} nodes, {} edges), {} vocabulary labels\n",
        pred_path.display(),
        pred.nodes.len(),
        pred.edges.len(),
        gt_path.display(),
        gt.nodes.len(),
        gt.edges.len(),
        evaluator.vocabulary().node_labels.len()
    );
    text.push_str(&text_report(&report));
    write_output(None, &text)?;
    if let Some(path) = json {
        let mut out = serde_json::to_string_pretty(&report).context("serialising the report")?;
        out.push('\n');
        write_output(Some(path), &out)?;
    }
    Ok(())
}
