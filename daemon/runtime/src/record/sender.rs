//! The producers' side of the recorder: a bounded queue per kind of input, each with its rate
//! limit, fed with `try_send` so the hot path never waits on the disk.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::Health;
use tracing::warn;

use super::{
    Channel, ChannelConfig, Event, RawFrame, RawInput, RecorderState, RecorderStats, SideChannelTap, annotations,
    now_ns,
};
use crate::flow::Detection;
use crate::graph::{NodePoint, SceneGraph};

/// A per-producer rate limit.
#[derive(Debug, Clone)]
pub(super) struct Limiter {
    enabled: bool,
    period: Option<Duration>,
    next: Option<Instant>,
}

impl Limiter {
    pub(super) fn new(config: ChannelConfig) -> Self {
        Self {
            enabled: config.enabled,
            period: (config.max_rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / config.max_rate_hz)),
            next: None,
        }
    }

    fn due(&mut self, now: Instant) -> bool {
        if !self.enabled {
            return false;
        }
        let Some(period) = self.period else { return true };
        if self.next.is_some_and(|next| now < next) {
            return false;
        }
        self.next = Some(self.next.map_or(now, |next| next.max(now - period)) + period);
        true
    }
}

/// The producers' side of the recorder; each producing thread owns a clone (its rate limits are
/// its own). Every call returns at once.
#[derive(Clone)]
pub struct RecordSender {
    pub(super) frames_tx: Sender<RawInput>,
    pub(super) events_tx: Sender<Event>,
    pub(super) pool_rx: Receiver<Box<RawFrame>>,
    pub(super) pool_tx: Sender<Box<RawFrame>>,
    pub(super) stats: Arc<RecorderStats>,
    pub(super) graph: Limiter,
    pub(super) scene: Limiter,
    pub(super) transforms: Limiter,
    pub(super) health: Limiter,
    pub(super) colour: Limiter,
    pub(super) depth: Limiter,
    pub(super) frame: Limiter,
    pub(super) sides: Limiter,
    pub(super) poses: Limiter,
    pub(super) detections: Limiter,
    pub(super) node_points: Limiter,
    pub(super) llm: Limiter,
    pub(super) node_points_per_node: usize,
}

impl std::fmt::Debug for RecordSender {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordSender").field("state", &self.stats.state()).finish_non_exhaustive()
    }
}

impl RecordSender {
    fn accepting(&self) -> bool {
        self.stats.state() == RecorderState::Recording
    }

    fn drop_counted(&self, what: &str, drops: &[(Channel, u64)]) {
        let mut dropped = 0;
        for &(channel, n) in drops.iter().filter(|(_, n)| *n > 0) {
            dropped = self.stats.count_drop(channel, n);
        }
        if dropped > 0 && (dropped.is_power_of_two() || dropped < 4) {
            warn!(dropped, what, "recorder queue full (the disk is slower than the input); message dropped");
        }
    }

    /// Offers a frame the keyframe gate received (colour, depth, meta and side channels, as
    /// enabled and due); `taps` are the source's side channels. Copies into a pooled buffer, or
    /// drops and counts when none is free.
    pub fn offer_frame(&mut self, frame: &Frame, taps: &mut [Box<dyn SideChannelTap>]) {
        if !self.accepting() {
            return;
        }
        let now = Instant::now();
        let colour = self.colour.due(now);
        let depth = self.depth.due(now);
        let meta = self.frame.due(now);
        let sides = !taps.is_empty() && self.sides.due(now);
        if !(colour || depth || meta || sides) {
            return;
        }
        let n = |due: bool| u64::from(due);
        let drops = [
            (Channel::Colour, n(colour)),
            (Channel::Depth, n(depth)),
            (Channel::Frame, n(meta)),
            (Channel::SideChannels, if sides { taps.len() as u64 } else { 0 }),
        ];
        let Ok(mut raw) = self.pool_rx.try_recv() else {
            self.drop_counted("frame", &drops);
            return;
        };
        raw.log_time_ns = now_ns();
        raw.seq = frame.seq;
        raw.stamp_ns = frame.stamp_ns;
        raw.intrinsics = frame.intrinsics;
        raw.depth_units_per_m = frame.depth_units_per_m;
        raw.world_from_camera = frame.world_from_camera;
        raw.has_meta = meta;
        raw.has_colour = colour;
        if colour {
            let buf = raw.colour.get_or_insert_with(Vec::new);
            buf.clear();
            buf.extend_from_slice(&frame.rgb);
        }
        raw.has_depth = depth;
        if depth {
            let buf = raw.depth.get_or_insert_with(Vec::new);
            buf.clear();
            buf.extend_from_slice(&frame.depth);
        }
        raw.sides.resize_with(taps.len(), || (Vec::new(), false));
        for ((buf, filled), tap) in raw.sides.iter_mut().zip(taps.iter_mut()) {
            *filled = false;
            if sides {
                buf.resize(frame.depth.len(), 0);
                *filled = tap.copy(frame, buf);
            }
        }
        if let Err(e) = self.frames_tx.try_send(RawInput::Frame(raw)) {
            if let TrySendError::Full(RawInput::Frame(raw)) | TrySendError::Disconnected(RawInput::Frame(raw)) = e {
                // Back to the pool (it has room: the buffer came from it).
                let _ = self.pool_tx.try_send(raw);
            }
            self.drop_counted("frame", &drops);
        }
    }

