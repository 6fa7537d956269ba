//! Loading a profile: the built-in base, the `extends` chain, `--set` overrides, paths relative
//! to the file that set them, the sections registered backends own, and errors that name the
//! file and the field.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{BASE_PROFILE, BASE_PROFILE_NAME, PATH_KEYS, Profile, ProfileError};
use crate::perception::YOLOX_DETECTOR;

/// A check of a section failed: `(field path, message)`. From a backend's own section the path
/// is inside the section (the loader prefixes the section's path); from [`SectionRegistry::check_kinds`]
/// it is the whole path.
pub type SectionError = (String, String);

/// The backends a build knows, as the loader sees them: the registry of the composition
/// (`crate::backend::Backends`) implements it. The loader hands each section of a registered
/// backend (`[source.<name>]`, `[detector.<name>]`, `[fusion.<name>]`) to it, and the loaded
/// profile for the checks across sections.
pub trait SectionRegistry {
    /// Checks, and may complete, the section `[<group>.<name>]` of the backend `name` of
    /// `group` (`source`, `detector`, `fusion`); an error naming the group and the backends the
    /// build has when there is no such backend.
    fn load_section(&self, group: &str, name: &str, section: &mut toml::Table) -> Result<(), SectionError>;

    /// The kinds the profile names (`source.kind`, `detector.kind`, `fusion.method`) exist, and
    /// their backends' checks across the profile hold.
    fn check_kinds(&self, profile: &Profile) -> Result<(), SectionError>;
}

/// A loaded profile with where each value came from.
#[derive(Debug, Clone)]
pub struct LoadedProfile {
    /// The typed, validated profile.
    pub profile: Profile,
    /// The merged TOML (for `--print-config`).
    pub effective: toml::Table,
    /// The layers in order (base first): the built-in base, the profile files, the environment
    /// variables that set a key, `--set`.
    pub layers: Vec<String>,
    /// The layer each value was last set by, per dotted key of a value (not of a table).
    pub origins: BTreeMap<String, String>,
}

impl LoadedProfile {
    /// The values set by a layer other than the built-in base, with that layer, in key order:
    /// what `--print-config` lists so a reader sees where each came from.
    pub fn set_values(&self) -> Vec<(&str, &str)> {
        self.origins
            .iter()
            .filter(|(_, layer)| layer.as_str() != BASE_PROFILE_NAME)
            .map(|(key, layer)| (key.as_str(), layer.as_str()))
            .collect()
    }
}

/// Loads the built-in base, the optional profile file (with its `extends` chain) and the
/// `--set` overrides, then deserialises and validates, with `backends` checking their own
/// sections and the kinds the profile names. A section under `[source]` or `[detector]` that no
/// backend of `backends` owns is an error naming it.
pub fn load_with(
    backends: &dyn SectionRegistry,
    profile_path: Option<&Path>,
    overrides: &[String],
) -> Result<LoadedProfile, ProfileError> {
    load_layers(Some(backends), profile_path, &[], overrides)
}

/// [`load_with`] with a layer per environment variable between the profile files and `--set`:
/// `environment` holds `(variable, "key=value")`, e.g. `("OP3DSG_PREFIX", "ipc.prefix=\"lab\"")`.
/// So the rule is one: the command line over the environment over the profile files over the
/// built-in base; errors in such a value name the variable.
pub fn load_with_environment(
    backends: &dyn SectionRegistry,
    profile_path: Option<&Path>,
    environment: &[(String, String)],
    overrides: &[String],
) -> Result<LoadedProfile, ProfileError> {
    load_layers(Some(backends), profile_path, environment, overrides)
}

/// [`load_with`] without a registry: only the runtime's own sections are checked; the
/// sections of other backends are kept as they are (in [`Profile::sections`]) and the kinds are
/// checked when the pipeline opens them. For tools and tests that use a profile's runtime
/// settings; `op3dsgd` loads with its registry.
pub fn load(profile_path: Option<&Path>, overrides: &[String]) -> Result<LoadedProfile, ProfileError> {
    load_layers(None, profile_path, &[], overrides)
}

