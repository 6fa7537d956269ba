//! The change benchmark behind `op3dsg bench change`: seeded scenes of the four benchmark rooms,
//! each mapped over one lap of its camera path, changed by a change script
//! (`[[source.synthetic.changes]]`, [`op3dsg_synthetic::change`]) at the start of the second lap
//! and looked at again, run through the batch pipeline with change handling on and, on the same
//! keyframes and detections, off (`fusion.change.enabled = false`: the map only grows).
//!
//! ## Scenes and scripts
//!
//! Scene `i` is the quality benchmark's ([`crate::eval::benchmark::scene`]: room `i mod 4`, seed
//! `i / 4 + 1`). Its script ([`scene_script`]) is drawn from the room with a generator seeded by
//! room and seed, never by looking at what fusion does, and holds, at lap 1 (fixtures such as
//! doors, windows and lights are never changed):
//!
//! | entry | what |
//! |---|---|
//! | move | a small object (one standing on another) onto another surface |
//! | remove | another small object (one without parts first) |
//! | remove | an object with parts (its parts go with it) |
//! | add | a box onto a surface |
//! | control: occluder | a box on the floor in front of an unchanged object, hiding it |
//! | control: depth hole | no depth on an unchanged object's pixels |
//! | control: far depth | depth beyond 3 m (the trusted range's end) is garbage |
//!
//! An entry the room cannot take (no free spot on the surface, no candidate) is left out; the
//! report counts what was scripted.
//!
//! ## Scoring (ground truth against the final graph and the change events)
//!
//! A node *is at* a ground-truth box when its centre lies in the box grown by
//! [`AT_MARGIN_M`]; a node at a removed or moved object's old box, and at no present object's
//! box, is a **ghost**. A change counts only when the run without change handling mapped it
//! before it happened (a node at its old place at the end: the map keeps everything); the rest
//! are "not mapped before".
//!
//! - **removal reflected**: no ghost at its old place at the end;
//! - **move reflected**: no ghost at the old place and a node at the new one; **linked**: a
//!   `moved` event from the old place to the new, and the node at the new place has the id the
//!   event names (the identity rule: a moved object keeps its id);
//! - **addition found**: a node at the added object's box;
//! - **keyframes to update**: from the first keyframe after the change that *sees* the changed
//!   place (of a move: either place) to the keyframe of the `removed` or `moved` event from the
//!   old place. *Sees*: at least half of 9 points of the box (its centre and its corners pulled a
//!   quarter towards it) project into the image at 0.3–3 m with the line of sight clear (exact
//!   depth, rendered from the true pose of the scene as it is then, at least the point's range
//!   less 5 cm). This reads the renderer, not fusion.
//! - **within 10**: reflected, and updated within [`WITHIN_KEYFRAMES`] keyframes of first sight;
//! - **unchanged removed**: `removed` / `moved` events whose old place is at no changed
//!   instance (removed or moved objects and their parts), against the nodes of the run without
//!   change handling that are not at a changed place;
//! - **controls**: a control's target is *hit* when a `removed` / `moved` event's old place lies
//!   in the target's box grown by [`AT_MARGIN_M`].
//!
//! | file | what |
//! |---|---|
//! | this file | the scenes, their scripts and runs ([`run_scene`], [`run_scenes`]) |
//! | `score.rs` | scoring a scene ([`score_scene`]) and a preset ([`PresetReport`]) |
//! | `sight.rs` | the first keyframe that sees a place ([`sight::first_sight`]) |
//! | `text.rs` | the printed report ([`text`]) |

mod score;
mod sight;
mod text;

pub use score::{PresetReport, SceneScore, score_scene};
pub use text::{goals_met, text};

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use op3dsg_runtime::config::Profile;
use op3dsg_synthetic::{AppliedChange, InstanceInfo, InstanceKind, RoomKind, Scene, SceneChange, SyntheticConfig};

use crate::backends::{set_synthetic_config, synthetic_config};
use crate::batch::{self, BatchRun, Lane, VisibilityThresholds};

/// A node is at a ground-truth box when its centre lies in the box grown by this, metres.
pub const AT_MARGIN_M: f32 = 0.05;
/// The goal's window: a change reflected within this many keyframes of first sight.
pub const WITHIN_KEYFRAMES: u64 = 10;
/// The far-depth control's range: depth beyond it is garbage, metres.
pub const FAR_DEPTH_CONTROL_M: f32 = 3.0;
/// Labels the scripts never change or use as controls (built into the room).
const FIXTURES: [&str; 7] = ["door", "window", "ceiling light", "wall light", "mirror", "radiator", "power strip"];
/// The presets the benchmark runs by default.
pub const PRESETS: [&str; 3] = ["clean", "realistic", "field"];

