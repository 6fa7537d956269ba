//! Knowledge bases the evaluation derives from the robot's: one that never heard of an object
//! category (the leave-one-category-out benchmark), one whose remote templates reach only a
//! neighbourhood (the single-reasoner ablation). The daemon reasons with neither.

use op3dsg_runtime::knowledge::{
    Category, KnowledgeBase, KnowledgeTables, ObjectCategory, ObjectId, PartId, PartPair, RemoteTemplate,
};

/// Variants of a knowledge base (module docs).
pub trait KnowledgeVariants {
    /// A copy that has never heard of the object category `name`; `None` when `name` is no object
    /// category (see the implementation on [`KnowledgeBase`]).
    fn without_object(&self, name: &str) -> Option<KnowledgeBase>;
    /// A copy whose remote templates reach at most `max_distance_m`.
    fn with_remote_reach(&self, max_distance_m: f32) -> KnowledgeBase;
}

impl KnowledgeVariants for KnowledgeBase {
    /// A copy that has never heard of the object category `name` (canonical name): the category,
    /// its synonyms and its object-part pairs are gone, and so are the part categories no other
    /// object has (with their synonyms), the remote templates whose source is gone, and the
    /// category among every remote template's targets (a template left without targets is
    /// dropped). Part categories other objects share stay: they are known from those objects.
    /// The leave-one-category-out benchmark reasons with it. `None` when `name` is no object
    /// category.
    fn without_object(&self, name: &str) -> Option<KnowledgeBase> {
        let tables = self.tables();
        let removed = tables.objects.iter().position(|o| o.name == name)?;
        let exclusive: Vec<bool> = (0..tables.parts.len())
            .map(|p| {
                let id = PartId(p as u16);
                tables.objects[removed].parts.iter().any(|pair| pair.part == id)
                    && !tables
                        .objects
                        .iter()
                        .enumerate()
                        .any(|(o, object)| o != removed && object.parts.iter().any(|pair| pair.part == id))
            })
            .collect();
        let object_map = |id: ObjectId| -> Option<ObjectId> {
            match (id.0 as usize).cmp(&removed) {
                std::cmp::Ordering::Less => Some(id),
                std::cmp::Ordering::Equal => None,
                std::cmp::Ordering::Greater => Some(ObjectId(id.0 - 1)),
            }
        };
        let mut part_ids = Vec::with_capacity(tables.parts.len());
        let mut next = 0u16;
        for gone in &exclusive {
            part_ids.push((!gone).then_some(PartId(next)));
            next += u16::from(!gone);
        }
        let part_map = |id: PartId| part_ids[id.0 as usize];
        let category_map = |c: Category| match c {
            Category::Object(o) => object_map(o).map(Category::Object),
            Category::Part(p) => part_map(p).map(Category::Part),
        };
        let objects = tables
            .objects
            .iter()
            .enumerate()
            .filter(|(o, _)| *o != removed)
            .map(|(_, object)| ObjectCategory {
                name: object.name.clone(),
                affordance_bits: object.affordance_bits,
                parts: object
                    .parts
                    .iter()
                    .filter_map(|pair| part_map(pair.part).map(|part| PartPair { part, ..pair.clone() }))
                    .collect(),
            })
            .collect();
        let parts = tables.parts.iter().zip(&exclusive).filter(|(_, gone)| !**gone).map(|(p, _)| p.clone()).collect();
        let remotes = tables
            .remotes
            .iter()
            .filter_map(|r| {
                let source = category_map(r.source)?;
                let targets: Vec<ObjectId> = r.targets.iter().filter_map(|t| object_map(*t)).collect();
                (!targets.is_empty()).then(|| RemoteTemplate { source, targets, ..r.clone() })
            })
            .collect();
        let labels = tables.labels.iter().filter_map(|(k, c)| category_map(*c).map(|c| (k.clone(), c))).collect();
        Some(KnowledgeBase::from_tables(KnowledgeTables { objects, parts, remotes, labels }))
    }

    /// A copy whose remote templates reach at most `max_distance_m` (the single-reasoner
    /// ablation, [`crate::reasoning_ablation`]).
    fn with_remote_reach(&self, max_distance_m: f32) -> KnowledgeBase {
        let mut tables = self.tables();
        for r in &mut tables.remotes {
            r.max_distance_m = r.max_distance_m.min(max_distance_m);
        }
        KnowledgeBase::from_tables(tables)
    }
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::relation_phrase;
    use op3dsg_runtime::knowledge::fallback::LabelFallback;

    use super::*;

    fn kb() -> KnowledgeBase {
        KnowledgeBase::builtin().expect("built-in knowledge base")
    }

    #[test]
    fn without_object_forgets_the_category_and_its_own_parts_only() {
        let kb = kb();
        let toilet = kb.object_category("toilet").unwrap();
        let own: Vec<String> = kb.parts_of(toilet).iter().map(|p| kb.part(p.part).name.clone()).collect();
        let loco = kb.without_object("toilet").unwrap();
        assert_eq!(loco.objects().len(), kb.objects().len() - 1);
        assert_eq!(loco.object_category("toilet"), None);
        assert_eq!(loco.object_category("wc"), None, "synonyms go with the category");
        assert_eq!(loco.pair_count(), kb.pair_count() - own.len());
        // A part only the toilet has is gone; one other objects have stays, with its pairs.
        let shared: Vec<&String> = own
            .iter()
            .filter(|p| kb.objects().iter().filter(|o| o.parts.iter().any(|q| &kb.part(q.part).name == *p)).count() > 1)
            .collect();
        assert!(loco.parts().len() < kb.parts().len() || shared.len() == own.len());
        for p in &shared {
            assert!(loco.parts().iter().any(|q| &q.name == *p), "{p} is shared and must stay");
        }
        // Ids are renumbered consistently: every other object keeps its pairs and relations.
        let cabinet = loco.object_category("cabinet").unwrap();
        let handle = loco.resolve("handle").unwrap().part().unwrap();
        let relation = loco.local_relation(handle, cabinet).unwrap();
        assert_eq!(op3dsg_ipc_types::relation_phrase(relation), Some("pull to open or close"));
        // Remote targets lose it; a category nothing targets leaves the templates alone.
        let light = kb.without_object("ceiling light").unwrap();
        let switch = light.resolve("light switch").unwrap().category;
        assert!(
            light
                .remote_templates_for(switch)
                .all(|t| t.targets.iter().all(|o| light.object(*o).name != "ceiling light"))
        );
        assert!(light.remote_templates_for(switch).next().is_some());
        assert!(kb.without_object("unicorn").is_none());
    }

    #[test]
    fn a_knowledge_base_without_the_cabinet_still_has_a_handle_rule_from_the_other_objects() {
        let loco = kb().without_object("cabinet").unwrap();
        let fallback = LabelFallback::new(&loco, None);
        let handle = loco.resolve("handle").unwrap().part().unwrap();
        assert_eq!(fallback.rule(handle).relation_id.and_then(relation_phrase), Some("pull to open or close"));
    }
}
