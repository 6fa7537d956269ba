//! The arguments of `op3dsg bench` and of the room benchmarks (`bench query`, `bench nav`,
//! `fusion-eval`).

use std::path::PathBuf;

use clap::Subcommand;

#[derive(Debug, clap::Args)]
pub(super) struct RecordBenchArgs {
    /// Seconds of input per compression.
    #[arg(long, default_value_t = 10.0)]
    pub(super) seconds: f64,
    /// Frame rate, Hz.
    #[arg(long, default_value_t = 30.0)]
    pub(super) rate_hz: f64,
    /// Image width, pixels (the D435i stream of the robot: 848x480).
    #[arg(long, default_value_t = 848)]
    pub(super) width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 480)]
    pub(super) height: u32,
    /// Distinct synthetic kitchen frames, rendered once and cycled.
    #[arg(long, default_value_t = 30)]
    pub(super) distinct_frames: u64,
    /// Nodes of the graph written with the keyframes.
    #[arg(long, default_value_t = 150)]
    pub(super) graph_nodes: usize,
    /// A keyframe (pose + graph version) every this many frames (0: none).
    #[arg(long, default_value_t = 3)]
    pub(super) graph_every: u64,
    /// zstd, lz4, none, or all (zstd then lz4).
    #[arg(long, default_value = "all")]
    pub(super) compression: String,
    /// Colour storage (record.colour): raw, png or jpeg.
    #[arg(long, default_value = "raw")]
    pub(super) colour: String,
    /// JPEG quality with --colour jpeg (record.jpeg_quality).
    #[arg(long, default_value_t = 90)]
    pub(super) jpeg_quality: u8,
    /// Chunk size, KiB (record.chunk_size_kib).
    #[arg(long, default_value_t = 4096)]
    pub(super) chunk_size_kib: u64,
    /// Folder for the files (default: a temporary folder, removed afterwards).
    #[arg(long)]
    pub(super) dir: Option<PathBuf>,
    /// Keep the files.
    #[arg(long)]
    pub(super) keep: bool,
}

