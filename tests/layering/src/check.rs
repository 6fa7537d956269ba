//! The rules `op3dsg-layers check` enforces, each violation as one message (a first line naming
//! file and line, then indented detail lines).

use std::collections::BTreeMap;

use crate::cycles;
use crate::model::{CRATE_ROOT, CrateModel, Occurrence};

/// Every violation of every crate, crates by name, then by rule.
pub fn violations(crates: &[CrateModel], max_file_lines: usize) -> Vec<String> {
    let mut out = Vec::new();
    for krate in crates {
        let rows = rows(krate, &mut out);
        circles(krate, &mut out);
        if let Some(rows) = &rows {
            upward(krate, rows, &mut out);
        }
        composition_only(krate, &mut out);
        for file in &krate.files {
            if file.lines > max_file_lines {
                out.push(format!(
                    "{}: {} lines, over {max_file_lines}: split it by responsibility",
                    file.path, file.lines
                ));
            }
        }
    }
    out
}

/// Each module's row (1 = bottom), after checking that the rows name every top-level module
/// exactly once; `None` without declared rows.
fn rows<'a>(krate: &'a CrateModel, out: &mut Vec<String>) -> Option<BTreeMap<&'a str, usize>> {
    let declared = krate.layers.as_ref()?.rows.as_ref()?;
    let lib = krate.lib.as_deref().unwrap_or("the crate (it has no lib.rs)");
    let at = format!("{}: [package.metadata.layers] rows", krate.manifest);
    let mut placed: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (index, row) in declared.iter().enumerate() {
        for name in row {
            placed.entry(name.as_str()).or_default().push(index + 1);
        }
    }
    for (name, rows) in &placed {
        if !krate.modules.iter().any(|m| m == name) {
            out.push(format!("{at} list \"{name}\", which is not a top-level module of {lib}"));
        } else if rows.len() > 1 {
            let listed = rows.iter().map(usize::to_string).collect::<Vec<_>>().join(", ");
            out.push(format!("{at} list \"{name}\" more than once (rows {listed}); a module belongs to one row"));
        }
    }
    for module in &krate.modules {
        if !placed.contains_key(module.as_str()) {
            out.push(format!("{at} do not list \"{module}\", a top-level module of {lib}; every one belongs to a row"));
        }
    }
    Some(placed.into_iter().map(|(name, rows)| (name, rows[0])).collect())
}

fn circles(krate: &CrateModel, out: &mut Vec<String>) {
    let edges = krate.arrows.iter().map(|a| (a.from.as_str(), a.to.as_str()));
    for circle in cycles::circles(edges) {
        let mut message = format!("{}: import circle of {} modules: {}", krate.name, circle.len(), circle.join(", "));
        for arrow in krate.arrows.iter().filter(|a| circle.contains(&a.from) && circle.contains(&a.to)) {
            let first = arrow.first();
            message.push_str(&format!(
                "\n  {}:{}: {} imports {} ({})",
                first.file, first.line, arrow.from, arrow.to, first.text
            ));
            if arrow.occurrences.len() > 1 {
                message.push_str(&format!(" +{} more", arrow.occurrences.len() - 1));
            }
        }
        out.push(message);
    }
}

fn upward(krate: &CrateModel, rows: &BTreeMap<&str, usize>, out: &mut Vec<String>) {
    for arrow in &krate.arrows {
        let Some(&from_row) = rows.get(arrow.from.as_str()) else { continue };
        let first = arrow.first();
        let head = if arrow.to == CRATE_ROOT {
            let lib = krate.lib.as_deref().unwrap_or("lib.rs");
            format!(
                "{}:{}: {} (row {from_row}) imports {CRATE_ROOT} ({}, defined in {lib}, which sits above every row)",
                first.file, first.line, arrow.from, first.text
            )
        } else {
            let Some(&to_row) = rows.get(arrow.to.as_str()) else { continue };
            if to_row < from_row {
                continue;
            }
            format!(
                "{}:{}: {} (row {from_row}) imports {} (row {to_row})",
                first.file, first.line, arrow.from, arrow.to
            )
        };
        out.push(head + ": a module may import only lower rows" + &also(&arrow.occurrences[1..]));
    }
}

fn composition_only(krate: &CrateModel, out: &mut Vec<String>) {
    let Some(layers) = &krate.layers else { return };
    if layers.composition_only.is_empty() {
        return;
    }
    let last_row: Vec<&str> =
        layers.rows.as_ref().and_then(|r| r.last()).map(|r| r.iter().map(String::as_str).collect()).unwrap_or_default();
    let composition: Vec<&str> = match &layers.composition {
        Some(modules) => modules.iter().map(String::as_str).collect(),
        None => last_row,
    };
    for arrow in &krate.arrows {
        if composition.contains(&arrow.from.as_str()) {
            continue;
        }
        for sub in &layers.composition_only {
            let hits: Vec<&Occurrence> =
                arrow.occurrences.iter().filter(|o| o.target[0] == arrow.to && names(sub, &o.target[1..])).collect();
            let Some(first) = hits.first() else { continue };
            let who = if composition.is_empty() {
                format!("only {} itself may import it", arrow.to)
            } else if layers.composition.is_some() {
                format!("only {} itself and the composition ({}) may import it", arrow.to, composition.join(", "))
            } else {
                format!("only {} itself and the last row ({}) may import it", arrow.to, composition.join(", "))
            };
            let rest: Vec<Occurrence> = hits[1..].iter().map(|o| (*o).clone()).collect();
            out.push(format!(
                "{}:{}: {} imports {}::{sub} ({}): {sub} is composition-only; {who}{}",
                first.file,
                first.line,
                arrow.from,
                arrow.to,
                first.text,
                also(&rest)
            ));
        }
    }
}

/// Whether a path below a top-level module takes what a `composition_only` entry names: a
/// submodule (`thread`: the path's first segment) or, written `*Suffix`, any item whose name
/// ends so (`*Thread`: a stage's thread struct, wherever it is re-exported).
fn names(entry: &str, below_module: &[String]) -> bool {
    match entry.strip_prefix('*') {
        Some(suffix) => below_module.iter().any(|segment| segment.ends_with(suffix)),
        None => below_module.first().map(String::as_str) == Some(entry),
    }
}

/// The further places of one arrow, a line each.
fn also(occurrences: &[Occurrence]) -> String {
    occurrences.iter().map(|o| format!("\n  also {}:{} ({})", o.file, o.line, o.text)).collect()
}
