//! `op3dsg`: the client CLI of the op3dsg scene-graph daemon: the clap definitions of every
//! subcommand, the dispatch to the module that runs it, and the helpers they share.
//!
//! Reads what a running `op3dsgd` publishes over iceoryx2 shared memory (graph, health) through
//! the planner client library (`op3dsg_ipc_types::client`), writes the synthetic benchmark's
//! ground truth, and runs the benchmarks (`op3dsg bench perf`).
//!
//! | module | subcommands |
//! |---|---|
//! | [`watch`] | `watch` |
//! | [`dump`] | `dump` |
//! | [`health`] | `health` |
//! | [`gt`] | `gt` |
//! | [`annotate`] | `annotate` |
//! | [`fusion_eval`] | `fusion-eval` |
//! | [`eval`] | `eval` |
//! | [`bench`] | `bench perf`, `bench soak`, `bench llm`, `bench quality`, `bench ipc-peer` |
//! | [`query`] | `query`, `bench query` |
//! | [`goal`] | `goal`, `bench nav` |
//! | [`map`] | `map info`, `map save`, `map reset` |
//! | [`record`] | `record info`, `bench record` |

mod annotate;
mod bench;
mod dump;
mod eval;
mod fusion_eval;
mod goal;
mod gt;
mod health;
mod map;
mod query;
mod record;
mod watch;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use iceoryx2::prelude::LogLevel;
use op3dsg_ipc_types::ClientError;
use op3dsg_synthetic::RoomKind;

