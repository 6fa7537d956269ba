//! # op3dsg layering check
//!
//! Keeps the workspace's crates in layers that point down. The *top-level modules* of a crate
//! are the modules its `src/lib.rs` declares; an *arrow* `a -> b` is any place in module `a`'s
//! product code that names module `b` of the same crate:
//!
//! - `use crate::b::…` (groups too: `use crate::{b, c::X}` is two arrows),
//! - a path in a type, expression, pattern, impl or bound (`crate::b::Thing`),
//! - a path inside a macro invocation (`tracing::warn!(x = %crate::b::f(y))`, read from tokens),
//! - `super::` climbing out of `a` to the crate root and down (`super::b::X` in `src/a/mod.rs`,
//!   `super::super::b` in `src/a/c.rs`),
//! - `crate::Item` where lib.rs re-exports `pub use b::Item`. An item defined in lib.rs itself
//!   is the node `(crate root)`, which sits above every row.
//!
//! Code under `#[cfg(test)]` is not product code: neither its paths nor the files it declares
//! (`#[cfg(test)] mod tests;`) count. Nor is code under `#[cfg(doc)]` (imports that only
//! intra-doc links use). Doc comments and string literals are not paths.
//!
//! `op3dsg-layers check` reports, for every workspace member, all of:
//!
//! 1. an import circle between top-level modules (every module of it, and every arrow in it
//!    with the file and line that writes it);
//! 2. with declared rows, an import of a module that is not in a lower row;
//! 3. with `composition_only`, an import of such a submodule or item from outside its module
//!    and the composition (`composition`, else the last row);
//! 4. with `[workspace.metadata.layers] crates` in the workspace's Cargo.toml, a member whose
//!    `[dependencies]` or `[build-dependencies]` name a member of its own or a higher row
//!    (`[dev-dependencies]` are the tests', not the product's);
//! 5. a product file over 700 lines (`--max-file-lines`): the module trees of each member's lib
//!    and binaries, `src/bin/**` and `examples/`; never `tests/` or `benches/`.
//!
//! A crate declares its rows in its own Cargo.toml; without `rows`, only circles are checked:
//!
//! ```toml
//! [package.metadata.layers]
//! # bottom first: a module may import only modules of earlier rows
//! rows = [
//!   ["world", "queue"],        # leaves
//!   ["graph"],
//!   ["fusion", "perception"],  # stages
//!   ["pipeline"],              # composition
//! ]
//! # what only the composition may import from another top-level module: a submodule, or
//! # (`*Suffix`) any item whose name ends so
//! composition_only = ["thread", "*Thread"]
//! # the modules of the composition (default: the last row)
//! composition = ["pipeline"]
//! ```
//!
//! Every top-level module must be in exactly one row. With the rows above, `fusion` may import
//! `graph`, `world` and `queue`, not `perception` (same row) or `pipeline` (above); and only
//! `fusion` itself and `pipeline` may name `crate::fusion::thread` or `crate::fusion::FusionThread`.

pub mod check;
pub mod crates;
pub mod cycles;
pub mod error;
pub mod manifest;
pub mod model;
pub mod report;
pub mod scan;
