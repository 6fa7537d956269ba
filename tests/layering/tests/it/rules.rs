//! The messages of `check` and the figures of `report`.

use crate::fixture;

use fixture::{app, check, lines};
use op3dsg_layering::{model, report};

const ROWS_AB: &str = "[package.metadata.layers]\nrows = [[\"a\"], [\"b\"]]\n";

#[test]
fn an_upward_import_names_both_modules_their_rows_and_the_line() {
    let dir = app(
        ROWS_AB,
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\n"),
            ("src/b.rs", "pub struct B;\npub fn f(_: crate::a::A) {}\n"),
            ("src/a.rs", "pub struct A;\n\nuse crate::b::B;\npub fn g() -> crate::b::B { B }\n"),
        ],
    );
    assert_eq!(
        check(&dir),
        [
            "app: import circle of 2 modules: a, b\n  \
             app/src/a.rs:3: a imports b (crate::b::B) +1 more\n  \
             app/src/b.rs:2: b imports a (crate::a::A)",
            "app/src/a.rs:3: a (row 1) imports b (row 2): a module may import only lower rows\n  \
             also app/src/a.rs:4 (crate::b::B)",
        ]
    );
}

#[test]
fn a_module_may_not_import_its_own_row_nor_lib_rs() {
    let dir = app(
        "[package.metadata.layers]\nrows = [[\"a\", \"b\"]]\n",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\npub struct Root;\n"),
            ("src/a.rs", "pub struct A;\n"),
            ("src/b.rs", "use crate::a::A;\nuse crate::Root;\n"),
        ],
    );
    assert_eq!(
        check(&dir),
        [
            "app/src/b.rs:2: b (row 1) imports (crate root) (crate::Root, defined in app/src/lib.rs, which sits \
             above every row): a module may import only lower rows",
            "app/src/b.rs:1: b (row 1) imports a (row 1): a module may import only lower rows",
        ]
    );
}

#[test]
fn a_circle_of_three_modules_is_reported_with_every_arrow() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\npub mod c;\npub mod d;\n"),
            ("src/a.rs", "pub struct A;\nuse crate::b::B;\n"),
            ("src/b.rs", "pub struct B;\nuse crate::c::C;\n"),
            ("src/c.rs", "pub struct C;\nuse crate::a::A;\n"),
            // d imports the circle but is not part of it.
            ("src/d.rs", "use crate::a::A;\n"),
        ],
    );
    assert_eq!(
        check(&dir),
        ["app: import circle of 3 modules: a, b, c\n  \
          app/src/a.rs:2: a imports b (crate::b::B)\n  \
          app/src/b.rs:2: b imports c (crate::c::C)\n  \
          app/src/c.rs:2: c imports a (crate::a::A)"]
    );
}

#[test]
fn rows_must_list_every_module_exactly_once() {
    let dir = app(
        "[package.metadata.layers]\nrows = [[\"a\", \"ghost\"], [\"a\"]]\n",
        &[("src/lib.rs", "pub mod a;\npub mod b;\n"), ("src/a.rs", ""), ("src/b.rs", "")],
    );
    assert_eq!(
        check(&dir),
        [
            "app/Cargo.toml: [package.metadata.layers] rows list \"a\" more than once (rows 1, 2); a module belongs \
             to one row",
            "app/Cargo.toml: [package.metadata.layers] rows list \"ghost\", which is not a top-level module of \
             app/src/lib.rs",
            "app/Cargo.toml: [package.metadata.layers] rows do not list \"b\", a top-level module of app/src/lib.rs; \
             every one belongs to a row",
        ]
    );
}

#[test]
fn a_composition_only_submodule_is_for_its_module_and_the_last_row() {
    let dir = app(
        "[package.metadata.layers]\nrows = [[\"fusion\"], [\"keyframe\"], [\"pipeline\"]]\n\
         composition_only = [\"thread\"]\n",
        &[
            ("src/lib.rs", "pub mod fusion;\npub mod keyframe;\npub mod pipeline;\n"),
            ("src/fusion/mod.rs", "pub mod thread;\npub use thread::Stage;\nuse self::thread::spawn;\n"),
            ("src/fusion/thread.rs", "pub struct Stage;\npub fn spawn() {}\n"),
            (
                "src/keyframe.rs",
                "use crate::fusion::Stage;\nuse crate::fusion::thread::spawn;\npub fn f() { super::fusion::thread::spawn() }\n",
            ),
            ("src/pipeline.rs", "use crate::fusion::thread::spawn;\n"),
        ],
    );
    assert_eq!(
        check(&dir),
        ["app/src/keyframe.rs:2: keyframe imports fusion::thread (crate::fusion::thread::spawn): thread is \
          composition-only; only fusion itself and the last row (pipeline) may import it\n  \
          also app/src/keyframe.rs:3 (super::fusion::thread::spawn)"]
    );
}

