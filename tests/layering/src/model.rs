//! A crate as the rules see it: its top-level modules, the arrows between them (every place
//! that writes one), and its product files with their lengths.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Component, Path, PathBuf};

use crate::error::Error;
use crate::manifest::{self, Layers, Member};
use crate::scan::{self, FileCtx, RootUse, Written};

/// The node of items defined in lib.rs itself: it sits above every top-level module.
pub const CRATE_ROOT: &str = "(crate root)";

/// One place that writes an arrow.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Occurrence {
    /// The file, relative to the workspace root, `/`-separated.
    pub file: String,
    pub line: usize,
    /// The path as written (`crate::graph::Graph`, `super::super::graph`).
    pub text: String,
    /// The same path from the crate root, re-exports of lib.rs followed.
    pub target: Vec<String>,
}

/// `from` imports `to`: top-level modules of one crate ([`CRATE_ROOT`] as `to` for an item
/// defined in lib.rs).
#[derive(Debug, Clone)]
pub struct Arrow {
    pub from: String,
    pub to: String,
    /// Sorted by file and line: the first is where the arrow is reported.
    pub occurrences: Vec<Occurrence>,
}

impl Arrow {
    pub fn first(&self) -> &Occurrence {
        &self.occurrences[0]
    }
}

/// A product file and its number of lines.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProductFile {
    pub path: String,
    pub lines: usize,
}

/// One workspace member.
#[derive(Debug, Clone)]
pub struct CrateModel {
    pub name: String,
    /// The member's Cargo.toml, relative to the workspace root.
    pub manifest: String,
    /// Its lib.rs, relative to the workspace root, if it has one.
    pub lib: Option<String>,
    /// Top-level modules (declared in lib.rs outside `#[cfg(test)]`), sorted.
    pub modules: Vec<String>,
    /// Sorted by `from`, then `to`.
    pub arrows: Vec<Arrow>,
    /// Sorted by path.
    pub files: Vec<ProductFile>,
    pub layers: Option<Layers>,
}

/// Every member of the workspace at `root`, sorted by crate name.
pub fn load(root: &Path) -> Result<Vec<CrateModel>, Error> {
    let root = &root.canonicalize().map_err(|e| Error::io(root, e))?;
    let mut crates = manifest::members(root)?.iter().map(|m| load_crate(root, m)).collect::<Result<Vec<_>, _>>()?;
    crates.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(crates)
}

fn load_crate(root: &Path, member: &Member) -> Result<CrateModel, Error> {
    let mut trees = Trees::default();
    let mut modules = Vec::new();
    let mut arrows = Vec::new();
    if let Some(lib) = &member.lib {
        let lib_tree = trees.walk(lib)?;
        let lib_scan = lib_tree.root.as_ref();
        if let Some(lib) = lib_scan {
            let declared = lib.mods.iter().filter(|d| !d.test_only && d.module.len() == 1).map(|d| &d.module);
            // Inline `mod x { … }` of lib.rs are top-level modules too.
            let inline = lib.inline_mods.iter().filter(|m| m.len() == 1);
            modules = declared.chain(inline).filter_map(|m| m.last().cloned()).collect();
        }
        modules.sort();
        modules.dedup();
        let names = RootNames::new(lib_scan, &lib_tree.exported_macros, &modules);
        arrows = arrows_of(root, &lib_tree.paths, &names);
    }
    for bin in bin_roots(member) {
        trees.walk(&bin)?;
    }
    for dir in ["src/bin", "examples"] {
        for file in rust_files(&member.dir.join(dir)) {
            if !trees.test_files.contains(&file) {
                trees.product_files.insert(file);
            }
        }
    }
    let mut files = Vec::new();
    for path in &trees.product_files {
        let under_crate = path.strip_prefix(normalize(&member.dir)).unwrap_or(path);
        if under_crate.starts_with("tests") || under_crate.starts_with("benches") {
            continue;
        }
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        files.push(ProductFile { path: relative(root, path), lines: text.lines().count() });
    }
    files.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(CrateModel {
        name: member.name.clone(),
        manifest: relative(root, &member.manifest),
        lib: member.lib.as_ref().map(|l| relative(root, l)),
        modules,
        arrows,
        files,
        layers: member.layers.clone(),
    })
}

