//! The thread `op3dsg-ros2-out`: the graph and the map out to ROS 2 (`[ros2.out]`).
//!
//! Its Zenoh session (a client of `ros2.connect`, as the tf input's) declares a publisher per
//! enabled topic under the profile's key style, with congestion control `drop`: a slow link or
//! router loses messages, never stalls the thread. It takes graph versions from a latest-wins
//! hand-over of the publisher and sends the newest at most every `ros2.out.period_ms`; it sends
//! the occupancy thread's newest map when it changed, and again every
//! `ros2.out.occupancy_repeat_ms` for a late RViz (the topics are volatile).
//!
//! With `rmw_zenoh` keys every message carries rmw_zenoh's attachment (sequence number, time, the
//! publisher's GID) and the node and each publisher are announced by rmw_zenoh's liveliness
//! tokens: `ros2 node list` shows the node, `ros2 topic list` the topics, and RViz subscribes.
//! With `bridge` keys each publisher is announced by the token by which zenoh-bridge-ros2dds
//! makes a DDS writer for the topic.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use ::zenoh::Wait;
use ::zenoh::liveliness::LivelinessToken;
use ::zenoh::pubsub::Publisher;
use ::zenoh::qos::CongestionControl;
use crossbeam_channel::Sender;
use op3dsg_ros2::attachment::Attachment;
use op3dsg_ros2::keys::{EntityKind, KeyStyle, NodeIdentity, Qos, bridge_publisher_token, gid_of_token, topic_keys};
use op3dsg_ros2::msg::nav_msgs::OccupancyGrid;
use op3dsg_ros2::msg::std_msgs;
use op3dsg_ros2::msg::visualization_msgs::MarkerArray;
use op3dsg_ros2::{MessageType, RosMessage};
use tracing::{debug, info};

use super::config::Ros2Config;
use super::counters::Ros2OutputCounters;
use super::messages::{MarkerState, graph_json, marker_array, occupancy_grid};
use crate::graph::SceneGraph;
use crate::occupancy::LatestOccupancy;
use crate::queue::{Popped, QueueReceiver};
use crate::world::UpAxis;

/// How long the thread waits for a graph before it looks at the map and the period again.
const TICK: Duration = Duration::from_millis(50);

/// The ROS output thread, built by the composition; [`Ros2OutputThread::run`] is its body. It
/// opens its session itself and says on `ready` whether it could.
pub struct Ros2OutputThread {
    /// `[ros2]` (its `out` section says which topics).
    pub config: Ros2Config,
    /// The frame the graph and the map are in (`ros2.tf.world_frame`, or `world.frame_id`).
    pub world_frame: String,
    /// `world.up_axis`: about which the boxes turn.
    pub up_axis: UpAxis,
    /// Who made the graph, named in the JSON (`op3dsgd`, as the recorder's).
    pub source: String,
    /// Graph versions from the publisher (latest wins); ends when the publisher does.
    pub graphs: QueueReceiver<(Arc<SceneGraph>, u64)>,
    /// The occupancy thread's newest map (`ros2.out.occupancy` with `occupancy.enabled`).
    pub occupancy: Option<Arc<LatestOccupancy>>,
    /// This stage's figures.
    pub counters: Arc<Ros2OutputCounters>,
    /// The daemon's stop flag.
    pub stop: Arc<AtomicBool>,
    /// Told once the session and its publishers exist, or why they could not be made.
    pub ready: Sender<Result<(), String>>,
}

impl std::fmt::Debug for Ros2OutputThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ros2OutputThread").field("world_frame", &self.world_frame).finish_non_exhaustive()
    }
}

/// One ROS publisher: its Zenoh publisher, the GID and sequence of its attachments (rmw_zenoh),
/// its announcement.
struct Topic {
    publisher: Publisher<'static>,
    /// rmw_zenoh: the GID for the attachment.
    gid: Option<[u8; 16]>,
    sequence: i64,
    _token: LivelinessToken,
}

/// The open session and what was declared on it.
struct Session {
    session: ::zenoh::Session,
    markers: Option<Topic>,
    occupancy: Option<Topic>,
    graph_json: Option<Topic>,
    _node_token: Option<LivelinessToken>,
}

impl Ros2OutputThread {
    /// Opens the session and declares the publishers, then sends until the publisher has ended
    /// or the stop flag is set.
    pub fn run(self) {
        let mut session = match self.open() {
            Ok(session) => {
                let _ = self.ready.send(Ok(()));
                session
            }
            Err(e) => {
                let _ = self.ready.send(Err(e));
                return;
            }
        };
        let out = &self.config.out;
        let period = Duration::from_millis(out.period_ms);
        let repeat = Duration::from_millis(out.occupancy_repeat_ms);
        let mut markers = MarkerState::default();
        let mut pending: Option<Arc<SceneGraph>> = None;
        let mut last_graph_sent: Option<Instant> = None;
        let (mut map_version, mut last_map_sent) = (0u64, None::<Instant>);
        while !self.stop.load(Ordering::Relaxed) {
            match self.graphs.pop_timeout(TICK) {
                Popped::Item((graph, _instance)) => pending = Some(graph),
                Popped::Empty => {}
                Popped::Finished => break,
            }
            if last_graph_sent.is_none_or(|at| at.elapsed() >= period)
                && let Some(graph) = pending.take()
            {
                self.send_graph(&mut session, &graph, &mut markers);
                last_graph_sent = Some(Instant::now());
            }
            if let (Some(latest), Some(topic)) = (&self.occupancy, session.occupancy.as_mut()) {
                let due = last_map_sent.is_none_or(|at| at.elapsed() >= repeat);
                let started = Instant::now();
                let grid = latest.read(|map| {
                    let map = map.filter(|m| m.version != map_version || due)?;
                    Some((map.version, occupancy_grid(map, &self.world_frame)))
                });
                if let Some((version, grid)) = grid {
                    map_version = version;
                    last_map_sent = Some(Instant::now());
                    if put(topic, &grid, &self.counters, &self.counters.occupancy_grids) {
                        self.counters.stage.record(started);
                    }
                }
            }
        }
        info!(
            marker_arrays = self.counters.marker_arrays.load(Ordering::Relaxed),
            occupancy_grids = self.counters.occupancy_grids.load(Ordering::Relaxed),
            graph_jsons = self.counters.graph_jsons.load(Ordering::Relaxed),
            "ros2 output closing"
        );
        if let Err(e) = session.session.close().wait() {
            debug!(error = %e, "ros2 output session close failed");
        }
    }

