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
//! | [`dump`], [`picture`] | `dump` |
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
mod bench_args;
mod bench_change;
mod bench_remote;
mod dump;
mod eval;
mod fusion_eval;
mod goal;
mod gt;
mod health;
mod map;
mod picture;
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

use bench_args::{BenchCommand, RoomBench};

/// Client of the op3dsg scene-graph daemon (op3dsgd).
///
/// op3dsgd serves a live, part-aware 3D scene graph over iceoryx2 shared memory under a service
/// prefix (services <prefix>/graph, <prefix>/graph_updated, <prefix>/health, <prefix>/pose,
/// <prefix>/query, <prefix>/occupancy).
/// This tool watches it, dumps it, shows its health, and writes synthetic ground truth.
///
/// Only processes of the daemon's own user can attach (iceoryx2 0.10 makes everything owner-only).
/// They meet in an iceoryx2 root folder: $OP3DSG_IPC_ROOT, else /run/op3dsg when it belongs to
/// this user (the installed service's), else /tmp/op3dsg-<uid>.
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
    /// Live view of the daemon. On a terminal: a full-screen view redrawn in place (graph
    /// version and age, objects, parts, edges; the daemon's counters; per stage its rate, p50,
    /// p99 and errors; queues with their drops; the pose and tf inputs, the LLM refiner,
    /// snapshots and the recorder; the last warnings derived from the health records); q, Esc or
    /// Ctrl-C quits. Otherwise (a pipe, a log): one compact line per interval (graph version,
    /// counts, capacity flag, frames, keyframes, per-stage rates and latencies, queue depths).
    ///
    /// Waits for the daemon if it is not up yet. Ctrl-C exits.
    Watch {
        /// Print a line this often (not on a terminal), or redraw at least this often (on a
        /// terminal, which also redraws on each graph and health record), milliseconds.
        #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(10..=60_000))]
        interval_ms: u64,
        #[command(flatten)]
        remote: Remote,
    },
    /// Print the current graph once: a table (nodes, then edges), the graph JSON form (schema
    /// op3dsg.graph/1, the same as `op3dsg gt` writes), the compact form for LLM prompts
    /// (op3dsg.llm/1: objects with their parts, affordances and relations by id; see
    /// docs/llm-graph.md), or a picture: Graphviz DOT (objects as boxes, parts as ellipses, each
    /// labelled with its id; relations as labelled arrows: part-of dashed, spatial, functional
    /// bold) or the same drawn as SVG without Graphviz.
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
        #[command(flatten)]
        remote: Remote,
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
        #[command(flatten)]
        remote: Remote,
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
        #[command(flatten)]
        remote: Remote,
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
        #[command(flatten)]
        remote: Remote,
    },
    /// Write the ground-truth scene graph (JSON, schema op3dsg.graph/1) of a synthetic room.
    /// With --profile or --set, of the room after the profile's change script
    /// (`[[source.synthetic.changes]]`, applied to --room / --seed): the final scene, whose
    /// instance ids are the generated room's plus one per added object.
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
        /// Profile of the run (`--frames`; default: the built-in base); its
        /// `[source.synthetic]` change script, if any, is applied (its room and seed are
        /// replaced by --room / --seed)
        #[arg(long)]
        profile: Option<PathBuf>,
        /// Profile overrides, section.key=value (of the run with `--frames`; a change script as
        /// `source.synthetic.changes=[{ at_lap = 1, remove = 12 }]`)
        #[arg(long = "set", value_name = "KEY=VALUE")]
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
        /// Snapshot directory (the daemon's snapshot.dir). Without it: the folder of the daemon
        /// serving --prefix (its card in the iceoryx2 root says), else the packaged unit's
        /// /var/lib/op3dsg/snapshots.
        #[arg(long, global = true, env = "OP3DSG_SNAPSHOT_DIR")]
        dir: Option<PathBuf>,
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

/// Environment variable giving the prefix when `--prefix` is absent.
const PREFIX_ENV: &str = "OP3DSG_PREFIX";

fn parse_room(name: &str) -> Result<RoomKind, String> {
    RoomKind::parse(name).ok_or_else(|| {
        let all: Vec<&str> = RoomKind::ALL.iter().chain(&RoomKind::TEST_SCENES).map(|r| r.as_str()).collect();
        format!("unknown room \"{name}\" (expected one of: {})", all.join(", "))
    })
}

