//! # ROS 2: the robot's own software, through Zenoh, without ROS
//!
//! A Stretch 3 runs ROS 2: its localisation publishes the robot's pose as the tf tree (`/tf`,
//! `/tf_static`). With `pose.source = "ros2"` this stage takes the camera's pose from that tree
//! (`op3dsg-ros2-tf`, [`TfInputThread`]) instead of the iceoryx2 pose service. ROS 2 reaches
//! Zenoh in two ways and both are spoken (`ros2.key_style`): `rmw_zenoh`, ROS 2's Zenoh
//! middleware (a client of its router, `rmw_zenohd`), and `zenoh-bridge-ros2dds` in front of a
//! DDS middleware. Messages are CDR, decoded by `op3dsg_ros2` (messages, tf buffer, keys).
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[ros2]` and `[ros2.tf]` ([`Ros2Config`]) |
//! | `tf_input.rs` | [`TfInputThread`] (feature `zenoh`) |
//! | `messages.rs` | the graph as `MarkerArray` and JSON, the map as `OccupancyGrid` |
//! | `output.rs` | [`Ros2OutputThread`] (`[ros2.out]`; feature `zenoh`) |
//! | `counters.rs` | their [`TfInputCounters`] and [`Ros2OutputCounters`] |
//!
//! Out to ROS 2 (`[ros2.out]`, each topic off by default), `op3dsg-ros2-out` publishes the graph
//! as markers for RViz, the occupancy map as a grid and the graph as JSON, from a latest-wins
//! hand-over of the publisher's graph versions and the occupancy thread's newest map: a slow or
//! absent ROS side costs the pipeline nothing. With `rmw_zenoh` keys each message carries the
//! attachment rmw_zenoh expects and the node and its publishers are announced by liveliness
//! tokens, so `ros2 topic list` and RViz see them.

mod config;
mod counters;
mod messages;
#[cfg(feature = "zenoh")]
mod output;
#[cfg(feature = "zenoh")]
mod tf_input;

pub use config::{MAX_DOMAIN_ID, Ros2Config, Ros2OutConfig, TfInputConfig};
pub use counters::{Ros2OutputCounters, TfInputCounters};
pub use messages::{MarkerState, graph_json, marker_array, occupancy_grid};
#[cfg(feature = "zenoh")]
pub use output::Ros2OutputThread;
#[cfg(feature = "zenoh")]
pub use tf_input::TfInputThread;
