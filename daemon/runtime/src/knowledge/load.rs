//! Loading the three tables (`objects.toml`, `parts.toml`, `remote.toml`): their file formats,
//! the strict checks, and the compiled [`KnowledgeBase`].

use std::path::Path;

use op3dsg_ipc_types::{EdgeKind, affordance_bits, relation_id};
use rustc_hash::FxHashMap;
use serde::Deserialize;

use super::*;

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

fn parse<T: serde::de::DeserializeOwned>(file: &str, text: &str) -> Result<T, KnowledgeError> {
    toml::from_str(text).map_err(|e| KnowledgeError {
        file: file.to_owned(),
        path: "-".to_owned(),
        message: e.to_string().trim().replace('\n', " "),
    })
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

        let mut labels = Labels::default();
        let parts = compile_parts(&Checker { file: parts_file }, &parts_raw, &mut labels)?;
        let checker = Checker { file: objects_file };
        let mut objects = compile_objects(&checker, &objects_raw, &mut labels)?;
        let names = Names {
            parts: parts.iter().enumerate().map(|(i, p)| (p.name.as_str(), PartId(i as u16))).collect(),
            objects: objects.iter().enumerate().map(|(i, o)| (o.name.clone(), ObjectId(i as u16))).collect(),
        };
        attach_pairs(&checker, &objects_raw, &parts, &names, &mut objects)?;
        let remotes = compile_remotes(&Checker { file: remote_file }, &remote_raw, &names)?;
        Ok(Self { objects, parts, remotes, labels: labels.labels })
    }
}

/// Every name and synonym with its category, and where each was defined (for duplicate
/// messages).
#[derive(Default)]
struct Labels {
    labels: FxHashMap<String, Category>,
    defined_at: FxHashMap<String, String>,
}

impl Labels {
    fn define(
        &mut self,
        checker: &Checker<'_>,
        path: String,
        label: &str,
        category: Category,
    ) -> Result<(), KnowledgeError> {
        let key = normalise(label);
        if key.is_empty() {
            return Err(checker.error(path, "empty name"));
        }
        if key != label {
            return Err(checker.error(path, format!("\"{label}\" is not normalised (write \"{key}\")")));
        }
        if let Some(first) = self.defined_at.get(&key) {
            return Err(checker.error(path, format!("\"{label}\" is already defined at {first}")));
        }
        self.defined_at.insert(key.clone(), format!("{}: {path}", checker.file));
        self.labels.insert(key, category);
        Ok(())
    }
}

/// The categories by name, for the pairs and the templates.
struct Names<'a> {
    parts: FxHashMap<&'a str, PartId>,
    objects: FxHashMap<String, ObjectId>,
}

/// `parts.toml`: the part categories, their names and synonyms defined in `labels`.
fn compile_parts(
    checker: &Checker<'_>,
    parts_raw: &PartsFile,
    labels: &mut Labels,
) -> Result<Vec<PartCategory>, KnowledgeError> {
    let mut parts = Vec::with_capacity(parts_raw.part.len());
    for (i, entry) in parts_raw.part.iter().enumerate() {
        let id = PartId(u16::try_from(i).map_err(|_| checker.error(format!("part[{i}]"), "too many parts"))?);
        let entry_path = format!("part \"{}\"", entry.name);
        labels.define(checker, format!("{entry_path}.name"), &entry.name, Category::Part(id))?;
        for (j, synonym) in entry.synonyms.iter().enumerate() {
            labels.define(checker, format!("{entry_path}.synonyms[{j}]"), synonym, Category::Part(id))?;
        }
        let bits = checker.affordances(&format!("{entry_path}.affordances"), &entry.affordances)?;
        parts.push(PartCategory { name: entry.name.clone(), affordance_bits: bits });
    }
    Ok(parts)
}

/// `objects.toml` without the pairs: the object categories, names and synonyms defined in
/// `labels`.
fn compile_objects(
    checker: &Checker<'_>,
    objects_raw: &ObjectsFile,
    labels: &mut Labels,
) -> Result<Vec<ObjectCategory>, KnowledgeError> {
    let mut objects = Vec::with_capacity(objects_raw.object.len());
    for (i, entry) in objects_raw.object.iter().enumerate() {
        let id = ObjectId(u16::try_from(i).map_err(|_| checker.error(format!("object[{i}]"), "too many objects"))?);
        let entry_path = format!("object \"{}\"", entry.name);
        labels.define(checker, format!("{entry_path}.name"), &entry.name, Category::Object(id))?;
        for (j, synonym) in entry.synonyms.iter().enumerate() {
            labels.define(checker, format!("{entry_path}.synonyms[{j}]"), synonym, Category::Object(id))?;
        }
        let bits = checker.affordances(&format!("{entry_path}.affordances"), &entry.affordances)?;
        objects.push(ObjectCategory { name: entry.name.clone(), affordance_bits: bits, parts: Vec::new() });
    }
    Ok(objects)
}

/// `objects.toml`'s object-part pairs, onto `objects`.
fn attach_pairs(
    checker: &Checker<'_>,
    objects_raw: &ObjectsFile,
    parts: &[PartCategory],
    names: &Names<'_>,
    objects: &mut [ObjectCategory],
) -> Result<(), KnowledgeError> {
    let mut pairs_per_object = Vec::with_capacity(objects.len());
    for entry in &objects_raw.object {
        let entry_path = format!("object \"{}\"", entry.name);
        let mut pairs: Vec<PartPair> = Vec::with_capacity(entry.parts.len());
        for (j, pair) in entry.parts.iter().enumerate() {
            let pair_path = format!("{entry_path}.parts[{j}]");
            let part = *names.parts.get(pair.part.as_str()).ok_or_else(|| {
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
    Ok(())
}

/// `remote.toml`: the remote templates.
fn compile_remotes(
    checker: &Checker<'_>,
    remote_raw: &RemoteFile,
    names: &Names<'_>,
) -> Result<Vec<RemoteTemplate>, KnowledgeError> {
    let mut remotes = Vec::with_capacity(remote_raw.remote.len());
    for (i, entry) in remote_raw.remote.iter().enumerate() {
        let entry_path = format!("remote[{i}] \"{}\"", entry.source);
        let source = if let Some(id) = names.objects.get(entry.source.as_str()) {
            Category::Object(*id)
        } else if let Some(id) = names.parts.get(entry.source.as_str()) {
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
            let id = *names.objects.get(target.as_str()).ok_or_else(|| {
                checker.error(format!("{entry_path}.targets[{j}]"), format!("unknown object category \"{target}\""))
            })?;
            if targets.contains(&id) || source == Category::Object(id) {
                return Err(checker
                    .error(format!("{entry_path}.targets[{j}]"), format!("duplicate or self target \"{target}\"")));
            }
            targets.push(id);
        }
        let relation_id = checker.relation(&format!("{entry_path}.relation"), &entry.relation)?;
        if !(entry.max_distance_m.is_finite() && entry.max_distance_m > 0.0) {
            return Err(checker.error(format!("{entry_path}.max_distance_m"), "must be a positive number of metres"));
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
    Ok(remotes)
}
