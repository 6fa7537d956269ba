//! # The live view: the graph in Foxglove while the robot runs
//!
//! `[live_view]` (off by default) serves Foxglove's WebSocket protocol through the `foxglove`
//! crate's server, on `127.0.0.1:8765` unless the profile says otherwise. Its thread
//! (`op3dsg-live-view`) takes graph versions from a latest-wins hand-over of the publisher, the
//! publisher's newest health record, the occupancy thread's newest map and the keyframe gate's
//! newest pose and images ([`crate::flow::LiveFeed`]); none of them ever waits for it, and the
//! server keeps a bounded backlog per viewer that drops its oldest messages, so a slow or absent
//! viewer costs the pipeline nothing. Nothing is encoded for a channel nobody subscribes to;
//! the gate copies no image while nobody watches one.
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/op3dsg/scene` | `foxglove.SceneUpdate` | the recorder's scene ([`crate::record::scene`]): a cube and a label per node, parts apart, edges as lines; every update replaces the last |
//! | `/tf` | `foxglove.FrameTransform` | world → `camera` at each keyframe |
//! | `/op3dsg/occupancy` | `foxglove.Grid` | the occupancy map (`occupancy.enabled`) |
//! | `/op3dsg/health` | `op3dsg.Health` (JSON) | the health record, as the recorder writes it |
//! | `/camera/colour`, `/camera/depth` | `foxglove.RawImage` | downscaled, rate-limited (`live_view.images`) |
//!
//! `docs/live.md` says how to connect and what each channel costs.
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[live_view]` ([`LiveViewConfig`]) |
//! | `handshake.rs` | the layer before the server that takes `foxglove.websocket.v1` as well as the SDK's names |
//! | `messages.rs` | the graph, the pose, the map and the images in Foxglove's types |
//! | `thread.rs` | [`LiveViewThread`] and its [`LiveViewCounters`] |

mod config;
pub mod handshake;
pub mod messages;
mod thread;

pub use config::LiveViewConfig;
pub use thread::{LiveViewCounters, LiveViewThread, TOPIC_OCCUPANCY};