/// One layer of `key=value` settings (`--set`, an environment variable); errors name `layer`.
fn settings_table(layer: &str, sets: &[String]) -> Result<toml::Table, ProfileError> {
    let mut table = toml::Table::new();
    for set in sets {
        let (key, value) = set
            .split_once('=')
            .ok_or_else(|| ProfileError::new(layer, format!("'{set}': expected section.key=value")))?;
        let value = parse_value(value.trim()).map_err(|e| ProfileError::new(layer, format!("{}: {e}", key.trim())))?;
        insert_dotted(&mut table, key.trim(), value)
            .map_err(|e| ProfileError::new(layer, format!("{}: {e}", key.trim())))?;
    }
    Ok(table)
}

fn load_layers(
    backends: Option<&dyn SectionRegistry>,
    profile_path: Option<&Path>,
    environment: &[(String, String)],
    overrides: &[String],
) -> Result<LoadedProfile, ProfileError> {
    let mut layers: Vec<(String, toml::Table)> = Vec::new();
    layers.push((BASE_PROFILE_NAME.to_owned(), parse_toml(BASE_PROFILE, BASE_PROFILE_NAME)?));
    if let Some(path) = profile_path {
        let mut chain = Vec::new();
        collect_chain(path, &mut chain, 0)?;
        chain.reverse();
        layers.extend(chain);
    }
    let files: Vec<String> = layers.iter().skip(1).map(|(name, _)| name.clone()).collect();
    for (variable, set) in environment {
        layers.push((variable.clone(), settings_table(variable, std::slice::from_ref(set))?));
    }
    if !overrides.is_empty() {
        layers.push(("--set".to_owned(), settings_table("--set", overrides)?));
    }

    let mut origins: BTreeMap<String, String> = BTreeMap::new();
    let mut merged = toml::Table::new();
    for (name, table) in &layers {
        record_origins(table, "", name, &mut origins);
        merge(&mut merged, table.clone());
    }
    merged.remove("extends");
    let origin_of = |path: &str| -> String {
        let mut p = path.to_owned();
        loop {
            if let Some(file) = origins.get(&p) {
                return file.clone();
            }
            match p.rfind('.') {
                Some(i) => p.truncate(i),
                None => return layers.last().map(|(n, _)| n.clone()).unwrap_or_default(),
            }
        }
    };

    resolve_paths(&mut merged, &origin_of, &files);
    let named = |(path, msg): (String, String)| ProfileError::new(origin_of(&path), format!("{path}: {msg}"));
    normalise_kinds(&mut merged);
    let sections = take_backend_sections(&mut merged, backends).map_err(named)?;
    let mut effective = merged.clone();
    for (path, section) in &sections {
        if let Some((group, name)) = path.split_once('.')
            && let Some(toml::Value::Table(table)) = effective.get_mut(group)
        {
            table.insert(name.to_owned(), toml::Value::Table(section.clone()));
        }
    }

    let mut profile: Profile = serde_path_to_error::deserialize(toml::Value::Table(merged)).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner().to_string();
        // The TOML deserialiser appends "in `path`" on its own line; the path is already named.
        let message = inner.lines().next().unwrap_or("").trim().to_owned();
        ProfileError::new(origin_of(&path), format!("{path}: {message}"))
    })?;
    profile.sections = sections;
    profile.validate().map_err(named)?;
    if let Some(backends) = backends {
        backends.check_kinds(&profile).map_err(named)?;
    }
    origins.retain(|key, _| !key.starts_with("extends") && value_at(&effective, key).is_some_and(|v| !v.is_table()));
    Ok(LoadedProfile { profile, effective, layers: layers.into_iter().map(|(n, _)| n).collect(), origins })
}

/// Sub-tables of `[source]`, `[detector]` and `[fusion]` that are the runtime's own typed sections
/// (`region_encoder` goes with every detector kind, `remote` with `detector.kind = "remote"`,
// `colour` and `change` are the OP3DSG fusion's); any other sub-table is a registered backend's.
const RUNTIME_SECTIONS: [(&str, &[&str]); 3] = [
    ("source", &["replay"]),
    ("detector", &["yolox", "open_vocab", "region_encoder", "remote"]),
    ("fusion", &["colour", "change"]),
];

