//! # op3dsg drivers: where frames and poses come from
//!
//! - [`frame`]: RGB-D frames, intrinsics and the start-up-allocated [`frame::FramePool`].
//! - [`pose`]: rigid transforms (`world_from_camera`), the interpolating [`pose::PoseBuffer`].
//! - [`source`]: the [`source::FrameSource`] trait every source implements.
//! - [`replay`]: recorded RGB-D in the TUM RGB-D layout (`rgb.txt`, `depth.txt`,
//!   `groundtruth.txt`, `camera.json`) with its poses; recorded-rate, fast or stepped playback.
//! - [`mcap`]: the channels of MCAP recordings and their replay ([`mcap::McapSource`]).
//! - [`graph_json`]: the scene-graph JSON form shared by published graphs and evaluation.
//!
//! Each module uses only those listed before it: `pose`, `frame`, `graph_json`, `source`, then
//! `replay` and `mcap` (which share the pacing and the input poses through `source` and `pose`).
//!
//! The synthetic rooms (world, renderer, camera path) are the crate `op3dsg-synthetic` in
//! `drivers/synthetic/`: their ground truth never travels in a [`frame::Frame`].
//!
//! ```
//! use op3dsg_drivers::frame::{FramePool, Intrinsics};
//!
//! let pool = FramePool::new(2, Intrinsics::d435i_640x480());
//! let frame = pool.try_take().expect("a free frame");
//! assert_eq!(frame.depth.len(), 640 * 480);
//! ```

pub mod frame;
pub mod graph_json;
pub mod mcap;
pub mod pose;
pub mod replay;
pub mod source;
