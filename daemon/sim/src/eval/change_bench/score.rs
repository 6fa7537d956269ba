//! Scoring a scene of the change benchmark against its ground truth (the rules are in the
//! module docs of [`super`]).

use glam::Vec3;
use op3dsg_runtime::fusion::change::{ChangeEvent, ChangeKind as EventKind};
use op3dsg_runtime::graph::SceneGraph;
use op3dsg_synthetic::{ChangeKind, InstanceKind, Scene};
use serde::Serialize;

use super::{AT_MARGIN_M, SceneRun, WITHIN_KEYFRAMES};

/// A fused centre is noisier than a node's place in the final graph: events are matched to a
/// box grown by this, metres.
const EVENT_MARGIN_M: f32 = 0.1;
/// A ghost is at no present object's box grown by this, metres.
const PRESENT_MARGIN_M: f32 = 0.02;

/// What became of one removal or move.
#[derive(Debug, Clone, Serialize)]
pub struct ChangeOutcome {
    /// `removed` or `moved`.
    pub kind: &'static str,
    /// Ground-truth instance.
    pub instance: u16,
    /// Its label.
    pub label: String,
    /// The run without change handling had a node at its old place at the end.
    pub mapped_before: bool,
    /// Reflected in the final graph, change handling on / off.
    pub reflected: [bool; 2],
    /// A move linked (the node at the new place has the id of the one at the old), on / off.
    pub linked: [bool; 2],
    /// First keyframe after the change that sees it.
    pub first_sight: Option<u64>,
    /// Keyframe of the `removed` / `moved` event from its old place (change handling on).
    pub updated: Option<u64>,
    /// A move: the nodes at the new place at the end (id, label), change handling on.
    pub at_new_place: Vec<(u32, String)>,
}

impl ChangeOutcome {
    /// Keyframes from first sight to the update (0 when the update came first).
    pub fn delay(&self) -> Option<u64> {
        Some(self.updated?.saturating_sub(self.first_sight?))
    }

    /// Reflected within [`WITHIN_KEYFRAMES`] of first sight (change handling on).
    pub fn within(&self) -> bool {
        self.reflected[0] && self.delay().is_some_and(|d| d <= WITHIN_KEYFRAMES)
    }
}

/// One control of a scene.
#[derive(Debug, Clone, Serialize)]
pub struct ControlOutcome {
    /// `occluder` or `depth hole`.
    pub kind: &'static str,
    /// The unchanged instance it makes hard to see.
    pub target: u16,
    /// Its label.
    pub label: String,
    /// The run without change handling mapped it.
    pub mapped: bool,
    /// A node at it was removed (change handling on).
    pub hit: bool,
}

/// One scene's score.
#[derive(Debug, Clone, Serialize)]
pub struct SceneScore {
    /// `kitchen seed 1`.
    pub name: String,
    /// Keyframes of the run.
    pub keyframes: u64,
    /// Removals and moves.
    pub changes: Vec<ChangeOutcome>,
    /// Additions found, on / off (only those mapped by either run count as seen).
    pub additions: Vec<[bool; 2]>,
    /// The occluder and depth-hole controls.
    pub controls: Vec<ControlOutcome>,
    /// The far-depth control is in the script.
    pub far_depth: bool,
    /// `removed` / `moved` events of unchanged nodes (change handling on).
    pub unchanged_removed: u32,
    /// Of them, after the change (under the far-depth control).
    pub unchanged_removed_after: u32,
    /// Nodes of the run without change handling not at a changed place.
    pub unchanged_nodes: u32,
    /// Ghosts at the end, on / off.
    pub ghosts: [u32; 2],
    /// Events of each kind, on: appeared, removed, moved.
    pub events: [u32; 3],
    /// Every event (change handling on), oldest first.
    pub log: Vec<EventRecord>,
    /// `Fusion::integrate` over the run, seconds, change handling on / off (same keyframes,
    /// one after the other on the same thread).
    pub fusion_s: [f64; 2],
}

/// One change event as the report lists it.
#[derive(Debug, Clone, Serialize)]
pub struct EventRecord {
    /// `appeared`, `removed`, `moved`.
    pub kind: &'static str,
    /// Node id.
    pub node: u32,
    /// Its label.
    pub label: String,
    /// Where it was, metres.
    pub from_m: Option<[f32; 3]>,
    /// Where it is, metres.
    pub to_m: Option<[f32; 3]>,
    /// The keyframe that decided it.
    pub keyframe: u64,
}

