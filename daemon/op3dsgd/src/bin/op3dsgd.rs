//! `op3dsgd`: the op3dsg scene-graph daemon.
//!
//! Runs the pipeline described by a profile (the built-in synthetic kitchen when none is given)
//! and serves the graph over iceoryx2 until SIGINT/SIGTERM, or until `--max-frames` frames /
//! the end of a finite source with `--exit-at-end`.
//!
//! Exit codes: 0 clean stop, 1 runtime failure (including a prefix another op3dsgd already
//! serves: the message names the prefix and that daemon's pid), 2 bad profile or arguments,
//! 130 second signal.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use clap::Parser;
use op3dsg_runtime::config;
use op3dsg_runtime::ipc::card::DaemonCard;
use op3dsg_runtime::pipeline::{Pipeline, RunSummary};
use tracing::{error, info, warn};

#[derive(Debug, Parser)]
#[command(
    name = "op3dsgd",
    version = version(),
    about = "op3dsg daemon: live part-aware 3D scene graph served over iceoryx2"
)]
struct Args {
    /// Profile (TOML) overriding the built-in base (the synthetic kitchen). See profiles/.
    #[arg(long, short = 'p', env = "OP3DSG_PROFILE")]
    profile: Option<PathBuf>,

    /// Override one profile value, TOML syntax: --set detector.workers=4 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,

    /// Stop after this many source frames and exit once the final graph is published.
    #[arg(long)]
    max_frames: Option<u64>,

    /// Exit when a finite source ends (default: keep serving the last graph).
    #[arg(long)]
    exit_at_end: bool,

    /// iceoryx2 service prefix: a shortcut for `--set ipc.prefix="PREFIX"`. Without it,
    /// $OP3DSG_PREFIX (when set) overrides the profile's ipc.prefix; the command line overrides
    /// both (--print-config says which layer set each value).
    #[arg(long)]
    prefix: Option<String>,

    /// Record to MCAP files in DIR: a shortcut for `--set record.enabled=true --set
    /// record.dir="DIR"` (DIR relative to the working directory); the profile's [record]
    /// section says what is written. `op3dsg record info FILE` shows what a file holds.
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,

    /// Print the effective profile (all layers merged, paths resolved: model and library files
    /// as the daemon will open them, or a note saying where it looked) and exit.
    #[arg(long)]
    print_config: bool,

    /// Log filter (tracing EnvFilter syntax), e.g. "info" or "op3dsg_runtime=debug".
    #[arg(long, env = "OP3DSG_LOG", default_value = "info")]
    log: String,
}

fn main() -> ExitCode {
    let args = Args::parse();
    init_logging(&args.log);
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);

    let overrides = profile_overrides(&args);
    let backends = op3dsgd::backends();
    let loaded = match config::load_with_environment(&backends, args.profile.as_deref(), &environment(), &overrides) {
        Ok(loaded) => loaded,
        Err(e) => {
            eprintln!("op3dsgd: bad profile: {e}");
            return ExitCode::from(2);
        }
    };
    if args.print_config {
        return print_config(&loaded);
    }

    // First signal: orderly shutdown ladder. Second: exit at once.
    let stop = Arc::new(AtomicBool::new(false));
    if let Err(e) = install_signal_handler(stop.clone()) {
        error!(error = %e, "cannot install the signal handler");
        return ExitCode::FAILURE;
    }

    let profile = &loaded.profile;
    info!(layers = %loaded.layers.join(" <- "), prefix = %profile.ipc.prefix, "op3dsgd starting");
    if profile.text_encoder.enabled
        && let Err(e) = check_text_encoder(profile)
    {
        error!("cannot start: text encoder: {e}");
        return ExitCode::FAILURE;
    }
    let pipeline = match Pipeline::start(profile, &backends, stop.clone()) {
        Ok(p) => p,
        Err(e) => {
            error!("cannot start: {}", op3dsg_ipc_types::without_source_locations(&e.to_string()));
            return ExitCode::FAILURE;
        }
    };
    info!(prefix = %profile.ipc.prefix, "serving");
    // The card in the root tells `op3dsg map` (run without --dir) where this daemon's snapshots are.
    let root = profile.ipc.ipc_root();
    let snapshot_dir = profile.snapshot.resolve_dir().map(|dir| std::path::absolute(&dir).unwrap_or(dir));
    if let Err(e) = DaemonCard::new(&profile.ipc.prefix, snapshot_dir).write(root.path()) {
        warn!(error = %e, root = %root, "cannot write the daemon card (op3dsg map then needs --dir)");
    }
    // READY=1 now: every stage runs and the graph service exists. Then STATUS= and the watchdog
    // (while the stages are alive), STOPPING=1 at the shutdown ladder (a no-op when not run by
    // systemd).
    let notifier = match op3dsg_runtime::service::ServiceNotifier::start(pipeline.counters().clone(), stop.clone()) {
        Ok(notifier) => notifier,
        Err(e) => {
            error!(error = %e, "cannot start the sd_notify thread");
            return ExitCode::FAILURE;
        }
    };
    let result = pipeline.wait();
    notifier.stopping();
    drop(notifier);
    DaemonCard::remove(root.path(), &profile.ipc.prefix);
    match result {
        Ok(summary) => report_stop(&summary),
        Err(stuck) => {
            error!(stages = ?stuck, "shutdown timed out");
            ExitCode::FAILURE
        }
    }
}

