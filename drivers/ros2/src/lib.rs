//! op3dsg and a ROS 2 robot, through Zenoh, without ROS: the protocol and data layer.
//!
//! A Stretch 3 (ROS 2 Humble; newer robots Jazzy and Kilted) publishes its pose as the tf tree
//! (`/tf`, `/tf_static`) and shows things in RViz from `visualization_msgs/MarkerArray` and
//! `nav_msgs/OccupancyGrid`. ROS 2 reaches Zenoh in two ways, both spoken here (the Zenoh I/O
//! itself is the daemon's):
//!
//! - **rmw_zenoh**, ROS 2's Zenoh middleware (`ros2/rmw_zenoh`, `docs/design.md`): keys
//!   `<domain>/<topic>/<DDS type>/<type hash>`, an attachment on every message, liveliness tokens
//!   for the ROS graph;
//! - **zenoh-bridge-ros2dds** in front of a DDS middleware (`eclipse-zenoh/zenoh-plugin-ros2dds`):
//!   topic `/tf` is key `tf`, under the bridge's namespace when it has one.
//!
//! Both carry CDR payloads.
//!
//! | module | what |
//! | --- | --- |
//! | [`cdr`] | [`encode`] / [`decode`]: the CDR envelope (encapsulation header, trailing bytes) |
//! | [`msg`] | the message types (Humble and Jazzy definitions; they agree field for field) |
//! | [`tf`] | [`TfBuffer`]: static and dynamic transforms, lookups through the tree at a stamp |
//! | [`keys`] | key expressions in both styles, liveliness tokens, GIDs, type hashes |
//! | [`attachment`] | rmw_zenoh's per-message attachment |
//! | [`rigid`] | [`RigidTransform`], the transform type of lookups |

pub mod attachment;
pub mod cdr;
pub mod keys;
pub mod msg;
pub mod rigid;
pub mod tf;

pub use cdr::{CdrError, MessageType, RosMessage, decode, encode};
pub use rigid::RigidTransform;
pub use tf::{TfBuffer, TfConfig, TfError, TfInsertError, TfPath};