fn grown(b: (Vec3, Vec3), m: f32) -> (Vec3, Vec3) {
    (b.0 - Vec3::splat(m), b.1 + Vec3::splat(m))
}

fn inside(p: Vec3, b: (Vec3, Vec3)) -> bool {
    p.cmpge(b.0).all() && p.cmple(b.1).all()
}

fn node_at(graph: &SceneGraph, b: (Vec3, Vec3)) -> impl Iterator<Item = &op3dsg_runtime::graph::GraphNode> {
    let b = grown(b, AT_MARGIN_M);
    graph.nodes.iter().filter(move |n| inside(Vec3::from_array(n.centre_m), b))
}

fn present_boxes(scene: &Scene) -> Vec<(Vec3, Vec3)> {
    scene
        .present_instances()
        .filter(|i| i.kind == InstanceKind::Object)
        .map(|i| grown((i.box_min_m, i.box_max_m), PRESENT_MARGIN_M))
        .collect()
}

fn ghosts_at(graph: &SceneGraph, b: (Vec3, Vec3), present: &[(Vec3, Vec3)]) -> usize {
    node_at(graph, b).filter(|n| !present.iter().any(|p| inside(Vec3::from_array(n.centre_m), *p))).count()
}

fn from_at(e: &ChangeEvent, b: (Vec3, Vec3)) -> bool {
    e.from_m.is_some_and(|p| inside(Vec3::from_array(p), grown(b, EVENT_MARGIN_M)))
}

fn is_removal(e: &ChangeEvent) -> bool {
    matches!(e.kind, EventKind::Removed | EventKind::Moved)
}

/// The outcome of removal or move `index` (from `from`), and its ghosts on / off.
fn removal_outcome(
    run: &SceneRun,
    index: usize,
    from: (Vec3, Vec3),
    change_keyframe: u64,
    present: &[(Vec3, Vec3)],
) -> (ChangeOutcome, [u32; 2]) {
    let (on, off) = (&run.on, &run.off);
    let c = &run.applied[index];
    let sight = |new_place: bool| {
        run.first_sight.iter().find(|(i, n, _)| *i == index && *n == new_place).and_then(|(_, _, k)| *k)
    };
    // The map without change handling keeps a ghost there: it had mapped the thing.
    let mapped_before = ghosts_at(&off.graph, from, present) > 0;
    let ghost = [ghosts_at(&on.graph, from, present) as u32, ghosts_at(&off.graph, from, present) as u32];
    let moved = c.kind == ChangeKind::Moved;
    let at_new = |g: &SceneGraph| c.to.is_some_and(|to| node_at(g, to).next().is_some());
    let reflected = [ghost[0] == 0 && (!moved || at_new(&on.graph)), ghost[1] == 0 && (!moved || at_new(&off.graph))];
    let event = on.changes.iter().find(|e| is_removal(e) && e.keyframe >= change_keyframe && from_at(e, from));
    let linked_in = |run: &crate::batch::BatchRun| {
        let Some(to) = c.to else { return false };
        run.changes.iter().any(|e| {
            e.kind == EventKind::Moved
                && from_at(e, from)
                && e.to_m.is_some_and(|p| inside(Vec3::from_array(p), grown(to, EVENT_MARGIN_M)))
                && node_at(&run.graph, to).any(|n| n.id == e.node_id)
        })
    };
    // The update is the old place's: first sight of the old place.
    let first_sight = sight(false);
    let outcome = ChangeOutcome {
        kind: if moved { "moved" } else { "removed" },
        instance: c.instance,
        label: c.label.clone(),
        mapped_before,
        reflected,
        linked: if moved { [linked_in(on), linked_in(off)] } else { [false; 2] },
        first_sight,
        updated: event.map(|e| e.keyframe),
        at_new_place: c.to.map_or(Vec::new(), |to| node_at(&on.graph, to).map(|n| (n.id, n.label.clone())).collect()),
    };
    (outcome, ghost)
}