#[derive(Debug, Subcommand)]
pub(super) enum BenchCommand {
    /// The MCAP recorder's throughput on raw colour + depth at camera rate plus the graph at
    /// every keyframe: messages, drops, MB/s in and on disk, and the recorder thread's CPU
    /// share of one core, with zstd and with lz4 chunks. Build with --release to measure.
    Record(Box<RecordBenchArgs>),
    /// Performance: the real pipeline on a synthetic scene (per-stage latency p50/p99 for capture,
    /// detection, fusion, prior graph and publish; keyframes/s; capture → published-graph latency;
    /// RSS over time), graph publish → receive latency between two processes next to raw iceoryx2
    /// with a payload of the same size, and fusion cost against map size (with a PNG plot).
    ///
    /// Prints the Markdown tables; --json, --markdown and --plot write files too. Timings of a
    /// debug build only check that the harness works: measure with `cargo build --release`.
    Perf(Box<PerfArgs>),
    /// Soak: the real pipeline as fast as possible on the looping synthetic path for many frames
    /// with map snapshots on, then again with them off: resident memory sampled over the run and
    /// its slope over the second half (a leak shows as a positive slope), snapshot write time
    /// p50/p99 on the writer thread, the map copy on the fusion thread, and the fusion stage's
    /// p99 with snapshots on and off. Prints Markdown; --json and --markdown write files too.
    /// Build with --release to measure.
    Soak(Box<SoakArgs>),
    /// The hot path against a slow LLM: the real pipeline as fast as possible, once with
    /// reasoner.kind = knowledge and once with reasoner.kind = llm against a chat-completions
    /// server in this process that answers every request after --delay-s; prints the p50/p99 of
    /// fusion, prior graph + reasoner, publish and capture → graph for both runs and the p99
    /// ratio. With --serve only the server runs (for a daemon started by hand), until
    /// interrupted. Measure with `cargo build --release`.
    Llm(Box<LlmBenchArgs>),
    /// Remote detection's keyframe encodings (raw, png, lz4, zstd, jpeg): kB per keyframe, the
    /// robot's CPU to encode one and the worker's to decode it, and the share of a link a stream
    /// takes, on keyframes of the synthetic kitchen at 848x480 (or --profile's source). Measure
    /// with a release build.
    Remote(Box<super::bench_remote::RemoteBenchArgs>),
    /// The language query benchmark: 64 needs phrased as users phrase them, asked of the graph
    /// the batch pipeline builds of each synthetic room (kitchen, bathroom, bedroom, living
    /// room); top-1 and top-3 accuracy for objects and parts, with and without the functional
    /// edges in the scoring, each miss, and the query latency p50/p99 at 50 and 2,000 nodes.
    /// Needs .models/ (scripts/setup-models.sh). Measure latency with a release build.
    Query {
        #[command(flatten)]
        rooms: RoomBench,
        /// Write the report (with every query's outcome) as JSON to this file.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
    },
    /// The navigation check: each synthetic room (kitchen, bathroom, bedroom, living room) is
    /// mapped by the batch pipeline with the occupancy map, and every object and part node gets
    /// the daemon's approach pose, checked against the room's true geometry (free for the
    /// robot's disc, within the standoff band, facing the node, on a part's side): the share
    /// reachable and correct, objects and parts apart, each failure by reason, and the occupancy
    /// integration cost per keyframe (p50/p99) and map memory. Measure cost with a release build.
    Nav {
        #[command(flatten)]
        rooms: RoomBench,
        /// Write the report (with every node's outcome) as JSON to this file.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
    },
    /// The change benchmark: per preset, 24 synthetic rooms mapped over one lap of the camera
    /// path, changed at the second lap by a change script drawn from the room (removals, a move,
    /// an addition, and controls that change nothing but make evidence hard: an occluder in
    /// front of an unchanged object, a patch of missing depth on one, garbage depth beyond 3 m),
    /// run with change handling on and off on the same keyframes: removals and moves reflected
    /// in the final graph, moves linked, additions found, keyframes from first sight of a
    /// changed place to the update (p50 / p90), unchanged nodes removed, ghosts left, controls
    /// hit, and each goal met or missed. Deterministic.
    Change(Box<super::bench_change::ChangeBenchArgs>),
    /// The subscriber process of `bench perf`'s IPC measurement (started by it).
    #[command(hide = true)]
    IpcPeer {
        /// Rounds of a graph (owned read), a raw sample and a graph (view read) to take before
        /// exiting.
        #[arg(long)]
        rounds: usize,
    },
    /// The synthetic quality benchmark: seeded kitchens, bathrooms, bedrooms and living rooms
    /// run through the batch pipeline (oracle detector with knowledge-guided prompt lists,
    /// fusion, prior graph, offline knowledge reasoner) and scored with the benchmark's protocol
    /// (see `op3dsg eval`), with the paper's ablations as extra rows (w/o knowledge-guided part
    /// candidates, w/o colour features, a flat node list instead of the prior graph, a single
    /// reasoner instead of the split), and two stage-isolated rows (the reasoner on the
    /// ground-truth nodes; fusion on exact detections), and a peer baseline (ConceptGraphs'
    /// association and merging in place of the fusion, on the same detections, reasoned alike).
    /// Then the leave-one-category-out test: per
    /// object category, the reasoner's tables without it, scored on the items involving it, with
    /// the label fallback's counts. Prints the table, strict node recall, coverage (ground-truth
    /// nodes scored of all), where the full system loses recall, how often the knowledge base
    /// gives the rooms' own ground truth (reasoner on ground-truth nodes), and the
    /// functional-relation mix next to the benchmark's. Deterministic: the same options give the same table. Needs .models/ for the encoder.
    Quality {
        /// Oracle noise preset: clean | realistic | field (realistic plus category confusion,
        /// split and merged instances, masks bleeding at depth edges, parts reported as objects,
        /// a tagger that misses and adds tags, pose drift and jitter).
        #[arg(long, default_value = "realistic")]
        preset: String,
        /// Scenes (scene i: room i mod 4, seed i / 4 + 1).
        #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u64).range(1..=400))]
        scenes: u64,
        /// Frames per scene (30 per second of camera path).
        #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..))]
        frames: u64,
        /// Scenes run in parallel (default: the machine's cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Profile to start from (default: the built-in base).
        #[arg(long)]
        profile: Option<PathBuf>,
        /// Profile overrides, section.key=value.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Write the report as JSON to this file.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
        /// Write the table as Markdown to this file.
        #[arg(long, value_name = "FILE")]
        markdown: Option<PathBuf>,
        /// Exit with code 1 when a target of the full row (R@3) is missed.
        #[arg(long)]
        check: bool,
        /// Also run the noise curves: the full row's R@3 per column against pose drift (0, 1,
        /// 2, 5 % of distance travelled, with 25 x that in degrees per metre of heading drift)
        /// and against category confusion (0, 10, 20, 30 %), each point a whole run on the
        /// preset with only that knob changed (about 8 times the run time). Printed as a
        /// table, in the JSON (`curves`), in the Markdown, and drawn as a PNG.
        #[arg(long)]
        curves: bool,
        /// Where --curves writes its PNG (default: quality_curves.png in the current directory).
        #[arg(long, value_name = "FILE", requires = "curves")]
        curves_png: Option<PathBuf>,
    },
}

