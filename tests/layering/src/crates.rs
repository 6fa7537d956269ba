//! The workspace's crate rows (`[workspace.metadata.layers] crates`): a member depends only on
//! members of earlier rows, so the drivers stay below the runtime and the composition on top.

use std::collections::BTreeMap;
use std::path::Path;

use crate::error::Error;
use crate::manifest::{self, Member};

/// Every violation of the crate rows of the workspace at `root`; none when it declares no rows.
pub fn violations(root: &Path) -> Result<Vec<String>, Error> {
    let Some(rows) = manifest::workspace_layers(root)?.crates else { return Ok(Vec::new()) };
    let members = manifest::members(root)?;
    let at = format!("{}: [workspace.metadata.layers] crates", root.join("Cargo.toml").display());
    let mut out = Vec::new();
    let mut row_of: BTreeMap<&str, usize> = BTreeMap::new();
    for (index, row) in rows.iter().enumerate() {
        for name in row {
            if row_of.insert(name.as_str(), index + 1).is_some() {
                out.push(format!("{at} list \"{name}\" more than once; a crate belongs to one row"));
            } else if !members.iter().any(|m| &m.name == name) {
                out.push(format!("{at} list \"{name}\", which is not a workspace member"));
            }
        }
    }
    for member in &members {
        let Some(&row) = row_of.get(member.name.as_str()) else {
            out.push(format!("{at} do not list \"{}\", a workspace member; every one belongs to a row", member.name));
            continue;
        };
        for dependency in &member.dependencies {
            upward(member, row, dependency, &row_of, &mut out);
        }
    }
    Ok(out)
}

fn upward(member: &Member, row: usize, dependency: &str, row_of: &BTreeMap<&str, usize>, out: &mut Vec<String>) {
    let Some(&to) = row_of.get(dependency) else { return };
    if to >= row {
        out.push(format!(
            "{}: {} (crate row {row}) depends on {dependency} (crate row {to}): a crate depends only on crates of \
             lower rows; move the code that needs {dependency} up, into a crate above both",
            member.manifest.display(),
            member.name
        ));
    }
}