/// Roots of the member's binaries and examples: `src/main.rs`, `src/bin/*.rs`,
/// `src/bin/*/main.rs`, `examples/*.rs`, `examples/*/main.rs` and any declared `path`.
fn bin_roots(member: &Member) -> Vec<PathBuf> {
    let mut roots = vec![member.dir.join("src/main.rs")];
    for dir in ["src/bin", "examples"] {
        let Ok(entries) = std::fs::read_dir(member.dir.join(dir)) else { continue };
        for entry in entries.filter_map(Result::ok) {
            let path = entry.path();
            if path.extension().is_some_and(|e| e == "rs") {
                roots.push(path);
            } else if path.join("main.rs").is_file() {
                roots.push(path.join("main.rs"));
            }
        }
    }
    roots.extend(member.declared_roots.iter().cloned());
    roots.retain(|p| p.is_file());
    roots.sort();
    roots.dedup();
    roots
}

fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else { return out };
    for entry in entries.filter_map(Result::ok) {
        let path = entry.path();
        if path.is_dir() {
            out.extend(rust_files(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(normalize(&path));
        }
    }
    out
}

/// The files reached from a crate's roots.
#[derive(Default)]
struct Trees {
    product_files: BTreeSet<PathBuf>,
    test_files: BTreeSet<PathBuf>,
}

/// What one root's module tree holds.
struct Tree {
    root: Option<scan::FileScan>,
    paths: Vec<(String, Written)>,
    exported_macros: Vec<(String, Vec<String>)>,
}

impl Trees {
    /// Walks the module tree from `root_file` (a crate root), following `mod x;`.
    fn walk(&mut self, root_file: &Path) -> Result<Tree, Error> {
        let mut tree = Tree { root: None, paths: Vec::new(), exported_macros: Vec::new() };
        let mut queue =
            vec![FileCtx { path: normalize(root_file), module: Vec::new(), mod_rs: true, test_only: false }];
        let mut seen = BTreeSet::new();
        while let Some(ctx) = queue.pop() {
            if !seen.insert((ctx.path.clone(), ctx.test_only)) {
                continue;
            }
            let source = std::fs::read_to_string(&ctx.path).map_err(|e| Error::io(&ctx.path, e))?;
            let scanned = scan::scan(&ctx, &source)?;
            if ctx.test_only {
                self.test_files.insert(ctx.path.clone());
            } else {
                self.product_files.insert(ctx.path.clone());
            }
            for decl in &scanned.mods {
                let found = decl.candidates.iter().map(|(p, m)| (normalize(p), *m)).find(|(p, _)| p.is_file());
                match found {
                    Some((path, mod_rs)) => {
                        queue.push(FileCtx { path, module: decl.module.clone(), mod_rs, test_only: decl.test_only })
                    }
                    // A test module's file may be absent without the product being wrong.
                    None if decl.test_only => {}
                    None => {
                        let tried: Vec<String> = decl.candidates.iter().map(|(p, _)| p.display().to_string()).collect();
                        return Err(Error::MissingModule {
                            path: ctx.path.clone(),
                            line: decl.line,
                            module: decl.module.join("::"),
                            tried: tried.join(" or "),
                        });
                    }
                }
            }
            let file = ctx.path.clone();
            let display = file.to_string_lossy().into_owned();
            tree.paths.extend(scanned.paths.iter().cloned().map(|w| (display.clone(), w)));
            tree.exported_macros.extend(scanned.exported_macros.iter().cloned());
            if ctx.module.is_empty() && !ctx.test_only {
                tree.root = Some(scanned);
            }
        }
        Ok(tree)
    }
}

/// What a name at the crate root stands for.
enum RootName {
    /// An item of a top-level module: the path from the crate root.
    Module(Vec<String>),
    /// An item defined in lib.rs itself.
    Root,
    /// Another crate's item.
    External,
}

struct RootNames {
    modules: Vec<String>,
    names: BTreeMap<String, RootName>,
    /// Modules lib.rs glob-imports (`pub use m::*`).
    globs: Vec<String>,
}

impl RootNames {
    fn new(lib: Option<&scan::FileScan>, macros: &[(String, Vec<String>)], modules: &[String]) -> Self {
        let mut names = BTreeMap::new();
        let mut globs = Vec::new();
        for (name, module) in macros {
            if let Some(top) = module.first() {
                names.insert(name.clone(), RootName::Module(vec![top.clone(), name.clone()]));
            }
        }
        if let Some(lib) = lib {
            for name in &lib.root_items {
                names.insert(name.clone(), RootName::Root);
            }
            for RootUse { name, segments } in &lib.root_uses {
                let from_root = match segments.first().map(String::as_str) {
                    Some("crate" | "self") => &segments[1..],
                    _ => &segments[..],
                };
                let internal = from_root.first().is_some_and(|first| modules.contains(first));
                match (name, internal) {
                    (Some(name), true) => {
                        names.insert(name.clone(), RootName::Module(from_root.to_vec()));
                    }
                    (Some(name), false) => {
                        names.entry(name.clone()).or_insert(RootName::External);
                    }
                    (None, true) => globs.push(from_root[0].clone()),
                    (None, false) => {}
                }
            }
        }
        RootNames { modules: modules.to_vec(), names, globs }
    }

    /// The path from the crate root of `target` through lib.rs's names, or `None` for
    /// another crate's item.
    fn resolve(&self, target: &[String]) -> Option<Vec<String>> {
        let first = target.first()?;
        if self.modules.contains(first) {
            return Some(target.to_vec());
        }
        match self.names.get(first) {
            Some(RootName::Module(path)) => Some(path.iter().chain(&target[1..]).cloned().collect()),
            Some(RootName::External) => None,
            Some(RootName::Root) => Some(root_target(target)),
            // Not defined in lib.rs: from its only glob import, else lib.rs itself.
            None => match self.globs.as_slice() {
                [only] => Some(std::iter::once(only).chain(target).cloned().collect()),
                _ => Some(root_target(target)),
            },
        }
    }
}

fn root_target(target: &[String]) -> Vec<String> {
    std::iter::once(CRATE_ROOT.to_owned()).chain(target.iter().cloned()).collect()
}

fn arrows_of(root: &Path, paths: &[(String, Written)], names: &RootNames) -> Vec<Arrow> {
    let mut by_pair: BTreeMap<(String, String), Vec<Occurrence>> = BTreeMap::new();
    for (file, written) in paths {
        // lib.rs sits on top: what it writes outside its inline modules is no arrow.
        let Some(from) = written.module.first() else { continue };
        let Some(target) = names.resolve(&written.target) else { continue };
        let to = &target[0];
        if to == from {
            continue;
        }
        let occurrence = Occurrence {
            file: relative(root, Path::new(file)),
            line: written.line,
            text: written.text.clone(),
            target: if to == CRATE_ROOT { target[1..].to_vec() } else { target.clone() },
        };
        by_pair.entry((from.clone(), to.clone())).or_default().push(occurrence);
    }
    by_pair
        .into_iter()
        .map(|((from, to), mut occurrences)| {
            occurrences.sort();
            occurrences.dedup();
            Arrow { from, to, occurrences }
        })
        .collect()
}

/// `path` relative to `root`, `/`-separated: how messages name files.
fn relative(root: &Path, path: &Path) -> String {
    let root = normalize(root);
    let path = normalize(path);
    let shown = path.strip_prefix(&root).unwrap_or(&path);
    shown.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/")
}

/// `path` with `.` and `name/..` taken out, without touching the file system (a `#[path]`
/// may climb, and the same file must compare equal however it was reached).
fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for component in path.components() {
        match component {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.components().next_back(), Some(Component::Normal(_))) => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}
