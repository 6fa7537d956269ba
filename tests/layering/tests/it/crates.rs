//! The workspace's crate rows: a member depends only on members of lower rows.

use std::path::Path;

use crate::fixture::write;

/// A workspace of `low` and `high`; `rows` goes into `[workspace.metadata.layers]`, `low_deps`
/// and `high_deps` are the members' dependency tables.
fn workspace(rows: &str, low_deps: &str, high_deps: &str) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("temporary folder");
    let root = format!("[workspace]\nmembers = [\"low\", \"high\"]\n\n[workspace.metadata.layers]\n{rows}\n");
    write(dir.path(), "Cargo.toml", &root);
    for (name, deps) in [("low", low_deps), ("high", high_deps)] {
        let manifest = format!("[package]\nname = \"{name}\"\nversion = \"0.1.0\"\nedition = \"2024\"\n\n{deps}\n");
        write(dir.path(), &format!("{name}/Cargo.toml"), &manifest);
        write(dir.path(), &format!("{name}/src/lib.rs"), "//! x\n");
    }
    dir
}

fn violations(root: &Path) -> Vec<String> {
    op3dsg_layering::crates::violations(root).expect("the fixture loads")
}

#[test]
fn a_dependency_on_a_lower_row_is_allowed_and_dev_dependencies_are_not_checked() {
    let dir = workspace(
        "crates = [[\"low\"], [\"high\"]]",
        "[dev-dependencies]\nhigh = { path = \"../high\" }",
        "[dependencies]\nlow = { path = \"../low\" }",
    );
    assert_eq!(violations(dir.path()), Vec::<String>::new());
}

#[test]
fn a_dependency_on_a_higher_row_names_the_manifest_both_crates_and_the_fix() {
    let dir = workspace(
        "crates = [[\"low\"], [\"high\"]]",
        "[dependencies]\nhigh = { path = \"../high\" }",
        "[dependencies]\nlow = { path = \"../low\" }",
    );
    let found = violations(dir.path());
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].contains("low/Cargo.toml"), "{}", found[0]);
    assert!(found[0].contains("low (crate row 1) depends on high (crate row 2)"), "{}", found[0]);
    assert!(found[0].contains("into a crate above both"), "{}", found[0]);
}

#[test]
fn same_row_renamed_and_build_dependencies_count() {
    let dir = workspace(
        "crates = [[\"low\", \"high\"]]",
        "[build-dependencies]\nhigher = { package = \"high\", path = \"../high\" }",
        "",
    );
    let found = violations(dir.path());
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].contains("low (crate row 1) depends on high (crate row 1)"), "{}", found[0]);
}

#[test]
fn every_member_in_exactly_one_row_and_no_stranger() {
    let dir = workspace("crates = [[\"low\", \"ghost\"], [\"low\"]]", "", "");
    let found = violations(dir.path()).join("\n");
    assert!(found.contains("list \"ghost\", which is not a workspace member"), "{found}");
    assert!(found.contains("list \"low\" more than once"), "{found}");
    assert!(found.contains("do not list \"high\""), "{found}");
}

#[test]
fn without_crate_rows_nothing_is_checked() {
    let dir =
        workspace("", "[dependencies]\nhigh = { path = \"../high\" }", "[dependencies]\nlow = { path = \"../low\" }");
    assert_eq!(violations(dir.path()), Vec::<String>::new());
}
