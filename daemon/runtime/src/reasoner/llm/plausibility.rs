//! The gate's plausibility rules: items that name real nodes and canonical labels but make no
//! sense for those nodes, anchored in the prior graph's geometry and in the knowledge base as
//! a soft prior. Each rejection is counted under its rule's reason
//! (`op3dsg_ipc_types::REFINER_REJECTIONS`), after the gate's id, kind and label checks passed:
//!
//! - **`implausible_geometry`**
//!   - a local relation whose part's box is more than `part_max_gap_m` (profile, 15 cm) from
//!     its object's box: the part is not on the object it is said to act on;
//!   - a remote relation whose source and target centres are further apart than the relation
//!     allows: the knowledge base's `max_distance_m` of the template it comes from, tightened
//!     per relation by `remote_max_distance_m` (profile);
//!   - an affordance on a part whose box's longest side exceeds `part_max_extent_m` of that
//!     affordance (profile: a 40 cm "knob" is not pinched). Objects are not limited by size:
//!     they afford through their parts.
//! - **`implausible_relation`**
//!   - a local relation no object-part pair of the knowledge base has (`remote to control` or
//!     `provide power` from a part to its own object);
//!   - a local relation where the knowledge base has the pair and says its part acts on
//!     something else (a power strip's outlets);
//!   - a local relation neither the object's category (nor the object named in the part's label,
//!     "oven handle" → oven) has with any of its parts, nor the part's category has with any
//!     object (`press to flush` on a door handle);
//!   - a remote relation no remote template of the source's category gives towards the
//!     target's category (`remote to control` from an outlet to a kettle).
//! - **`implausible_affordance`**: an affordance the knowledge base gives neither the node's
//!   category (an object: its own affordances and its parts'; a part: its defaults and what it
//!   affords on any object) nor, for a part, the other parts of its object's category
//!   (`foot_push` or `plug_in` on a door or a cabinet).
//!
//! The knowledge rules are soft: a category the knowledge base does not know, or knows no
//! relation (affordance) for, says nothing, and an item about nodes of which no category says
//! anything is accepted. Within an agent the order is: local relations geometry then knowledge;
//! remote relations knowledge (which template) then distance; affordances size then knowledge.

use std::sync::Arc;

use op3dsg_ipc_types::{AFFORDANCES, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS, NodeKind, relation_phrase};

use super::config::PlausibilityConfig;
use super::gate::{Rejection, normalise};
use crate::knowledge::{KnowledgeBase, ObjectId, PartId};
use crate::prior::{PriorGraph, PriorNode};

/// Bit of a functional relation id in a relation set (`None` for a spatial id).
fn relation_bit(relation_id: u16) -> Option<u16> {
    let i = relation_id.checked_sub(FUNCTIONAL_RELATION_BASE)?;
    ((i as usize) < FUNCTIONAL_RELATIONS.len()).then(|| 1 << i)
}

/// `(part, object)` box gap, metres (0 when they touch or overlap).
fn box_gap(a: &PriorNode, b: &PriorNode) -> f32 {
    (a.box_min_m - b.box_max_m).max(b.box_min_m - a.box_max_m).max(glam::Vec3::ZERO).length()
}

/// The rules, with the knowledge base's relation and affordance sets per category compiled once.
#[derive(Debug, Clone)]
pub struct Plausibility {
    enabled: bool,
    part_max_gap_m: f32,
    remote_max_distance_m: [Option<f32>; FUNCTIONAL_RELATIONS.len()],
    part_max_extent_m: [Option<f32>; AFFORDANCES.len()],
    knowledge: Arc<KnowledgeBase>,
    /// Per object category: the relations of its pairs (bits over `FUNCTIONAL_RELATIONS`).
    object_relations: Vec<u16>,
    /// Per object category: its own affordances and its parts' (bits over `AFFORDANCES`).
    object_affordances: Vec<u16>,
    /// Per part category: its relations on any object.
    part_relations: Vec<u16>,
    /// Per part category: its defaults and its affordances on any object.
    part_affordances: Vec<u16>,
    /// Relations some object-part pair has.
    local_relations: u16,
}

/// Why an item is implausible: the reason and what was wrong (for the log).
pub type Verdict = Result<(), (Rejection, String)>;

