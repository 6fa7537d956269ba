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

use std::path::Path;

use op3dsg_ipc_types::{EdgeKind, affordance_bits, relation_id};
use rustc_hash::FxHashMap;
use serde::Deserialize;

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

// ---- file formats --------------------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectsFile {
    #[serde(default)]
    object: Vec<ObjectEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectEntry {
    name: String,
    #[serde(default)]
    synonyms: Vec<String>,
    #[serde(default)]
    affordances: Vec<String>,
    #[serde(default)]
    parts: Vec<PairEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PairEntry {
    part: String,
    affordances: Option<Vec<String>>,
    relation: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PartsFile {
    #[serde(default)]
    part: Vec<PartEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PartEntry {
    name: String,
    #[serde(default)]
    synonyms: Vec<String>,
    #[serde(default)]
    affordances: Vec<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RemoteFile {
    #[serde(default)]
    remote: Vec<RemoteEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RemoteEntry {
    source: String,
    targets: Vec<String>,
    relation: String,
    max_distance_m: f32,
    confidence: f32,
    #[serde(default)]
    choose: TargetChoice,
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

fn parse<T: serde::de::DeserializeOwned>(file: &str, text: &str) -> Result<T, KnowledgeError> {
    toml::from_str(text).map_err(|e| KnowledgeError {
        file: file.to_owned(),
        path: "-".to_owned(),
        message: e.to_string().trim().replace('\n', " "),
    })
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

struct Checker<'a> {
    file: &'a str,
}

impl Checker<'_> {
    fn error(&self, path: impl Into<String>, message: impl Into<String>) -> KnowledgeError {
        KnowledgeError { file: self.file.to_owned(), path: path.into(), message: message.into() }
    }

    fn affordances(&self, path: &str, names: &[String]) -> Result<u16, KnowledgeError> {
        let mut seen: Vec<&str> = Vec::new();
        for (i, name) in names.iter().enumerate() {
            if seen.contains(&name.as_str()) {
                return Err(self.error(format!("{path}[{i}]"), format!("duplicate affordance \"{name}\"")));
            }
            seen.push(name);
        }
        affordance_bits(names.iter().map(String::as_str)).map_err(|bad| {
            let i = names.iter().position(|n| n == bad).unwrap_or(0);
            self.error(
                format!("{path}[{i}]"),
                format!("\"{bad}\" is not a canonical affordance (one of {:?})", op3dsg_ipc_types::AFFORDANCES),
            )
        })
    }

    fn relation(&self, path: &str, phrase: &str) -> Result<u16, KnowledgeError> {
        match relation_id(phrase) {
            Some((EdgeKind::Functional, id)) => Ok(id),
            _ => Err(self.error(
                path,
                format!(
                    "\"{phrase}\" is not a canonical functional relation (one of {:?})",
                    op3dsg_ipc_types::FUNCTIONAL_RELATIONS
                ),
            )),
        }
    }
}

impl KnowledgeBase {
    /// The tables of `[reasoner] knowledge_dir` when set, else the built-in ones.
    pub fn from_profile_dir(dir: Option<&str>) -> Result<Self, KnowledgeError> {
        match dir {
            Some(dir) => Self::load_dir(Path::new(dir)),
            None => Self::builtin(),
        }
    }

    /// The knowledge base compiled into the binary.
    pub fn builtin() -> Result<Self, KnowledgeError> {
        Self::from_sources(KnowledgeSources {
            objects: (OBJECTS_FILE, BUILTIN_OBJECTS_TOML),
            parts: (PARTS_FILE, BUILTIN_PARTS_TOML),
            remote: (REMOTE_FILE, BUILTIN_REMOTE_TOML),
        })
    }

    /// Loads `objects.toml`, `parts.toml` and `remote.toml` from `dir`.
    pub fn load_dir(dir: &Path) -> Result<Self, KnowledgeError> {
        let read =
            |name: &str| {
                let path = dir.join(name);
                std::fs::read_to_string(&path).map(|text| (path.display().to_string(), text)).map_err(|e| {
                    KnowledgeError { file: path.display().to_string(), path: "-".to_owned(), message: e.to_string() }
                })
            };
        let objects = read(OBJECTS_FILE)?;
        let parts = read(PARTS_FILE)?;
        let remote = read(REMOTE_FILE)?;
        Self::from_sources(KnowledgeSources {
            objects: (&objects.0, &objects.1),
            parts: (&parts.0, &parts.1),
            remote: (&remote.0, &remote.1),
        })
    }

    /// Parses and validates the three tables.
    pub fn from_sources(sources: KnowledgeSources<'_>) -> Result<Self, KnowledgeError> {
        let (parts_file, parts_text) = sources.parts;
        let (objects_file, objects_text) = sources.objects;
        let (remote_file, remote_text) = sources.remote;
        let parts_raw: PartsFile = parse(parts_file, parts_text)?;
        let objects_raw: ObjectsFile = parse(objects_file, objects_text)?;
        let remote_raw: RemoteFile = parse(remote_file, remote_text)?;

        let mut labels: FxHashMap<String, Category> = FxHashMap::default();
        // Where each label was defined, for duplicate messages.
        let mut defined_at: FxHashMap<String, String> = FxHashMap::default();
        let mut define = |checker: &Checker<'_>, path: String, label: &str, category: Category| {
            let key = normalise(label);
            if key.is_empty() {
                return Err(checker.error(path, "empty name"));
            }
            if key != label {
                return Err(checker.error(path, format!("\"{label}\" is not normalised (write \"{key}\")")));
            }
            if let Some(first) = defined_at.get(&key) {
                return Err(checker.error(path, format!("\"{label}\" is already defined at {first}")));
            }
            defined_at.insert(key.clone(), format!("{}: {path}", checker.file));
            labels.insert(key, category);
            Ok(())
        };

        let checker = Checker { file: parts_file };
        let mut parts = Vec::with_capacity(parts_raw.part.len());
        for (i, entry) in parts_raw.part.iter().enumerate() {
            let id = PartId(u16::try_from(i).map_err(|_| checker.error(format!("part[{i}]"), "too many parts"))?);
            let entry_path = format!("part \"{}\"", entry.name);
            define(&checker, format!("{entry_path}.name"), &entry.name, Category::Part(id))?;
            for (j, synonym) in entry.synonyms.iter().enumerate() {
                define(&checker, format!("{entry_path}.synonyms[{j}]"), synonym, Category::Part(id))?;
            }
            let bits = checker.affordances(&format!("{entry_path}.affordances"), &entry.affordances)?;
            parts.push(PartCategory { name: entry.name.clone(), affordance_bits: bits });
        }

        let checker = Checker { file: objects_file };
        let mut objects = Vec::with_capacity(objects_raw.object.len());
        for (i, entry) in objects_raw.object.iter().enumerate() {
            let id = ObjectId(u16::try_from(i).map_err(|_| checker.error(format!("object[{i}]"), "too many objects"))?);
            let entry_path = format!("object \"{}\"", entry.name);
            define(&checker, format!("{entry_path}.name"), &entry.name, Category::Object(id))?;
            for (j, synonym) in entry.synonyms.iter().enumerate() {
                define(&checker, format!("{entry_path}.synonyms[{j}]"), synonym, Category::Object(id))?;
            }
            let bits = checker.affordances(&format!("{entry_path}.affordances"), &entry.affordances)?;
            objects.push(ObjectCategory { name: entry.name.clone(), affordance_bits: bits, parts: Vec::new() });
        }
        let part_by_name: FxHashMap<&str, PartId> =
            parts.iter().enumerate().map(|(i, p)| (p.name.as_str(), PartId(i as u16))).collect();
        let object_by_name: FxHashMap<String, ObjectId> =
            objects.iter().enumerate().map(|(i, o)| (o.name.clone(), ObjectId(i as u16))).collect();

        let mut pairs_per_object = Vec::with_capacity(objects.len());
        for entry in &objects_raw.object {
            let entry_path = format!("object \"{}\"", entry.name);
            let mut pairs: Vec<PartPair> = Vec::with_capacity(entry.parts.len());
            for (j, pair) in entry.parts.iter().enumerate() {
                let pair_path = format!("{entry_path}.parts[{j}]");
                let part = *part_by_name.get(pair.part.as_str()).ok_or_else(|| {
                    checker.error(format!("{pair_path}.part"), format!("unknown part category \"{}\"", pair.part))
                })?;
                if pairs.iter().any(|p| p.part == part) {
                    return Err(checker.error(
                        format!("{pair_path}.part"),
                        format!("duplicate pair \"{}\" - \"{}\"", entry.name, pair.part),
                    ));
                }
                let affordance_bits = match &pair.affordances {
                    Some(names) => checker.affordances(&format!("{pair_path}.affordances"), names)?,
                    None => parts[part.0 as usize].affordance_bits,
                };
                let relation_id = match &pair.relation {
                    Some(phrase) => Some(checker.relation(&format!("{pair_path}.relation"), phrase)?),
                    None => None,
                };
                pairs.push(PartPair { part, affordance_bits, relation_id });
            }
            pairs_per_object.push(pairs);
        }
        for (object, pairs) in objects.iter_mut().zip(pairs_per_object) {
            object.parts = pairs;
        }

        let checker = Checker { file: remote_file };
        let mut remotes = Vec::with_capacity(remote_raw.remote.len());
        for (i, entry) in remote_raw.remote.iter().enumerate() {
            let entry_path = format!("remote[{i}] \"{}\"", entry.source);
            let source = if let Some(id) = object_by_name.get(entry.source.as_str()) {
                Category::Object(*id)
            } else if let Some(id) = part_by_name.get(entry.source.as_str()) {
                Category::Part(*id)
            } else {
                return Err(checker.error(
                    format!("{entry_path}.source"),
                    format!("unknown object or part category \"{}\"", entry.source),
                ));
            };
            if entry.targets.is_empty() {
                return Err(checker.error(format!("{entry_path}.targets"), "no targets"));
            }
            let mut targets = Vec::with_capacity(entry.targets.len());
            for (j, target) in entry.targets.iter().enumerate() {
                let id = *object_by_name.get(target.as_str()).ok_or_else(|| {
                    checker.error(format!("{entry_path}.targets[{j}]"), format!("unknown object category \"{target}\""))
                })?;
                if targets.contains(&id) || source == Category::Object(id) {
                    return Err(checker.error(
                        format!("{entry_path}.targets[{j}]"),
                        format!("duplicate or self target \"{target}\""),
                    ));
                }
                targets.push(id);
            }
            let relation_id = checker.relation(&format!("{entry_path}.relation"), &entry.relation)?;
            if !(entry.max_distance_m.is_finite() && entry.max_distance_m > 0.0) {
                return Err(
                    checker.error(format!("{entry_path}.max_distance_m"), "must be a positive number of metres")
                );
            }
            if !(entry.confidence > 0.0 && entry.confidence <= 1.0) {
                return Err(checker.error(format!("{entry_path}.confidence"), "must be in (0, 1]"));
            }
            if remotes.iter().any(|r: &RemoteTemplate| r.source == source && r.relation_id == relation_id) {
                return Err(checker.error(
                    format!("{entry_path}.source"),
                    format!("duplicate template for \"{}\" and \"{}\"", entry.source, entry.relation),
                ));
            }
            remotes.push(RemoteTemplate {
                source,
                targets,
                relation_id,
                max_distance_m: entry.max_distance_m,
                confidence: entry.confidence,
                choose: entry.choose,
            });
        }
        Ok(Self { objects, parts, remotes, labels })
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

    /// A copy that has never heard of the object category `name` (canonical name): the category,
    /// its synonyms and its object-part pairs are gone, and so are the part categories no other
    /// object has (with their synonyms), the remote templates whose source is gone, and the
    /// category among every remote template's targets (a template left without targets is
    /// dropped). Part categories other objects share stay: they are known from those objects.
    /// The leave-one-category-out benchmark reasons with it. `None` when `name` is no object
    /// category.
    pub fn without_object(&self, name: &str) -> Option<Self> {
        let removed = self.objects.iter().position(|o| o.name == name)?;
        let exclusive: Vec<bool> = (0..self.parts.len())
            .map(|p| {
                let id = PartId(p as u16);
                self.objects[removed].parts.iter().any(|pair| pair.part == id)
                    && !self
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
        let mut part_ids = Vec::with_capacity(self.parts.len());
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
        let objects = self
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
        let parts = self.parts.iter().zip(&exclusive).filter(|(_, gone)| !**gone).map(|(p, _)| p.clone()).collect();
        let remotes = self
            .remotes
            .iter()
            .filter_map(|r| {
                let source = category_map(r.source)?;
                let targets: Vec<ObjectId> = r.targets.iter().filter_map(|t| object_map(*t)).collect();
                (!targets.is_empty()).then(|| RemoteTemplate { source, targets, ..r.clone() })
            })
            .collect();
        let labels = self.labels.iter().filter_map(|(k, c)| category_map(*c).map(|c| (k.clone(), c))).collect();
        Some(Self { objects, parts, remotes, labels })
    }

    /// A copy whose remote templates reach at most `max_distance_m` (the single-reasoner
    /// ablation, `crate::reasoner::ablation`).
    pub fn with_remote_reach(&self, max_distance_m: f32) -> Self {
        let mut kb = self.clone();
        for r in &mut kb.remotes {
            r.max_distance_m = r.max_distance_m.min(max_distance_m);
        }
        kb
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kb() -> KnowledgeBase {
        KnowledgeBase::builtin().expect("built-in knowledge base")
    }

    #[test]
    fn builtin_has_paper_scale() {
        let kb = kb();
        assert!(kb.objects().len() >= 85, "{} object categories", kb.objects().len());
        assert!(kb.parts().len() >= 60, "{} part categories", kb.parts().len());
        assert!(kb.pair_count() >= 190, "{} pairs", kb.pair_count());
        // Every part category is used by some object or remote template.
        for (i, part) in kb.parts().iter().enumerate() {
            let id = PartId(i as u16);
            let used = kb.objects().iter().any(|o| o.parts.iter().any(|p| p.part == id))
                || kb.remote_templates().iter().any(|r| r.source == Category::Part(id));
            assert!(used, "part \"{}\" is used nowhere", part.name);
        }
    }

    #[test]
    fn resolution_rules() {
        let kb = kb();
        let name = |label: &str| match kb.resolve(label).map(|r| r.category) {
            Some(Category::Object(id)) => kb.object(id).name.clone(),
            Some(Category::Part(id)) => kb.part(id).name.clone(),
            None => "-".into(),
        };
        assert_eq!(name("  Refrigerator "), "fridge");
        assert_eq!(name("drawers"), "drawer");
        assert_eq!(name("trash_cans"), "trash can");
        assert_eq!(name("Power-Outlet"), "outlet");
        assert_eq!(name("microwave oven"), "microwave");
        assert_eq!(name("cabinet handles"), "handle");
        assert_eq!(name("unicorn"), "-");
        let handle = kb.resolve("cabinet handle").unwrap();
        assert_eq!(handle.object_hint.map(|o| kb.object(o).name.as_str()), Some("cabinet"));
        let deep = kb.resolve("tv stand drawer handle").unwrap();
        assert_eq!(deep.object_hint.map(|o| kb.object(o).name.as_str()), Some("drawer"));
        let brass = kb.resolve("brass knob").unwrap();
        assert_eq!((brass.part().map(|p| kb.part(p).name.as_str()), brass.object_hint), (Some("knob"), None));
    }

    #[test]
    fn affordances_depend_on_the_parent() {
        let kb = kb();
        let knob = kb.resolve("knob").unwrap().part().unwrap();
        let cabinet = kb.object_category("cabinet").unwrap();
        let drawer = kb.object_category("drawer").unwrap();
        let names = |bits| op3dsg_ipc_types::affordance_names(bits).collect::<Vec<_>>();
        assert_eq!(names(kb.part_affordances(knob, Some(cabinet))), ["rotate", "pinch_pull"]);
        assert_eq!(names(kb.part_affordances(knob, Some(drawer))), ["pinch_pull"]);
        assert_eq!(names(kb.part_affordances(knob, None)), ["rotate"]);
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

    fn load(objects: &str, parts: &str, remote: &str) -> Result<KnowledgeBase, KnowledgeError> {
        KnowledgeBase::from_sources(KnowledgeSources {
            objects: ("objects.toml", objects),
            parts: ("parts.toml", parts),
            remote: ("remote.toml", remote),
        })
    }

    const PARTS: &str = "[[part]]\nname = \"knob\"\naffordances = [\"rotate\"]\n";
    const OBJECTS: &str = "[[object]]\nname = \"stove\"\nparts = [{ part = \"knob\", relation = \"rotate to adjust the setting or temperature\" }]\n";

    #[test]
    fn load_dir_reads_the_three_files_and_names_the_path_in_errors() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(OBJECTS_FILE), BUILTIN_OBJECTS_TOML).unwrap();
        std::fs::write(dir.path().join(PARTS_FILE), BUILTIN_PARTS_TOML).unwrap();
        std::fs::write(dir.path().join(REMOTE_FILE), BUILTIN_REMOTE_TOML).unwrap();
        let kb = KnowledgeBase::load_dir(dir.path()).unwrap();
        assert_eq!(kb.pair_count(), KnowledgeBase::builtin().unwrap().pair_count());
        let bad = BUILTIN_REMOTE_TOML.replace("\"remote to control\"", "\"beam to control\"");
        std::fs::write(dir.path().join(REMOTE_FILE), bad).unwrap();
        let error = KnowledgeBase::load_dir(dir.path()).unwrap_err();
        assert_eq!(error.file, dir.path().join(REMOTE_FILE).display().to_string());
        assert!(error.path.ends_with(".relation"), "{error}");
        std::fs::remove_file(dir.path().join(PARTS_FILE)).unwrap();
        let missing = KnowledgeBase::load_dir(dir.path()).unwrap_err();
        assert!(missing.file.ends_with(PARTS_FILE), "{missing}");
    }

    #[test]
    fn minimal_tables_load() {
        let kb = load(OBJECTS, PARTS, "").unwrap();
        assert_eq!(kb.pair_count(), 1);
    }

    #[test]
    fn validation_errors_name_file_entry_and_field() {
        let cases: [(&str, &str, &str, &str); 9] = [
            (
                OBJECTS,
                "[[part]]\nname = \"knob\"\naffordances = [\"twist\"]\n",
                "",
                "parts.toml: part \"knob\".affordances[0]: \"twist\" is not a canonical affordance",
            ),
            (
                "[[object]]\nname = \"stove\"\nparts = [{ part = \"knob\", relation = \"twist it\" }]\n",
                PARTS,
                "",
                "objects.toml: object \"stove\".parts[0].relation: \"twist it\" is not a canonical functional relation",
            ),
            (
                "[[object]]\nname = \"stove\"\nparts = [{ part = \"dial\" }]\n",
                PARTS,
                "",
                "objects.toml: object \"stove\".parts[0].part: unknown part category \"dial\"",
            ),
            (
                "[[object]]\nname = \"stove\"\nsynonyms = [\"knob\"]\n",
                PARTS,
                "",
                "objects.toml: object \"stove\".synonyms[0]: \"knob\" is already defined at parts.toml: part \"knob\".name",
            ),
            (
                "[[object]]\nname = \"stove\"\nparts = [{ part = \"knob\" }, { part = \"knob\" }]\n",
                PARTS,
                "",
                "objects.toml: object \"stove\".parts[1].part: duplicate pair",
            ),
            (
                OBJECTS,
                PARTS,
                "[[remote]]\nsource = \"knob\"\ntargets = [\"oven\"]\nrelation = \"provide power\"\nmax_distance_m = 1.0\nconfidence = 0.5\n",
                "remote.toml: remote[0] \"knob\".targets[0]: unknown object category \"oven\"",
            ),
            (
                OBJECTS,
                PARTS,
                "[[remote]]\nsource = \"remote\"\ntargets = [\"stove\"]\nrelation = \"provide power\"\nmax_distance_m = 1.0\nconfidence = 0.5\n",
                "remote.toml: remote[0] \"remote\".source: unknown object or part category",
            ),
            (
                OBJECTS,
                PARTS,
                "[[remote]]\nsource = \"knob\"\ntargets = [\"stove\"]\nrelation = \"part of\"\nmax_distance_m = 1.0\nconfidence = 0.5\n",
                "remote.toml: remote[0] \"knob\".relation: \"part of\" is not a canonical functional relation",
            ),
            (OBJECTS, "[[part]]\nname = \"Knob\"\n", "", "parts.toml: part \"Knob\".name: \"Knob\" is not normalised"),
        ];
        for (objects, parts, remote, expected) in cases {
            let error = load(objects, parts, remote).expect_err(expected).to_string();
            assert!(error.starts_with(expected), "got: {error}\nexpected: {expected}");
        }
        let unknown_field = load("[[object]]\nname = \"stove\"\ncolour = \"red\"\n", PARTS, "").unwrap_err();
        assert_eq!(unknown_field.file, "objects.toml");
        assert!(unknown_field.message.contains("colour"), "{unknown_field}");
    }
}
