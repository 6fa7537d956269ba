//! The keyframe gate: gives each frame its `world_from_camera` and decides whether it is a
//! keyframe. Shared by the threaded pipeline (on its `op3dsg-keyframe` thread, [`KeyframeThread`])
//! and the synchronous batch runner of `op3dsg-sim`, so both select exactly the same keyframes.
//!
//! A frame's pose comes from the frame itself (`pose.source = "frame"`) or from the pose buffer
//! filled from `<prefix>/pose` (`"ipc"`), as a navigation stack sends it: at its own rate
//! (10 Hz is common), a little late, now and then out of order or broken.
//!
//! ## Looking up a frame's pose (`pose.source = "ipc"`)
//!
//! - Two buffered poses that bracket the frame's stamp and are at most
//!   `pose.max_interpolation_gap_ms` apart: the pose is interpolated between them (linear in
//!   translation, SLERP in rotation; [`PoseBuffer`]).
//! - A frame stamped after the newest pose waits (on its thread, frames kept in order, at most
//!   [`MAX_PENDING_FRAMES`] at once) up to `pose.max_wait_ms` of host time for the pose after it.
//!   The wait adds latency, not loss: at 30 Hz the 200 ms default holds 6 frames.
//! - Otherwise, or once the wait is over, the nearest pose is held if it is at most
//!   `pose.tolerance_ms` from the stamp. Nothing is extrapolated beyond that: the frame is
//!   dropped and counted (`frames_without_pose` in health, a rate-limited warning per reason).
//!
//! ## Which received poses are adopted
//!
//! Each received pose is counted once in health (`PoseHealth`), under the first check it fails,
//! and every refusal is logged at warn, rate-limited per reason:
//!
//! | reason | when | where |
//! |---|---|---|
//! | `unknown_kind` | `kind` is neither 0 (`world_from_camera`) nor 1 (`world_from_base`) | wire check |
//! | `non_finite` | a translation or quaternion component is NaN or infinite | wire check |
//! | `non_unit_quaternion` | the quaternion's norm is off 1 by more than 1e-3 | wire check |
//! | `no_base_from_camera` | `world_from_base` while the profile sets no `pose.base_from_camera` | gate |
//! | `out_of_order` | stamped before the newest adopted pose | gate |
//! | `stale` | stamped more than `max(pose.max_interpolation_gap_ms, pose.tolerance_ms)` before the oldest frame still waiting for a pose (the newest frame when none waits): no frame can use it | gate |
//! | `future` | stamped more than `pose.future_tolerance_ms` after the newest frame; **not** adopted, so it cannot make the poses that follow out of order | gate |
//!
//! The wire checks run on the publisher thread (`GraphServer::poll_poses`), the gate's here.
//! `world_from_base` poses become `world_from_base * base_from_camera` (the profile's fixed mount).
//!
//! The buffer recovers by itself: a refused pose changes nothing; poses adopted before the first
//! frame that turn out to lie beyond `pose.future_tolerance_ms` are discarded when that frame
//! comes; frame stamps that jump back by more than that (a replay that loops, a restarted camera)
//! empty the buffer. An adopted pose at most `pose.future_tolerance_ms` ahead can hold back
//! earlier poses as out of order for at most that long.
//!
//! ## Clocks
//!
//! Poses are looked up by the frame's stamp, so the navigation stack must stamp them on the
//! clock of the frame source ([`StampClock`]):
//!
//! | `source.kind` | frames are stamped on |
//! |---|---|
//! | `realsense` | the host clock, through librealsense's global time (hardware timestamps mapped to the host's system clock, ns since the Unix epoch) |
//! | `replay` | the recording's own stamps (its poses, or poses on its clock) |
//! | `synthetic` | scene time: 0 at the first frame, frame `k` at `k / source.synthetic.frame_rate_hz`, whatever the delivery rate |
//!
//! When poses keep arriving but their stamps stay more than `pose.future_tolerance_ms` ahead of
//! the frames, or more than `max(pose.max_interpolation_gap_ms, pose.tolerance_ms)` behind, for
//! `pose.clock_warning_after_s`, the gate warns that the clocks differ (then at most once per
//! that period while it lasts).
//!
//! ## Keyframes
//!
//! A frame with a pose is a keyframe when it is the first one, or when since the last keyframe
//! the camera moved `keyframe.min_translation_m`, turned `keyframe.min_rotation_deg`, or
//! `keyframe.max_interval_s` passed.
//!
//! ```
//! use op3dsg_runtime::keyframe::{GateDecision, KeyframeGate};
//! let profile = op3dsg_runtime::config::load(None, &[]).unwrap().profile;
//! let mut gate = KeyframeGate::new(&profile.keyframe, &profile.pose);
//! let mut frame = op3dsg_drivers::frame::Frame::new(op3dsg_drivers::frame::Intrinsics::d435i_640x480());
//! frame.world_from_camera = Some(op3dsg_drivers::pose::Isometry::IDENTITY);
//! assert!(matches!(gate.decide(&frame), GateDecision::Keyframe(_)));
//! frame.stamp_ns = 1_000_000; // 1 ms later, not moved: not a keyframe
//! assert_eq!(gate.decide(&frame), GateDecision::Skip);
//! ```
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[pose]`, `[keyframe]` ([`PoseConfig`], [`KeyframeConfig`]) |
//! | `gate.rs` | [`KeyframeGate`]: pose lookup, pose checks, the motion test |
//! | `counters.rs` | [`KeyframeCounters`]: keyframes, frames without a pose, the pose input |
//! | `thread.rs` | [`KeyframeThread`]: frames and poses in, keyframes out |

mod config;
mod counters;
mod gate;
mod log_limit;
mod thread;

#[cfg(test)]
mod tests;

pub use config::{KeyframeConfig, PoseConfig, PoseSourceKind, TransformConfig};
pub use counters::{KeyframeCounters, count_gate};
pub use gate::{GateDecision, KeyframeGate, MAX_PENDING_FRAMES, PoseRefusal};
pub use thread::{KeyframeRecorder, KeyframeThread};