/// Index of `key` in `table`, compared as normalised phrases (`remote_to_control`).
fn index_in(table: &[&str], key: &str) -> Option<usize> {
    let key = normalise(key);
    table.iter().position(|p| normalise(p) == key)
}

impl Plausibility {
    /// The rules of `config` over `knowledge` (keys validated by `PlausibilityConfig::validate`;
    /// unknown ones are ignored here).
    pub fn new(config: &PlausibilityConfig, knowledge: Arc<KnowledgeBase>) -> Self {
        let mut remote_max_distance_m = [None; FUNCTIONAL_RELATIONS.len()];
        for (key, &m) in &config.remote_max_distance_m {
            if let Some(i) = index_in(&FUNCTIONAL_RELATIONS, key) {
                remote_max_distance_m[i] = Some(m);
            }
        }
        let mut part_max_extent_m = [None; AFFORDANCES.len()];
        for (key, &m) in &config.part_max_extent_m {
            if let Some(i) = index_in(&AFFORDANCES, key) {
                part_max_extent_m[i] = Some(m);
            }
        }
        let mut object_relations = Vec::with_capacity(knowledge.objects().len());
        let mut object_affordances = Vec::with_capacity(knowledge.objects().len());
        let mut part_relations = vec![0u16; knowledge.parts().len()];
        let mut part_affordances: Vec<u16> = knowledge.parts().iter().map(|p| p.affordance_bits).collect();
        let mut local_relations = 0u16;
        for object in knowledge.objects() {
            let (mut relations, mut affordances) = (0u16, object.affordance_bits);
            for pair in &object.parts {
                let bit = pair.relation_id.and_then(relation_bit).unwrap_or(0);
                relations |= bit;
                affordances |= pair.affordance_bits;
                part_relations[pair.part.0 as usize] |= bit;
                part_affordances[pair.part.0 as usize] |= pair.affordance_bits;
            }
            local_relations |= relations;
            object_relations.push(relations);
            object_affordances.push(affordances);
        }
        Self {
            enabled: config.enabled,
            part_max_gap_m: config.part_max_gap_m,
            remote_max_distance_m,
            part_max_extent_m,
            knowledge,
            object_relations,
            object_affordances,
            part_relations,
            part_affordances,
            local_relations,
        }
    }

    /// Rules that accept everything (`enabled = false`).
    pub fn disabled(knowledge: Arc<KnowledgeBase>) -> Self {
        Self::new(&PlausibilityConfig { enabled: false, ..PlausibilityConfig::default() }, knowledge)
    }

    fn object_name(&self, id: ObjectId) -> &str {
        &self.knowledge.object(id).name
    }

    fn part_name(&self, id: PartId) -> &str {
        &self.knowledge.part(id).name
    }

    /// A local relation `part → object` (a part-of pair of `prior`, checked by the gate).
    pub fn local(&self, part: &PriorNode, object: &PriorNode, relation_id: u16) -> Verdict {
        if !self.enabled {
            return Ok(());
        }
        let phrase = relation_phrase(relation_id).unwrap_or("?");
        let gap = box_gap(part, object);
        if gap > self.part_max_gap_m {
            return Err((
                Rejection::ImplausibleGeometry,
                format!(
                    "{} -> {}: the part's box is {gap:.2} m from its object's (part_max_gap_m = {})",
                    part.id, object.id, self.part_max_gap_m
                ),
            ));
        }
        let Some(bit) = relation_bit(relation_id) else { return Ok(()) };
        if self.local_relations & bit == 0 {
            return Err((
                Rejection::ImplausibleRelation,
                format!("{} -> {}: {phrase:?} is no part's relation to its own object", part.id, object.id),
            ));
        }
        let part_category = part.category.and_then(|c| c.part());
        let object_category = object.category.and_then(|c| c.object());
        if let (Some(p), Some(o)) = (part_category, object_category)
            && self.knowledge.pair(p, o).is_some_and(|pair| pair.relation_id.is_none())
        {
            return Err((
                Rejection::ImplausibleRelation,
                format!(
                    "{} -> {}: a {}'s {} acts on something else, not on the {}",
                    part.id,
                    object.id,
                    self.object_name(o),
                    self.part_name(p),
                    self.object_name(o)
                ),
            ));
        }
        // The categories that know relations vote; any one of them knowing this one suffices.
        let hint = part.category.and_then(|c| c.object_hint);
        let mut voters: Vec<&str> = Vec::new();
        let mut supported = false;
        for o in [object_category, hint].into_iter().flatten() {
            let known = self.object_relations[o.0 as usize];
            if known != 0 {
                supported |= known & bit != 0;
                voters.push(self.object_name(o));
            }
        }
        if let Some(p) = part_category {
            let known = self.part_relations[p.0 as usize];
            if known != 0 {
                supported |= known & bit != 0;
                voters.push(self.part_name(p));
            }
        }
        if voters.is_empty() || supported {
            return Ok(());
        }
        Err((
            Rejection::ImplausibleRelation,
            format!(
                "{} -> {}: the knowledge base knows {phrase:?} for none of: {}",
                part.id,
                object.id,
                voters.join(", ")
            ),
        ))
    }

