//! Publish: the thread that serves each graph version and the health record over iceoryx2 (the
//! services themselves are `crate::ipc`'s) and takes the navigation stack's poses in.
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[health]` ([`HealthConfig`]) |
//! | `thread.rs` | [`PublishThread`] and its [`PublishCounters`] |

mod config;
mod thread;

pub use config::HealthConfig;
pub use thread::{PublishCounters, PublishThread, add_wire_checks};