/// The profile overrides of the command line: `--set` values, then those `--max-frames`,
/// `--exit-at-end`, `--record` and `--prefix` stand for.
/// The profile values the environment sets, a layer between the profile files and the command
/// line: `$OP3DSG_PREFIX` (when set and not empty) is `ipc.prefix`.
fn environment() -> Vec<(String, String)> {
    let prefix = std::env::var(PREFIX_ENV).ok().filter(|p| !p.is_empty());
    prefix.map(|p| (PREFIX_ENV.to_owned(), format!("ipc.prefix={}", toml::Value::String(p)))).into_iter().collect()
}

/// The variable whose value is the iceoryx2 prefix when the command line sets none.
const PREFIX_ENV: &str = op3dsg_ipc_types::services::PREFIX_ENV;

fn profile_overrides(args: &Args) -> Vec<String> {
    let mut overrides = args.set.clone();
    if let Some(n) = args.max_frames {
        overrides.push(format!("run.max_frames={n}"));
        overrides.push("run.exit_at_end=true".to_owned());
    }
    if args.exit_at_end {
        overrides.push("run.exit_at_end=true".to_owned());
    }
    if let Some(dir) = &args.record {
        let dir = dir.display().to_string();
        overrides.push("record.enabled=true".to_owned());
        overrides.push(format!("record.dir={}", toml::Value::String(dir)));
    }
    if let Some(prefix) = &args.prefix {
        overrides.push(format!("ipc.prefix={}", toml::Value::String(prefix.clone())));
    }
    overrides
}

/// The cargo features this binary was built with, as `--version` shows them
/// (`op3dsgd 0.1.0 (features: realsense, zenoh)`): `systemd/install.sh` refuses a binary without
/// the camera or Zenoh.
const FEATURES: &[(&str, bool)] = &[
    ("realsense", cfg!(feature = "realsense")),
    ("zenoh", cfg!(feature = "zenoh")),
    ("cuda", cfg!(feature = "cuda")),
    ("openvino", cfg!(feature = "openvino")),
    ("fault-hooks", cfg!(feature = "fault-hooks")),
];

/// `--version`: the package version and the features built in.
fn version() -> &'static str {
    static VERSION: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    VERSION.get_or_init(|| {
        let on: Vec<&str> = FEATURES.iter().filter(|(_, built)| *built).map(|(name, _)| *name).collect();
        let features = if on.is_empty() { "none".to_owned() } else { on.join(", ") };
        format!("{} (features: {features})", env!("CARGO_PKG_VERSION"))
    })
}