fn main() -> std::process::ExitCode {
    iceoryx2::prelude::set_log_level_from_env_or(LogLevel::Error);
    // Colour only on a terminal: a log file or a pipe gets plain text.
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // What went wrong, not where in a dependency it was noticed (Zenoh's errors name
            // their source files).
            eprintln!("op3dsg: error: {}", op3dsg_ipc_types::without_source_locations(&format!("{e:#}")));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Where a daemon on another computer is: `--zenoh ENDPOINT --key-prefix PREFIX`.
#[derive(Debug, clap::Args)]
struct Remote {
    /// Reach a daemon on another computer over Zenoh instead of iceoryx2 (its keys under
    /// --key-prefix: the graph and its deltas, health, the query service): a Zenoh endpoint to
    /// connect to as a client (its `zenoh.listen`, or a router), e.g. tcp/192.168.1.20:7447.
    /// Needs --key-prefix.
    #[arg(long, value_name = "ENDPOINT", requires = "key_prefix")]
    zenoh: Option<String>,
    /// With --zenoh: the daemon's `zenoh.key_prefix` (op3dsg/<its hostname> by default).
    #[arg(long, value_name = "PREFIX", requires = "zenoh")]
    key_prefix: Option<String>,
}

/// Where a subcommand finds the daemon: on this computer over iceoryx2, or on another computer
/// through its Zenoh keys (`--zenoh ENDPOINT --key-prefix P`, which clap makes go together).
#[derive(Debug, Clone, Copy)]
enum DaemonAt<'a> {
    /// The daemon's iceoryx2 services on this computer.
    Iceoryx2 {
        /// Their prefix.
        prefix: &'a str,
    },
    /// A daemon's Zenoh keys, from another computer (a build with the feature `zenoh`).
    #[cfg(feature = "zenoh")]
    Zenoh {
        /// The endpoint to connect to as a client.
        endpoint: &'a str,
        /// The daemon's `zenoh.key_prefix`.
        key_prefix: &'a str,
    },
}

impl<'a> DaemonAt<'a> {
    fn new(prefix: &'a str, remote: &'a Remote) -> Result<Self> {
        match (&remote.zenoh, &remote.key_prefix) {
            #[cfg(feature = "zenoh")]
            (Some(endpoint), Some(key_prefix)) => Ok(Self::Zenoh { endpoint, key_prefix }),
            #[cfg(not(feature = "zenoh"))]
            (Some(_), _) => anyhow::bail!(
                "--zenoh: this op3dsg is built without Zenoh; build it with the cargo feature `zenoh` \
                 (`cargo build --release -p op3dsgd --features zenoh`; the Debian package has it)"
            ),
            _ => Ok(Self::Iceoryx2 { prefix }),
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    let prefix = cli.prefix;
    op3dsg_ipc_types::validate_prefix(&prefix).map_err(|e| anyhow::anyhow!("--prefix / {PREFIX_ENV}: {e}"))?;
    match cli.command {
        Command::Watch { interval_ms, remote } => {
            watch::watch(DaemonAt::new(&prefix, &remote)?, Duration::from_millis(interval_ms))
        }
        Command::Dump { format, json, timeout_s, out, remote } => {
            let format = if json { dump::DumpFormat::Json } else { format };
            let from = DaemonAt::new(&prefix, &remote)?;
            dump::dump(from, format, seconds(timeout_s)?, out.as_deref())
        }
        Command::Health { json, timeout_s, remote } => match DaemonAt::new(&prefix, &remote)? {
            #[cfg(feature = "zenoh")]
            DaemonAt::Zenoh { endpoint, key_prefix } => health::remote(endpoint, key_prefix, json, seconds(timeout_s)?),
            DaemonAt::Iceoryx2 { prefix } => health::health(prefix, json, seconds(timeout_s)?),
        },
        Command::Query { text, k, json, timeout_s, remote } => {
            let from = DaemonAt::new(&prefix, &remote)?;
            query::query(from, &text, k, json, seconds(timeout_s)?)
        }
        Command::Bench { command: BenchCommand::Query { rooms, json } } => {
            query::bench(rooms.profile.as_deref(), &rooms.sets(), rooms.seed, json.as_deref())
        }
        Command::Goal { target, json, timeout_s, remote } => {
            let from = DaemonAt::new(&prefix, &remote)?;
            goal::goal(from, &target, json, seconds(timeout_s)?)
        }
        Command::Bench { command: BenchCommand::Nav { rooms, json } } => {
            goal::bench(rooms.profile.as_deref(), &rooms.sets(), rooms.seed, json.as_deref())
        }
        Command::Gt { room, seed, out, frames, profile, overrides } => {
            let run = gt::RunSeen { frames, profile, overrides };
            gt::write_ground_truth(room, seed, &run, out.as_deref())
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
        Command::Bench { command: BenchCommand::Remote(args) } => bench_remote::run(*args),
        Command::Bench { command: BenchCommand::Change(args) } => bench_change::run(*args),
        Command::Map { dir, command: MapCommand::Info { json } } => map::info(&map::dir_of(dir, &prefix)?, json),
        Command::Map { dir, command: MapCommand::Save { timeout_s } } => {
            map::save(&map::dir_of(dir, &prefix)?, seconds(timeout_s)?)
        }
        Command::Map { dir, command: MapCommand::Reset } => map::reset(&map::dir_of(dir, &prefix)?),
        Command::Bench { command: BenchCommand::Record(args) } => record::bench(*args),
        Command::Record { command: RecordCommand::Info { files, json } } => record::info(&files, json),
        Command::Bench { command: BenchCommand::IpcPeer { rounds } } => bench::ipc_peer(&prefix, rounds),
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

/// The iceoryx2 node name of this process's clients.
/// A failed connection, with how long it waited when no daemon was serving (a refused root or
/// another error fails at once).
fn connect_error(prefix: &str, timeout: Duration, e: ClientError) -> anyhow::Error {
    let context = if e.is_not_serving() {
        format!("connecting to op3dsgd under prefix '{prefix}' (waited {:.1} s)", timeout.as_secs_f64())
    } else {
        format!("connecting to op3dsgd under prefix '{prefix}'")
    };
    anyhow::Error::new(e).context(context)
}

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
