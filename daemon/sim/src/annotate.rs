//! Ground truth for a recorded RGB-D sequence from hand-drawn 2D boxes (`op3dsg annotate`).
//!
//! A person draws, on a few frames of a recording in the TUM RGB-D layout (read by the replay
//! source, [`op3dsg_drivers::replay`]), a pixel box around each object and part they see. This
//! module lifts the boxes to world-frame 3D boxes and writes an `op3dsg.graph/1` ground-truth
//! graph, the form `op3dsg gt` writes and `op3dsg eval --gt` reads.
//!
//! # The annotation file (TOML, schema `op3dsg.annotation/1`)
//!
//! ```toml
//! schema = "op3dsg.annotation/1"
//! # The recording; relative to this file's folder (`op3dsg annotate --sequence` overrides it).
//! sequence = "../../../../../shared/data/rgbd/icl_livingroom1"
//! # Who drew the boxes and how: copied into the graph's `source`.
//! annotator = "an op3dsg engineer, by hand"
//!
//! [lift]                      # all optional; the defaults shown
//! band_m = 0.25               # keep depths within +-band_m of the box's reference depth
//! reference_percentile = 50   # the reference depth: this percentile of the box's depths
//! box_percentiles = [2, 98]   # the 3D box: these percentiles of the fused points, per axis
//! pixel_step = 2              # back-project every pixel_step-th pixel in x and y
//! min_points = 30             # fewer kept pixels in one box is an error
//!
//! [[node]]
//! id = 1
//! label = "cabinet / sideboard"   # `a / b`: either name is correct
//! kind = "object"                 # object | part
//! boxes = [
//!   { frame = 60, box = [384, 205, 640, 385] },   # [x0, y0, x1, y1] pixels, x1/y1 exclusive
//! ]
//!
//! [[node]]
//! id = 2
//! label = "cabinet door"
//! kind = "part"
//! parent = 1                      # a part names its object's id
//! affordances = ["hook_pull"]     # optional; canonical names (op3dsg_ipc_types::AFFORDANCES)
//! band_m = 0.1                    # optional: band_m and reference_percentile per node ...
//! boxes = [
//!   { frame = 60, box = [470, 240, 555, 380] },
//!   { frame = 85, box = [474, 272, 602, 410], band_m = 0.05 },   # ... and per box
//! ]
//! ```
//!
//! `frame` is the 0-based number of the frame as the replay source delivers it (the line of
//! the associated colour image in `rgb.txt`; for ICL-NUIM the image's own number, `00060.jpg`).
//! A node may have several boxes on one frame (a chair's seat and its legs).
//!
//! # How a box becomes points
//!
//! For every box, the depth pixels inside it (every `pixel_step`-th in x and y, depth > 0) are
//! the candidates. A hand-drawn box also holds what is behind the object (the wall behind a
//! chair's frame, the floor under it) and in front of it; those are rejected by a **depth band**:
//! the box's reference depth is the `reference_percentile`-th percentile of the candidates'
//! depths (the median by default, which is the object where it fills most of the box), and only
//! the pixels within `band_m` of it are kept. For an object the box is mostly background of (a
//! see-through chair frame), a lower percentile picks the nearer surface. The kept pixels are
//! back-projected with the recording's intrinsics and moved into the world with the frame's
//! `world_from_camera` pose, and the points of all of a node's boxes over all frames are fused.
//! The node's box is, per world axis, the `box_percentiles` of the fused points (2 % and 98 %
//! by default, so a few stray pixels at depth edges do not stretch it); its centre is the box's
//! centre. A part gets a `part of` edge to its object (origin `ground_truth`).
//!
//! [`preview`] draws the boxes and tints the kept pixels on each annotated frame, so the
//! annotator sees what was lifted.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

use glam::DVec3;
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::graph_json::{EdgeJson, GraphJson, NodeJson};
use op3dsg_drivers::replay::{PlaybackMode, ReplayConfig, ReplaySource};
use op3dsg_drivers::source::{FrameSource, SourceStatus};
use serde::Deserialize;