    /// A remote relation `source → target` (a candidate pair the prompt offered).
    pub fn remote(&self, source: &PriorNode, target: &PriorNode, relation_id: u16) -> Verdict {
        if !self.enabled {
            return Ok(());
        }
        let phrase = relation_phrase(relation_id).unwrap_or("?");
        let distance = source.centre_m.distance(target.centre_m);
        let target_category = target.category.and_then(|c| c.object());
        let mut limit: Option<f32> = None;
        if let Some(resolved) = source.category {
            let mut templates = self.knowledge.remote_templates_for(resolved.category).peekable();
            if templates.peek().is_some() {
                for t in templates {
                    if t.relation_id == relation_id && target_category.is_some_and(|c| t.targets.contains(&c)) {
                        limit = Some(limit.map_or(t.max_distance_m, |l: f32| l.max(t.max_distance_m)));
                    }
                }
                if limit.is_none() {
                    let target_name = target_category.map_or("an unknown object", |c| self.object_name(c));
                    return Err((
                        Rejection::ImplausibleRelation,
                        format!(
                            "{} -> {}: {phrase:?} is not how the knowledge base's remote templates let a {} act on {target_name}",
                            source.id, target.id, source.label
                        ),
                    ));
                }
            }
        }
        let profile =
            relation_bit(relation_id).map(|b| b.trailing_zeros() as usize).and_then(|i| self.remote_max_distance_m[i]);
        let limit = match (limit, profile) {
            (Some(l), Some(p)) => Some(l.min(p)),
            (l, p) => l.or(p),
        };
        if let Some(limit) = limit
            && (distance.is_nan() || distance > limit)
        {
            return Err((
                Rejection::ImplausibleGeometry,
                format!("{} -> {}: {distance:.2} m apart, beyond {limit:.2} m for {phrase:?}", source.id, target.id),
            ));
        }
        Ok(())
    }

    /// Affordance `AFFORDANCES[index]` on `node` of `prior`.
    pub fn affordance(&self, prior: &PriorGraph, node: &PriorNode, index: usize) -> Verdict {
        if !self.enabled {
            return Ok(());
        }
        let name = AFFORDANCES.get(index).copied().unwrap_or("?");
        if node.kind == NodeKind::Part
            && let Some(limit) = self.part_max_extent_m.get(index).copied().flatten()
        {
            let extent = (node.box_max_m - node.box_min_m).max_element();
            if extent > limit {
                return Err((
                    Rejection::ImplausibleGeometry,
                    format!(
                        "node {}: {name:?} on a part {extent:.2} m long (part_max_extent_m.{name} = {limit})",
                        node.id
                    ),
                ));
            }
        }
        // The categories that know affordances vote; any one of them knowing this one suffices.
        let mut sets: Vec<(u16, String)> = Vec::new();
        if let Some(resolved) = node.category {
            if let Some(o) = resolved.object() {
                sets.push((self.object_affordances[o.0 as usize], format!("a {} (or its parts)", self.object_name(o))));
            }
            if let Some(p) = resolved.part() {
                sets.push((self.part_affordances[p.0 as usize], format!("a {}", self.part_name(p))));
            }
            if node.kind == NodeKind::Part
                && let Some(hint) = resolved.object_hint
            {
                sets.push((self.object_affordances[hint.0 as usize], format!("a {}'s parts", self.object_name(hint))));
            }
        }
        if node.kind == NodeKind::Part
            && let Some(parent) = node.parent_id.and_then(|id| prior.index_of(id)).map(|i| &prior.nodes[i])
            && let Some(o) = parent.category.and_then(|c| c.object())
        {
            sets.push((self.object_affordances[o.0 as usize], format!("a {}'s parts", self.object_name(o))));
        }
        sets.retain(|(known, _)| *known != 0);
        let bit = 1u16 << index;
        if sets.is_empty() || sets.iter().any(|(known, _)| known & bit != 0) {
            return Ok(());
        }
        let voters: Vec<&str> = sets.iter().map(|(_, who)| who.as_str()).collect();
        Err((
            Rejection::ImplausibleAffordance,
            format!(
                "node {} ({}): the knowledge base knows {name:?} for none of: {}",
                node.id,
                node.label,
                voters.join(", ")
            ),
        ))
    }
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::{affordance_bits, relation_id};