#[test]
fn a_thread_struct_is_for_the_composition_wherever_it_is_re_exported() {
    let dir = app(
        "[package.metadata.layers]\nrows = [[\"fusion\"], [\"keyframe\"], [\"config\"], [\"pipeline\"], [\"service\"]]\n\
         composition_only = [\"thread\", \"*Thread\"]\ncomposition = [\"config\", \"pipeline\", \"service\"]\n",
        &[
            (
                "src/lib.rs",
                "pub mod config;\npub mod fusion;\npub mod keyframe;\npub mod pipeline;\npub mod service;\n",
            ),
            ("src/fusion/mod.rs", "mod thread;\npub use thread::FusionThread;\npub struct Fused;\n"),
            ("src/fusion/thread.rs", "pub struct FusionThread;\n"),
            ("src/keyframe.rs", "use crate::fusion::{Fused, FusionThread};\n"),
            ("src/config.rs", "pub struct Profile;\n"),
            ("src/pipeline.rs", "use crate::fusion::FusionThread;\n"),
            ("src/service.rs", "use crate::pipeline::*;\n"),
        ],
    );
    assert_eq!(
        check(&dir),
        ["app/src/keyframe.rs:1: keyframe imports fusion::*Thread (crate::fusion::FusionThread): *Thread is \
          composition-only; only fusion itself and the composition (config, pipeline, service) may import it"]
    );
}

#[test]
fn an_oversized_product_file_is_flagged_and_test_files_are_not() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod big;\npub mod small;\n#[cfg(test)]\nmod tests;\n"),
            ("src/big.rs", &lines(701)),
            ("src/small.rs", &(lines(700) + "#[cfg(test)]\nmod tests;\n")),
            ("src/small/tests.rs", &lines(900)),
            ("src/tests.rs", &lines(900)),
            ("src/bin/tool.rs", &lines(800)),
            ("examples/demo.rs", &lines(750)),
            ("tests/huge.rs", &lines(2000)),
            ("benches/huge.rs", &lines(2000)),
        ],
    );
    assert_eq!(
        check(&dir),
        [
            "app/examples/demo.rs: 750 lines, over 700: split it by responsibility",
            "app/src/big.rs: 701 lines, over 700: split it by responsibility",
            "app/src/bin/tool.rs: 800 lines, over 700: split it by responsibility",
            "app/src/small.rs: 702 lines, over 700: split it by responsibility",
        ]
    );
    let crates = model::load(dir.path()).unwrap();
    assert!(op3dsg_layering::check::violations(&crates, 800).is_empty());
}

#[test]
fn report_counts_modules_arrows_circles_and_the_largest_file() {
    let dir = app(
        "[package.metadata.layers]\nrows = [[\"a\", \"b\", \"c\"], [\"d\"]]\n",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\npub mod c;\npub mod d;\n"),
            ("src/a.rs", "use crate::b::B;\n"),
            ("src/b.rs", "use crate::a::A;\nuse crate::c::C;\n"),
            ("src/c.rs", "use crate::b::B;\n"),
            ("src/d.rs", &(lines(40) + "use crate::a::A;\nuse crate::a::Other;\n")),
        ],
    );
    let crates = model::load(dir.path()).unwrap();
    assert_eq!(
        report::render(&crates, false),
        "crate  rows  modules  arrows  circles  largest circle  largest product file\n\
         app       2        4       5        1               3  app/src/d.rs (42 lines)\n"
    );
    assert_eq!(
        report::render(&crates, true),
        "crate  rows  modules  arrows  circles  largest circle  largest product file\n\
         app       2        4       5        1               3  app/src/d.rs (42 lines)\n\
         \n\
         app\n  \
           circle of 3: a, b, c\n  \
           a -> b  app/src/a.rs:1\n  \
           b -> a  app/src/b.rs:1\n  \
           b -> c  app/src/b.rs:2\n  \
           c -> b  app/src/c.rs:1\n  \
           d -> a  app/src/d.rs:41 (2 places)\n"
    );
}