/// Schema tag of the annotation file.
pub const ANNOTATION_SCHEMA: &str = "op3dsg.annotation/1";

/// An annotation file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Annotation {
    /// Always [`ANNOTATION_SCHEMA`].
    pub schema: String,
    /// The recording (TUM RGB-D layout), relative to the annotation file's folder.
    #[serde(default)]
    pub sequence: Option<PathBuf>,
    /// Who annotated, and how.
    pub annotator: String,
    /// Lifting parameters.
    #[serde(default)]
    pub lift: LiftParams,
    /// Objects and parts.
    #[serde(rename = "node")]
    pub nodes: Vec<AnnotatedNode>,
}

/// `[lift]`: how boxes become points and points a box (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LiftParams {
    /// Half-width of the depth band around the reference depth, metres.
    pub band_m: f64,
    /// Percentile (0..=100) of a box's depths that is its reference depth.
    pub reference_percentile: f64,
    /// Percentiles (low, high) of the fused points that bound the 3D box, per axis.
    pub box_percentiles: [f64; 2],
    /// Back-project every this many pixels in x and in y.
    pub pixel_step: u32,
    /// Fewest kept pixels a box may give.
    pub min_points: usize,
}

impl Default for LiftParams {
    fn default() -> Self {
        Self { band_m: 0.25, reference_percentile: 50.0, box_percentiles: [2.0, 98.0], pixel_step: 2, min_points: 30 }
    }
}

/// One object or part of the annotation.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnnotatedNode {
    /// Unique id; becomes the ground-truth node id.
    pub id: u32,
    /// Label (`a / b` for alternatives).
    pub label: String,
    /// `object` or `part`.
    pub kind: String,
    /// The object a part belongs to.
    #[serde(default)]
    pub parent: Option<u32>,
    /// Canonical affordance names.
    #[serde(default)]
    pub affordances: Vec<String>,
    /// Overrides `[lift].band_m` for this node.
    #[serde(default)]
    pub band_m: Option<f64>,
    /// Overrides `[lift].reference_percentile` for this node.
    #[serde(default)]
    pub reference_percentile: Option<f64>,
    /// Free text (what the box holds, why a setting).
    #[serde(default)]
    pub note: Option<String>,
    /// The 2D boxes.
    pub boxes: Vec<FrameBox>,
}

/// One 2D box on one frame.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameBox {
    /// Frame number (0-based, as the replay source delivers frames).
    pub frame: u64,
    /// `[x0, y0, x1, y1]`, pixels; x1 and y1 exclusive.
    #[serde(rename = "box")]
    pub rect: [u32; 4],
    /// Overrides the node's `band_m` for this box.
    #[serde(default)]
    pub band_m: Option<f64>,
    /// Overrides the node's `reference_percentile` for this box.
    #[serde(default)]
    pub reference_percentile: Option<f64>,
}

/// What one box gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxLift {
    /// Node id.
    pub node: u32,
    /// Index of the box in the node's `boxes`.
    pub index: usize,
    /// Frame number.
    pub frame: u64,
    /// Sampled pixels with depth.
    pub with_depth: usize,
    /// Pixels kept by the depth band.
    pub kept: usize,
    /// Reference depth, metres.
    pub reference_m: f64,
}

/// A lifted node: its ground-truth box and the points it came from.
#[derive(Debug, Clone)]
pub struct NodeLift {
    /// Node id.
    pub id: u32,
    /// Fused world points.
    pub points: usize,
    /// Frames its boxes are on.
    pub frames: usize,
    /// Box minimum corner, world, metres.
    pub box_min_m: [f32; 3],
    /// Box maximum corner, world, metres.
    pub box_max_m: [f32; 3],
}

