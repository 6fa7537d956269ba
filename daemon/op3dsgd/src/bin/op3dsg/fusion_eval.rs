//! `op3dsg fusion-eval`: one synthetic room through the batch pipeline, its fused graph scored
//! against the room's ground truth (for tuning fusion).

use std::path::Path;

use anyhow::{Context, Result, bail};

use super::write_output;

/// `op3dsg fusion-eval`: a batch run of the profile and its score against ground truth.
pub(super) fn fusion_eval(
    profile_path: Option<&Path>,
    overrides: &[String],
    details: bool,
    check: bool,
    json: Option<&Path>,
) -> Result<()> {
    use op3dsg_sim::eval::fusion_match::{self, MatchCriteria, QualityTargets};
    let loaded = op3dsg_sim::load_profile(profile_path, overrides).map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
    let profile = loaded.profile;
    let synthetic = op3dsg_sim::backends::synthetic_config(&profile)?;
    let name = format!("{} seed {}", synthetic.room.as_str(), synthetic.seed);
    let run = op3dsg_sim::batch::run(&profile, &Default::default()).with_context(|| format!("batch run of {name}"))?;
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let report = fusion_match::match_run(&run, &criteria);
    let mut text = fusion_match::table_header();
    text.push_str(&fusion_match::table_row(&name, run.keyframes, &report));
    text.push_str(fusion_match::TABLE_LEGEND);
    text.push('\n');
    let t = &run.timing;
    text.push_str(&format!(
        "{} frames, {} keyframes, {} detections in {:.1} s (source {:.1} s, detect {:.1} s, fusion {:.1} s)\n",
        run.frames,
        run.keyframes,
        run.detections,
        t.total.as_secs_f64(),
        t.source.as_secs_f64(),
        t.detect.as_secs_f64(),
        t.fusion.as_secs_f64() + t.build_graph.as_secs_f64()
    ));
    text.push_str(&format!(
        "map: {} nodes ({} published, the rest pending confirmation), {:.1} MiB\n",
        run.map_nodes,
        run.graph.nodes.len(),
        op3dsg_runtime::stats::mib(run.map_memory_bytes as u64)
    ));
    let failures = QualityTargets::default().failures(&report);
    if failures.is_empty() {
        text.push_str("quality targets: met\n");
    } else {
        text.push_str(&format!("quality targets missed: {}\n", failures.join("; ")));
    }
    if details {
        text.push_str(&fusion_match::details(&report));
    }
    write_output(None, &text)?;
    if let Some(path) = json {
        let graph = serde_json::to_string_pretty(&run.graph.to_json("fusion-eval"))?;
        write_output(Some(path), &graph)?;
    }
    if check && !failures.is_empty() {
        bail!("{name}: quality targets missed");
    }
    Ok(())
}
