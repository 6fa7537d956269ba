//! The prior graph (paper: "Prior 3D Scene Graph Generation"): the fused nodes with their
//! resolved knowledge categories, their spatial neighbours and the spatial relations between
//! objects, computed from geometry and the gravity axis only. Reasoners
//! ([`crate::reasoner`]) read it; it is rebuilt from every published [`SceneGraph`].
//!
//! # Neighbours
//!
//! Two nodes are neighbours when their centres are within `neighbour_radius_m` (default 1 m).
//! Pairs are found through a uniform hash grid with cells of that size (each node looks at its
//! own and the 26 surrounding cells), never by testing all pairs.
//!
//! # Spatial relations between objects
//!
//! Boxes are the axis-aligned boxes of the fused points, read in a frame whose third axis is
//! `up` (profile `world.up_axis`); the other two axes span the floor ("footprint"). For each
//! neighbouring pair of *objects* (parts only get `part of`), first rule that applies:
//!
//! 1. **inside**: A's box lies within B's box grown by `inside_tolerance_m` (2 cm) on every
//!    side and A's volume is under half of B's → `A inside B`.
//! 2. **vertical** (footprints overlap by at least `min_footprint_overlap`, 0.2, of the smaller
//!    footprint): with U the one whose centre is higher and L the other, `gap = U.min_up −
//!    L.max_up`. `|gap| ≤ contact_tolerance_m` (4 cm) → `U on L` and `L under U`; `gap >`
//!    tolerance → `U above L` and `L below U`; deeper interpenetration → no relation.
//! 3. **next to** (footprints overlap less): the up-extents overlap and the footprints are at most
//!    `next_to_gap_m` (25 cm) apart → one `next to` edge from the lower id to the higher (the
//!    relation is symmetric).
//!
//! Edge confidence is the smaller of the two node confidences; the origin is geometry.
//!
//! # Part of
//!
//! Fusion sets each part's parent (`fusion::multiview::attach_parts`: among objects whose box,
//! grown by a margin, contains the part's centre, the one whose label is contained in the part's
//! label — "cabinet handle" → cabinet — else the nearest by surface distance; one object per
//! part). The prior graph keeps those parents and their `part of` edges as they are.
//!
//! A part fusion left without a parent (none within its margin) is attached here by the same
//! rule over its spatially close objects, the objects among its neighbours (centres within
//! `neighbour_radius_m`): an object whose label is contained in the part's label (normalised
//! words, or the object named by the part's compound label in the knowledge base) wins, else the
//! nearest by surface distance (the gap between the two boxes) among the objects whose category
//! has that part in the knowledge base and whose box is within [`ORPHAN_MAX_GAP_M`]; ties go to
//! the lower id. A part with no such object stays unattached: wall outlets and light switches
//! belong to the room, not to the lamp or sofa beside them (attaching them there would also make
//! that object unreachable as the target of their remote relation). These attachments are listed in
//! [`PriorGraph::attached`] and get a `part of` edge of origin geometry.

use glam::Vec3;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind, relation_id};
use rustc_hash::FxHashMap;

use crate::graph::{GraphEdge, SceneGraph};
use crate::knowledge::fallback::LabelFallback;
use crate::knowledge::{KnowledgeBase, Resolved};
use crate::world::UpAxis;

/// Tolerances of the prior graph (see the module docs for how each is used).
#[derive(Debug, Clone, PartialEq)]
pub struct PriorConfig {
    /// Which axis is up.
    pub up_axis: UpAxis,
    /// Centres within this distance are neighbours, metres.
    pub neighbour_radius_m: f32,
    /// `on` / `under` when the vertical gap is at most this, metres.
    pub contact_tolerance_m: f32,
    /// `next to` when footprints are at most this far apart, metres.
    pub next_to_gap_m: f32,
    /// Footprint overlap (fraction of the smaller footprint) for a vertical relation.
    pub min_footprint_overlap: f32,
    /// Slack for `inside`, metres.
    pub inside_tolerance_m: f32,
}

impl Default for PriorConfig {
    fn default() -> Self {
        Self {
            up_axis: UpAxis::Z,
            neighbour_radius_m: 1.0,
            contact_tolerance_m: 0.04,
            next_to_gap_m: 0.25,
            min_footprint_overlap: 0.2,
            inside_tolerance_m: 0.02,
        }
    }
}