/// The result of [`lift`]: the ground-truth graph and what each node and box gave.
#[derive(Debug, Clone)]
pub struct Lifted {
    /// The ground truth.
    pub graph: GraphJson,
    /// Per node, in file order.
    pub nodes: Vec<NodeLift>,
    /// Per box, in file order.
    pub boxes: Vec<BoxLift>,
}

impl Annotation {
    /// Reads and checks an annotation file; errors name the file and the field
    /// (`annotation.toml: node[3] (id 4 "vase").boxes[1].box: x1 700 is past the image width 640`
    /// comes from [`lift`], which knows the image size).
    pub fn read(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let value: toml::Value = toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        let annotation: Self = serde_path_to_error::deserialize(value)
            .map_err(|e| format!("{}: {}: {}", path.display(), e.path(), e.inner()))?;
        annotation.check().map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(annotation)
    }

    /// The recording's folder: `sequence` relative to the folder of `annotation_path`.
    pub fn sequence_dir(&self, annotation_path: &Path) -> Option<PathBuf> {
        let sequence = self.sequence.as_ref()?;
        Some(annotation_path.parent().unwrap_or(Path::new("")).join(sequence))
    }

    /// Checks everything that needs no recording: schema, parameters, unique ids, kinds, parents,
    /// affordances, box corners in order.
    pub fn check(&self) -> Result<(), String> {
        if self.schema != ANNOTATION_SCHEMA {
            return Err(format!("schema: expected \"{ANNOTATION_SCHEMA}\", found \"{}\"", self.schema));
        }
        check_params(&self.lift, "lift")?;
        if self.nodes.is_empty() {
            return Err("node: no [[node]] entries".to_owned());
        }
        let kinds: HashMap<u32, &str> = self.nodes.iter().map(|n| (n.id, n.kind.as_str())).collect();
        let mut ids = BTreeSet::new();
        for (i, node) in self.nodes.iter().enumerate() {
            let at = node_path(i, node);
            if !ids.insert(node.id) {
                return Err(format!("{at}.id: duplicate id {}", node.id));
            }
            if node.label.trim().is_empty() {
                return Err(format!("{at}.label: empty"));
            }
            match (node.kind.as_str(), node.parent) {
                ("object", None) => {}
                ("object", Some(_)) => return Err(format!("{at}.parent: an object has no parent (only parts do)")),
                ("part", None) => return Err(format!("{at}.parent: a part must name its object's id")),
                ("part", Some(parent)) => match kinds.get(&parent) {
                    Some(&"object") => {}
                    Some(kind) => return Err(format!("{at}.parent: node {parent} is a {kind}, not an object")),
                    None => return Err(format!("{at}.parent: no node with id {parent}")),
                },
                (kind, _) => return Err(format!("{at}.kind: expected \"object\" or \"part\", found \"{kind}\"")),
            }
            for (a, name) in node.affordances.iter().enumerate() {
                if !op3dsg_ipc_types::AFFORDANCES.contains(&name.as_str()) {
                    return Err(format!(
                        "{at}.affordances[{a}]: unknown affordance \"{name}\" (expected one of {:?})",
                        op3dsg_ipc_types::AFFORDANCES
                    ));
                }
            }
            let params = node_params(&self.lift, node);
            check_params(&params, &at)?;
            if node.boxes.is_empty() {
                return Err(format!("{at}.boxes: no boxes"));
            }
            for (b, frame_box) in node.boxes.iter().enumerate() {
                check_params(&box_params(&params, frame_box), &format!("{at}.boxes[{b}]"))?;
                let [x0, y0, x1, y1] = frame_box.rect;
                if x0 >= x1 || y0 >= y1 {
                    return Err(format!(
                        "{at}.boxes[{b}].box: expected [x0, y0, x1, y1] with x0 < x1 and y0 < y1, found {:?}",
                        frame_box.rect
                    ));
                }
            }
        }
        Ok(())
    }
}

fn node_path(i: usize, node: &AnnotatedNode) -> String {
    format!("node[{i}] (id {} \"{}\")", node.id, node.label)
}

