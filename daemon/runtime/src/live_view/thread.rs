//! The thread `op3dsg-live-view`: owns the Foxglove WebSocket server (on a one-worker runtime,
//! thread `op3dsg-live-ws`) and its channels, and logs the newest of everything it is handed
//! on the channels a viewer subscribes to. Nothing is encoded for a channel nobody watches.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use foxglove::messages::{FrameTransform, Grid, RawImage, SceneUpdate};
use foxglove::{Channel, Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use op3dsg_drivers::mcap::{self as topics, CAMERA_FRAME, schemas};
use op3dsg_ipc_types::Health;
use tracing::{debug, info, warn};

use super::config::LiveViewConfig;
use super::messages::{occupancy_grid, raw_images};
use crate::flow::{LiveImages, LiveIntake};
use crate::graph::SceneGraph;
use crate::occupancy::LatestOccupancy;
use crate::queue::{Latest, Popped, QueueReceiver};
use crate::record::scene::{frame_transform, scene_update};
use crate::stats::StageStats;
use crate::world::UpAxis;

/// How long the thread waits for a graph before it looks at the other inputs again.
const TICK: Duration = Duration::from_millis(20);

/// The newest scene is sent again this often while nothing newer comes, for a viewer that
/// subscribed after it went out.
const SCENE_REPEAT: Duration = Duration::from_secs(1);

/// The occupancy topic (the recorder writes no map).
pub const TOPIC_OCCUPANCY: &str = "/op3dsg/occupancy";

/// The live view's figures.
#[derive(Debug)]
pub struct LiveViewCounters {
    /// The stage `live_view`: one graph version made a scene and logged (an error: the server
    /// could not start; never a viewer's trouble).
    pub stage: Arc<StageStats>,
    /// Scene updates logged (repeats included).
    pub scenes: AtomicU64,
    /// Camera transforms logged.
    pub transforms: AtomicU64,
    /// Occupancy grids logged.
    pub grids: AtomicU64,
    /// Health records logged.
    pub healths: AtomicU64,
    /// Colour and depth images logged.
    pub images: AtomicU64,
    /// Viewers connected now.
    pub clients: AtomicU64,
    /// The port the server listens on (0 before it does).
    pub port: AtomicU64,
}

impl Default for LiveViewCounters {
    fn default() -> Self {
        Self {
            stage: Arc::new(StageStats::new("live_view")),
            scenes: AtomicU64::new(0),
            transforms: AtomicU64::new(0),
            grids: AtomicU64::new(0),
            healths: AtomicU64::new(0),
            images: AtomicU64::new(0),
            clients: AtomicU64::new(0),
            port: AtomicU64::new(0),
        }
    }
}

/// The live view thread, built by the composition; [`LiveViewThread::run`] is its body. It
/// starts its server itself and says on `ready` whether it could.
pub struct LiveViewThread {
    /// `[live_view]`.
    pub config: LiveViewConfig,
    /// `world.frame_id`: the scene's, the grid's and the transform's parent frame.
    pub world_frame: String,
    /// `world.up_axis`: about which the boxes turn.
    pub up_axis: UpAxis,
    /// Graph versions from the publisher (latest wins); ends when the publisher does.
    pub graphs: QueueReceiver<(Arc<SceneGraph>, u64)>,
    /// The publisher's newest health record.
    pub health: Arc<Latest<(Health, u64)>>,
    /// The occupancy thread's newest map (`occupancy.enabled`).
    pub occupancy: Option<Arc<LatestOccupancy>>,
    /// The keyframe gate's newest pose and images.
    pub frames: LiveIntake,
    /// This stage's figures.
    pub counters: Arc<LiveViewCounters>,
    /// The daemon's stop flag.
    pub stop: Arc<AtomicBool>,
    /// Told once the server listens, or why it could not.
    pub ready: Sender<Result<(), String>>,
}

impl std::fmt::Debug for LiveViewThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveViewThread").field("bind", &self.config.bind).finish_non_exhaustive()
    }
}