#[derive(Debug, clap::Args)]
pub(super) struct LlmBenchArgs {
    /// Frames per pipeline run.
    #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) frames: u64,
    /// Seconds the server takes to answer each request.
    #[arg(long, default_value_t = 5.0)]
    pub(super) delay_s: f64,
    /// Profile both runs start from (default: the built-in base: synthetic kitchen).
    #[arg(long)]
    pub(super) profile: Option<PathBuf>,
    /// Profile overrides, section.key=value, applied to both runs.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub(super) overrides: Vec<String>,
    /// Write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub(super) json: Option<PathBuf>,
    /// Only serve chat completions on this address (e.g. 127.0.0.1:8099) until interrupted.
    #[arg(long, value_name = "ADDRESS")]
    pub(super) serve: Option<String>,
}

#[derive(Debug, clap::Args)]
pub(super) struct PerfArgs {
    /// Frames per pipeline run (one run as fast as possible, one at camera rate).
    #[arg(long, default_value_t = 900, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) frames: u64,
    /// Rate of the camera-rate run, Hz (0 skips it).
    #[arg(long, default_value_t = 30.0)]
    pub(super) live_rate_hz: f64,
    /// Profile the pipeline runs and the fusion curve start from (default: the built-in base:
    /// synthetic kitchen, oracle detector with realistic noise).
    #[arg(long)]
    pub(super) profile: Option<PathBuf>,
    /// Profile overrides, section.key=value, applied after each run's own settings.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub(super) overrides: Vec<String>,
    /// Sample the process's resident memory this often, milliseconds.
    #[arg(long, default_value_t = 250, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    pub(super) rss_period_ms: u64,
    /// Graph sizes (nodes) of the IPC measurement, comma-separated ("none": skip it).
    #[arg(long, default_value = "100,2000,10000", value_parser = parse_sizes)]
    pub(super) ipc_nodes: Sizes,
    /// Timed messages per IPC size, each for the graph and for raw iceoryx2.
    #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) ipc_messages: u64,
    /// Untimed messages per IPC size and kind before the timed ones.
    #[arg(long, default_value_t = 20)]
    pub(super) ipc_warmup: usize,
    /// Graph sizes (nodes) of the Zenoh latency rows (a full graph message over TCP loopback next
    /// to a raw Zenoh put of the same bytes), comma-separated ("none": skip them).
    #[arg(long, default_value = "100,2000,10000", value_parser = parse_sizes)]
    pub(super) zenoh_nodes: Sizes,
    /// Timed messages per Zenoh size, each for the graph and for the raw put.
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) zenoh_messages: u64,
    /// Untimed messages per Zenoh size and kind before the timed ones.
    #[arg(long, default_value_t = 20)]
    pub(super) zenoh_warmup: usize,
    /// Run the camera-rate pipeline twice more, without and with the Zenoh stage (one consumer
    /// following the graph over loopback): fusion and publish latency, delta and full sizes,
    /// the stage's CPU (skipped with --live-rate-hz 0).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set, value_name = "true|false")]
    pub(super) zenoh_stage: bool,
    /// Map sizes (nodes) of the fusion curve, comma-separated ("none": skip it).
    #[arg(long, default_value = "100,500,1000,2000,5000,10000,20000", value_parser = parse_sizes)]
    pub(super) fusion_sizes: Sizes,
    /// Timed fusion steps per map size.
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) fusion_steps: u64,
    /// Keyframes of the kitchen path the fusion maps are built from.
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub(super) fusion_keyframes: u64,
    /// Write the report as JSON (schema op3dsg.bench_perf/1) to this file.
    #[arg(long, value_name = "FILE")]
    pub(super) json: Option<PathBuf>,
    /// Write the Markdown tables to this file.
    #[arg(long, value_name = "FILE")]
    pub(super) markdown: Option<PathBuf>,
    /// Write the plot of fusion cost against map size to this PNG file.
    #[arg(long, value_name = "FILE.png")]
    pub(super) plot: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub(super) struct SoakArgs {
    /// Frames of the run with snapshots on.
    #[arg(long, default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) frames: u64,
    /// Frames of the comparison run with snapshots off (default: as many as --frames; 0: no
    /// comparison run).
    #[arg(long)]
    pub(super) compare_frames: Option<u64>,
    /// Seconds between snapshots (snapshot.period_s; the daemon's default is 30).
    #[arg(long, default_value_t = 2.0)]
    pub(super) snapshot_period_s: f64,
    /// Sample the process's resident memory this often, milliseconds.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..=600_000))]
    pub(super) rss_period_ms: u64,
    /// Profile the runs start from (default: the built-in base: synthetic kitchen, oracle
    /// detector with realistic noise).
    #[arg(long)]
    pub(super) profile: Option<PathBuf>,
    /// Profile overrides, section.key=value, applied after the soak's own settings.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub(super) overrides: Vec<String>,
    /// Write the report as JSON (schema op3dsg.bench_soak/1) to this file.
    #[arg(long, value_name = "FILE")]
    pub(super) json: Option<PathBuf>,
    /// Write the Markdown to this file.
    #[arg(long, value_name = "FILE")]
    pub(super) markdown: Option<PathBuf>,
}

