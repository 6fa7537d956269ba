//! Which paths become arrows between top-level modules, and where they are reported.

use crate::fixture;

use fixture::{app, arrows, check};

#[test]
fn a_use_group_gives_one_arrow_per_module() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\npub mod c;\n"),
            ("src/a.rs", "pub struct X;\n"),
            ("src/b.rs", "pub struct Y;\n"),
            ("src/c.rs", "//! c\n\nuse crate::{a::X, b};\n"),
        ],
    );
    assert_eq!(arrows(&dir), ["c -> a at app/src/c.rs:3 (crate::a::X)", "c -> b at app/src/c.rs:3 (crate::b)"]);
}

#[test]
fn paths_in_types_expressions_patterns_impls_and_bounds_are_arrows() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\npub mod c;\npub mod d;\npub mod e;\n"),
            ("src/a.rs", "pub struct X;\n"),
            ("src/b.rs", "pub trait T {}\n"),
            ("src/c.rs", "pub enum E { V }\n"),
            ("src/d.rs", "pub const N: usize = 1;\n"),
            (
                "src/e.rs",
                "pub struct S(crate::a::X);\n\
                 impl crate::b::T for S {}\n\
                 pub fn f<U: crate::b::T>(e: crate::c::E) -> usize {\n\
                 \x20   match e { crate::c::E::V => crate::d::N }\n\
                 }\n",
            ),
        ],
    );
    assert_eq!(
        arrows(&dir),
        [
            "e -> a at app/src/e.rs:1 (crate::a::X)",
            "e -> b at app/src/e.rs:2 (crate::b::T)",
            "e -> c at app/src/e.rs:3 (crate::c::E)",
            "e -> d at app/src/e.rs:4 (crate::d::N)",
        ]
    );
}

#[test]
fn a_path_inside_a_macro_invocation_is_found() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod stats;\npub mod fusion;\n"),
            ("src/stats.rs", "pub fn mib(bytes: usize) -> f64 { bytes as f64 }\n"),
            (
                "src/fusion.rs",
                "pub fn log(y: usize) {\n\
                 \x20   tracing::warn!(\n\
                 \x20       x = %crate::stats::mib(y),\n\
                 \x20       \"crate::other::not_a_path\"\n\
                 \x20   );\n\
                 }\n",
            ),
        ],
    );
    assert_eq!(arrows(&dir), ["fusion -> stats at app/src/fusion.rs:3 (crate::stats::mib)"]);
}

#[test]
fn super_climbing_out_of_a_module_resolves_to_the_module_it_names() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod graph;\npub mod queue;\n"),
            ("src/graph.rs", "pub struct Graph;\n"),
            ("src/queue.rs", "pub struct Queue;\n"),
            // mod.rs: one `super` reaches the crate root.
            ("src/a/mod.rs", "mod b;\n\nuse super::graph::Graph;\npub(crate) use self::b::Local;\n"),
            // b.rs inside a: `super` is a, `super::super` the crate root.
            ("src/a/b.rs", "pub struct Local;\n\npub fn f(_: super::Local, _: super::super::queue::Queue) {}\n"),
        ],
    );
    assert_eq!(
        arrows(&dir),
        [
            "a -> graph at app/src/a/mod.rs:3 (super::graph::Graph)",
            "a -> queue at app/src/a/b.rs:3 (super::super::queue::Queue)"
        ]
    );
}

#[test]
fn test_code_doc_comments_and_strings_are_not_arrows() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\n#[cfg(test)]\nmod tests;\n"),
            // b imports a: any arrow a -> b would make a circle.
            ("src/b.rs", "pub struct B;\npub fn f(_: crate::a::A) {}\n"),
            (
                "src/a.rs",
                "//! Not [`crate::b::B`] either.\n\
                 pub struct A;\n\
                 /// Uses [`crate::b::B`].\n\
                 pub const NAME: &str = \"crate::b::B\";\n\
                 #[cfg(test)]\n\
                 mod tests;\n\
                 #[cfg(test)]\n\
                 fn helper() -> crate::b::B { crate::b::B }\n\
                 #[cfg(doc)]\n\
                 use crate::b::B;\n\
                 #[cfg(all(test, unix))]\n\
                 mod unix_tests { use crate::b::B; }\n",
            ),
            ("src/a/tests.rs", "use crate::b::B;\n"),
            ("src/tests.rs", "use crate::b::B;\n"),
        ],
    );
    assert_eq!(arrows(&dir), ["b -> a at app/src/b.rs:2 (crate::a::A)"]);
    assert_eq!(check(&dir), Vec::<String>::new());
}

#[test]
fn a_root_name_resolves_through_lib_rs_re_exports() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b;\npub use b::Thing;\nuse serde::Serialize;\npub struct Root;\n"),
            ("src/b.rs", "pub struct Thing;\n"),
            ("src/a.rs", "use crate::Thing;\nuse crate::Serialize;\npub fn f(_: crate::Root) {}\n"),
        ],
    );
    assert_eq!(
        arrows(&dir),
        ["a -> (crate root) at app/src/a.rs:3 (crate::Root)", "a -> b at app/src/a.rs:1 (crate::Thing)"]
    );
}

#[test]
fn inline_modules_and_path_attributes_are_followed() {
    let dir = app(
        "",
        &[
            ("src/lib.rs", "pub mod a;\npub mod b {\n    pub fn f(_: crate::a::A) {}\n}\n"),
            ("src/a.rs", "#[path = \"elsewhere/impl_a.rs\"]\nmod imp;\npub use imp::A;\n"),
            ("src/elsewhere/impl_a.rs", "pub struct A;\npub fn g() { super::super::b::f(A) }\n"),
        ],
    );
    assert_eq!(
        arrows(&dir),
        ["a -> b at app/src/elsewhere/impl_a.rs:2 (super::super::b::f)", "b -> a at app/src/lib.rs:3 (crate::a::A)"]
    );
}
