//! `op3dsg eval`: a predicted graph scored against a ground-truth graph with the benchmark's
//! protocol, and the text encoder it (and `bench quality`) ranks labels with.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

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
    // A ground truth written for a run (`op3dsg gt --frames`) scores what the run saw.
    let seen: std::collections::HashMap<u32, Option<u32>> = gt.nodes.iter().map(|n| (n.id, n.seen_keyframes)).collect();
    let for_run = seen.values().any(Option::is_some);
    let scored = |id: u32| op3dsg_sim::eval::coverage::is_scored(seen.get(&id).copied().flatten());
    let report = evaluator
        .evaluate(&pred, &gt, for_run.then_some(&scored as &dyn Fn(u32) -> bool))
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
    if for_run {
        let n = gt.nodes.iter().filter(|n| scored(n.id)).count();
        let _ = std::fmt::Write::write_fmt(
            &mut text,
            format_args!(
                "coverage: {n} of {} ground-truth nodes seen in at least 3 keyframes of the run and scored; recall is over these\n",
                gt.nodes.len()
            ),
        );
    }
    text.push_str(&text_report(&report));
    super::write_report(&text, json, &report)
}
