//! The command line: exit status, `--root`, `--max-file-lines`, and this workspace's own crate.

use crate::fixture;

use std::path::Path;
use std::process::Command;

use fixture::{app, lines};

fn layers(root: &Path, args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_op3dsg-layers"))
        .arg("--root")
        .arg(root)
        .args(args)
        .output()
        .expect("run op3dsg-layers");
    (out.status.code(), String::from_utf8(out.stdout).expect("UTF-8 output"))
}

#[test]
fn check_exits_1_listing_every_violation_and_0_when_clean() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\n"),
            ("src/a.rs", &(lines(20) + "use crate::b::B;\n")),
            ("src/b.rs", "use crate::a::A;\n"),
        ],
    );
    let (code, out) = layers(dir.path(), &["check", "--max-file-lines", "10"]);
    assert_eq!(code, Some(1));
    assert_eq!(
        out,
        "app: import circle of 2 modules: a, b\n  \
         app/src/a.rs:21: a imports b (crate::b::B)\n  \
         app/src/b.rs:1: b imports a (crate::a::A)\n\
         app/src/a.rs: 21 lines, over 10: split it by responsibility\n\
         layering: 2 violations in 1 crates\n"
    );

    fixture::write(dir.path(), "app/src/b.rs", "pub struct B;\n");
    let (code, out) = layers(dir.path(), &["check"]);
    assert_eq!((code, out.as_str()), (Some(0), "layering: 1 crates, no violation\n"));
}

#[test]
fn a_file_that_cannot_be_read_stops_the_check_with_status_2() {
    let dir = app("", &[("src/lib.rs", "pub mod missing;\n")]);
    let (code, _) = layers(dir.path(), &["check"]);
    assert_eq!(code, Some(2));
}

#[test]
fn this_crate_keeps_its_own_rows() {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let crates = op3dsg_layering::model::load(&workspace).unwrap();
    let own = crates.iter().find(|c| c.name == "op3dsg-layering").unwrap();
    assert!(own.layers.as_ref().and_then(|l| l.rows.as_ref()).is_some());
    let violations = op3dsg_layering::check::violations(std::slice::from_ref(own), 700);
    assert_eq!(violations, Vec::<String>::new());
}