/// A comma-separated list of sizes; "none" (or nothing) is the empty list.
#[derive(Debug, Clone)]
pub(super) struct Sizes(pub(super) Vec<usize>);

fn parse_sizes(text: &str) -> Result<Sizes, String> {
    let text = text.trim();
    if text.is_empty() || text == "none" {
        return Ok(Sizes(Vec::new()));
    }
    text.split(',')
        .map(|v| v.trim().parse::<usize>().map_err(|e| format!("\"{v}\": {e} (expected sizes like 100,2000 or none)")))
        .collect::<Result<Vec<_>, _>>()
        .map(Sizes)
}

/// The synthetic rooms a room benchmark (`bench query`, `bench nav`) or `fusion-eval` maps:
/// seed, frames, oracle preset and profile.
#[derive(clap::Args, Debug)]
pub(super) struct RoomBench {
    /// Scene seed (of every room).
    #[arg(long, default_value_t = 1)]
    pub(super) seed: u64,
    /// Frames per room (30 per second of camera path).
    #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..))]
    pub(super) frames: u64,
    /// Oracle noise preset (clean | realistic).
    #[arg(long, default_value = "realistic")]
    pub(super) preset: String,
    /// Profile to start from (default: the built-in base).
    #[arg(long)]
    pub(super) profile: Option<PathBuf>,
    /// Profile overrides, section.key=value.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub(super) overrides: Vec<String>,
}

impl RoomBench {
    /// The frames and preset as profile overrides, then the user's.
    pub(super) fn sets(&self) -> Vec<String> {
        let mut sets = vec![
            format!("source.synthetic.frame_count={}", self.frames),
            format!("detector.oracle.preset={}", self.preset),
        ];
        sets.extend(self.overrides.iter().cloned());
        sets
    }
}