/// One scene's runs: change handling on and off, on the same keyframes, with its ground truth.
#[derive(Debug)]
pub struct SceneRun {
    /// Room.
    pub room: RoomKind,
    /// Seed.
    pub seed: u64,
    /// Change handling on.
    pub on: BatchRun,
    /// Change handling off.
    pub off: BatchRun,
    /// The room before the script.
    pub initial: Scene,
    /// The room after it.
    pub last: Scene,
    /// What the script did.
    pub applied: Vec<AppliedChange>,
    /// Per changed place (index into `applied`, and whether the new place of a move or an
    /// addition): the first keyframe (1-based, fusion's counter) after the change that sees it.
    pub first_sight: Vec<(usize, bool, Option<u64>)>,
}

/// The script of `room` / `seed` (see the module docs), checked against the room: every
/// entry applies. `frame_count` and `rate_hz` as the run's.
pub fn scene_script(base: &SyntheticConfig) -> Vec<SceneChange> {
    let initial = Scene::generate(base.room, base.seed);
    let mut rng = ChaCha8Rng::seed_from_u64(base.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ base.room as u64);
    // Fixtures stay where they are: people move things, not doors.
    let objects: Vec<&InstanceInfo> = initial
        .instances()
        .iter()
        .filter(|i| i.kind == InstanceKind::Object && !FIXTURES.contains(&i.label.as_str()))
        .collect();
    let carries = |id: u16| initial.edges().iter().any(|e| e.relation == "on" && e.target == id);
    let support = |id: u16| initial.edges().iter().find(|e| e.relation == "on" && e.source == id).map(|e| e.target);
    let has_parts = |id: u16| initial.instances().iter().any(|i| i.parent == Some(id));
    let extent = |i: &InstanceInfo| (i.box_max_m - i.box_min_m).max_element();
    // Things standing on another object that carry nothing: without parts first.
    let mut small: Vec<u16> = objects
        .iter()
        .filter(|i| support(i.id).is_some() && !carries(i.id) && extent(i) <= 0.6)
        .map(|i| i.id)
        .collect();
    let mut big: Vec<u16> = objects.iter().filter(|i| has_parts(i.id) && !carries(i.id)).map(|i| i.id).collect();
    let mut surfaces: Vec<u16> = objects
        .iter()
        .filter(|i| {
            let size = i.box_max_m - i.box_min_m;
            (0.3..=1.3).contains(&i.box_max_m.z) && size.x >= 0.3 && size.y >= 0.3 && support(i.id).is_none()
        })
        .map(|i| i.id)
        .collect();
    small.shuffle(&mut rng);
    small.sort_by_key(|&id| has_parts(id));
    big.shuffle(&mut rng);
    surfaces.shuffle(&mut rng);
    let at = |c: SceneChange| SceneChange { at_lap: Some(1), ..c };
    let mut script: Vec<SceneChange> = Vec::new();
    let mut touched: Vec<u16> = Vec::new();
    let fits = |script: &[SceneChange], entry: &SceneChange| {
        let mut trial = base.clone();
        trial.changes = script.to_vec();
        trial.changes.push(entry.clone());
        trial.final_scene().is_ok()
    };
    let push = |script: &mut Vec<SceneChange>, touched: &mut Vec<u16>, entry: SceneChange, ids: &[u16]| {
        if fits(script, &entry) {
            script.push(entry);
            touched.extend_from_slice(ids);
            true
        } else {
            false
        }
    };
    'moved: for &id in &small {
        for &onto in &surfaces {
            if Some(onto) == support(id) || touched.contains(&onto) {
                continue;
            }
            let entry = at(SceneChange { move_instance: Some(id), onto: Some(onto), ..Default::default() });
            if push(&mut script, &mut touched, entry, &[id, onto]) {
                break 'moved;
            }
        }
    }
    for pool in [&small, &big] {
        if let Some(&id) = pool.iter().find(|id| !touched.contains(id)) {
            push(&mut script, &mut touched, at(SceneChange { remove: Some(id), ..Default::default() }), &[id]);
        }
    }
    for &onto in &surfaces {
        if touched.contains(&onto) {
            continue;
        }
        let entry = at(SceneChange { add: Some("box".to_owned()), onto: Some(onto), ..Default::default() });
        if push(&mut script, &mut touched, entry, &[onto]) {
            break;
        }
    }
    // Controls on unchanged objects (neither changed nor a surface something is put on), those
    // that carry nothing first.
    let mut unchanged: Vec<u16> =
        objects.iter().filter(|i| !touched.contains(&i.id) && extent(i) >= 0.25).map(|i| i.id).collect();
    unchanged.shuffle(&mut rng);
    unchanged.sort_by_key(|&id| carries(id));
    let mut controls = unchanged.into_iter();
    for target in controls.by_ref() {
        let entry = at(SceneChange { add: Some("box".to_owned()), in_front_of: Some(target), ..Default::default() });
        if push(&mut script, &mut touched, entry, &[target]) {
            break;
        }
    }
    for target in controls {
        if push(
            &mut script,
            &mut touched,
            at(SceneChange { hide_depth: Some(target), ..Default::default() }),
            &[target],
        ) {
            break;
        }
    }
    let far = at(SceneChange { degrade_depth_beyond_m: Some(FAR_DEPTH_CONTROL_M), ..Default::default() });
    push(&mut script, &mut touched, far, &[]);
    script
}