/// One node of the prior graph.
#[derive(Debug, Clone, PartialEq)]
pub struct PriorNode {
    /// Node id (as in the scene graph).
    pub id: u32,
    /// Object or part.
    pub kind: NodeKind,
    /// Parent object of a part.
    pub parent_id: Option<u32>,
    /// Voted label.
    pub label: String,
    /// The label resolved against the knowledge base (or, for a label the tables do not know,
    /// its nearest known category by embedding when the builder has a fallback; then
    /// `by_embedding` is set).
    pub category: Option<Resolved>,
    /// `category` came from the embedding fallback ([`crate::knowledge::fallback`]), not from
    /// the tables.
    pub by_embedding: bool,
    /// Node confidence.
    pub confidence: f32,
    /// Centre, world, metres.
    pub centre_m: Vec3,
    /// Axis-aligned box, world, metres.
    pub box_min_m: Vec3,
    /// Axis-aligned box, world, metres.
    pub box_max_m: Vec3,
}

/// A versioned prior graph.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PriorGraph {
    /// Version of the scene graph it was built from.
    pub version: u64,
    /// Nodes, sorted by id.
    pub nodes: Vec<PriorNode>,
    /// Neighbouring pairs as node indices `(i, j)`, `i < j`.
    pub neighbours: Vec<(u32, u32)>,
    /// Spatial edges: `part of` from fusion, then the object relations, then `part of` for the
    /// parts attached here.
    pub spatial_edges: Vec<GraphEdge>,
    /// Parts fusion left without a parent that were attached here: `(part_id, object_id)`.
    pub attached: Vec<(u32, u32)>,
}

impl PriorGraph {
    /// Index of the node with `id`.
    pub fn index_of(&self, id: u32) -> Option<usize> {
        self.nodes.binary_search_by_key(&id, |n| n.id).ok()
    }
}

/// A box in the up frame: `[h0, h1, up]`.
#[derive(Debug, Clone, Copy)]
struct UpBox {
    min: Vec3,
    max: Vec3,
}

impl UpBox {
    fn new(up_axis: UpAxis, min: Vec3, max: Vec3) -> Self {
        match up_axis {
            UpAxis::Z => Self { min, max },
            UpAxis::Y => Self { min: Vec3::new(min.x, min.z, min.y), max: Vec3::new(max.x, max.z, max.y) },
            // Up is -y: negating y swaps the ends.
            UpAxis::NegY => Self { min: Vec3::new(min.x, min.z, -max.y), max: Vec3::new(max.x, max.z, -min.y) },
        }
    }
    fn size(&self) -> Vec3 {
        (self.max - self.min).max(Vec3::ZERO)
    }
    fn footprint_area(&self) -> f32 {
        let s = self.size();
        s.x * s.y
    }
    fn volume(&self) -> f32 {
        let s = self.size();
        s.x * s.y * s.z
    }
    fn footprint_overlap_area(&self, other: &Self) -> f32 {
        let dx = (self.max.x.min(other.max.x) - self.min.x.max(other.min.x)).max(0.0);
        let dy = (self.max.y.min(other.max.y) - self.min.y.max(other.min.y)).max(0.0);
        dx * dy
    }
    fn footprint_gap(&self, other: &Self) -> f32 {
        let dx = (self.min.x - other.max.x).max(other.min.x - self.max.x).max(0.0);
        let dy = (self.min.y - other.max.y).max(other.min.y - self.max.y).max(0.0);
        (dx * dx + dy * dy).sqrt()
    }
    fn within(&self, other: &Self, slack: f32) -> bool {
        self.min.cmpge(other.min - slack).all() && self.max.cmple(other.max + slack).all()
    }
}