/// The server, its runtime and its channels.
struct Server {
    /// The channels' context: dropping it would disconnect them from the server.
    _context: Arc<Context>,
    runtime: tokio::runtime::Runtime,
    handle: WebSocketServerHandle,
    scene: Channel<SceneUpdate>,
    transforms: Channel<FrameTransform>,
    health: Arc<RawChannel>,
    occupancy: Option<Channel<Grid>>,
    colour: Option<Channel<RawImage>>,
    depth: Option<Channel<RawImage>>,
}

/// What the thread keeps between ticks.
#[derive(Default)]
struct State {
    pending: Option<Arc<SceneGraph>>,
    last: Option<Arc<SceneGraph>>,
    last_scene_at: Option<Instant>,
    camera_stamp_ns: u64,
    health_stamp_ns: u64,
    map_version: u64,
    images: LiveImages,
    health_json: Vec<u8>,
}

impl LiveViewThread {
    /// Starts the server, then serves until the publisher has ended or the stop flag is set.
    pub fn run(self) {
        let server = match self.start() {
            Ok(server) => {
                let _ = self.ready.send(Ok(()));
                server
            }
            Err(e) => {
                self.counters.stage.record_error();
                let _ = self.ready.send(Err(e));
                return;
            }
        };
        let period = Duration::from_millis(self.config.scene_period_ms);
        let mut state = State::default();
        while !self.stop.load(Ordering::Relaxed) {
            match self.graphs.pop_timeout(TICK) {
                Popped::Item((graph, _instance)) => state.pending = Some(graph),
                Popped::Empty => {}
                Popped::Finished => break,
            }
            self.counters.clients.store(server.handle.client_count() as u64, Ordering::Relaxed);
            self.send_scene(&server, &mut state, period);
            self.send_camera(&server, &mut state);
            self.send_health(&server, &mut state);
            self.send_occupancy(&server, &mut state);
            self.send_images(&server, &mut state);
        }
        info!(
            scenes = self.counters.scenes.load(Ordering::Relaxed),
            images = self.counters.images.load(Ordering::Relaxed),
            "live view closing"
        );
        let Server { runtime, handle, .. } = server;
        let shutdown = handle.stop();
        // The timer is made inside the runtime: outside it, tokio has no clock to arm it with.
        let closed = runtime.block_on(async { tokio::time::timeout(Duration::from_secs(2), shutdown.wait()).await });
        if closed.is_err() {
            debug!("live view: viewers did not close within 2 s");
        }
        runtime.shutdown_timeout(Duration::from_secs(1));
    }

