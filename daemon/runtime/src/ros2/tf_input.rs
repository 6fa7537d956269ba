//! The thread `op3dsg-ros2-tf`: the camera's pose from the robot's tf tree (`pose.source =
//! "ros2"`).
//!
//! Its Zenoh session (a client of `ros2.connect`) subscribes to `/tf` and `/tf_static` in the
//! profile's key style; the subscribers' callbacks only queue the payloads (bounded; a full queue
//! drops and counts). The thread decodes each `tf2_msgs/TFMessage` (CDR), adds its transforms to
//! the [`TfBuffer`] (static ones for ever, dynamic ones for `ros2.tf.window_s`), and for every
//! stamp of a dynamic transform looks up `world_frame → camera_frame` through the chain, once
//! every link has transforms around that stamp. Each pose found goes to the keyframe gate as a
//! received pose, which then applies the rules of the iceoryx2 pose input (interpolation to the
//! frame's stamp, hold tolerance, future and stale poses).
//!
//! A camera turned in its mount (`source.realsense.rotate`) delivers upright images; the pose
//! handed on is that of the upright image's camera: tf's camera frame composed with the turn.
//!
//! Refusals, by reason, in the health record's pose counters: `no_transform_path` (the log names
//! the missing link), `frame_not_found`, `extrapolation`; transforms with NaN or a quaternion off
//! unit length under `non_finite` and `non_unit_quaternion`; payloads that are not a TFMessage as
//! errors of the stage `ros2_tf`. Each reason is logged once (with the count at powers of two).

use std::collections::{BTreeSet, HashSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, PoisonError};
use std::time::{Duration, Instant};

use ::zenoh::Wait;
use crossbeam_channel::{Receiver, Sender, TrySendError};
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{PoseKind, PoseStamped};
use op3dsg_ros2::keys::topic_keys;
use op3dsg_ros2::msg::tf2_msgs::TFMessage;
use op3dsg_ros2::{RosMessage, TfBuffer, TfConfig, TfError, TfInsertError};
use tracing::{debug, info, warn};
use zenoh_ext::{AdvancedSubscriber, AdvancedSubscriberBuilderExt, HistoryConfig};

use super::config::Ros2Config;
use super::counters::TfInputCounters;
use crate::flow::hand_over_pose;
use crate::stats::PoseStats;

/// Payloads waiting for the thread; more are dropped (and counted).
const INTAKE_CAPACITY: usize = 1024;
/// How long the thread waits for a payload before it looks at the stop flag.
const TICK: Duration = Duration::from_millis(50);
/// Stamps waiting for every link of the chain to catch up; the oldest go first.
const MAX_PENDING: usize = 512;

/// The tf input thread, built by the composition; [`TfInputThread::run`] is its body. It opens
/// its session itself and says on `ready` whether it could.
pub struct TfInputThread {
    /// `[ros2]`.
    pub config: Ros2Config,
    /// The frame poses are in (`ros2.tf.world_frame`, or `world.frame_id`).
    pub world_frame: String,
    /// The turn of the camera in its mount (`source.realsense.rotate`): `camera_from_upright`.
    pub camera_from_upright: Isometry,
    /// Interpolation and hold rules of the lookups (`[pose]`), and the window.
    pub buffer: TfConfig,
    /// Hand-over to the keyframe gate.
    pub poses: Sender<PoseStamped>,
    /// The pose input's counters (shared with the gate).
    pub pose_stats: Arc<PoseStats>,
    /// This stage's figures.
    pub counters: Arc<TfInputCounters>,
    /// The daemon's stop flag.
    pub stop: Arc<AtomicBool>,
    /// Disconnected once the keyframe gate has ended (the composition keeps its sender alive
    /// with the gate): the thread ends with it.
    pub gate_alive: Receiver<()>,
    /// Told once the session and its subscribers exist, or why they could not be made.
    pub ready: Sender<Result<(), String>>,
}

impl std::fmt::Debug for TfInputThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TfInputThread").field("world_frame", &self.world_frame).finish_non_exhaustive()
    }
}

/// A payload from one of the two topics.
struct Payload {
    is_static: bool,
    bytes: Vec<u8>,
}

impl TfInputThread {
    /// Opens the session and subscribes, then turns transforms into poses until the stop flag or
    /// until the keyframe gate has ended.
    pub fn run(self) {
        let (tx, rx) = crossbeam_channel::bounded(INTAKE_CAPACITY);
        let session = match self.open(&tx) {
            Ok(session) => {
                let _ = self.ready.send(Ok(()));
                session
            }
            Err(e) => {
                let _ = self.ready.send(Err(e));
                return;
            }
        };
        drop(tx);
        self.follow(&rx);
        if let Err(e) = session.session.close().wait() {
            debug!(error = %e, "ros2 session close failed");
        }
    }