/// The spatial relation phrases between two objects `a` and `b` from the rules in the module
/// docs: each `(phrase, a_is_source)`.
pub fn object_relations(
    config: &PriorConfig,
    a_min: Vec3,
    a_max: Vec3,
    b_min: Vec3,
    b_max: Vec3,
) -> Vec<(&'static str, bool)> {
    let a = UpBox::new(config.up_axis, a_min, a_max);
    let b = UpBox::new(config.up_axis, b_min, b_max);
    if a.within(&b, config.inside_tolerance_m) && a.volume() < 0.5 * b.volume() {
        return vec![("inside", true)];
    }
    if b.within(&a, config.inside_tolerance_m) && b.volume() < 0.5 * a.volume() {
        return vec![("inside", false)];
    }
    let smaller = a.footprint_area().min(b.footprint_area()).max(1e-6);
    if a.footprint_overlap_area(&b) / smaller >= config.min_footprint_overlap {
        let a_upper = a.min.z + a.max.z >= b.min.z + b.max.z;
        let (upper, lower) = if a_upper { (a, b) } else { (b, a) };
        let gap = upper.min.z - lower.max.z;
        if gap.abs() <= config.contact_tolerance_m {
            return vec![("on", a_upper), ("under", !a_upper)];
        }
        if gap > config.contact_tolerance_m {
            return vec![("above", a_upper), ("below", !a_upper)];
        }
        return Vec::new();
    }
    let up_overlap = a.min.z < b.max.z && b.min.z < a.max.z;
    if up_overlap && a.footprint_gap(&b) <= config.next_to_gap_m {
        return vec![("next to", true)];
    }
    Vec::new()
}

/// Neighbouring pairs (indices `i < j`) whose centres are within `radius_m`, through a hash
/// grid of `radius_m` cells.
pub fn neighbours(centres: &[Vec3], radius_m: f32) -> Vec<(u32, u32)> {
    let mut pairs = Vec::new();
    neighbours_into(centres, radius_m, &mut FxHashMap::default(), &mut pairs);
    pairs
}

/// [`neighbours`] into `pairs`, with `grid` as reusable scratch space (its cell vectors keep
/// their capacity between calls).
fn neighbours_into(
    centres: &[Vec3],
    radius_m: f32,
    grid: &mut FxHashMap<(i32, i32, i32), Vec<u32>>,
    pairs: &mut Vec<(u32, u32)>,
) {
    pairs.clear();
    if !(radius_m.is_finite() && radius_m > 0.0) {
        return;
    }
    let cell_of = |p: Vec3| {
        let c = (p / radius_m).floor();
        (c.x as i32, c.y as i32, c.z as i32)
    };
    // Keep the cells' allocations, unless the map kept far more cells than there are points.
    if grid.len() > 4 * centres.len().max(64) {
        grid.clear();
    }
    grid.values_mut().for_each(Vec::clear);
    for (i, centre) in centres.iter().enumerate() {
        if centre.is_finite() {
            grid.entry(cell_of(*centre)).or_default().push(i as u32);
        }
    }
    let radius_sq = radius_m * radius_m;
    for (i, centre) in centres.iter().enumerate() {
        if !centre.is_finite() {
            continue;
        }
        let (cx, cy, cz) = cell_of(*centre);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(cell) = grid.get(&(cx + dx, cy + dy, cz + dz)) else { continue };
                    for &j in cell {
                        if (j as usize) > i && centre.distance_squared(centres[j as usize]) <= radius_sq {
                            pairs.push((i as u32, j));
                        }
                    }
                }
            }
        }
    }
    pairs.sort_unstable();
}

/// Builds the prior graph of `graph` (a one-off [`PriorBuilder`]).
pub fn build(graph: &SceneGraph, knowledge: &KnowledgeBase, config: &PriorConfig) -> PriorGraph {
    PriorBuilder::default().build(graph, knowledge, config)
}

/// Rebuilds prior graphs with state kept between rebuilds: the labels already resolved against
/// the knowledge base (labels repeat from one graph to the next) and the neighbour grid's
/// cells. The owner of a knowledge base keeps one builder per knowledge base.
#[derive(Debug, Default)]
pub struct PriorBuilder {
    resolved: FxHashMap<String, Option<Resolved>>,
    /// Nearest known category for labels the tables do not know (with an embedder).
    fallback: Option<LabelFallback>,
    grid: FxHashMap<(i32, i32, i32), Vec<u32>>,
    centres: Vec<Vec3>,
}

