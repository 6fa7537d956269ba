//! The knowledge base: object categories and their interactive parts, affordances, local
//! functional-relation templates (part → its parent object) and remote templates (a source
//! acting on a separate object), with synonyms.
//!
//! The tables are TOML written by this project, in `profiles/knowledge/` (`objects.toml`,
//! `parts.toml`, `remote.toml`; each file's header documents its fields). They are compiled into
//! the binary ([`KnowledgeBase::builtin`]); a profile may point at another folder with the same
//! three files ([`KnowledgeBase::load_dir`]).
//!
//! Loading is strict: unknown fields are refused, every affordance must be one of
//! [`op3dsg_ipc_types::AFFORDANCES`], every relation one of
//! [`op3dsg_ipc_types::FUNCTIONAL_RELATIONS`], every name or synonym may map to one category
//! only, templates may name only known categories. Errors read `file: entry.field: message`.
//!
//! Labels are resolved by [`KnowledgeBase::resolve`]: lower case, `_`/`-` as spaces, trimmed,
//! whitespace collapsed; then the exact name or synonym; then the singular of the last word;
//! then, for compound part labels, an object prefix and a part suffix ("cabinet handle" →
//! part `handle`, object hint `cabinet`).
//!
//! ```
//! let kb = op3dsg_runtime::knowledge::KnowledgeBase::builtin().unwrap();
//! let knob = kb.resolve("Stove Knob").unwrap();
//! let stove = knob.object_hint.unwrap();
//! let relation = kb.local_relation(knob.part().unwrap(), stove).unwrap();
//! assert_eq!(op3dsg_ipc_types::relation_phrase(relation), Some("rotate to adjust the setting or temperature"));
//! ```

use rustc_hash::FxHashMap;
use serde::Deserialize;

pub mod fallback;
mod load;
#[cfg(test)]
mod tests;

/// Built-in `objects.toml`.
pub const BUILTIN_OBJECTS_TOML: &str = include_str!("../../../../profiles/knowledge/objects.toml");
/// Built-in `parts.toml`.
pub const BUILTIN_PARTS_TOML: &str = include_str!("../../../../profiles/knowledge/parts.toml");
/// Built-in `remote.toml`.
pub const BUILTIN_REMOTE_TOML: &str = include_str!("../../../../profiles/knowledge/remote.toml");

/// File names of the three tables.
pub const OBJECTS_FILE: &str = "objects.toml";
/// File name of the part table.
pub const PARTS_FILE: &str = "parts.toml";
/// File name of the remote-template table.
pub const REMOTE_FILE: &str = "remote.toml";

/// A knowledge base that could not be loaded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}: {path}: {message}")]
pub struct KnowledgeError {
    /// The file (name, or the path when loaded from disk).
    pub file: String,
    /// Entry and field, e.g. `object "cabinet".parts[1].relation`; `-` for whole-file errors.
    pub path: String,
    /// What is wrong.
    pub message: String,
}

/// Index of an object category.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ObjectId(pub u16);

/// Index of a part category.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PartId(pub u16);

/// What a label names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Category {
    /// An object category.
    Object(ObjectId),
    /// A part category.
    Part(PartId),
}

/// A resolved label.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Resolved {
    /// The canonical category.
    pub category: Category,
    /// For compound part labels ("cabinet handle"), the object named in the prefix.
    pub object_hint: Option<ObjectId>,
}

impl Resolved {
    /// The object category, if the label names an object.
    pub fn object(&self) -> Option<ObjectId> {
        match self.category {
            Category::Object(id) => Some(id),
            Category::Part(_) => None,
        }
    }
    /// The part category, if the label names a part.
    pub fn part(&self) -> Option<PartId> {
        match self.category {
            Category::Part(id) => Some(id),
            Category::Object(_) => None,
        }
    }
}

/// One object-part pair.
#[derive(Debug, Clone, PartialEq)]
pub struct PartPair {
    /// The part category.
    pub part: PartId,
    /// Affordances of this part on this parent (bits over `AFFORDANCES`).
    pub affordance_bits: u16,
    /// Local functional relation part → parent (canonical relation id), if any.
    pub relation_id: Option<u16>,
}