    /// Offers a pose the keyframe gate received from the pose input (`/op3dsg/input_pose`), in
    /// order with the frames.
    pub fn offer_input_pose(&mut self, pose: &op3dsg_ipc_types::PoseStamped) {
        if !self.accepting() || !self.poses.due(Instant::now()) {
            return;
        }
        use op3dsg_drivers::mcap::messages::{InputPose, InputPoseKind};
        let kind = match op3dsg_ipc_types::PoseKind::from_u8(pose.kind) {
            Some(op3dsg_ipc_types::PoseKind::WorldFromBase) => InputPoseKind::WorldFromBase,
            // The gate refuses an unknown kind; the replay would refuse it as camera too.
            _ => InputPoseKind::WorldFromCamera,
        };
        let pose = InputPose {
            stamp_ns: pose.stamp_ns,
            kind,
            frame_id: op3dsg_ipc_types::fixed_str(&pose.frame_id).to_owned(),
            translation_m: pose.translation_m,
            rotation_xyzw: pose.rotation_xyzw,
        };
        if self.frames_tx.try_send(RawInput::Pose { log_time_ns: now_ns(), pose }).is_err() {
            self.drop_counted("input pose", &[(Channel::InputPoses, 1)]);
        }
    }

    /// Offers a keyframe's pose (`/tf`).
    pub fn offer_keyframe(&mut self, stamp_ns: u64, world_from_camera: &Isometry) {
        if !self.accepting() || !self.transforms.due(Instant::now()) {
            return;
        }
        let event = Event::Keyframe { log_time_ns: now_ns(), stamp_ns, world_from_camera: *world_from_camera };
        if self.events_tx.try_send(event).is_err() {
            self.drop_counted("keyframe", &[(Channel::Transforms, 1)]);
        }
    }

    /// Offers a published graph version (moved: the publisher has sent it already).
    pub fn offer_graph(&mut self, graph: SceneGraph) {
        if !self.accepting() {
            return;
        }
        let now = Instant::now();
        let json = self.graph.due(now);
        let scene = self.scene.due(now);
        if !(json || scene) {
            return;
        }
        if self.events_tx.try_send(Event::Graph { log_time_ns: now_ns(), graph, json, scene }).is_err() {
            self.drop_counted("graph", &[(Channel::Graph, u64::from(json)), (Channel::Scene, u64::from(scene))]);
        }
    }

    /// Offers a keyframe's detections (`/op3dsg/detections`), fused at `stamp_ns`.
    pub fn offer_detections(&mut self, stamp_ns: u64, detections: &[Detection]) {
        if !self.accepting() || !self.detections.due(Instant::now()) {
            return;
        }
        let boxes = detections
            .iter()
            .map(|d| annotations::DetectionBox {
                label: d.label.clone(),
                kind: d.kind,
                score: d.score,
                x0: d.mask.x0,
                y0: d.mask.y0,
                width: d.mask.width,
                height: d.mask.height,
            })
            .collect();
        if self.events_tx.try_send(Event::Detections { log_time_ns: now_ns(), stamp_ns, boxes }).is_err() {
            self.drop_counted("detections", &[(Channel::Detections, 1)]);
        }
    }

    /// Offers the nodes' points of a published graph version (`/op3dsg/node_points`) when the
    /// channel is due: `collect(max_per_node, out)` fills them (called only then).
    pub fn offer_node_points(&mut self, stamp_ns: u64, collect: impl FnOnce(usize, &mut Vec<NodePoint>)) {
        if !self.accepting() || !self.node_points.due(Instant::now()) {
            return;
        }
        let mut points = Vec::new();
        collect(self.node_points_per_node, &mut points);
        if self.events_tx.try_send(Event::NodePoints { log_time_ns: now_ns(), stamp_ns, points }).is_err() {
            self.drop_counted("node points", &[(Channel::NodePoints, 1)]);
        }
    }

    /// Offers one call of an LLM agent (`/op3dsg/llm`); the refiner's thread calls it after the
    /// gate checked the answer.
    pub fn offer_llm_exchange(&mut self, exchange: op3dsg_drivers::mcap::messages::LlmExchange) {
        if !self.accepting() || !self.llm.due(Instant::now()) {
            return;
        }
        let event = Event::LlmExchange { log_time_ns: now_ns(), exchange: Box::new(exchange) };
        if self.events_tx.try_send(event).is_err() {
            self.drop_counted("llm exchange", &[(Channel::LlmExchanges, 1)]);
        }
    }

    /// Offers a health record.
    pub fn offer_health(&mut self, health: &Health) {
        if !self.accepting() || !self.health.due(Instant::now()) {
            return;
        }
        let event = Event::Health { log_time_ns: now_ns(), health: Box::new(*health) };
        if self.events_tx.try_send(event).is_err() {
            self.drop_counted("health", &[(Channel::Health, 1)]);
        }
    }
}