    fn send_graph(&self, session: &mut Session, graph: &SceneGraph, markers: &mut MarkerState) {
        let started = Instant::now();
        let mut ok = true;
        if let Some(topic) = session.markers.as_mut() {
            let array = marker_array(graph, self.up_axis, &self.world_frame, markers);
            ok &= put(topic, &array, &self.counters, &self.counters.marker_arrays);
        }
        if let Some(topic) = session.graph_json.as_mut() {
            ok &= put(topic, &graph_json(graph, &self.source), &self.counters, &self.counters.graph_jsons);
        }
        if ok {
            self.counters.stage.record(started);
        }
    }

    fn open(&self) -> Result<Session, String> {
        let c = &self.config;
        let (style, distro) = (c.key_style().map_err(|e| e.to_string())?, c.distro().map_err(|e| e.to_string())?);
        let session = ::zenoh::open(c.session_config()?).wait().map_err(|e| {
            format!("ros2.connect: no Zenoh session to the ROS side at {:?} (is rmw_zenohd or zenoh-bridge-ros2dds running?): {e}", c.connect)
        })?;
        let zid = session.zid().to_string();
        let node = match style {
            KeyStyle::RmwZenoh => Some(
                NodeIdentity::new(c.domain_id, &zid, 0, &c.namespace, &c.out.node_name)
                    .map_err(|e| format!("ros2.out.node_name: {e}"))?,
            ),
            KeyStyle::Bridge => None,
        };
        let declare_token = |token: String| {
            session
                .liveliness()
                .declare_token(token.clone())
                .wait()
                .map_err(|e| format!("ros2: announcing {token}: {e}"))
        };
        let node_token = node.as_ref().map(|n| declare_token(n.node_token())).transpose()?;
        let mut next_entity = 1;
        let mut topic = |enabled: bool, field: &str, name: &str, ty: &MessageType| -> Result<Option<Topic>, String> {
            if !enabled {
                return Ok(None);
            }
            let keys = topic_keys(style, c.domain_id, &c.namespace, name, ty, distro)
                .map_err(|e| format!("ros2.out.{field}: {name:?}: {e}"))?;
            let publisher = session
                .declare_publisher(keys.publish.clone())
                .congestion_control(CongestionControl::Drop)
                .wait()
                .map_err(|e| format!("ros2.out.{field}: declaring {}: {e}", keys.publish))?;
            let qos = Qos::DEFAULT;
            let (token, gid) = match &node {
                Some(node) => {
                    let token =
                        node.endpoint_token(next_entity, EntityKind::Publisher, &keys.fq_topic, ty, distro, &qos);
                    next_entity += 1;
                    let gid = gid_of_token(&token);
                    (token, Some(gid))
                }
                None => (bridge_publisher_token(&zid, &keys.publish, ty, distro, &qos), None),
            };
            info!(topic = %keys.fq_topic, key = %keys.publish, style = style.as_str(), "publishing to ROS 2");
            Ok(Some(Topic { publisher, gid, sequence: 0, _token: declare_token(token)? }))
        };
        let out = &c.out;
        let markers = topic(out.markers, "markers_topic", &out.markers_topic, &MarkerArray::TYPE)?;
        let occupancy = topic(
            out.occupancy && self.occupancy.is_some(),
            "occupancy_topic",
            &out.occupancy_topic,
            &OccupancyGrid::TYPE,
        )?;
        let graph_json = topic(out.graph_json, "graph_json_topic", &out.graph_json_topic, &std_msgs::String::TYPE)?;
        Ok(Session { session, markers, occupancy, graph_json, _node_token: node_token })
    }
}

/// Encodes `message` (CDR) and puts it on `topic`, with rmw_zenoh's attachment when the topic has
/// a GID; counts it in `count`, or a stage error.
fn put<T: RosMessage>(topic: &mut Topic, message: &T, counters: &Ros2OutputCounters, count: &AtomicU64) -> bool {
    let bytes = op3dsg_ros2::encode(message);
    let len = bytes.len() as u64;
    let mut put = topic.publisher.put(bytes);
    if let Some(gid) = topic.gid {
        topic.sequence += 1;
        let attachment = Attachment {
            sequence_number: topic.sequence,
            source_timestamp_ns: crate::world::clock::wall_clock_ns() as i64,
            source_gid: gid,
        };
        put = put.attachment(attachment.encode().to_vec());
    }
    match put.wait() {
        Ok(()) => {
            count.fetch_add(1, Ordering::Relaxed);
            counters.bytes.fetch_add(len, Ordering::Relaxed);
            true
        }
        Err(e) => {
            counters.stage.record_error();
            debug!(error = %e, key = %topic.publisher.key_expr(), "ros2 put failed");
            false
        }
    }
}