/// Client of the op3dsg scene-graph daemon (op3dsgd).
///
/// op3dsgd serves a live, part-aware 3D scene graph over iceoryx2 shared memory under a service
/// prefix (services <prefix>/graph, <prefix>/graph_updated, <prefix>/health, <prefix>/pose,
/// <prefix>/query, <prefix>/occupancy).
/// This tool watches it, dumps it, shows its health, and writes synthetic ground truth.
#[derive(Debug, Parser)]
#[command(name = "op3dsg", version, propagate_version = true)]
struct Cli {
    /// Service name prefix the daemon serves under (its profile's `ipc.prefix`).
    #[arg(long, global = true, value_name = "PREFIX", env = PREFIX_ENV, default_value = "op3dsg")]
    prefix: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Live view: one text line per graph update or per interval (graph version, counts,
    /// capacity flag, frames, keyframes, per-stage rates and latencies, queue depths).
    ///
    /// Waits for the daemon if it is not up yet. Ctrl-C exits.
    Watch {
        /// Print at least this often even without a graph update, milliseconds.
        #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(10..=60_000))]
        interval_ms: u64,
    },
    /// Print the current graph once: a table (nodes, then edges), the graph JSON form (schema
    /// op3dsg.graph/1, the same as `op3dsg gt` writes), or the compact form for LLM prompts
    /// (op3dsg.llm/1: objects with their parts, affordances and relations by id; see
    /// docs/llm-graph.md).
    Dump {
        /// Output form.
        #[arg(long, value_enum, default_value_t = dump::DumpFormat::Table)]
        format: dump::DumpFormat,
        /// Shorthand for --format json.
        #[arg(long, conflicts_with = "format")]
        json: bool,
        /// Give up (exit code 1) if no graph arrives within this many seconds.
        #[arg(long, default_value_t = 5.0)]
        timeout_s: f64,
        /// Write to this file instead of standard output.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Print the daemon's latest health record (frames, keyframes, stage rates and latencies,
    /// queue depths and drops, and with reasoner.kind = "llm" the LLM refiner: state, calls,
    /// failures, rejections by reason, last latency, breaker).
    Health {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Give up (exit code 1) if no record arrives within this many seconds.
        #[arg(long, default_value_t = 5.0)]
        timeout_s: f64,
    },
    /// Ask the daemon which nodes serve a need in words ("somewhere to wash my hands", "what
    /// controls the ceiling light"): the top-k objects and parts with their score and the text
    /// that matched (label, parent label, affordance or functional edge), from the service
    /// <prefix>/query. The daemon needs text_encoder.enabled = true (and scripts/setup-models.sh).
    ///
    /// Exit code 1 with the reason when the daemon is not running, runs without the text
    /// encoder, refuses (its query queue is full), or does not answer in time.
    Query {
        /// The need, in words.
        text: String,
        /// Nodes to return (1..=16).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=16))]
        k: u32,
        /// Print JSON (schema op3dsg.query/1) instead of a table.
        #[arg(long)]
        json: bool,
        /// Give up after this many seconds (waiting for the daemon included).
        #[arg(long, default_value_t = 5.0)]
        timeout_s: f64,
    },
    /// Where to stand to reach a node: an approach pose on the daemon's occupancy map (a free
    /// cell at the profile's standoff from the node, facing it; for a part, on the side it
    /// faces) reachable from the robot's latest pose by A*, from the service <prefix>/query.
    ///
    /// TARGET is a node id (digits; needs no text encoder) or a need in words, answered by the
    /// query's top hit (needs text_encoder.enabled = true). Prints x, y (metres, world floor
    /// plane), yaw (radians, facing the node), the standoff and the A* path length.
    ///
    /// Exit code 1 with the reason when there is no pose ("no free cell within the standoff
    /// band", "unreachable from the robot's pose", no map yet), the node does not exist, or the
    /// daemon does not answer.
    Goal {
        /// A node id of the current graph, or a need in words ("somewhere to wash my hands").
        target: String,
        /// Print JSON (schema op3dsg.goal/1) instead of a line; printed also when there is no
        /// pose (status and reason), before exit code 1.
        #[arg(long)]
        json: bool,
        /// Give up after this many seconds (waiting for the daemon included).
        #[arg(long, default_value_t = 5.0)]
        timeout_s: f64,
    },
    /// Write the ground-truth scene graph (JSON, schema op3dsg.graph/1) of a synthetic room.
    Gt {
        /// Room type.
        #[arg(long, value_parser = parse_room)]
        room: RoomKind,
        /// Scene seed (the same seed gives the same scene).
        #[arg(long)]
        seed: u64,
        /// Write to this file instead of standard output.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the ground truth as a run of this many frames saw it: each node gets
        /// `seen_keyframes` (the keyframes of the run in which it was visible, the benchmark's
        /// rule), and `op3dsg eval` then scores only the nodes seen in at least 3, as
        /// `op3dsg bench quality` does. Use the profile (and `--set`s) the daemon ran with: the
        /// camera path and the keyframe gate decide what is seen
        #[arg(long)]
        frames: Option<u64>,
        /// Profile of the run (`--frames`; default: the built-in base)
        #[arg(long, requires = "frames")]
        profile: Option<PathBuf>,
        /// Profile overrides of the run, section.key=value (`--frames`)
        #[arg(long = "set", value_name = "KEY=VALUE", requires = "frames")]
        overrides: Vec<String>,
    },
    /// Write the ground truth (JSON, schema op3dsg.graph/1, as `op3dsg gt` writes) of a recorded
    /// RGB-D sequence from hand-drawn 2D boxes: an annotation file (TOML, schema
    /// op3dsg.annotation/1) lists per object and part its label, kind, parent and pixel boxes on
    /// frames of a recording in the TUM RGB-D layout. Each box's depth pixels within a depth band
    /// around the box's median depth (`band_m`, default 0.25 m) are back-projected with the
    /// frame's pose, fused over the frames, and bounded per world axis by the 2nd and 98th
    /// percentile. Prints per node the frames, points and box size on standard error. The file
    /// format and the lifting are documented in daemon/sim/src/annotate.rs.
    Annotate {
        /// The annotation file (TOML).
        annotation: PathBuf,
        /// The recording (TUM RGB-D layout; default: the file's `sequence`, relative to the file).
        #[arg(long, value_name = "DIR")]
        sequence: Option<PathBuf>,
        /// Write the ground truth to this file instead of standard output.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Also write each annotated frame as a PNG into this folder, with the boxes outlined and
        /// the pixels kept by the depth band tinted in the node's colour.
        #[arg(long, value_name = "DIR")]
        preview: Option<PathBuf>,
    },
    /// Run a synthetic room through source, keyframe gate, oracle detector and fusion on one
    /// thread (deterministic, no daemon needed) and score the fused graph against the room's
    /// ground truth: per kind the eligible nodes, matched %, fragmentation, false positives,
    /// wrong merges, and the stage that lost each miss. For tuning fusion.
    FusionEval {
        /// Room type (benchmark rooms, or the test scene colour_panel).
        #[arg(long, value_parser = parse_room)]
        room: RoomKind,
        #[command(flatten)]
        scene: RoomBench,
        /// Also list every miss, wrong merge and false positive.
        #[arg(long)]
        details: bool,
        /// Exit with code 1 when the quality targets are missed.
        #[arg(long)]
        check: bool,
        /// Also write the fused graph as JSON (`op3dsg.graph/1`) to this file.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
    },
    /// Score a predicted graph against a ground-truth graph with the benchmark's protocol (paper,
    /// "Metrics"): node R@K for objects, parts and overall (a ground-truth node is retrieved when
    /// a predicted node of its kind overlaps its box and its label ranks in the top K of the
    /// label vocabulary by all-MiniLM-L6-v2 similarity to the predicted label), the strict
    /// variants IoU >= 0.10 and IoP >= 0.25, affordance R@K, functional and spatial triplet R@K
    /// and associated node R@K, for K = 3, 5, 10. Needs .models/ (./scripts/setup-models.sh).
    /// The choices the paper leaves open are listed in daemon/sim/src/eval/recall/mod.rs.
    Eval {
        /// Predicted graph (op3dsg.graph/1, e.g. from `op3dsg dump --json`).
        #[arg(long, value_name = "FILE")]
        pred: PathBuf,
        /// Ground-truth graph (op3dsg.graph/1, e.g. from `op3dsg gt`).
        #[arg(long, value_name = "FILE")]
        gt: PathBuf,
        /// More ground-truth graphs whose labels join the ranking vocabulary (a benchmark ranks
        /// in the labels of all its scenes, not of one).
        #[arg(long, value_name = "FILE")]
        vocabulary: Vec<PathBuf>,
        /// Profile whose [onnx] and [text_encoder] locate the model (default: the built-in base).
        #[arg(long)]
        profile: Option<PathBuf>,
        /// Write the report (figures and per-item results) as JSON to this file.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
    },
    /// MCAP recordings of op3dsgd (`op3dsgd --record DIR`, profile section [record]).
    Record {
        #[command(subcommand)]
        command: RecordCommand,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        command: BenchCommand,
    },
    /// The daemon's map snapshots (the map it restores after a restart): info, save now, reset.
    Map {
        /// Snapshot directory (the daemon's snapshot.dir; under systemd
        /// /var/lib/op3dsg/snapshots).
        #[arg(long, global = true, env = "OP3DSG_SNAPSHOT_DIR", default_value = map::DEFAULT_DIR)]
        dir: PathBuf,
        #[command(subcommand)]
        command: MapCommand,
    },
}

#[derive(Debug, Subcommand)]
enum MapCommand {
    /// Check the snapshot (header, checksum, decoding) and print what it holds: graph version,
    /// age, objects, parts, points, whether a daemon runs with it, files moved aside. No daemon
    /// needed.
    Info {
        /// Print JSON (schema op3dsg.map_info/1).
        #[arg(long)]
        json: bool,
    },
    /// Ask the running daemon to write a snapshot now, wait for it, and print its info.
    Save {
        /// Give up (exit code 1) after this many seconds.
        #[arg(long, default_value_t = 10.0)]
        timeout_s: f64,
    },
    /// Move the snapshot aside (never deleted: map.snapshot.reset-<unix ms>) so the next start
    /// begins with an empty map. Refused while a daemon runs with the directory.
    Reset,
}

#[derive(Debug, Subcommand)]
enum RecordCommand {
    /// What recordings hold: per channel its schema, message count and rate; the time range;
    /// whether the recorder finished the file and how many messages it dropped while recording.
    /// Reads files cut off by a crash or a full disk up to where they end, and says so.
    Info {
        /// The .mcap files.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Debug, clap::Args)]
struct RecordBenchArgs {
    /// Seconds of input per compression.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Frame rate, Hz.
    #[arg(long, default_value_t = 30.0)]
    rate_hz: f64,
    /// Image width, pixels (the D435i stream of the robot: 848x480).
    #[arg(long, default_value_t = 848)]
    width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Distinct synthetic kitchen frames, rendered once and cycled.
    #[arg(long, default_value_t = 30)]
    distinct_frames: u64,
    /// Nodes of the graph written with the keyframes.
    #[arg(long, default_value_t = 150)]
    graph_nodes: usize,
    /// A keyframe (pose + graph version) every this many frames (0: none).
    #[arg(long, default_value_t = 3)]
    graph_every: u64,
    /// zstd, lz4, none, or all (zstd then lz4).
    #[arg(long, default_value = "all")]
    compression: String,
    /// Colour storage (record.colour): raw, png or jpeg.
    #[arg(long, default_value = "raw")]
    colour: String,
    /// JPEG quality with --colour jpeg (record.jpeg_quality).
    #[arg(long, default_value_t = 90)]
    jpeg_quality: u8,
    /// Chunk size, KiB (record.chunk_size_kib).
    #[arg(long, default_value_t = 4096)]
    chunk_size_kib: u64,
    /// Folder for the files (default: a temporary folder, removed afterwards).
    #[arg(long)]
    dir: Option<PathBuf>,
    /// Keep the files.
    #[arg(long)]
    keep: bool,
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
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
    /// The subscriber process of `bench perf`'s IPC measurement (started by it).
    #[command(hide = true)]
    IpcPeer {
        /// Graph + raw message pairs to take before exiting.
        #[arg(long)]
        pairs: usize,
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
struct LlmBenchArgs {
    /// Frames per pipeline run.
    #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..))]
    frames: u64,
    /// Seconds the server takes to answer each request.
    #[arg(long, default_value_t = 5.0)]
    delay_s: f64,
    /// Profile both runs start from (default: the built-in base: synthetic kitchen).
    #[arg(long)]
    profile: Option<PathBuf>,
    /// Profile overrides, section.key=value, applied to both runs.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Only serve chat completions on this address (e.g. 127.0.0.1:8099) until interrupted.
    #[arg(long, value_name = "ADDRESS")]
    serve: Option<String>,
}

#[derive(Debug, clap::Args)]
struct PerfArgs {
    /// Frames per pipeline run (one run as fast as possible, one at camera rate).
    #[arg(long, default_value_t = 900, value_parser = clap::value_parser!(u64).range(1..))]
    frames: u64,
    /// Rate of the camera-rate run, Hz (0 skips it).
    #[arg(long, default_value_t = 30.0)]
    live_rate_hz: f64,
    /// Profile the pipeline runs and the fusion curve start from (default: the built-in base:
    /// synthetic kitchen, oracle detector with realistic noise).
    #[arg(long)]
    profile: Option<PathBuf>,
    /// Profile overrides, section.key=value, applied after each run's own settings.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Sample the process's resident memory this often, milliseconds.
    #[arg(long, default_value_t = 250, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    rss_period_ms: u64,
    /// Graph sizes (nodes) of the IPC measurement, comma-separated ("none": skip it).
    #[arg(long, default_value = "100,2000,10000", value_parser = parse_sizes)]
    ipc_nodes: Sizes,
    /// Timed messages per IPC size, each for the graph and for raw iceoryx2.
    #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u64).range(1..))]
    ipc_messages: u64,
    /// Untimed messages per IPC size and kind before the timed ones.
    #[arg(long, default_value_t = 20)]
    ipc_warmup: usize,
    /// Map sizes (nodes) of the fusion curve, comma-separated ("none": skip it).
    #[arg(long, default_value = "100,500,1000,2000,5000,10000,20000", value_parser = parse_sizes)]
    fusion_sizes: Sizes,
    /// Timed fusion steps per map size.
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u64).range(1..))]
    fusion_steps: u64,
    /// Keyframes of the kitchen path the fusion maps are built from.
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..=1000))]
    fusion_keyframes: u64,
    /// Write the report as JSON (schema op3dsg.bench_perf/1) to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Write the Markdown tables to this file.
    #[arg(long, value_name = "FILE")]
    markdown: Option<PathBuf>,
    /// Write the plot of fusion cost against map size to this PNG file.
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct SoakArgs {
    /// Frames of the run with snapshots on.
    #[arg(long, default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..))]
    frames: u64,
    /// Frames of the comparison run with snapshots off (default: as many as --frames; 0: no
    /// comparison run).
    #[arg(long)]
    compare_frames: Option<u64>,
    /// Seconds between snapshots (snapshot.period_s; the daemon's default is 30).
    #[arg(long, default_value_t = 2.0)]
    snapshot_period_s: f64,
    /// Sample the process's resident memory this often, milliseconds.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..=600_000))]
    rss_period_ms: u64,
    /// Profile the runs start from (default: the built-in base: synthetic kitchen, oracle
    /// detector with realistic noise).
    #[arg(long)]
    profile: Option<PathBuf>,
    /// Profile overrides, section.key=value, applied after the soak's own settings.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Write the report as JSON (schema op3dsg.bench_soak/1) to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Write the Markdown to this file.
    #[arg(long, value_name = "FILE")]
    markdown: Option<PathBuf>,
}

/// Environment variable giving the prefix when `--prefix` is absent.
const PREFIX_ENV: &str = "OP3DSG_PREFIX";

/// A comma-separated list of sizes; "none" (or nothing) is the empty list.
#[derive(Debug, Clone)]
struct Sizes(Vec<usize>);

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

fn parse_room(name: &str) -> Result<RoomKind, String> {
    RoomKind::parse(name).ok_or_else(|| {
        let all: Vec<&str> = RoomKind::ALL.iter().chain(&RoomKind::TEST_SCENES).map(|r| r.as_str()).collect();
        format!("unknown room \"{name}\" (expected one of: {})", all.join(", "))
    })
}

fn main() -> std::process::ExitCode {
    iceoryx2::prelude::set_log_level_from_env_or(LogLevel::Error);
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("op3dsg: error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    let prefix = cli.prefix;
    op3dsg_ipc_types::validate_prefix(&prefix).map_err(|e| anyhow::anyhow!("--prefix / {PREFIX_ENV}: {e}"))?;
    match cli.command {
        Command::Watch { interval_ms } => watch::watch(&prefix, Duration::from_millis(interval_ms)),
        Command::Dump { format, json, timeout_s, out } => {
            let format = if json { dump::DumpFormat::Json } else { format };
            dump::dump(&prefix, format, seconds(timeout_s)?, out.as_deref())
        }
        Command::Health { json, timeout_s } => health::health(&prefix, json, seconds(timeout_s)?),
        Command::Query { text, k, json, timeout_s } => query::query(&prefix, &text, k, json, seconds(timeout_s)?),
        Command::Bench { command: BenchCommand::Query { rooms, json } } => {
            query::bench(rooms.profile.as_deref(), &rooms.sets(), rooms.seed, json.as_deref())
        }
        Command::Goal { target, json, timeout_s } => goal::goal(&prefix, &target, json, seconds(timeout_s)?),
        Command::Bench { command: BenchCommand::Nav { rooms, json } } => {
            goal::bench(rooms.profile.as_deref(), &rooms.sets(), rooms.seed, json.as_deref())
        }
        Command::Gt { room, seed, out, frames, profile, overrides } => {
            let run = frames.map(|frames| gt::RunSeen { frames, profile, overrides });
            gt::write_ground_truth(room, seed, run.as_ref(), out.as_deref())
        }
        Command::Annotate { annotation, sequence, out, preview } => {
            annotate::annotate(&annotation, sequence.as_deref(), out.as_deref(), preview.as_deref())
        }
        Command::FusionEval { room, scene, details, check, json } => {
            let mut sets = vec![
                format!("source.synthetic.room={}", room.as_str()),
                format!("source.synthetic.seed={}", scene.seed),
            ];
            sets.extend(scene.sets());
            fusion_eval::fusion_eval(scene.profile.as_deref(), &sets, details, check, json.as_deref())
        }
        Command::Bench { command: BenchCommand::Perf(args) } => bench::perf(*args),
        Command::Bench { command: BenchCommand::Soak(args) } => bench::soak(*args),
        Command::Bench { command: BenchCommand::Llm(args) } => bench::llm(*args),
        Command::Map { dir, command: MapCommand::Info { json } } => map::info(&dir, json),
        Command::Map { dir, command: MapCommand::Save { timeout_s } } => map::save(&dir, seconds(timeout_s)?),
        Command::Map { dir, command: MapCommand::Reset } => map::reset(&dir),
        Command::Bench { command: BenchCommand::Record(args) } => record::bench(*args),
        Command::Record { command: RecordCommand::Info { files, json } } => record::info(&files, json),
        Command::Bench { command: BenchCommand::IpcPeer { pairs } } => bench::ipc_peer(&prefix, pairs),
        Command::Eval { pred, gt, vocabulary, profile, json } => {
            eval::evaluate(&pred, &gt, &vocabulary, profile.as_deref(), json.as_deref())
        }
        Command::Bench {
            command:
                BenchCommand::Quality {
                    preset,
                    scenes,
                    frames,
                    threads,
                    profile,
                    overrides,
                    json,
                    markdown,
                    check,
                    curves,
                    curves_png,
                },
        } => {
            let mut sets =
                vec![format!("source.synthetic.frame_count={frames}"), format!("detector.oracle.preset={preset}")];
            sets.extend(overrides);
            let threads = threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
            bench::quality(
                profile.as_deref(),
                &sets,
                scenes as usize,
                threads,
                bench::QualityOutputs {
                    json: json.as_deref(),
                    markdown: markdown.as_deref(),
                    check,
                    curves_png: curves
                        .then(|| curves_png.unwrap_or_else(|| PathBuf::from("quality_curves.png")))
                        .as_deref(),
                },
            )
        }
    }
}

/// `--timeout-s` as a duration.
fn seconds(value: f64) -> Result<Duration> {
    Duration::try_from_secs_f64(value).with_context(|| format!("--timeout-s {value}: not a valid duration"))
}

/// The synthetic rooms a room benchmark (`bench query`, `bench nav`) or `fusion-eval` maps:
/// seed, frames, oracle preset and profile.
#[derive(clap::Args, Debug)]
struct RoomBench {
    /// Scene seed (of every room).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Frames per room (30 per second of camera path).
    #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..))]
    frames: u64,
    /// Oracle noise preset (clean | realistic).
    #[arg(long, default_value = "realistic")]
    preset: String,
    /// Profile to start from (default: the built-in base).
    #[arg(long)]
    profile: Option<PathBuf>,
    /// Profile overrides, section.key=value.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
}

impl RoomBench {
    /// The frames and preset as profile overrides, then the user's.
    fn sets(&self) -> Vec<String> {
        let mut sets = vec![
            format!("source.synthetic.frame_count={}", self.frames),
            format!("detector.oracle.preset={}", self.preset),
        ];
        sets.extend(self.overrides.iter().cloned());
        sets
    }
}

/// The iceoryx2 node name of this process's clients.
fn node_name() -> String {
    format!("op3dsg-cli-{}", std::process::id())
}

/// Polls `read` until it yields a value or `timeout` passes.
fn poll_until<T>(timeout: Duration, mut read: impl FnMut() -> Result<Option<T>, ClientError>) -> Result<Option<T>> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(value) = read()? {
            return Ok(Some(value));
        }
        let now = Instant::now();
        if now >= deadline {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(10).min(deadline - now));
    }
}

/// Prints a report's text and, with `json`, writes the report as pretty JSON to that file.
fn write_report(text: &str, json: Option<&Path>, report: &impl serde::Serialize) -> Result<()> {
    write_output(None, text)?;
    if let Some(path) = json {
        let mut out = serde_json::to_string_pretty(report).context("serialising the report")?;
        out.push('\n');
        write_output(Some(path), &out)?;
    }
    Ok(())
}

/// Writes `text` to `out`, or to standard output.
fn write_output(out: Option<&Path>, text: &str) -> Result<()> {
    match out {
        Some(path) => std::fs::write(path, text).with_context(|| format!("writing {}", path.display())),
        None => {
            let mut stdout = std::io::stdout().lock();
            stdout.write_all(text.as_bytes()).and_then(|()| stdout.flush()).context("writing to standard output")
        }
    }
}