fn node_params(lift: &LiftParams, node: &AnnotatedNode) -> LiftParams {
    LiftParams {
        band_m: node.band_m.unwrap_or(lift.band_m),
        reference_percentile: node.reference_percentile.unwrap_or(lift.reference_percentile),
        ..*lift
    }
}

/// The parameters of one box: the node's, with the box's own band and reference percentile.
fn box_params(node_params: &LiftParams, frame_box: &FrameBox) -> LiftParams {
    LiftParams {
        band_m: frame_box.band_m.unwrap_or(node_params.band_m),
        reference_percentile: frame_box.reference_percentile.unwrap_or(node_params.reference_percentile),
        ..*node_params
    }
}

fn check_params(p: &LiftParams, at: &str) -> Result<(), String> {
    if !(p.band_m > 0.0 && p.band_m <= 5.0) {
        return Err(format!("{at}.band_m: must be within (0, 5] metres, got {}", p.band_m));
    }
    let percent = |v: f64| (0.0..=100.0).contains(&v);
    if !percent(p.reference_percentile) {
        return Err(format!("{at}.reference_percentile: must be within [0, 100], got {}", p.reference_percentile));
    }
    let [lo, hi] = p.box_percentiles;
    if !(percent(lo) && percent(hi) && lo < hi) {
        return Err(format!(
            "{at}.box_percentiles: expected [low, high] within [0, 100] with low < high, got {:?}",
            p.box_percentiles
        ));
    }
    if p.pixel_step == 0 || p.pixel_step > 64 {
        return Err(format!("{at}.pixel_step: must be within [1, 64], got {}", p.pixel_step));
    }
    if p.min_points == 0 {
        return Err(format!("{at}.min_points: must be at least 1"));
    }
    Ok(())
}

/// The frames `wanted` of the recording at `dir`, read with the replay source (fast mode).
/// Errors name the recording and the frame.
pub fn read_frames(dir: &Path, wanted: &BTreeSet<u64>) -> Result<BTreeMap<u64, Frame>, String> {
    let config = ReplayConfig { mode: PlaybackMode::Fast, ..ReplayConfig::new(dir.to_path_buf()) };
    let mut source = ReplaySource::new(&config).map_err(|e| format!("opening the recording: {e}"))?;
    let count = source.frame_count() as u64;
    if let Some(&last) = wanted.iter().next_back()
        && last >= count
    {
        return Err(format!(
            "frame {last}: the recording {} has {count} frames (0..={})",
            dir.display(),
            count.saturating_sub(1)
        ));
    }
    let mut frames = BTreeMap::new();
    let mut frame = Frame::new(source.intrinsics());
    while frames.len() < wanted.len() {
        match source.next_frame(&mut frame).map_err(|e| format!("reading {}: {e}", dir.display()))? {
            SourceStatus::Frame => {
                if wanted.contains(&frame.seq) {
                    frames.insert(frame.seq, frame.clone());
                }
            }
            SourceStatus::Pending => {}
            SourceStatus::EndOfStream => break,
        }
    }
    Ok(frames)
}

/// The sampled depth pixels of `rect` on `frame` kept by the depth band of `params`: their
/// pixel indices, how many had depth, and the reference depth (`None` without depth).
fn kept_pixels(frame: &Frame, rect: [u32; 4], params: &LiftParams) -> (Vec<usize>, usize, Option<f64>) {
    let width = frame.intrinsics.width;
    let step = params.pixel_step as usize;
    let mut candidates: Vec<(usize, f64)> = Vec::new();
    for v in (rect[1]..rect[3]).step_by(step) {
        for u in (rect[0]..rect[2]).step_by(step) {
            let i = (v * width + u) as usize;
            let z = f64::from(frame.depth_m(i));
            if z > 0.0 {
                candidates.push((i, z));
            }
        }
    }
    let mut depths: Vec<f64> = candidates.iter().map(|c| c.1).collect();
    let Some(reference) = percentile(&mut depths, params.reference_percentile) else {
        return (Vec::new(), 0, None);
    };
    let kept = candidates.iter().filter(|c| (c.1 - reference).abs() <= params.band_m).map(|c| c.0).collect();
    (kept, candidates.len(), Some(reference))
}