/// One object category.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectCategory {
    /// Canonical name.
    pub name: String,
    /// Affordances of the object handled as a whole.
    pub affordance_bits: u16,
    /// Its interactive parts.
    pub parts: Vec<PartPair>,
}

/// One part category.
#[derive(Debug, Clone, PartialEq)]
pub struct PartCategory {
    /// Canonical name.
    pub name: String,
    /// Default affordances (bits over `AFFORDANCES`).
    pub affordance_bits: u16,
}

/// A remote template: `source` acts on the nearest of `targets` within `max_distance_m`.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteTemplate {
    /// The acting category (object or part).
    pub source: Category,
    /// Target object categories, in order of preference.
    pub targets: Vec<ObjectId>,
    /// Canonical functional relation id.
    pub relation_id: u16,
    /// Centre-to-centre distance limit, metres.
    pub max_distance_m: f32,
    /// Confidence of the resulting edge.
    pub confidence: f32,
    /// How the target is chosen among the candidates within `max_distance_m`.
    pub choose: TargetChoice,
}

/// How a remote template picks its target (`choose` in `remote.toml`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetChoice {
    /// The nearest candidate; ties go to the earlier listed target (outlets, switches).
    #[default]
    Nearest,
    /// The earliest listed target category, the nearest of that category (a remote control
    /// controls the TV before the game console beside it).
    ListedOrder,
}

/// The compiled knowledge base.
#[derive(Debug, Clone)]
pub struct KnowledgeBase {
    objects: Vec<ObjectCategory>,
    parts: Vec<PartCategory>,
    remotes: Vec<RemoteTemplate>,
    labels: FxHashMap<String, Category>,
}

/// The compiled tables of a knowledge base, for code that derives a variant of one (the
/// evaluation's leave-one-category-out knowledge bases). [`KnowledgeBase::from_tables`] takes
/// them as they are: ids in `parts` pairs, templates and `labels` must index `objects` and
/// `parts`.
#[derive(Debug, Clone)]
pub struct KnowledgeTables {
    /// Object categories; [`ObjectId`] indexes them.
    pub objects: Vec<ObjectCategory>,
    /// Part categories; [`PartId`] indexes them.
    pub parts: Vec<PartCategory>,
    /// Remote templates.
    pub remotes: Vec<RemoteTemplate>,
    /// Every normalised name and synonym with its category.
    pub labels: FxHashMap<String, Category>,
}

/// Sources of the three tables: `(file name for messages, TOML text)`.
#[derive(Debug, Clone, Copy)]
pub struct KnowledgeSources<'a> {
    /// `objects.toml`.
    pub objects: (&'a str, &'a str),
    /// `parts.toml`.
    pub parts: (&'a str, &'a str),
    /// `remote.toml`.
    pub remote: (&'a str, &'a str),
}

