//! The layering checker's tests on small fixture workspaces: which paths become arrows, the
//! rules, and the binary's output. One test binary, a module per area.

mod arrows;
mod binary;
mod crates;
mod fixture;
mod rules;