/// `detector.kind = "onnx"` is the older name of `"yolox"`.
fn normalise_kinds(merged: &mut toml::Table) {
    if let Some(toml::Value::Table(detector)) = merged.get_mut("detector")
        && detector.get("kind").and_then(toml::Value::as_str) == Some("onnx")
    {
        detector.insert("kind".to_owned(), toml::Value::String(YOLOX_DETECTOR.to_owned()));
    }
}

/// Takes the sections of registered backends out of `merged` (which the typed profile would
/// refuse as unknown fields), each checked and completed by its backend. Without a registry
/// they are kept unchecked.
fn take_backend_sections(
    merged: &mut toml::Table,
    backends: Option<&dyn SectionRegistry>,
) -> Result<BTreeMap<String, toml::Table>, (String, String)> {
    let mut sections = BTreeMap::new();
    for (group, runtime_own) in RUNTIME_SECTIONS {
        let Some(toml::Value::Table(table)) = merged.get_mut(group) else { continue };
        let names: Vec<String> = table
            .iter()
            .filter(|(name, value)| value.is_table() && !runtime_own.contains(&name.as_str()))
            .map(|(name, _)| name.clone())
            .collect();
        for name in names {
            let Some(toml::Value::Table(mut section)) = table.remove(&name) else { continue };
            let path = format!("{group}.{name}");
            if let Some(backends) = backends {
                backends.load_section(group, &name, &mut section).map_err(|(field, msg)| {
                    (if field.is_empty() { path.clone() } else { format!("{path}.{field}") }, msg)
                })?;
            }
            sections.insert(path, section);
        }
    }
    Ok(sections)
}

fn parse_toml(text: &str, name: &str) -> Result<toml::Table, ProfileError> {
    text.parse::<toml::Table>().map_err(|e| ProfileError::new(name, e.to_string().trim().to_owned()))
}

fn collect_chain(path: &Path, chain: &mut Vec<(String, toml::Table)>, depth: usize) -> Result<(), ProfileError> {
    let name = path.display().to_string();
    if depth > 8 {
        return Err(ProfileError::new(name, "extends: chain deeper than 8 files (a cycle?)"));
    }
    let text =
        std::fs::read_to_string(path).map_err(|e| ProfileError::new(&name, format!("cannot read profile: {e}")))?;
    let table = parse_toml(&text, &name)?;
    let parent = match table.get("extends") {
        None => None,
        Some(toml::Value::String(s)) => Some(s.clone()),
        Some(other) => {
            return Err(ProfileError::new(
                &name,
                format!("extends: expected a file path string, found {}", other.type_str()),
            ));
        }
    };
    chain.push((name.clone(), table));
    if let Some(parent) = parent {
        let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."));
        let parent_path = find_extended(&base_dir, Path::new(&parent), crate::install::installed_profiles_dir())
            .map_err(|looked_for| {
                ProfileError::new(
                    &name,
                    format!(
                        "extends: no profile {parent:?}: looked for {}",
                        looked_for.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
                    ),
                )
            })?;
        collect_chain(&parent_path, chain, depth + 1)?;
    }
    Ok(())
}

/// The file an `extends = "<parent>"` names: beside the profile that names it (`base_dir`);
/// failing that, a relative name among the installed profiles (`installed`:
/// `/usr/share/op3dsg/profiles` for `/usr/bin/op3dsgd`), so a robot's `/etc/op3dsg/op3dsgd.toml`
/// says `extends = "stretch3-d435i.toml"`. Every place looked at when none has it.
pub(super) fn find_extended(
    base_dir: &Path,
    parent: &Path,
    installed: Option<PathBuf>,
) -> Result<PathBuf, Vec<PathBuf>> {
    let mut candidates = vec![base_dir.join(parent)];
    if parent.is_relative()
        && let Some(dir) = installed
    {
        candidates.push(dir.join(parent));
    }
    match candidates.iter().find(|p| p.is_file()) {
        Some(found) => Ok(found.clone()),
        None => Err(candidates),
    }
}