/// The `p`-th percentile (0..=100, nearest rank on the sorted values) of `values`.
fn percentile(values: &mut [f64], p: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let rank = ((p / 100.0) * (values.len() - 1) as f64).round() as usize;
    let (_, value, _) = values.select_nth_unstable_by(rank.min(values.len() - 1), f64::total_cmp);
    Some(*value)
}

/// Lifts `annotation` (read from `annotation_path`, named in errors) on the recording at
/// `sequence`: the ground-truth graph, and what each node and box gave. Errors name the file,
/// the node, the box and the frame.
pub fn lift(annotation: &Annotation, annotation_path: &Path, sequence: &Path) -> Result<Lifted, String> {
    let file = annotation_path.display().to_string();
    let wanted: BTreeSet<u64> = annotation.nodes.iter().flat_map(|n| n.boxes.iter().map(|b| b.frame)).collect();
    let frames =
        read_frames(sequence, &wanted).map_err(|e| format!("{file}: {}", with_box_of_frame(annotation, &e)))?;
    let mut graph = GraphJson::new(format!(
        "hand annotation {} of {} ({} nodes on {} frames; {}), lifted with op3dsg annotate",
        annotation_path.file_name().map_or_else(|| file.clone(), |n| n.to_string_lossy().into_owned()),
        sequence.file_name().map_or_else(|| sequence.display().to_string(), |n| n.to_string_lossy().into_owned()),
        annotation.nodes.len(),
        wanted.len(),
        annotation.annotator
    ));
    let mut nodes = Vec::new();
    let mut boxes = Vec::new();
    for (i, node) in annotation.nodes.iter().enumerate() {
        let (node_json, node_lift) = lift_node(&file, i, node, &annotation.lift, &frames, &mut boxes)?;
        graph.nodes.push(node_json);
        if let Some(parent) = node.parent {
            graph.edges.push(EdgeJson {
                source: node.id,
                target: parent,
                kind: "spatial".to_owned(),
                relation: "part of".to_owned(),
                confidence: 1.0,
                origin: "ground_truth".to_owned(),
            });
        }
        nodes.push(node_lift);
    }
    graph.check().map_err(|e| format!("{file}: the lifted graph: {e}"))?;
    Ok(Lifted { graph, nodes, boxes })
}

/// `error` of [`read_frames`], preceded by the first box on a frame the recording does not
/// have, when it names one.
fn with_box_of_frame(annotation: &Annotation, error: &str) -> String {
    let past_end = annotation.nodes.iter().enumerate().find_map(|(i, node)| {
        let b = node.boxes.iter().position(|b| error.starts_with(&format!("frame {}:", b.frame)))?;
        Some(format!("{}.boxes[{b}].frame", node_path(i, node)))
    });
    match past_end {
        Some(at) => format!("{at}: {error}"),
        None => error.to_owned(),
    }
}

