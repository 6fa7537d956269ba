//! # op3dsg-realsense: the Intel RealSense D435i as a frame source
//!
//! `source.kind = "realsense"` (`[source.realsense]`, [`RealsenseConfig`]): a live camera chosen
//! by serial number or by product ([`select`]: the Stretch 3's head D435i, not its gripper's
//! D405), or a librealsense `.bag` recording played through the same code. Depth is
//! aligned to colour ([`align`]: from the device's calibration, or by librealsense's align block
//! with `align = "librealsense"`); intrinsics and depth units come from the
//! device (or the recording); frames are rotated upright ([`rotate`], the Stretch 3's head camera
//! is mounted turned by 90°) while they are copied from the driver's buffers into the pooled
//! [`op3dsg_drivers::frame::Frame`], with no per-frame buffer allocation.
//!
//! The librealsense part ([`device`]) is behind the crate feature `librealsense` (what `op3dsgd
//! --features realsense` turns on), so the default build needs no librealsense; the
//! configuration, the rotation and the copy kernels (and their benchmark) always build. The crate
//! knows nothing of the runtime: `op3dsgd` registers it as `source.kind = "realsense"`.
//!
//! `unsafe` is in two files only, each use with its `// SAFETY:` argument: `device/ffi.rs`
//! (librealsense's C API where `realsense-rust` stops short) and `unchecked.rs` (the entries into
//! the quarter turns' SIMD kernels with their prefetch hints, and the alignment's z-buffer writes
//! without a bounds check per value).
//!
//! ```
//! use op3dsg_drivers::frame::Intrinsics;
//! use op3dsg_realsense::rotate::Rotation;
//!
//! let k = Intrinsics { width: 848, height: 480, fx: 421.0, fy: 421.0, cx: 424.0, cy: 240.0 };
//! let upright = Rotation::Cw90.intrinsics(&k);
//! assert_eq!((upright.width, upright.height), (480, 848));
//! assert_eq!(Rotation::Cw90.map_pixel(0, 0, 848, 480), (479, 0));
//! ```

pub mod align;
pub mod config;
#[cfg(feature = "librealsense")]
pub mod device;
pub mod imu;
pub mod rotate;
pub mod select;
mod unchecked;

pub use config::RealsenseConfig;
#[cfg(feature = "librealsense")]
pub use device::RealsenseSource;

/// `source.kind` of this source.
pub const REALSENSE_SOURCE: &str = "realsense";