    fn start(&self) -> Result<Server, String> {
        let address = self.config.bind_address().map_err(|e| format!("live_view.bind: {e}"))?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("op3dsg-live-ws")
            .enable_all()
            .build()
            .map_err(|e| format!("live_view: no runtime for the server: {e}"))?;
        let ctx = Context::new();
        let scene = ctx.channel_builder(topics::TOPIC_SCENE).build::<SceneUpdate>();
        let transforms = ctx.channel_builder(topics::TOPIC_TF).build::<FrameTransform>();
        let health_schema = schemas::schema_text(schemas::HEALTH).unwrap_or_default();
        let health = ctx
            .channel_builder(topics::TOPIC_HEALTH)
            .message_encoding(schemas::MESSAGE_ENCODING)
            .schema(Schema::new(schemas::HEALTH, schemas::SCHEMA_ENCODING, health_schema.into_bytes()))
            .build_raw()
            .map_err(|e| format!("live_view: the health channel: {e}"))?;
        let occupancy = self.occupancy.as_ref().map(|_| ctx.channel_builder(TOPIC_OCCUPANCY).build::<Grid>());
        let images = self.config.images;
        let colour = images.then(|| ctx.channel_builder(topics::TOPIC_COLOUR).build::<RawImage>());
        let depth = images.then(|| ctx.channel_builder(topics::TOPIC_DEPTH).build::<RawImage>());
        // The address the profile names is the handshake layer's (it takes both names of the
        // protocol, `super::handshake`); the crate's server listens on a loopback port of its own.
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind(address))
            .map_err(|e| format!("live_view.bind: cannot listen on {}: {e}", self.config.bind))?;
        let port = listener.local_addr().map_err(|e| format!("live_view.bind: {e}"))?.port();
        let handle = WebSocketServer::new()
            .name("op3dsg")
            .bind("127.0.0.1", 0)
            .context(&ctx)
            .message_backlog_size(self.config.backlog)
            .tokio_runtime(runtime.handle())
            .start_blocking()
            .map_err(|e| format!("live_view: cannot start the WebSocket server on a loopback port: {e}"))?;
        let server = std::net::SocketAddr::from(([127, 0, 0, 1], handle.port()));
        runtime.spawn(super::handshake::accept(listener, server));
        self.counters.port.store(u64::from(port), Ordering::Relaxed);
        if self.config.open_beyond_loopback() {
            warn!(bind = %self.config.bind, "the live view listens beyond loopback: anyone who reaches it watches the robot");
        }
        info!(address = %format!("{}:{port}", address.ip()), images, "live view listening (Foxglove: ws://…)");
        Ok(Server { _context: ctx, runtime, handle, scene, transforms, health, occupancy, colour, depth })
    }

    fn send_scene(&self, server: &Server, state: &mut State, period: Duration) {
        let due = state.last_scene_at.is_none_or(|at| at.elapsed() >= period);
        let repeat = state.last_scene_at.is_some_and(|at| at.elapsed() >= SCENE_REPEAT);
        let graph = match state.pending.take() {
            Some(graph) if due => graph,
            Some(graph) => {
                state.pending = Some(graph);
                return;
            }
            None if repeat => match &state.last {
                Some(graph) => graph.clone(),
                None => return,
            },
            None => return,
        };
        state.last_scene_at = Some(Instant::now());
        state.last = Some(graph.clone());
        if !server.scene.has_sinks() {
            return;
        }
        let started = Instant::now();
        server.scene.log_with_time(&scene_update(&graph, self.up_axis, &self.world_frame), now_ns());
        self.counters.scenes.fetch_add(1, Ordering::Relaxed);
        self.counters.stage.record(started);
    }

    fn send_camera(&self, server: &Server, state: &mut State) {
        let Some((stamp_ns, world_from_camera)) = self.frames.camera.get() else { return };
        if stamp_ns == state.camera_stamp_ns || !server.transforms.has_sinks() {
            return;
        }
        state.camera_stamp_ns = stamp_ns;
        let transform = frame_transform(stamp_ns, &world_from_camera, &self.world_frame, CAMERA_FRAME);
        server.transforms.log_with_time(&transform, now_ns());
        self.counters.transforms.fetch_add(1, Ordering::Relaxed);
    }

    fn send_health(&self, server: &Server, state: &mut State) {
        let Some((health, _instance)) = self.health.get() else { return };
        if health.stamp_ns == state.health_stamp_ns || !server.health.has_sinks() {
            return;
        }
        state.health_stamp_ns = health.stamp_ns;
        state.health_json.clear();
        if serde_json::to_writer(&mut state.health_json, &crate::record::health_json(&health)).is_ok() {
            server.health.log_with_meta(&state.health_json, foxglove::PartialMetadata::with_log_time(now_ns()));
            self.counters.healths.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn send_occupancy(&self, server: &Server, state: &mut State) {
        let (Some(latest), Some(channel)) = (&self.occupancy, &server.occupancy) else { return };
        if !channel.has_sinks() {
            return;
        }
        let sent = state.map_version;
        let grid = latest.read(|map| {
            let map = map.filter(|map| map.version != sent)?;
            Some((map.version, occupancy_grid(map, &self.world_frame)))
        });
        if let Some((version, grid)) = grid {
            state.map_version = version;
            channel.log_with_time(&grid, now_ns());
            self.counters.grids.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn send_images(&self, server: &Server, state: &mut State) {
        let (Some(colour), Some(depth)) = (&server.colour, &server.depth) else { return };
        let (want_colour, want_depth) = (colour.has_sinks(), depth.has_sinks());
        self.frames.set_images_wanted(want_colour || want_depth);
        if !self.frames.take_images(&mut state.images) {
            return;
        }
        let (colour_image, depth_image) = raw_images(&state.images, CAMERA_FRAME);
        let now = now_ns();
        for (channel, image, wanted) in [(colour, colour_image, want_colour), (depth, depth_image, want_depth)] {
            if let (Some(image), true) = (image, wanted) {
                channel.log_with_time(&image, now);
                self.counters.images.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

fn now_ns() -> u64 {
    crate::world::clock::wall_clock_ns()
}
