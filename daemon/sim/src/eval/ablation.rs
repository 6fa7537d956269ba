//! The colour-feature ablation: part association on the `colour_panel` scene with fusion's
//! colour-distribution similarity on and off.
//!
//! The scene (`RoomKind::ColourPanel`) has rows of same-label knobs and push buttons 0.5–1 cm
//! apart, neighbours in different saturated colours, seen from 0.55–2.1 m with depth noise and
//! the realistic oracle. Geometry and labels alone can confuse neighbours there; colour should
//! not. The figures that tell: wrong merges across materials (lower is better), matched
//! fraction and fragmentation of parts.
//!
//! Measured with `SimpleFusion` (box overlap: at least 25 % of a detection's points inside the
//! node's box grown by 5 mm) the panel gives no wrong merge at all: exact poses and a strict
//! geometric test keep 5 mm gaps apart. The scene is aimed at similarity-threshold association
//! (the paper's `S^p`), where same-label neighbours score a semantic similarity near 1 and
//! geometry alone must hold them apart.
//!
//! The two fusions come from factories ([`FusionFactory`]) so that the benchmark can reuse
//! [`run_colour_ablation`] with any pair; [`fusion_with_colour`] and [`fusion_without_colour`]
//! are the defaults.
//!
//! ```no_run
//! use op3dsg_sim::eval::ablation::*;
//! let profile = colour_panel_profile(&op3dsg_runtime::config::load(None, &[]).unwrap().profile, 1, 600).unwrap();
//! let result = run_colour_ablation(&profile, &fusion_with_colour, &fusion_without_colour).unwrap();
//! print!("{}", ablation_table(&result));
//! ```

use std::fmt::Write as _;

use op3dsg_synthetic::RoomKind;

use super::fusion_match::{FusionMatchReport, KindReport, MatchCriteria, match_run};
use crate::backends::{oracle_config, set_oracle_config, set_synthetic_config, synthetic_config};
use crate::batch::{BatchError, BatchRun, VisibilityThresholds, run_with_fusions};
use crate::oracle::OracleConfig;
use op3dsg_runtime::backend::StartError;
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::fusion::Fusion;

/// Makes a fusion for a profile.
pub type FusionFactory = dyn Fn(&Profile) -> Box<dyn Fusion>;

/// The profile's OP3DSG fusion with its colour features on.
pub fn fusion_with_colour(profile: &Profile) -> Box<dyn Fusion> {
    op3dsg_runtime::fusion::build(&profile.fusion, profile.world.up_axis)
}

/// The profile's fusion with its colour features off (`fusion.colour_features = false`).
pub fn fusion_without_colour(profile: &Profile) -> Box<dyn Fusion> {
    let mut p = profile.clone();
    p.fusion.colour_features = false;
    op3dsg_runtime::fusion::build(&p.fusion, p.world.up_axis)
}

/// `base` turned into the ablation's setting: the `colour_panel` scene with `seed`, `frames`
/// frames, depth noise on (the base profile's model when `base` has none) and the realistic
/// oracle (its seed kept).
pub fn colour_panel_profile(base: &Profile, seed: u64, frames: u64) -> Result<Profile, StartError> {
    let mut profile = base.clone();
    let mut synthetic = synthetic_config(base)?;
    synthetic.room = RoomKind::ColourPanel;
    synthetic.seed = seed;
    synthetic.frame_count = Some(frames);
    if synthetic.depth_noise.is_none() {
        synthetic.depth_noise = Some(Default::default());
    }
    set_synthetic_config(&mut profile, &synthetic);
    let oracle_seed = oracle_config(base)?.seed;
    set_oracle_config(&mut profile, &OracleConfig { seed: oracle_seed, ..OracleConfig::realistic() });
    Ok(profile)
}

/// One side of the ablation.
#[derive(Debug, Clone)]
pub struct AblationSide {
    /// The batch run.
    pub run: BatchRun,
    /// Its match against ground truth.
    pub report: FusionMatchReport,
}

impl AblationSide {
    /// The part figures.
    pub fn parts(&self) -> &KindReport {
        &self.report.parts
    }
}

/// Both sides.
#[derive(Debug, Clone)]
pub struct AblationResult {
    /// Colour features on.
    pub with_colour: AblationSide,
    /// Colour features off.
    pub without_colour: AblationSide,
}

/// Runs `profile` (normally from [`colour_panel_profile`]) once, feeding the same keyframes and
/// detections to both fusions, and matches both graphs against the scene's ground truth, with the default visibility thresholds and
/// matching criteria (`min_observations` from the profile).
pub fn run_colour_ablation(
    profile: &Profile,
    with_colour: &FusionFactory,
    without_colour: &FusionFactory,
) -> Result<AblationResult, BatchError> {
    let visibility = VisibilityThresholds::default();
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let [with, without] = run_with_fusions(profile, &visibility, [with_colour(profile), without_colour(profile)])?;
    let side = |run: BatchRun| {
        let report = match_run(&run, &criteria);
        AblationSide { run, report }
    };
    Ok(AblationResult { with_colour: side(with), without_colour: side(without) })
}

/// The part figures of both sides, one line each, under a header.
pub fn ablation_table(result: &AblationResult) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<16} {:>4} {:>5} {:>7} {:>5} {:>4} {:>12} {:>11} {:>4}",
        "colour features", "kf", "parts", "match%", "frag", "fp", "wrong merges", "across mat.", "gt"
    );
    for (name, side) in [("on", &result.with_colour), ("off", &result.without_colour)] {
        let p = side.parts();
        let _ = writeln!(
            s,
            "{:<16} {:>4} {:>5} {:>7} {:>5} {:>4} {:>12} {:>11} {:>4}",
            name,
            side.run.keyframes,
            p.eligible,
            p.matched_fraction().map_or_else(|| "-".to_owned(), |f| format!("{:.1}", f * 100.0)),
            p.fragmentation().map_or_else(|| "-".to_owned(), |f| format!("{f:.2}")),
            p.false_positives,
            p.wrong_merge_nodes,
            p.wrong_merges_across_materials,
            p.wrongly_merged_gt,
        );
    }
    s.push_str(
        "parts: eligible part nodes; wrong merges: fused parts spanning >= 2 same-label parts; across mat.: of those, \
         spanning different colours; gt: ground-truth parts involved\n",
    );
    s
}
