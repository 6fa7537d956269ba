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
//! | `tf_input.rs` | [`TfInputThread`] and its [`TfInputCounters`] |

mod config;
mod tf_input;

pub use config::{MAX_DOMAIN_ID, Ros2Config, TfInputConfig};
pub use tf_input::{TfInputCounters, TfInputThread};