/// Lifts node `i` of the annotation `file` from its boxes on `frames`: the ground-truth node
/// (the box of its fused points) and what it gave; what each box gave is appended to `boxes`.
fn lift_node(
    file: &str,
    i: usize,
    node: &AnnotatedNode,
    lift: &LiftParams,
    frames: &BTreeMap<u64, Frame>,
    boxes: &mut Vec<BoxLift>,
) -> Result<(NodeJson, NodeLift), String> {
    let at = node_path(i, node);
    let params = node_params(lift, node);
    let mut points: [Vec<f64>; 3] = Default::default();
    for (b, frame_box) in node.boxes.iter().enumerate() {
        let at = format!("{file}: {at}.boxes[{b}] (frame {})", frame_box.frame);
        let frame = frames.get(&frame_box.frame).ok_or_else(|| format!("{at}: frame not read from the recording"))?;
        let (kept, with_depth, reference_m) =
            lift_box(frame, frame_box, &box_params(&params, frame_box), &at, &mut points)?;
        boxes.push(BoxLift { node: node.id, index: b, frame: frame_box.frame, with_depth, kept, reference_m });
    }
    let count = points[0].len();
    let [lo, hi] = params.box_percentiles;
    let mut min = DVec3::ZERO;
    let mut max = DVec3::ZERO;
    for (axis, values) in points.iter_mut().enumerate() {
        // Cannot be empty: every box kept at least min_points >= 1 pixels.
        min[axis] = percentile(values, lo).unwrap_or(0.0);
        max[axis] = percentile(values, hi).unwrap_or(0.0);
    }
    let round = |v: DVec3| v.to_array().map(|c| ((c * 1e4).round() / 1e4) as f32);
    let (box_min_m, box_max_m) = (round(min), round(max));
    let centre_m = round((min + max) * 0.5);
    let node_json = NodeJson {
        id: node.id,
        label: node.label.clone(),
        kind: node.kind.clone(),
        parent: node.parent,
        centre_m,
        box_min_m,
        box_max_m,
        obb: None,
        affordances: node.affordances.clone(),
        affordance_origins: BTreeMap::new(),
        confidence: 1.0,
        observation_count: 0,
        seen_keyframes: None,
    };
    let frames_of_node: BTreeSet<u64> = node.boxes.iter().map(|b| b.frame).collect();
    let node_lift = NodeLift { id: node.id, points: count, frames: frames_of_node.len(), box_min_m, box_max_m };
    Ok((node_json, node_lift))
}

/// Lifts one box (`at` names it in errors) on its `frame`: its kept pixels, back-projected and
/// moved into the world, are appended to `points` (per axis). Returns how many pixels were kept,
/// how many had depth, and the reference depth in metres.
fn lift_box(
    frame: &Frame,
    frame_box: &FrameBox,
    params: &LiftParams,
    at: &str,
    points: &mut [Vec<f64>; 3],
) -> Result<(usize, usize, f64), String> {
    let k = frame.intrinsics;
    let [_, _, x1, y1] = frame_box.rect;
    if x1 > k.width || y1 > k.height {
        return Err(format!(
            "{at}.box: {:?} reaches past the {}x{} image (x1 <= {}, y1 <= {})",
            frame_box.rect, k.width, k.height, k.width, k.height
        ));
    }
    let pose = frame.world_from_camera.ok_or_else(|| format!("{at}: the frame has no pose in groundtruth.txt"))?;
    let (kept, with_depth, reference) = kept_pixels(frame, frame_box.rect, params);
    let Some(reference) = reference else {
        return Err(format!("{at}: no pixel of {:?} has depth", frame_box.rect));
    };
    if kept.len() < params.min_points {
        return Err(format!(
            "{at}: only {} pixels within {} m of the reference depth {reference:.2} m (of {with_depth} with depth; min_points {})",
            kept.len(),
            params.band_m,
            params.min_points
        ));
    }
    for &p in &kept {
        let (u, v) = ((p as u32 % k.width) as f32, (p as u32 / k.width) as f32);
        let world = pose.transform_point(k.point_in_camera(u, v, frame.depth_m(p)).as_dvec3());
        for (axis, values) in points.iter_mut().enumerate() {
            values.push(world[axis]);
        }
    }
    Ok((kept.len(), with_depth, reference))
}