/// Scores one scene.
pub fn score_scene(run: &SceneRun) -> SceneScore {
    let (on, off) = (&run.on, &run.off);
    let present = present_boxes(&run.last);
    let change_frame = run.applied.iter().map(|c| c.frame).min().unwrap_or(u64::MAX);
    let change_keyframe =
        on.keyframe_poses.iter().position(|(seq, _)| *seq >= change_frame).map_or(u64::MAX, |k| k as u64 + 1);
    let box_of = |id: u16| run.initial.instance(id).map(|i| (i.box_min_m, i.box_max_m));
    // Places of changed things: old boxes (with parts) and new boxes.
    let mut changed_old: Vec<(Vec3, Vec3)> = Vec::new();
    let mut changed_new: Vec<(Vec3, Vec3)> = Vec::new();
    for c in &run.applied {
        if let Some(from) = c.from {
            changed_old.push(from);
            changed_old.extend(c.parts.iter().filter_map(|&p| box_of(p)));
        }
        if let Some(to) = c.to {
            changed_new.push(to);
        }
    }
    // An event from a changed instance's old place (a part of a moved object on a control
    // target, say) is the change's, not the control's.
    let at_changed_old = |e: &ChangeEvent| {
        e.from_m.is_some_and(|p| changed_old.iter().any(|b| inside(Vec3::from_array(p), grown(*b, EVENT_MARGIN_M))))
    };
    let mut changes = Vec::new();
    let mut additions = Vec::new();
    let mut controls = Vec::new();
    let mut ghosts = [0u32; 2];
    for (index, c) in run.applied.iter().enumerate() {
        match c.kind {
            ChangeKind::Removed | ChangeKind::Moved => {
                let Some(from) = c.from else { continue };
                let (outcome, ghost) = removal_outcome(run, index, from, change_keyframe, &present);
                ghosts[0] += ghost[0];
                ghosts[1] += ghost[1];
                changes.push(outcome);
            }
            ChangeKind::Added => {
                if let Some(to) = c.to {
                    additions.push([node_at(&on.graph, to).next().is_some(), node_at(&off.graph, to).next().is_some()]);
                }
            }
            ChangeKind::Occluder | ChangeKind::DepthHole => {
                let Some(target) = c.target else { continue };
                let Some(b) = box_of(target) else { continue };
                controls.push(ControlOutcome {
                    kind: if c.kind == ChangeKind::Occluder { "occluder" } else { "depth hole" },
                    target,
                    label: run.initial.instance(target).map(|i| i.label.clone()).unwrap_or_default(),
                    mapped: node_at(&off.graph, b).next().is_some(),
                    hit: on.changes.iter().any(|e| is_removal(e) && from_at(e, b) && !at_changed_old(e)),
                });
            }
            ChangeKind::FarDepth => {}
        }
    }
    let wrong: Vec<&ChangeEvent> = on
        .changes
        .iter()
        .filter(|e| is_removal(e))
        .filter(|e| e.keyframe < change_keyframe || !at_changed_old(e))
        .collect();
    let at_changed = |p: Vec3| changed_old.iter().chain(&changed_new).any(|b| inside(p, grown(*b, AT_MARGIN_M)));
    let unchanged_nodes = off.graph.nodes.iter().filter(|n| !at_changed(Vec3::from_array(n.centre_m))).count() as u32;
    let mut events = [0u32; 3];
    for e in &on.changes {
        events[match e.kind {
            EventKind::Appeared => 0,
            EventKind::Removed => 1,
            EventKind::Moved => 2,
        }] += 1;
    }
    SceneScore {
        name: format!("{} seed {}", run.room.as_str(), run.seed),
        keyframes: on.keyframes,
        changes,
        additions,
        controls,
        far_depth: run.applied.iter().any(|c| c.kind == ChangeKind::FarDepth),
        unchanged_removed: wrong.len() as u32,
        unchanged_removed_after: wrong.iter().filter(|e| e.keyframe >= change_keyframe).count() as u32,
        unchanged_nodes,
        ghosts,
        events,
        fusion_s: [on.timing.fusion.as_secs_f64(), off.timing.fusion.as_secs_f64()],
        log: on
            .changes
            .iter()
            .map(|e| EventRecord {
                kind: e.kind.as_str(),
                node: e.node_id,
                label: e.label.clone(),
                from_m: e.from_m,
                to_m: e.to_m,
                keyframe: e.keyframe,
            })
            .collect(),
    }
}