/// `base` on `room` / `seed` for two laps with its script; the run's synthetic config.
pub fn scene_profile(base: &Profile, room: RoomKind, seed: u64) -> Result<(Profile, SyntheticConfig), String> {
    let name = format!("{} seed {seed}", room.as_str());
    let mut profile = base.clone();
    let mut synthetic = synthetic_config(&profile).map_err(|e| format!("{name}: {e}"))?;
    synthetic.room = room;
    synthetic.seed = seed;
    synthetic.changes.clear();
    let scene = Scene::generate(room, seed);
    let lap = op3dsg_synthetic::CameraPath::new(&scene, seed, synthetic.frame_rate_hz).period_frames();
    synthetic.frame_count = Some(2 * lap);
    synthetic.changes = scene_script(&synthetic);
    set_synthetic_config(&mut profile, &synthetic);
    Ok((profile, synthetic))
}

/// Runs one scene with change handling on and off.
pub fn run_scene(base: &Profile, room: RoomKind, seed: u64) -> Result<SceneRun, String> {
    let name = format!("{} seed {seed}", room.as_str());
    let (profile, synthetic) = scene_profile(base, room, seed)?;
    let source = op3dsg_synthetic::SyntheticSource::new(&synthetic).map_err(|e| format!("{name}: {e}"))?;
    let truth = source.ground_truth();
    let up = profile.world.up_axis;
    let mut off_config = profile.fusion.clone();
    off_config.change.enabled = false;
    let on_config = {
        let mut c = profile.fusion.clone();
        c.change.enabled = true;
        c
    };
    let lane = Lane {
        detector: None,
        fusions: vec![op3dsg_runtime::fusion::build(&on_config, up), op3dsg_runtime::fusion::build(&off_config, up)],
    };
    let mut runs = batch::run_lanes(&profile, &VisibilityThresholds::default(), vec![lane])
        .map_err(|e| format!("{name}: {e}"))?
        .pop()
        .unwrap_or_default();
    let (Some(off), Some(on)) = (runs.pop(), runs.pop()) else {
        return Err(format!("{name}: the batch run gave fewer runs than fusions"));
    };
    let initial = truth.initial.clone().unwrap_or_else(|| source.scene().clone());
    let first_sight = sight::first_sights(&source, &truth.changes, &on.keyframe_poses, &synthetic.intrinsics);
    Ok(SceneRun { room, seed, on, off, initial, last: truth.scene, applied: truth.changes, first_sight })
}

/// Runs scenes `0..scenes` on `threads` threads, in scene order; `progress` after each.
pub fn run_scenes(
    base: &Profile,
    scenes: usize,
    threads: usize,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Vec<SceneRun>, String> {
    crate::eval::parallel::in_order(scenes, threads, "op3dsg-change", &|i| {
        let (room, seed) = crate::eval::benchmark::scene(i);
        let result = run_scene(base, room, seed);
        progress(&format!("{} seed {seed}", room.as_str()));
        result
    })
}

#[cfg(test)]
mod tests;
