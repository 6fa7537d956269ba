//! # Zenoh: the graph, its changes and its health for consumers off the robot's computer
//!
//! Inside the computer planners read the graph over iceoryx2 (`crate::publish`); everything that
//! leaves it goes through the process's one Zenoh session (`[zenoh]`, off by default,
//! [`ZenohSession`]), which remote detection shares. The
//! publisher hands each graph version it sent to this stage's thread on a bounded latest-wins
//! queue (`crate::flow::RemoteFeed`) and never waits for it; puts use congestion control
//! `drop`, so a slow or absent network loses messages here, not time on the hot path.
//!
//! Keys under the prefix (`zenoh.key_prefix`, `op3dsg/<hostname>` by default):
//!
//! | key | what |
//! |---|---|
//! | `<prefix>/graph` | the full graph: the first version, then every `full_period_s` |
//! | `<prefix>/graph/delta` | per version sent: the changes from the version before ([`codec::DeltaEncoder`]) |
//! | `<prefix>/health` | the health record (JSON) at the health rate |
//! | `<prefix>/occupancy` | the occupancy map, when it changed, at its publish period (`occupancy.enabled`) |
//! | `<prefix>/graph` (queryable) | the newest full graph, for a consumer that joins |
//! | `<prefix>/health` (queryable) | the newest health record, as published |
//! | `<prefix>/occupancy` (queryable) | the newest occupancy map, as published |
//! | `<prefix>/query` (queryable) | the language query service: the iceoryx2 request and response bytes, answered by the query worker ([`crate::flow::RemoteQueries`]) |
//!
//! The bytes are [`codec`]'s; `docs/remote.md` describes them field by field.
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[zenoh]` ([`ZenohConfig`]), the session's Zenoh configuration |
//! | `session.rs` | [`ZenohSession`]: the process's one session, shared with remote detection |
//! | `codec.rs` | the envelope, full graphs, deltas, health and occupancy messages |
//! | `thread.rs` | [`ZenohThread`] (feature `zenoh`) |
//! | `counters.rs` | its [`ZenohCounters`] |

pub mod codec;
mod config;
mod counters;
mod session;
#[cfg(feature = "zenoh")]
mod thread;

#[cfg(test)]
mod tests;

#[cfg(feature = "zenoh")]
pub use config::check_prefix;
pub use config::{ZenohConfig, ZenohMode};
pub use counters::ZenohCounters;
pub use session::ZenohSession;
#[cfg(feature = "zenoh")]
pub use thread::ZenohThread;
