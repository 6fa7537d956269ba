//! Capture: the thread that reads the frame source (`[source]`, opened by its backend) into
//! pooled frames and hands them to the keyframe gate.
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[source]` ([`SourceConfig`]) |
//! | `counters.rs` | [`CaptureCounters`]: frames, the source's state, latency |
//! | `thread.rs` | [`CaptureThread`] |

mod config;
mod counters;
mod thread;

pub use config::{REPLAY_SOURCE, SourceConfig};
pub use counters::CaptureCounters;
pub use thread::CaptureThread;