/// Distinct labels kept resolved at most; beyond, the cache starts over.
const RESOLVED_CACHE_CAPACITY: usize = 4096;

impl PriorBuilder {
    /// A builder that gives a label the tables do not know its nearest known category by
    /// embedding ([`LabelFallback::nearest`]), so that orphan parts attach to such an object and
    /// the reasoner sees the category; the node's `by_embedding` says so.
    pub fn with_fallback(fallback: LabelFallback) -> Self {
        Self { fallback: fallback.has_embedder().then_some(fallback), ..Self::default() }
    }

    /// Builds the prior graph of `graph`. Use one builder with one knowledge base only.
    pub fn build(&mut self, graph: &SceneGraph, knowledge: &KnowledgeBase, config: &PriorConfig) -> PriorGraph {
        if self.resolved.len() > RESOLVED_CACHE_CAPACITY {
            self.resolved.clear();
        }
        let resolved = &mut self.resolved;
        let fallback = &mut self.fallback;
        let mut nodes: Vec<PriorNode> = graph
            .nodes
            .iter()
            .map(|n| {
                let mut category = match resolved.get(n.label.as_str()) {
                    Some(category) => *category,
                    None => *resolved.entry(n.label.clone()).or_insert_with(|| knowledge.resolve(&n.label)),
                };
                let mut by_embedding = false;
                if let (None, Some(fallback)) = (category, fallback.as_mut())
                    && let Some((nearest, _)) = fallback.nearest(&n.label, n.kind == NodeKind::Object)
                {
                    category = Some(Resolved { category: nearest, object_hint: None });
                    by_embedding = true;
                }
                PriorNode {
                    by_embedding,
                    id: n.id,
                    kind: n.kind,
                    parent_id: n.parent_id,
                    label: n.label.clone(),
                    category,
                    confidence: n.confidence,
                    centre_m: Vec3::from(n.centre_m),
                    box_min_m: Vec3::from(n.box_min_m),
                    box_max_m: Vec3::from(n.box_max_m),
                }
            })
            .collect();
        nodes.sort_unstable_by_key(|n| n.id);
        self.centres.clear();
        self.centres.extend(nodes.iter().map(|n| n.centre_m));
        let mut neighbours = Vec::new();
        neighbours_into(&self.centres, config.neighbour_radius_m, &mut self.grid, &mut neighbours);
        let part_of = relation_id("part of").map_or(0, |(_, id)| id);
        let mut spatial_edges: Vec<GraphEdge> =
            graph.edges.iter().filter(|e| e.kind == EdgeKind::Spatial && e.relation_id == part_of).cloned().collect();
        for &(i, j) in &neighbours {
            let (a, b) = (&nodes[i as usize], &nodes[j as usize]);
            if a.kind != NodeKind::Object || b.kind != NodeKind::Object {
                continue;
            }
            for (phrase, a_is_source) in object_relations(config, a.box_min_m, a.box_max_m, b.box_min_m, b.box_max_m) {
                let Some((_, relation_id)) = relation_id(phrase) else { continue };
                let (source, target) = if a_is_source { (a, b) } else { (b, a) };
                spatial_edges.push(GraphEdge {
                    source_id: source.id,
                    target_id: target.id,
                    kind: EdgeKind::Spatial,
                    relation_id,
                    confidence: a.confidence.min(b.confidence),
                    origin: EdgeOrigin::Geometry,
                });
            }
        }
        let attached = attach_orphan_parts(&mut nodes, &neighbours, knowledge);
        for &(part_id, object_id) in &attached {
            let confidence = [part_id, object_id]
                .iter()
                .filter_map(|id| nodes.binary_search_by_key(id, |n| n.id).ok())
                .map(|i| nodes[i].confidence)
                .fold(1.0f32, f32::min);
            spatial_edges.push(GraphEdge {
                source_id: part_id,
                target_id: object_id,
                kind: EdgeKind::Spatial,
                relation_id: part_of,
                confidence,
                origin: EdgeOrigin::Geometry,
            });
        }
        PriorGraph { version: graph.version, nodes, neighbours, spatial_edges, attached }
    }
}