/// `--print-config`: the effective profile, after the layers it came from, with the model and
/// library files the daemon will open (a note for each it cannot find).
fn print_config(loaded: &config::LoadedProfile) -> ExitCode {
    let (effective, notes) = loaded.effective_with_files();
    match toml::to_string_pretty(&effective) {
        Ok(text) => {
            println!("# layers: {}", loaded.layers.join(" <- "));
            // Where each value that is not the built-in base's came from (the last layer wins).
            let set = loaded.set_values();
            if !set.is_empty() {
                println!("# set by a layer above the built-in base:");
                let width = set.iter().map(|(key, _)| key.len()).max().unwrap_or(0);
                for (key, layer) in set {
                    println!("#   {key:width$}  <- {layer}");
                }
            }
            for note in notes {
                println!("# {note}");
            }
            println!("{text}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("op3dsgd: cannot print the profile: {e}");
            ExitCode::FAILURE
        }
    }
}

/// SIGINT/SIGTERM: the first sets `stop` (the orderly shutdown ladder), the second exits at once
/// with 130.
fn install_signal_handler(stop: Arc<AtomicBool>) -> Result<(), ctrlc::Error> {
    let signals = AtomicU32::new(0);
    ctrlc::set_handler(move || {
        if signals.fetch_add(1, Ordering::SeqCst) == 0 {
            stop.store(true, Ordering::SeqCst);
        } else {
            std::process::exit(130);
        }
    })
}

/// Logs what the run did once every stage stopped; failure when the source stopped on bad data.
fn report_stop(summary: &RunSummary) -> ExitCode {
    info!(
        frames = summary.frames,
        keyframes = summary.keyframes,
        graph_version = summary.graph_version,
        map_nodes = summary.map_nodes,
        map_mib = format!("{:.1}", op3dsg_runtime::stats::mib(summary.map_memory_bytes)),
        elapsed_s = format!("{:.2}", summary.elapsed_s),
        keyframes_per_s = format!("{:.1}", summary.keyframes_per_s()),
        bad_data_skipped = summary.bad_data_skipped,
        "stopped"
    );
    if summary.source_failed {
        // The source logged its error when it stopped.
        error!("the frame source stopped on bad data");
        return ExitCode::FAILURE;
    }
    ExitCode::SUCCESS
}

/// Logging: under systemd, when stderr is the journal (`$JOURNAL_STREAM` names stderr's device
/// and inode), events go to the journal directly with their level as priority and every field
/// as a journal field (`journalctl -u op3dsgd -o verbose` shows e.g. `F_FRAME_SEQ=`); otherwise
/// text on stderr, with ANSI colour only on a terminal. `filter` is `--log` / `OP3DSG_LOG`.
fn init_logging(filter: &str) {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let (filter, bad_filter) = match tracing_subscriber::EnvFilter::try_new(filter) {
        Ok(f) => (f, None),
        Err(e) => (
            tracing_subscriber::EnvFilter::new("info"),
            Some(format!("--log / OP3DSG_LOG {filter:?}: {e}; using \"info\"")),
        ),
    };
    // The live view's server logs every viewer that went away mid-send (a closed laptop, a
    // dropped tunnel) as an error; that is the viewer's business, not the daemon's. A filter
    // that names `foxglove` itself decides.
    let filter = match "foxglove::websocket::connected_client::poller=off".parse() {
        Ok(quiet) if !filter.to_string().contains("foxglove") => filter.add_directive(quiet),
        _ => filter,
    };
    // Zenoh's own warnings repeat, with its source files, what the daemon reports in its words
    // (a listener that cannot open: "cannot start: zenoh: ..."); its errors still show. A filter
    // that names `zenoh` itself decides.
    let filter = match "zenoh=error".parse() {
        Ok(quiet) if !filter.to_string().contains("zenoh") => filter.add_directive(quiet),
        _ => filter,
    };
    let registry = tracing_subscriber::registry().with(filter);
    let journal = stderr_is_journal().then(tracing_journald::layer);
    match journal {
        Some(Ok(layer)) => registry.with(layer.with_syslog_identifier("op3dsgd".to_owned())).init(),
        other => {
            let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
            registry.with(tracing_subscriber::fmt::layer().with_ansi(ansi).with_writer(std::io::stderr)).init();
            if let Some(Err(e)) = other {
                tracing::warn!(error = %e, "stderr is the journal but its socket cannot be used; logging text to stderr");
            }
        }
    }
    if let Some(message) = bad_filter {
        tracing::warn!("{message}");
    }
}

/// Whether stderr is connected to the journal (systemd sets `JOURNAL_STREAM=<dev>:<inode>`).
fn stderr_is_journal() -> bool {
    use std::os::unix::fs::MetadataExt;
    let Some(stream) = std::env::var_os("JOURNAL_STREAM") else { return false };
    let Ok(meta) = std::fs::metadata("/proc/self/fd/2") else { return false };
    stream.to_string_lossy() == format!("{}:{}", meta.dev(), meta.ino())
}

/// Loads ONNX Runtime and the text encoder and embeds one label, so that a profile asking for
/// the encoder stops at start-up, naming the missing file, rather than when a stage first needs
/// it. The pipeline's stages take their own encoder when they use one (one per thread).
fn check_text_encoder(profile: &config::Profile) -> Result<(), op3dsg_runtime::onnx::OnnxError> {
    use op3dsg_runtime::onnx::{OnnxRuntime, text_encoder::TextEncoder};
    let started = std::time::Instant::now();
    let runtime = OnnxRuntime::init(&profile.onnx)?;
    let mut encoder = TextEncoder::new(&runtime, &profile.text_encoder)?;
    encoder.encode("chair")?;
    info!(
        model = %encoder.model_path().display(),
        library = %runtime.library_path().display(),
        load_ms = started.elapsed().as_millis() as u64,
        "text encoder ready"
    );
    Ok(())
}
