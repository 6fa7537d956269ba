//! The Cargo.toml files: the workspace's members, each member's name, targets, dependencies and
//! declared layers (`[package.metadata.layers]`), and the workspace's crate rows
//! (`[workspace.metadata.layers]`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::Error;

/// `[package.metadata.layers]` of a crate's Cargo.toml.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layers {
    /// Bottom first: a module may import only modules of earlier rows. Absent: only circles
    /// are checked.
    pub rows: Option<Vec<Vec<String>>>,
    /// What only `<m>` itself and the composition may import from another top-level module
    /// `<m>`: a submodule (`thread`: `crate::<m>::thread`), or, written `*Suffix`, any item whose
    /// name ends so (`*Thread`).
    #[serde(default)]
    pub composition_only: Vec<String>,
    /// The modules that make up the composition (they may import what `composition_only`
    /// names). Absent: the last row.
    pub composition: Option<Vec<String>>,
}

/// One workspace member.
#[derive(Debug, Clone)]
pub struct Member {
    pub name: String,
    /// The member's folder, under the workspace root.
    pub dir: PathBuf,
    pub manifest: PathBuf,
    pub lib: Option<PathBuf>,
    /// Roots of binaries and examples declared with an explicit `path`.
    pub declared_roots: Vec<PathBuf>,
    pub layers: Option<Layers>,
    /// The packages of `[dependencies]` and `[build-dependencies]` (the package a renamed
    /// dependency stands for), not `[dev-dependencies]`: what the product links.
    pub dependencies: Vec<String>,
}

/// `[workspace.metadata.layers]` of the workspace's Cargo.toml.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkspaceLayers {
    /// The members by package name, bottom first: a member may depend only on members of
    /// earlier rows. Absent: crate dependencies are not checked.
    pub crates: Option<Vec<Vec<String>>>,
}

#[derive(Deserialize)]
struct WorkspaceManifest {
    workspace: Option<Workspace>,
}

#[derive(Deserialize)]
struct Workspace {
    #[serde(default)]
    members: Vec<String>,
    metadata: Option<WorkspaceMetadata>,
}

#[derive(Deserialize)]
struct WorkspaceMetadata {
    layers: Option<WorkspaceLayers>,
}

#[derive(Deserialize)]
struct CrateManifest {
    package: Package,
    lib: Option<Target>,
    #[serde(default)]
    bin: Vec<Target>,
    #[serde(default)]
    example: Vec<Target>,
    #[serde(default)]
    dependencies: BTreeMap<String, toml::Value>,
    #[serde(default, rename = "build-dependencies")]
    build_dependencies: BTreeMap<String, toml::Value>,
}

#[derive(Deserialize)]
struct Package {
    name: String,
    metadata: Option<Metadata>,
}

#[derive(Deserialize)]
struct Metadata {
    layers: Option<Layers>,
}

#[derive(Deserialize)]
struct Target {
    path: Option<PathBuf>,
}

/// Whether `dir/Cargo.toml` declares a `[workspace]`.
pub fn is_workspace_root(dir: &Path) -> bool {
    let path = dir.join("Cargo.toml");
    std::fs::read_to_string(&path)
        .ok()
        .and_then(|text| toml::from_str::<WorkspaceManifest>(&text).ok())
        .is_some_and(|m| m.workspace.is_some())
}

/// `[workspace.metadata.layers]` of the workspace at `root` (the default when it has none).
pub fn workspace_layers(root: &Path) -> Result<WorkspaceLayers, Error> {
    let path = root.join("Cargo.toml");
    let manifest: WorkspaceManifest = read_toml(&path)?;
    Ok(manifest.workspace.and_then(|w| w.metadata).and_then(|m| m.layers).unwrap_or_default())
}

/// The members of the workspace at `root`, in the order `members` lists them. A member ending
/// in `/*` stands for every folder under it that has a Cargo.toml.
pub fn members(root: &Path) -> Result<Vec<Member>, Error> {
    let path = root.join("Cargo.toml");
    let manifest: WorkspaceManifest = read_toml(&path)?;
    let Some(workspace) = manifest.workspace else {
        return Err(Error::Manifest { path, message: "no [workspace] table".into() });
    };
    let mut dirs = Vec::new();
    for member in &workspace.members {
        match member.strip_suffix("/*") {
            Some(parent) => {
                let parent = root.join(parent);
                let entries = std::fs::read_dir(&parent).map_err(|e| Error::io(&parent, e))?;
                let mut found: Vec<PathBuf> = entries
                    .filter_map(|e| e.ok().map(|e| e.path()))
                    .filter(|p| p.join("Cargo.toml").is_file())
                    .collect();
                found.sort();
                dirs.extend(found);
            }
            None => dirs.push(root.join(member)),
        }
    }
    dirs.into_iter().map(|dir| member(&dir)).collect()
}

fn member(dir: &Path) -> Result<Member, Error> {
    let manifest_path = dir.join("Cargo.toml");
    let manifest: CrateManifest = read_toml(&manifest_path)?;
    let lib = match manifest.lib.and_then(|l| l.path) {
        Some(path) => Some(dir.join(path)),
        None => Some(dir.join("src/lib.rs")).filter(|p| p.is_file()),
    };
    let declared_roots =
        manifest.bin.iter().chain(&manifest.example).filter_map(|t| t.path.as_ref()).map(|p| dir.join(p)).collect();
    let dependencies = manifest
        .dependencies
        .iter()
        .chain(&manifest.build_dependencies)
        .map(|(key, value)| match value.get("package").and_then(toml::Value::as_str) {
            Some(package) => package.to_owned(),
            None => key.clone(),
        })
        .collect();
    Ok(Member {
        name: manifest.package.name,
        dir: dir.to_path_buf(),
        manifest: manifest_path,
        lib,
        declared_roots,
        layers: manifest.package.metadata.and_then(|m| m.layers),
        dependencies,
    })
}

fn read_toml<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, Error> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    toml::from_str(&text).map_err(|e| Error::Manifest { path: path.to_path_buf(), message: e.to_string() })
}