fn parse_value(text: &str) -> Result<toml::Value, String> {
    // Parse as the right-hand side of a TOML assignment; a bare word is taken as a string.
    match format!("v = {text}").parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").ok_or_else(|| "no value".to_owned()),
        Err(_) if text.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '/' || c == '.') => {
            Ok(toml::Value::String(text.to_owned()))
        }
        // The parser's own words ("invalid boolean, expected `true`") describe its guess, not the
        // value: say how to write one.
        Err(_) => Err(format!(
            "'{text}' is not a TOML value: quote a string ('key=\"{}\"') and write a list in brackets \
             ('key=[\"{}\"]'), inside single quotes for the shell",
            text.trim_matches('"'),
            text.trim_matches(|c| c == '"' || c == '[' || c == ']')
        )),
    }
}

fn insert_dotted(table: &mut toml::Table, key: &str, value: toml::Value) -> Result<(), String> {
    let mut parts = key.split('.').peekable();
    let mut current = table;
    while let Some(part) = parts.next() {
        if part.is_empty() {
            return Err("empty key segment".to_owned());
        }
        if parts.peek().is_none() {
            current.insert(part.to_owned(), value);
            return Ok(());
        }
        let entry = current.entry(part.to_owned()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
        current = entry.as_table_mut().ok_or_else(|| format!("{part} is not a table"))?;
    }
    Ok(())
}

/// Merges `from` into `into` key by key (tables recursively; other values replace): how profile
/// layers and presets combine.
pub fn merge(into: &mut toml::Table, from: toml::Table) {
    for (key, value) in from {
        match (into.get_mut(&key), value) {
            (Some(toml::Value::Table(existing)), toml::Value::Table(incoming)) => merge(existing, incoming),
            (_, value) => {
                into.insert(key, value);
            }
        }
    }
}

fn record_origins(table: &toml::Table, prefix: &str, file: &str, origins: &mut BTreeMap<String, String>) {
    for (key, value) in table {
        let path = if prefix.is_empty() { key.clone() } else { format!("{prefix}.{key}") };
        origins.insert(path.clone(), file.to_owned());
        if let toml::Value::Table(inner) = value {
            record_origins(inner, &path, file, origins);
        }
    }
}

/// The value at a dotted key of `table`, if any.
fn value_at<'a>(table: &'a toml::Table, key: &str) -> Option<&'a toml::Value> {
    let mut parts = key.split('.');
    let mut value = table.get(parts.next()?)?;
    for part in parts {
        value = value.as_table()?.get(part)?;
    }
    Some(value)
}

/// Joins each relative path of [`PATH_KEYS`] to the folder of the profile file (of `files`) that
/// set it; a path set on the command line or in the environment stays relative to the working
/// directory, and one in the model store (`.models/...`, [`crate::install`]) stays as it is, found
/// where the store is.
fn resolve_paths(merged: &mut toml::Table, origin_of: &dyn Fn(&str) -> String, files: &[String]) {
    for key in PATH_KEYS {
        let origin = origin_of(key);
        if !files.contains(&origin) {
            continue;
        }
        let mut value = Some(&mut *merged);
        let mut parts = key.split('.').peekable();
        while let (Some(part), Some(table)) = (parts.next(), value.take()) {
            let entry = table.get_mut(part);
            if parts.peek().is_none() {
                // "" keeps its meaning of "not set" (snapshot.dir: the systemd state directory).
                if let Some(toml::Value::String(path)) = entry
                    && !path.is_empty()
                    && Path::new(path.as_str()).is_relative()
                    && crate::install::in_model_store(Path::new(path.as_str())).is_none()
                {
                    let dir = Path::new(&origin).parent().unwrap_or(Path::new(""));
                    *path = dir.join(path.as_str()).display().to_string();
                }
                break;
            }
            value = entry.and_then(toml::Value::as_table_mut);
        }
    }
}
