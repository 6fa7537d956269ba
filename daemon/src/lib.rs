//! # op3dsg daemon library
//!
//! The pipeline stages of `op3dsgd` and the pieces the `op3dsg` CLI shares with it.

pub mod graph;
pub mod ipc;
pub mod perception;