    fn open(&self, tx: &Sender<Payload>) -> Result<Session, String> {
        let c = &self.config;
        let (style, distro) = (c.key_style().map_err(|e| e.to_string())?, c.distro().map_err(|e| e.to_string())?);
        let session = ::zenoh::open(c.session_config()?).wait().map_err(|e| {
            format!("ros2.connect: no Zenoh session to the ROS side at {:?} (is rmw_zenohd or zenoh-bridge-ros2dds running?): {e}", c.connect)
        })?;
        let mut subscribers = Vec::new();
        let mut late_joining = None;
        for (field, topic, is_static) in
            [("tf_topic", &c.tf.tf_topic, false), ("tf_static_topic", &c.tf.tf_static_topic, true)]
        {
            let keys = topic_keys(style, c.domain_id, &c.namespace, topic, &TFMessage::TYPE, distro)
                .map_err(|e| format!("ros2.tf.{field}: {topic:?}: {e}"))?;
            let (tx, dropped) = (tx.clone(), self.counters.clone());
            let callback = move |sample: ::zenoh::sample::Sample| {
                let payload = Payload { is_static, bytes: sample.payload().to_bytes().into_owned() };
                if let Err(TrySendError::Full(_)) = tx.try_send(payload) {
                    dropped.intake_dropped.fetch_add(1, Ordering::Relaxed);
                }
            };
            let failed = |e| format!("ros2.tf.{field}: subscribing to {}: {e}", keys.subscribe);
            if is_static {
                // Transient local: what the static broadcasters sent before the daemon came,
                // from their publishers' caches, and from any that appear later.
                let history = HistoryConfig::default().detect_late_publishers();
                let subscriber = session
                    .declare_subscriber(keys.subscribe.clone())
                    .history(history)
                    .callback(callback)
                    .wait()
                    .map_err(failed)?;
                late_joining = Some(subscriber);
            } else {
                subscribers.push(
                    session.declare_subscriber(keys.subscribe.clone()).callback(callback).wait().map_err(failed)?,
                );
            }
            info!(topic = %keys.fq_topic, key = %keys.subscribe, style = style.as_str(), "following tf");
        }
        Ok(Session { session, _subscribers: subscribers, _static_subscriber: late_joining })
    }

    /// The loop: payloads in, poses out.
    fn follow(&self, rx: &Receiver<Payload>) {
        let mut state = State {
            buffer: TfBuffer::new(self.buffer),
            pending: BTreeSet::new(),
            newest_dynamic_ns: 0,
            reported_stamp_ns: None,
            logged: HashSet::new(),
        };
        while !self.stop.load(Ordering::Relaxed)
            && !matches!(self.gate_alive.try_recv(), Err(crossbeam_channel::TryRecvError::Disconnected))
        {
            let payload = match rx.recv_timeout(TICK) {
                Ok(payload) => payload,
                Err(crossbeam_channel::RecvTimeoutError::Timeout) => continue,
                Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
            };
            let started = Instant::now();
            if !self.apply(&mut state, &payload) {
                continue;
            }
            if !self.resolve_pending(&mut state) {
                break;
            }
            if let Some(path) = state.buffer.last_path()
                && state.reported_stamp_ns != Some(path.stamp_ns)
            {
                state.reported_stamp_ns = Some(path.stamp_ns);
                *self.counters.last_path.lock().unwrap_or_else(PoisonError::into_inner) = Some(path.clone());
            }
            self.counters.stage.record(started);
        }
    }

    /// Decodes and buffers one payload; false for one that is no TFMessage.
    fn apply(&self, state: &mut State, payload: &Payload) -> bool {
        let topic = if payload.is_static { &self.config.tf.tf_static_topic } else { &self.config.tf.tf_topic };
        let message = match op3dsg_ros2::decode::<TFMessage>(&payload.bytes) {
            Ok(message) => message,
            Err(e) => {
                self.counters.stage.record_error();
                state.log_once(
                    "malformed",
                    || warn!(topic = %topic, error = %e, "a tf payload that is no tf2_msgs/TFMessage; dropped"),
                );
                return false;
            }
        };
        let count = if payload.is_static { &self.counters.static_messages } else { &self.counters.dynamic_messages };
        count.fetch_add(1, Ordering::Relaxed);
        let mut errors = state.buffer.insert_message(&message, payload.is_static);
        if !payload.is_static
            && !message.transforms.is_empty()
            && errors.len() == message.transforms.len()
            && errors.iter().all(|e| matches!(e, TfInsertError::TooOld { .. }))
        {
            // Every transform is older than the window before its link's newest: tf's time went
            // back (a bag started again, a clock corrected after stamps from the future). As
            // tf2's listener does on a jump back in time, the dynamic transforms are forgotten.
            self.counters.time_jumps.fetch_add(1, Ordering::Relaxed);
            let back_s = (state.newest_dynamic_ns.saturating_sub(first_stamp_ns(&message)) as f64) * 1e-9;
            warn!(topic = %topic, back_s, "tf stamps jumped back in time: dynamic transforms cleared");
            state.buffer.clear_dynamic();
            state.pending.clear();
            state.newest_dynamic_ns = 0;
            errors = state.buffer.insert_message(&message, payload.is_static);
        }
        for error in errors {
            let (counter, reason) = match &error {
                TfInsertError::NonFinite { .. } => (&self.pose_stats.non_finite, "non_finite"),
                TfInsertError::NonUnitQuaternion { .. } => {
                    (&self.pose_stats.non_unit_quaternion, "non_unit_quaternion")
                }
                _ => (&self.counters.transforms_refused, "refused"),
            };
            counter.fetch_add(1, Ordering::Relaxed);
            state.log_once(reason, || warn!(topic = %topic, error = %error, "transform refused"));
        }
        if !payload.is_static {
            for t in &message.transforms {
                if let Some(stamp_ns) = t.header.stamp.to_ns() {
                    state.newest_dynamic_ns = state.newest_dynamic_ns.max(stamp_ns);
                    state.pending.insert(stamp_ns);
                }
            }
            while state.pending.len() > MAX_PENDING {
                state.pending.pop_first();
                self.pose_stats.extrapolation.fetch_add(1, Ordering::Relaxed);
            }
        }
        true
    }