/// One preset's scenes, and the figures over them.
#[derive(Debug, Clone, Serialize)]
pub struct PresetReport {
    /// `clean`, `realistic`, `field`.
    pub preset: String,
    /// Per scene.
    pub scenes: Vec<SceneScore>,
}

/// `part / whole` as a percentage (100 when `whole` is 0).
pub fn percent(part: usize, whole: usize) -> f64 {
    if whole == 0 { 100.0 } else { 100.0 * part as f64 / whole as f64 }
}

impl PresetReport {
    /// Removals and moves that were mapped before they happened and whose old place the camera
    /// saw again within the trusted range, of `kind` (`None`: both).
    pub fn mapped(&self, kind: Option<&str>) -> Vec<&ChangeOutcome> {
        self.scenes
            .iter()
            .flat_map(|s| &s.changes)
            .filter(|c| c.mapped_before && c.first_sight.is_some() && kind.is_none_or(|k| c.kind == k))
            .collect()
    }

    /// Changes scripted but not mapped before they happened.
    pub fn not_mapped(&self) -> usize {
        self.scenes.iter().flat_map(|s| &s.changes).filter(|c| !c.mapped_before).count()
    }

    /// Changes mapped before whose old place the camera never saw again within the trusted
    /// range (left out of the rates), and of them how many were reflected anyway.
    pub fn not_seen_again(&self) -> (usize, usize) {
        let unseen: Vec<_> = self
            .scenes
            .iter()
            .flat_map(|s| &s.changes)
            .filter(|c| c.mapped_before && c.first_sight.is_none())
            .collect();
        (unseen.len(), unseen.iter().filter(|c| c.reflected[0]).count())
    }

    /// Reflected of `kind`, change handling on (`side` 0) or off (1): (count, of).
    pub fn reflected(&self, kind: Option<&str>, side: usize) -> (usize, usize) {
        let m = self.mapped(kind);
        (m.iter().filter(|c| c.reflected[side]).count(), m.len())
    }

    /// Moves linked: (count, of).
    pub fn linked(&self, side: usize) -> (usize, usize) {
        let m = self.mapped(Some("moved"));
        (m.iter().filter(|c| c.linked[side]).count(), m.len())
    }

    /// Within [`WITHIN_KEYFRAMES`] of first sight: (count, of).
    pub fn within(&self) -> (usize, usize) {
        let m = self.mapped(None);
        (m.iter().filter(|c| c.within()).count(), m.len())
    }

    /// Keyframes from first sight to update, p50 and p90 (nearest rank), over updated changes.
    pub fn delay_percentiles(&self) -> Option<(u64, u64)> {
        let mut d: Vec<u64> = self.mapped(None).iter().filter_map(|c| c.delay()).collect();
        if d.is_empty() {
            return None;
        }
        d.sort_unstable();
        let rank = |q: f64| d[((q * d.len() as f64).ceil() as usize).clamp(1, d.len()) - 1];
        Some((rank(0.5), rank(0.9)))
    }

    /// Additions found: (on, off, of).
    pub fn additions(&self) -> (usize, usize, usize) {
        let a: Vec<&[bool; 2]> = self.scenes.iter().flat_map(|s| &s.additions).collect();
        (a.iter().filter(|x| x[0]).count(), a.iter().filter(|x| x[1]).count(), a.len())
    }

    /// Unchanged nodes removed: (removed, unchanged nodes).
    pub fn unchanged_removed(&self) -> (u32, u32) {
        self.scenes.iter().fold((0, 0), |(r, n), s| (r + s.unchanged_removed, n + s.unchanged_nodes))
    }

    /// Controls of `kind` hit: (hit, mapped targets).
    pub fn controls(&self, kind: &str) -> (usize, usize) {
        let c: Vec<_> = self.scenes.iter().flat_map(|s| &s.controls).filter(|c| c.kind == kind && c.mapped).collect();
        (c.iter().filter(|c| c.hit).count(), c.len())
    }

    /// Ghosts at the end: on, off.
    pub fn ghosts(&self) -> [u32; 2] {
        self.scenes.iter().fold([0, 0], |a, s| [a[0] + s.ghosts[0], a[1] + s.ghosts[1]])
    }
}