    use super::*;
    use crate::reasoner::llm::prompt::tests::corner_prior;

    fn id(phrase: &str) -> u16 {
        relation_id(phrase).unwrap().1
    }

    fn rules(config: PlausibilityConfig) -> (Plausibility, PriorGraph) {
        let (prior, kb) = corner_prior();
        (Plausibility::new(&config, Arc::new(kb)), prior)
    }

    fn node(prior: &PriorGraph, id: u32) -> &PriorNode {
        &prior.nodes[prior.index_of(id).unwrap()]
    }

    fn reason(verdict: Verdict) -> Option<Rejection> {
        verdict.err().map(|(reason, _)| reason)
    }

    fn bit(name: &str) -> usize {
        affordance_bits([name]).unwrap().trailing_zeros() as usize
    }

    #[test]
    fn local_relations_need_an_attached_part_and_a_relation_some_category_has() {
        let (r, mut prior) = rules(PlausibilityConfig::default());
        let (handle, cabinet) = (node(&prior, 5), node(&prior, 1));
        assert_eq!(reason(r.local(handle, cabinet, id("pull to open or close"))), None);
        // The cabinet's latch opens by pushing: a soft prior lets the handle do it too.
        assert_eq!(reason(r.local(handle, cabinet, id("push or press to open"))), None);
        assert_eq!(reason(r.local(handle, cabinet, id("remote to control"))), Some(Rejection::ImplausibleRelation));
        assert_eq!(reason(r.local(handle, cabinet, id("provide power"))), Some(Rejection::ImplausibleRelation));
        let (_, detail) = r.local(handle, cabinet, id("press to flush")).unwrap_err();
        assert!(
            detail.contains("press to flush") && detail.contains("cabinet") && detail.contains("handle"),
            "{detail}"
        );
        // The same handle 40 cm off its cabinet.
        let i = prior.index_of(5).unwrap();
        prior.nodes[i].box_min_m.x -= 0.8;
        prior.nodes[i].box_max_m.x -= 0.8;
        let (far, cabinet) = (node(&prior, 5), node(&prior, 1));
        let (reason_far, detail) = r.local(far, cabinet, id("pull to open or close")).unwrap_err();
        assert_eq!(reason_far, Rejection::ImplausibleGeometry);
        assert!(detail.contains("0.40 m"), "{detail}");
        // Off: anything canonical passes.
        let off = Plausibility::disabled(r.knowledge.clone());
        assert_eq!(reason(off.local(far, cabinet, id("remote to control"))), None);
    }

    #[test]
    fn unknown_categories_say_nothing() {
        let (r, mut prior) = rules(PlausibilityConfig::default());
        for i in [prior.index_of(5).unwrap(), prior.index_of(1).unwrap()] {
            prior.nodes[i].category = None;
        }
        let (part, object) = (node(&prior, 5), node(&prior, 1));
        assert_eq!(reason(r.local(part, object, id("press to flush"))), None);
        // Except that no part is known to act on its own object by remote.
        assert_eq!(reason(r.local(part, object, id("remote to control"))), Some(Rejection::ImplausibleRelation));
        assert_eq!(reason(r.affordance(&prior, object, bit("foot_push"))), None);
    }

