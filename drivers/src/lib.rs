//! # op3dsg drivers: where frames and poses come from
//!
//! - [`frame`]: RGB-D frames, intrinsics and the start-up-allocated [`frame::FramePool`].
//! - [`pose`]: rigid transforms (`world_from_camera`), the interpolating [`pose::PoseBuffer`].
//! - [`source`]: the [`source::FrameSource`] trait every source implements.
//! - [`replay`]: recorded RGB-D in the TUM RGB-D layout (`rgb.txt`, `depth.txt`,
//!   `groundtruth.txt`, `camera.json`) with its poses; recorded-rate, fast or stepped playback.
//! - [`synthetic`]: seeded procedural rooms with exact ground truth, a CPU ray-cast renderer
//!   with a D435i-like depth noise model, and a robot-like camera path.
//! - [`graph_json`]: the scene-graph JSON form shared by ground truth and published graphs.
//!
//! ```
//! use op3dsg_drivers::frame::{Frame, Intrinsics};
//! use op3dsg_drivers::source::{FrameSource, SourceStatus};
//! use op3dsg_drivers::synthetic::{RoomKind, SyntheticConfig, SyntheticSource};
//!
//! let config = SyntheticConfig { room: RoomKind::Kitchen, seed: 1, frame_count: Some(2), ..Default::default() };
//! let mut source = SyntheticSource::new(&config).unwrap();
//! let mut frame = Frame::new(source.intrinsics(), true);
//! assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
//! assert!(frame.world_from_camera.is_some());
//! let ground_truth = source.scene().ground_truth();
//! assert!(ground_truth.nodes.iter().any(|n| n.kind == "part"));
//! ```

pub mod frame;
pub mod graph_json;
pub mod pose;
pub mod replay;
pub mod source;
pub mod synthetic;