/// Gap between two axis-aligned boxes (0 when they touch or overlap), metres.
fn box_gap(a_min: Vec3, a_max: Vec3, b_min: Vec3, b_max: Vec3) -> f32 {
    (a_min - b_max).max(b_min - a_max).max(Vec3::ZERO).length()
}

/// An orphan part is attached to an object by proximity alone only when their boxes are at most
/// this far apart, metres (a part touches its object; depth noise and a coarse map leave gaps).
pub const ORPHAN_MAX_GAP_M: f32 = 0.1;

/// Whether the words of `object` appear, in order and whole, in `part` (both normalised).
fn label_contains(part: &str, object: &str) -> bool {
    !object.is_empty() && format!(" {part} ").contains(&format!(" {object} "))
}

/// Attaches parts without a (present) parent by the rule in the module docs; returns the new
/// `(part_id, object_id)` pairs, in part id order.
fn attach_orphan_parts(
    nodes: &mut [PriorNode],
    neighbours: &[(u32, u32)],
    knowledge: &KnowledgeBase,
) -> Vec<(u32, u32)> {
    let present = |nodes: &[PriorNode], id: u32| nodes.binary_search_by_key(&id, |n| n.id).is_ok();
    let orphan: Vec<bool> =
        nodes.iter().map(|n| n.kind == NodeKind::Part && n.parent_id.is_none_or(|p| !present(nodes, p))).collect();
    if !orphan.contains(&true) {
        return Vec::new();
    }
    // Per orphan part index: (lexical, gap, object id, object index).
    let mut best: FxHashMap<u32, (bool, f32, u32, u32)> = FxHashMap::default();
    for &(i, j) in neighbours {
        for (p, o) in [(i, j), (j, i)] {
            let (part, object) = (&nodes[p as usize], &nodes[o as usize]);
            if !orphan[p as usize] || object.kind != NodeKind::Object {
                continue;
            }
            let hint = part.category.and_then(|c| c.object_hint);
            let lexical = (hint.is_some() && hint == object.category.and_then(|c| c.object()))
                || label_contains(
                    &crate::knowledge::normalise(&part.label),
                    &crate::knowledge::normalise(&object.label),
                );
            let gap = box_gap(part.box_min_m, part.box_max_m, object.box_min_m, object.box_max_m);
            let known_pair = match (part.category.and_then(|c| c.part()), object.category.and_then(|c| c.object())) {
                (Some(part), Some(object)) => knowledge.pair(part, object).is_some(),
                _ => false,
            };
            if !(lexical || (known_pair && gap <= ORPHAN_MAX_GAP_M)) {
                continue;
            }
            let candidate = (lexical, gap, object.id, o);
            let better = best.get(&p).is_none_or(|&(bl, bg, bid, _)| {
                (lexical, std::cmp::Reverse(gap.to_bits()), std::cmp::Reverse(object.id))
                    > (bl, std::cmp::Reverse(bg.to_bits()), std::cmp::Reverse(bid))
            });
            if better {
                best.insert(p, candidate);
            }
        }
    }
    let mut attached: Vec<(u32, u32)> = best
        .into_iter()
        .map(|(p, (_, _, object_id, _))| {
            nodes[p as usize].parent_id = Some(object_id);
            (nodes[p as usize].id, object_id)
        })
        .collect();
    attached.sort_unstable();
    attached
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::GraphNode;

    fn rel(config: &PriorConfig, a: ([f32; 3], [f32; 3]), b: ([f32; 3], [f32; 3])) -> Vec<(&'static str, bool)> {
        object_relations(config, a.0.into(), a.1.into(), b.0.into(), b.1.into())
    }

    const TABLE: ([f32; 3], [f32; 3]) = ([0.0, 0.0, 0.0], [1.0, 0.6, 0.75]);

    #[test]
    fn a_kettle_on_a_table_and_the_table_under_it() {
        let kettle = ([0.4, 0.2, 0.76], [0.6, 0.4, 1.0]);
        assert_eq!(rel(&PriorConfig::default(), kettle, TABLE), [("on", true), ("under", false)]);
        assert_eq!(rel(&PriorConfig::default(), TABLE, kettle), [("on", false), ("under", true)]);
    }

    #[test]
    fn a_shelf_lamp_above_a_table_with_a_gap() {
        let lamp = ([0.3, 0.1, 1.5], [0.7, 0.5, 1.8]);
        assert_eq!(rel(&PriorConfig::default(), lamp, TABLE), [("above", true), ("below", false)]);
    }

    #[test]
    fn a_chair_next_to_a_table_and_not_when_far() {
        let chair = ([1.1, 0.0, 0.0], [1.5, 0.4, 0.9]);
        assert_eq!(rel(&PriorConfig::default(), chair, TABLE), [("next to", true)]);
        let far = ([1.5, 0.0, 0.0], [1.9, 0.4, 0.9]);
        assert!(rel(&PriorConfig::default(), far, TABLE).is_empty());
    }

    #[test]
    fn a_cup_inside_a_cabinet() {
        let cabinet = ([0.0, 0.0, 0.0], [0.6, 0.6, 0.9]);
        let cup = ([0.2, 0.2, 0.3], [0.3, 0.3, 0.42]);
        assert_eq!(rel(&PriorConfig::default(), cup, cabinet), [("inside", true)]);
        assert_eq!(rel(&PriorConfig::default(), cabinet, cup), [("inside", false)]);
    }

    #[test]
    fn the_up_axis_decides_what_is_on_what() {
        // The same kettle and table with y up (z and y swapped); -y up mirrors y.
        let y_up = PriorConfig { up_axis: UpAxis::Y, ..PriorConfig::default() };
        let kettle = ([0.4, 0.76, 0.2], [0.6, 1.0, 0.4]);
        let table = ([0.0, 0.0, 0.0], [1.0, 0.75, 0.6]);
        assert_eq!(rel(&y_up, kettle, table), [("on", true), ("under", false)]);
        let neg_y = PriorConfig { up_axis: UpAxis::NegY, ..PriorConfig::default() };
        let kettle = ([0.4, -1.0, 0.2], [0.6, -0.76, 0.4]);
        let table = ([0.0, -0.75, 0.0], [1.0, 0.0, 0.6]);
        assert_eq!(rel(&neg_y, kettle, table), [("on", true), ("under", false)]);
        // With z up, that pair stands side by side.
        assert_eq!(rel(&PriorConfig::default(), kettle, table), [("next to", true)]);
    }

    #[test]
    fn neighbours_through_the_grid_match_all_pairs() {
        let mut centres = Vec::new();
        for i in 0..300u32 {
            let f = i as f32;
            centres.push(Vec3::new((f * 0.37) % 5.0, (f * 0.71) % 4.0, (f * 0.13) % 2.5 - 1.0));
        }
        let mut brute = Vec::new();
        for i in 0..centres.len() {
            for j in i + 1..centres.len() {
                if centres[i].distance(centres[j]) <= 1.0 {
                    brute.push((i as u32, j as u32));
                }
            }
        }
        assert_eq!(neighbours(&centres, 1.0), brute);
        assert!(!brute.is_empty());
    }

    fn node(id: u32, label: &str, kind: NodeKind, min: [f32; 3], max: [f32; 3]) -> GraphNode {
        let centre = (Vec3::from(min) + Vec3::from(max)) * 0.5;
        GraphNode {
            id,
            kind,
            parent_id: None,
            label: label.to_owned(),
            confidence: 0.8,
            centre_m: centre.to_array(),
            box_min_m: min,
            box_max_m: max,
            obb: Default::default(),
            observation_count: 5,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            missing: false,
            ..Default::default()
        }
    }

    #[test]
    fn build_keeps_part_of_and_adds_object_relations() {
        let kb = KnowledgeBase::builtin().unwrap();
        let mut handle = node(3, "cabinet handle", NodeKind::Part, [0.3, -0.03, 0.5], [0.4, 0.0, 0.52]);
        handle.parent_id = Some(1);
        let graph = SceneGraph {
            version: 7,
            stamp_ns: 0,
            nodes: vec![
                node(1, "cabinet", NodeKind::Object, [0.0, 0.0, 0.0], [0.6, 0.6, 0.9]),
                node(2, "microwave", NodeKind::Object, [0.1, 0.1, 0.91], [0.5, 0.45, 1.2]),
                handle,
            ],
            edges: vec![GraphEdge {
                source_id: 3,
                target_id: 1,
                kind: EdgeKind::Spatial,
                relation_id: 0,
                confidence: 0.8,
                origin: EdgeOrigin::Geometry,
            }],
        };
        let prior = build(&graph, &kb, &PriorConfig::default());
        assert_eq!(prior.version, 7);
        assert_eq!(
            prior.nodes[2].category.and_then(|c| c.object_hint).map(|o| kb.object(o).name.as_str()),
            Some("cabinet")
        );
        let phrases: Vec<(u32, u32, &str)> = prior
            .spatial_edges
            .iter()
            .map(|e| (e.source_id, e.target_id, op3dsg_ipc_types::relation_phrase(e.relation_id).unwrap_or("?")))
            .collect();
        assert_eq!(phrases, [(3, 1, "part of"), (2, 1, "on"), (1, 2, "under")]);
        assert!(prior.attached.is_empty());
    }

    #[test]
    fn a_reused_builder_builds_what_a_fresh_one_does() {
        let kb = KnowledgeBase::builtin().unwrap();
        let mut builder = PriorBuilder::default();
        let mut graph = SceneGraph::default();
        for round in 0..3u32 {
            // Shift and grow the scene so cells empty, fill and move between rounds.
            let shift = round as f32 * 1.7;
            graph.nodes.clear();
            for i in 0..(40 + 20 * round) {
                let f = i as f32;
                let min = [(f * 0.37) % 4.0 + shift, (f * 0.71) % 3.0, (f * 0.13) % 1.5];
                let label = ["cabinet", "microwave", "table", "cabinet handle", "knob"][i as usize % 5];
                let kind = if label.contains(' ') || label == "knob" { NodeKind::Part } else { NodeKind::Object };
                graph.nodes.push(node(i, label, kind, min, [min[0] + 0.3, min[1] + 0.2, min[2] + 0.25]));
            }
            graph.version = u64::from(round);
            assert_eq!(
                builder.build(&graph, &kb, &PriorConfig::default()),
                build(&graph, &kb, &PriorConfig::default())
            );
        }
    }

    #[test]
    fn parts_fusion_left_alone_are_attached_lexically_else_nearest() {
        let kb = KnowledgeBase::builtin().unwrap();
        let graph = SceneGraph {
            version: 3,
            stamp_ns: 0,
            nodes: vec![
                node(1, "cabinet", NodeKind::Object, [0.0, 0.0, 0.0], [0.6, 0.6, 0.9]),
                node(2, "microwave", NodeKind::Object, [0.0, -0.5, 0.5], [0.4, -0.15, 0.8]),
                // Nearer the microwave's box, but its label names the cabinet.
                node(3, "cabinet handle", NodeKind::Part, [0.3, -0.14, 0.5], [0.4, -0.12, 0.52]),
                // No label match: the nearest box that has buttons (the microwave) wins.
                node(4, "button", NodeKind::Part, [0.1, -0.14, 0.6], [0.14, -0.1, 0.64]),
                // A wall outlet 5 cm from the microwave: microwaves have no outlets, it stays
                // the room's.
                node(6, "outlet", NodeKind::Part, [0.0, -0.5, 0.85], [0.05, -0.49, 0.9]),
                // Nothing within the neighbour radius.
                node(5, "drawer handle", NodeKind::Part, [9.0, 9.0, 0.5], [9.1, 9.02, 0.52]),
            ],
            edges: Vec::new(),
        };
        let prior = build(&graph, &kb, &PriorConfig::default());
        assert_eq!(prior.attached, [(3, 1), (4, 2)]);
        assert_eq!(prior.nodes[2].parent_id, Some(1));
        assert_eq!(prior.nodes[4].parent_id, None);
        assert_eq!(prior.nodes[5].parent_id, None, "the outlet stays unattached");
        let part_of: Vec<(u32, u32)> =
            prior.spatial_edges.iter().filter(|e| e.relation_id == 0).map(|e| (e.source_id, e.target_id)).collect();
        assert_eq!(part_of, [(3, 1), (4, 2)]);
        assert!(label_contains("tv stand drawer handle", "tv stand") && !label_contains("cabinets handle", "cabinet"));
    }
}