/// Lower case, `_` and `-` as spaces, trimmed, whitespace collapsed.
pub fn normalise(label: &str) -> String {
    let lowered = label.to_lowercase().replace(['_', '-'], " ");
    lowered.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// The singular of the last word by simple English rules (`drawers` → `drawer`, `shelves` is
/// left alone); `None` when the word does not look plural.
pub fn singular(label: &str) -> Option<String> {
    let (head, last) = match label.rfind(' ') {
        Some(i) => (&label[..=i], &label[i + 1..]),
        None => ("", label),
    };
    let stem = if last.len() > 4 && last.ends_with("ies") {
        format!("{}y", &last[..last.len() - 3])
    } else if ["ches", "shes", "xes", "sses"].iter().any(|s| last.ends_with(s)) {
        last[..last.len() - 2].to_owned()
    } else if last.len() > 3 && last.ends_with('s') && !["ss", "us", "is"].iter().any(|s| last.ends_with(s)) {
        last[..last.len() - 1].to_owned()
    } else {
        return None;
    };
    Some(format!("{head}{stem}"))
}

impl KnowledgeBase {
    /// A knowledge base of tables derived from another's ([`KnowledgeTables`]).
    pub fn from_tables(tables: KnowledgeTables) -> Self {
        let KnowledgeTables { objects, parts, remotes, labels } = tables;
        Self { objects, parts, remotes, labels }
    }

    /// A copy of the compiled tables.
    pub fn tables(&self) -> KnowledgeTables {
        KnowledgeTables {
            objects: self.objects.clone(),
            parts: self.parts.clone(),
            remotes: self.remotes.clone(),
            labels: self.labels.clone(),
        }
    }

    /// Object categories.
    pub fn objects(&self) -> &[ObjectCategory] {
        &self.objects
    }

    /// Part categories.
    pub fn parts(&self) -> &[PartCategory] {
        &self.parts
    }

    /// Remote templates.
    pub fn remote_templates(&self) -> &[RemoteTemplate] {
        &self.remotes
    }

    /// Number of object-part pairs.
    pub fn pair_count(&self) -> usize {
        self.objects.iter().map(|o| o.parts.len()).sum()
    }

    /// The object category.
    pub fn object(&self, id: ObjectId) -> &ObjectCategory {
        &self.objects[id.0 as usize]
    }

    /// The part category.
    pub fn part(&self, id: PartId) -> &PartCategory {
        &self.parts[id.0 as usize]
    }

    fn lookup(&self, key: &str) -> Option<Category> {
        self.labels.get(key).copied().or_else(|| singular(key).and_then(|s| self.labels.get(&s).copied()))
    }

    /// Resolves a detector label (see the module docs for the rules).
    pub fn resolve(&self, label: &str) -> Option<Resolved> {
        let key = normalise(label);
        if let Some(category) = self.lookup(&key) {
            return Some(Resolved { category, object_hint: None });
        }
        // Compound part label: object prefix + part suffix, longest suffix first. The prefix
        // may itself end in the object ("tv stand drawer handle" → drawer).
        let words: Vec<&str> = key.split(' ').collect();
        let mut fallback = None;
        for split in 1..words.len() {
            let Some(Category::Part(part)) = self.lookup(&words[split..].join(" ")) else {
                continue;
            };
            for start in 0..split {
                if let Some(Category::Object(object)) = self.lookup(&words[start..split].join(" ")) {
                    return Some(Resolved { category: Category::Part(part), object_hint: Some(object) });
                }
            }
            fallback.get_or_insert(Resolved { category: Category::Part(part), object_hint: None });
        }
        fallback
    }

    /// The object category a label names, if it names an object.
    pub fn object_category(&self, label: &str) -> Option<ObjectId> {
        self.resolve(label).and_then(|r| r.object())
    }

    /// The parts of an object category.
    pub fn parts_of(&self, object: ObjectId) -> &[PartPair] {
        &self.object(object).parts
    }

    /// The object-part pair, if the knowledge base has it.
    pub fn pair(&self, part: PartId, parent: ObjectId) -> Option<&PartPair> {
        self.parts_of(parent).iter().find(|p| p.part == part)
    }

    /// Affordances of a part given its parent: the pair's, else the part's defaults.
    pub fn part_affordances(&self, part: PartId, parent: Option<ObjectId>) -> u16 {
        parent
            .and_then(|parent| self.pair(part, parent))
            .map_or(self.part(part).affordance_bits, |pair| pair.affordance_bits)
    }

    /// The local functional relation part → parent (canonical relation id), if any.
    pub fn local_relation(&self, part: PartId, parent: ObjectId) -> Option<u16> {
        self.pair(part, parent).and_then(|p| p.relation_id)
    }

    /// Remote templates whose source is `category`.
    pub fn remote_templates_for(&self, category: Category) -> impl Iterator<Item = &RemoteTemplate> {
        self.remotes.iter().filter(move |r| r.source == category)
    }

    /// Every label (names and synonyms, normalised) with the category it names, in no order.
    pub fn labels(&self) -> impl Iterator<Item = (&str, Category)> {
        self.labels.iter().map(|(k, c)| (k.as_str(), *c))
    }
}