    #[test]
    fn remote_relations_follow_the_templates_and_their_distances() {
        let (r, prior) = rules(PlausibilityConfig::default());
        let (remote, tv) = (node(&prior, 4), node(&prior, 3));
        assert_eq!(reason(r.remote(remote, tv, id("remote to control"))), None);
        assert_eq!(reason(r.remote(remote, tv, id("provide power"))), Some(Rejection::ImplausibleRelation));
        // 1.73 m apart: beyond a profile's 1 m for this relation, within its 10 m template.
        let tight = PlausibilityConfig {
            remote_max_distance_m: [("remote_to_control".to_owned(), 1.0)].into_iter().collect(),
            ..PlausibilityConfig::default()
        };
        let (r, prior) = rules(tight);
        let (verdict, detail) = r.remote(node(&prior, 4), node(&prior, 3), id("remote to control")).unwrap_err();
        assert_eq!(verdict, Rejection::ImplausibleGeometry);
        assert!(detail.contains("1.73 m apart, beyond 1.00 m"), "{detail}");
    }

    #[test]
    fn affordances_need_a_category_that_affords_them_and_a_part_small_enough() {
        let (r, mut prior) = rules(PlausibilityConfig::default());
        let (cabinet, handle) = (node(&prior, 1), node(&prior, 5));
        assert_eq!(reason(r.affordance(&prior, cabinet, bit("foot_push"))), Some(Rejection::ImplausibleAffordance));
        assert_eq!(reason(r.affordance(&prior, cabinet, bit("plug_in"))), Some(Rejection::ImplausibleAffordance));
        // A cabinet is pulled open by its handle: the object affords what its parts do.
        assert_eq!(reason(r.affordance(&prior, cabinet, bit("hook_pull"))), None);
        assert_eq!(reason(r.affordance(&prior, handle, bit("hook_pull"))), None);
        // The cabinet's knobs are pinched: its small handle may be too.
        assert_eq!(reason(r.affordance(&prior, handle, bit("pinch_pull"))), None);
        assert_eq!(reason(r.affordance(&prior, handle, bit("foot_push"))), Some(Rejection::ImplausibleAffordance));
        let remote = node(&prior, 4);
        assert_eq!(reason(r.affordance(&prior, remote, bit("key_press"))), None);
        assert_eq!(reason(r.affordance(&prior, remote, bit("rotate"))), Some(Rejection::ImplausibleAffordance));
        // The stove knob smeared over 60 cm.
        let i = prior.index_of(6).unwrap();
        prior.nodes[i].box_min_m.x = 1.0;
        prior.nodes[i].box_max_m.x = 1.6;
        let (verdict, detail) = r.affordance(&prior, node(&prior, 6), bit("rotate")).unwrap_err();
        assert_eq!(verdict, Rejection::ImplausibleGeometry);
        assert!(detail.contains("0.60 m long") && detail.contains("part_max_extent_m.rotate = 0.5"), "{detail}");
        // Objects are not limited by size: a 1 m TV still has its buttons.
        assert_eq!(reason(r.affordance(&prior, node(&prior, 3), bit("tip_push"))), None);
    }

    #[test]
    fn profile_keys_must_be_canonical() {
        let mut config = PlausibilityConfig::default();
        assert_eq!(config.validate("p"), Ok(()));
        config.remote_max_distance_m.insert("remote_to_control".to_owned(), 3.0);
        config.remote_max_distance_m.insert("provide power".to_owned(), 1.5);
        assert_eq!(config.validate("p"), Ok(()));
        config.part_max_extent_m.insert("lick".to_owned(), 0.1);
        let err = config.validate("reasoner.llm.plausibility").unwrap_err();
        assert!(
            err.starts_with("reasoner.llm.plausibility.part_max_extent_m.lick: not a canonical affordance"),
            "{err}"
        );
        let bad = PlausibilityConfig { part_max_gap_m: -1.0, ..PlausibilityConfig::default() };
        assert!(bad.validate("p").unwrap_err().starts_with("p.part_max_gap_m:"));
    }
}