/// A text summary of a lift: per node its label, frames, points, box size and corners; per box
/// its reference depth and kept share.
pub fn summary(annotation: &Annotation, lifted: &Lifted) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:>3} {:<28} {:<6} {:>6} {:>7}  {:<20} box min .. max (world, m)",
        "id", "label", "kind", "frames", "points", "size x y z (m)"
    );
    for (node, lift) in annotation.nodes.iter().zip(&lifted.nodes) {
        let size: Vec<String> = (0..3).map(|a| format!("{:.2}", lift.box_max_m[a] - lift.box_min_m[a])).collect();
        let _ = writeln!(
            s,
            "{:>3} {:<28} {:<6} {:>6} {:>7}  {:<20} [{:.2}, {:.2}, {:.2}] .. [{:.2}, {:.2}, {:.2}]",
            node.id,
            node.label,
            node.kind,
            lift.frames,
            lift.points,
            size.join(" "),
            lift.box_min_m[0],
            lift.box_min_m[1],
            lift.box_min_m[2],
            lift.box_max_m[0],
            lift.box_max_m[1],
            lift.box_max_m[2]
        );
    }
    let _ = writeln!(s, "\nboxes: node, box, frame, reference depth, kept of sampled pixels with depth");
    for b in &lifted.boxes {
        let _ = writeln!(
            s,
            "  {:>3} [{}] frame {:>3}: {:.2} m, {} of {} ({:.0} %)",
            b.node,
            b.index,
            b.frame,
            b.reference_m,
            b.kept,
            b.with_depth,
            100.0 * b.kept as f64 / b.with_depth.max(1) as f64
        );
    }
    s
}

/// Writes one PNG per annotated frame into `dir` (`frame_NNNNN.png`): the colour image, each
/// box outlined and the pixels its depth band kept tinted, in the node's colour (the colour of
/// node `i` in file order is [`preview_colour`]`(i)`). Returns the files written.
pub fn preview(annotation: &Annotation, sequence: &Path, dir: &Path) -> Result<Vec<PathBuf>, String> {
    let wanted: BTreeSet<u64> = annotation.nodes.iter().flat_map(|n| n.boxes.iter().map(|b| b.frame)).collect();
    let frames = read_frames(sequence, &wanted)?;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut written = Vec::new();
    for (&seq, frame) in &frames {
        let k = frame.intrinsics;
        let mut rgb = frame.rgb.clone();
        for (i, node) in annotation.nodes.iter().enumerate() {
            let colour = preview_colour(i);
            let params = node_params(&annotation.lift, node);
            for frame_box in node.boxes.iter().filter(|b| b.frame == seq) {
                let mut rect = frame_box.rect;
                rect[2] = rect[2].min(k.width);
                rect[3] = rect[3].min(k.height);
                for p in kept_pixels(frame, rect, &box_params(&params, frame_box)).0 {
                    for c in 0..3 {
                        let value = &mut rgb[p * 3 + c];
                        *value = ((u16::from(*value) + u16::from(colour[c])) / 2) as u8;
                    }
                }
                let [x0, y0, x1, y1] = rect;
                let mut put = |u: u32, v: u32| rgb[(v * k.width + u) as usize * 3..][..3].copy_from_slice(&colour);
                for u in x0..x1 {
                    for v in [y0, y0 + 1, y1 - 1, y1.saturating_sub(2)] {
                        put(u, v.min(k.height - 1));
                    }
                }
                for v in y0..y1 {
                    for u in [x0, x0 + 1, x1 - 1, x1.saturating_sub(2)] {
                        put(u.min(k.width - 1), v);
                    }
                }
            }
        }
        let path = dir.join(format!("frame_{seq:05}.png"));
        image::save_buffer(&path, &rgb, k.width, k.height, image::ExtendedColorType::Rgb8)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        written.push(path);
    }
    Ok(written)
}

/// The preview colour of the `i`-th node of the file.
pub fn preview_colour(i: usize) -> [u8; 3] {
    const COLOURS: [[u8; 3]; 10] = [
        [230, 25, 75],
        [60, 180, 75],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
        [210, 245, 60],
        [255, 225, 25],
        [0, 0, 128],
    ];
    COLOURS[i % COLOURS.len()]
}

#[cfg(test)]
mod tests;