    /// Looks up the camera at every waiting stamp whose links have caught up; false once the
    /// keyframe gate has ended.
    fn resolve_pending(&self, state: &mut State) -> bool {
        let tf = &self.config.tf;
        let (frame, kind) = if tf.base_frame.is_empty() {
            (tf.camera_frame.as_str(), PoseKind::WorldFromCamera)
        } else {
            (tf.base_frame.as_str(), PoseKind::WorldFromBase)
        };
        // A stamp may wait for later transforms of a slower link, up to the interpolation gap.
        let patience = self.buffer.max_interpolation_gap_ns.max(self.buffer.hold_tolerance_ns);
        while let Some(&stamp_ns) = state.pending.first() {
            match state.buffer.lookup(&self.world_frame, frame, stamp_ns) {
                Ok(world_from_frame) => {
                    state.pending.pop_first();
                    let mut pose = Isometry::new(world_from_frame.rotation, world_from_frame.translation);
                    if kind == PoseKind::WorldFromCamera {
                        pose = pose.compose(&self.camera_from_upright);
                    }
                    if !self.hand_over(stamp_ns, kind, &pose, frame) {
                        return false;
                    }
                }
                Err(e) if e.is_after_newest() && state.newest_dynamic_ns.saturating_sub(stamp_ns) <= patience => break,
                Err(e) => {
                    state.pending.pop_first();
                    let (counter, reason) = match &e {
                        TfError::FrameNotFound(_) => (&self.pose_stats.frame_not_found, "frame_not_found"),
                        TfError::NoPath { .. } => (&self.pose_stats.no_transform_path, "no_transform_path"),
                        TfError::Extrapolation { .. } | TfError::Gap { .. } => {
                            (&self.pose_stats.extrapolation, "extrapolation")
                        }
                    };
                    let n = counter.fetch_add(1, Ordering::Relaxed) + 1;
                    state.log_once(reason, || {
                        warn!(world = %self.world_frame, frame, error = %e, "no camera pose from tf");
                    });
                    if n.is_power_of_two() && n > 1 {
                        warn!(reason, count = n, "no camera pose from tf (counted in health under pose.{reason})");
                    }
                }
            }
        }
        true
    }

    /// Hands one pose to the gate; false once the gate has ended.
    fn hand_over(&self, stamp_ns: u64, kind: PoseKind, pose: &Isometry, frame: &str) -> bool {
        let q = pose.rotation;
        let t = pose.translation;
        match PoseStamped::new(stamp_ns, kind, [t.x, t.y, t.z], [q.x, q.y, q.z, q.w], frame) {
            Ok(stamped) => {
                let open = hand_over_pose(&self.poses, stamped, &self.pose_stats, "tf pose");
                if open {
                    self.counters.poses.fetch_add(1, Ordering::Relaxed);
                }
                open
            }
            Err(_) => {
                self.pose_stats.non_finite.fetch_add(1, Ordering::Relaxed);
                true
            }
        }
    }
}

/// The session and its subscribers (undeclared when dropped with it).
/// The session with its subscribers (declared as long as they are held).
struct Session {
    session: ::zenoh::Session,
    _subscribers: Vec<::zenoh::pubsub::Subscriber<()>>,
    _static_subscriber: Option<AdvancedSubscriber<()>>,
}

/// The oldest stamp of a message's transforms (0 when none has a valid stamp).
fn first_stamp_ns(message: &TFMessage) -> u64 {
    message.transforms.iter().filter_map(|t| t.header.stamp.to_ns()).min().unwrap_or(0)
}

/// What the thread keeps between payloads.
struct State {
    buffer: TfBuffer,
    pending: BTreeSet<u64>,
    newest_dynamic_ns: u64,
    /// The stamp of the last path handed to the counters.
    reported_stamp_ns: Option<u64>,
    logged: HashSet<&'static str>,
}

impl State {
    /// Runs `log` the first time `reason` comes up.
    fn log_once(&mut self, reason: &'static str, log: impl FnOnce()) {
        if self.logged.insert(reason) {
            log();
        }
    }
}
