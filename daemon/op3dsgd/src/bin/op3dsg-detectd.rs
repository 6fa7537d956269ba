//! `op3dsg-detectd`: a detection worker for a GPU box beside the robot.
//!
//! Loads the profile's `[detector]` (the same kinds and sections as `op3dsgd`: `yolox`,
//! `open_vocab` with its tagger, prompts and mask decoder, `[detector.region_encoder]`; ONNX
//! Runtime with the execution provider of `[onnx]` or the detector's own), opens a Zenoh
//! session from `[zenoh]`, and serves keyframes for each robot prefix it is told to
//! (`--serve`, repeatable; default `zenoh.key_prefix`):
//!
//! | key | what |
//! |---|---|
//! | `<prefix>/detect/<id>` | liveliness token: robots with `detector.remote.workers = ["auto"]` find it |
//! | `<prefix>/detect/<id>/request` | queryable: a keyframe request in, detections out |
//! | `<prefix>/detect/<id>/status` | queryable: models, execution provider, load (JSON) |
//!
//! A request whose contract it cannot serve (another model, a prompt its model does not know,
//! embeddings it does not make) is answered with a refusal that says why; a request beyond its
//! queue is refused as busy. Exit codes: 0 clean stop, 1 start-up failure, 2 bad profile or
//! arguments.

use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use clap::Parser;
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::source::{FrameSource, SourceError, SourceKind, SourceStatus};
use op3dsg_runtime::backend::{DetectorFactory, OpenedSource};
use op3dsg_runtime::config::{self, Profile};
use op3dsg_runtime::perception::remote::wire::{self, Contract, Reply, ReplyBody};
use op3dsg_runtime::perception::remote::{REMOTE_DETECTOR, announce, request_key, worker_key};
use op3dsg_runtime::perception::{OPEN_VOCAB_DETECTOR, YOLOX_DETECTOR, detect};
use op3dsg_runtime::stats::LatencyHistogram;
use tracing::{error, info, warn};
use zenoh::Wait;
use zenoh::query::Query;

#[derive(Debug, Parser)]
#[command(
    name = "op3dsg-detectd",
    version,
    about = "op3dsg detection worker: serves keyframe detection to robots over Zenoh"
)]
struct Args {
    /// Profile (TOML) whose [detector], [onnx] and [zenoh] sections the worker uses. See profiles/.
    #[arg(long, short = 'p', env = "OP3DSG_PROFILE")]
    profile: Option<std::path::PathBuf>,

    /// Override one profile value, TOML syntax: --set detector.workers=2 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,

    /// This worker's id in its keys (`<prefix>/detect/<id>`); default: the hostname.
    #[arg(long, env = "OP3DSG_DETECTD_ID")]
    id: Option<String>,

    /// A robot's key prefix to serve (repeatable); default: the profile's zenoh.key_prefix.
    #[arg(long = "serve", value_name = "PREFIX")]
    serve: Vec<String>,

    /// Log filter (tracing EnvFilter syntax), e.g. "info".
    #[arg(long, env = "OP3DSG_LOG", default_value = "info")]
    log: String,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let filter = tracing_subscriber::EnvFilter::try_new(&args.log).unwrap_or_else(|_| "info".into());
    // Colour only on a terminal: the journal or a pipe gets plain text.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    tracing_subscriber::fmt().with_env_filter(filter).with_ansi(ansi).with_writer(std::io::stderr).init();
    // With the camera's backend too, so a robot's profile (its [source.realsense]) loads here
    // unchanged: the worker uses only its [detector], [onnx] and [zenoh].
    let backends = op3dsgd::backends();
    let loaded = match config::load_with(&backends, args.profile.as_deref(), &args.set) {
        Ok(loaded) => loaded,
        Err(e) => {
            eprintln!("op3dsg-detectd: bad profile: {e}");
            return ExitCode::from(2);
        }
    };
    let profile = loaded.profile;
    let kind = profile.detector.kind.clone();
    if kind == REMOTE_DETECTOR {
        eprintln!("op3dsg-detectd: bad profile: detector.kind: a worker runs a local detector, not \"remote\"");
        return ExitCode::from(2);
    }
    let id = args.id.clone().unwrap_or_else(hostname);
    if let Err(e) = op3dsg_runtime::zenoh::check_prefix(&format!("x/{id}")) {
        eprintln!("op3dsg-detectd: --id {id:?}: {e}");
        return ExitCode::from(2);
    }
    let z = &profile.zenoh;
    if z.connect.is_empty() && z.listen.is_empty() && !z.multicast_scouting && z.config_file.is_none() {
        eprintln!(
            "op3dsg-detectd: bad profile{}: no robot can reach this worker: set zenoh.connect to the \
             robot's zenoh.listen endpoint (e.g. [\"tcp/192.168.1.20:7447\"]), or zenoh.listen here and \
             the robot's zenoh.connect to it",
            args.profile.as_ref().map(|f| format!(" {}", f.display())).unwrap_or_default()
        );
        return ExitCode::from(2);
    }
    let prefixes = if args.serve.is_empty() { vec![profile.zenoh.prefix()] } else { args.serve.clone() };
    for prefix in &prefixes {
        if let Err(e) = op3dsg_runtime::zenoh::check_prefix(prefix) {
            eprintln!("op3dsg-detectd: --serve {prefix:?}: {e}");
            return ExitCode::from(2);
        }
    }
    match serve(&profile, &backends, &id, &prefixes) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            error!("cannot start: {}", op3dsg_ipc_types::without_source_locations(&e));
            ExitCode::FAILURE
        }
    }
}

/// What the worker counts (its status key).
#[derive(Debug, Default)]
struct Load {
    requests: AtomicU64,
    replies: AtomicU64,
    refusals: AtomicU64,
    failures: AtomicU64,
    busy: AtomicU64,
    detect: std::sync::Mutex<LatencyHistogram>,
}

/// The model contract this worker serves.
#[derive(Debug)]
struct Serves {
    kind: String,
    /// Labels its model can report; empty: any (an open vocabulary without a fixed list).
    vocabulary: Vec<String>,
    /// Whether its detections carry region embeddings.
    embeddings: bool,
    execution_provider: String,
}

impl Serves {
    fn of(profile: &Profile) -> Self {
        let d = &profile.detector;
        let (vocabulary, provider, embeddings) = match d.kind.as_str() {
            YOLOX_DETECTOR => {
                (d.yolox.class_map.values().cloned().collect(), d.yolox.execution_provider, d.region_encoder.is_some())
            }
            OPEN_VOCAB_DETECTOR => {
                let p = &d.open_vocab.prompts;
                let embeddings = d.region_encoder.is_some() || d.open_vocab.outputs.region_embeddings.is_some();
                (p.objects.iter().chain(&p.parts).cloned().collect(), d.open_vocab.execution_provider, embeddings)
            }
            _ => (Vec::new(), None, d.region_encoder.is_some()),
        };
        let provider = provider.unwrap_or(profile.onnx.execution_provider);
        Self { kind: d.kind.clone(), vocabulary, embeddings, execution_provider: provider.as_str().to_owned() }
    }

    /// Why this worker cannot serve `contract`, if it cannot.
    fn refuses(&self, contract: &Contract) -> Option<String> {
        if contract.model != self.kind {
            return Some(format!("model {:?}: this worker runs {:?}", contract.model, self.kind));
        }
        if !self.vocabulary.is_empty()
            && let Some(prompt) = contract.prompts.iter().find(|p| !self.vocabulary.contains(p))
        {
            return Some(format!(
                "prompt {prompt:?} is not in this worker's vocabulary ({})",
                self.vocabulary.join(", ")
            ));
        }
        if contract.embedding_dim > 0 && !self.embeddings {
            return Some(format!(
                "embeddings of dimension {} asked; this worker's detector makes none (set [detector.region_encoder])",
                contract.embedding_dim
            ));
        }
        None
    }
}

fn serve(
    profile: &Profile,
    backends: &op3dsg_runtime::backend::Backends,
    id: &str,
    prefixes: &[String],
) -> Result<(), String> {
    let opened = OpenedSource { source: Box::new(NoFrames), side_channel: None };
    let factory: DetectorFactory =
        backends.prepare_detectors(profile, &profile.detector.kind, &opened, None).map_err(|e| e.to_string())?;
    let serves = Arc::new(Serves::of(profile));
    let workers = profile.detector.workers;
    let session_config = profile.zenoh.session_config().map_err(|(key, e)| format!("{key}: {e}"))?;
    let session = zenoh::open(session_config)
        .wait()
        .map_err(|e| format!("zenoh: the session did not open (zenoh.listen, zenoh.connect): {e}"))?;
    let stop = Arc::new(AtomicBool::new(false));
    let handler_stop = stop.clone();
    ctrlc::set_handler(move || handler_stop.store(true, Ordering::SeqCst))
        .map_err(|e| format!("signal handler: {e}"))?;

    let load = Arc::new(Load::default());
    let (jobs_tx, jobs_rx) = crossbeam_channel::bounded::<Query>(workers * 2);
    let mut declared = Vec::new();
    let mut tokens = Vec::new();
    for prefix in prefixes {
        let key = worker_key(prefix, id);
        let (tx, busy_load, busy_id) = (jobs_tx.clone(), load.clone(), id.to_owned());
        let requests = session
            .declare_queryable(request_key(&key))
            .callback(move |query| {
                if let Err(crossbeam_channel::TrySendError::Full(query)) = tx.try_send(query) {
                    busy_load.busy.fetch_add(1, Ordering::Relaxed);
                    refuse(&query, &busy_id, "busy: every detection thread is taken".to_owned());
                }
            })
            .wait()
            .map_err(|e| format!("declaring {}: {e}", request_key(&key)))?;
        let (status_load, status_serves, status_id) = (load.clone(), serves.clone(), id.to_owned());
        let all_prefixes = prefixes.to_vec();
        let status = session
            .declare_queryable(format!("{key}/status"))
            .callback(move |query| {
                let body = status_json(&status_id, &status_serves, &status_load, workers, &all_prefixes);
                let _ = query.reply(query.key_expr().clone(), body.to_string()).wait();
            })
            .wait()
            .map_err(|e| format!("declaring {key}/status: {e}"))?;
        declared.push(requests);
        declared.push(status);
        tokens.push(announce(&session, prefix, id)?);
    }
    drop(jobs_tx);
    let mut threads = Vec::new();
    for worker in 0..workers {
        let (jobs, load, serves, stop, id) =
            (jobs_rx.clone(), load.clone(), serves.clone(), stop.clone(), id.to_owned());
        let mut detector = factory(worker as u32);
        let thread = std::thread::Builder::new()
            .name(format!("op3dsg-detectd-{worker}"))
            .spawn(move || {
                let mut out = Vec::new();
                while !stop.load(Ordering::Relaxed) {
                    let Ok(query) = jobs.recv_timeout(Duration::from_millis(50)) else { continue };
                    answer(&query, &id, detector.as_mut(), &serves, &load, &mut out);
                }
            })
            .map_err(|e| format!("thread op3dsg-detectd-{worker}: {e}"))?;
        threads.push(thread);
    }
    info!(id, prefixes = ?prefixes, kind = %serves.kind, execution_provider = %serves.execution_provider, workers, "serving detection");
    // Under systemd (Type=notify, systemd/op3dsg-detectd.service): ready once every key is
    // declared; a no-op without $NOTIFY_SOCKET.
    let serving = format!("{} on {} serving {}", serves.kind, serves.execution_provider, prefixes.join(", "));
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready, sd_notify::NotifyState::Status(&serving)]);
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
    drop(declared);
    drop(tokens);
    for thread in threads {
        let _ = thread.join();
    }
    info!(status = %status_json(id, &serves, &load, workers, prefixes), "stopping");
    let _ = session.close().wait();
    Ok(())
}

/// Detects on one request and replies.
fn answer(
    query: &Query,
    id: &str,
    detector: &mut dyn op3dsg_runtime::perception::Detector,
    serves: &Serves,
    load: &Load,
    out: &mut Vec<op3dsg_runtime::perception::Detection>,
) {
    load.requests.fetch_add(1, Ordering::Relaxed);
    let bytes = query.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
    let request = match wire::decode_request(&bytes) {
        Ok(request) => request,
        Err(e) => {
            load.refusals.fetch_add(1, Ordering::Relaxed);
            warn!(error = %e, "a request that is not one; refused");
            refuse(query, id, format!("not a request: {e}"));
            return;
        }
    };
    if let Some(why) = serves.refuses(&request.contract) {
        load.refusals.fetch_add(1, Ordering::Relaxed);
        warn!(frame_seq = request.frame.seq, why, "request refused");
        refuse(query, id, why);
        return;
    }
    let started = Instant::now();
    let body = match detect(detector, &request.frame, out) {
        Ok(()) => {
            let elapsed = started.elapsed();
            load.detect.lock().unwrap_or_else(std::sync::PoisonError::into_inner).record(elapsed);
            let embedding_dim = out
                .iter()
                .find_map(|d| d.semantic_feature.as_ref())
                .map_or(0, |f| f.len().min(u16::MAX as usize) as u16);
            ReplyBody::Detections {
                detect_us: elapsed.as_micros().min(u128::from(u32::MAX)) as u32,
                embedding_dim,
                detections: std::mem::take(out),
            }
        }
        Err(e) => {
            load.failures.fetch_add(1, Ordering::Relaxed);
            warn!(frame_seq = request.frame.seq, error = %e, "detection failed");
            ReplyBody::Failed(e.to_string())
        }
    };
    let mut reply = Reply { request_id: request.request_id, frame_seq: request.frame.seq, worker: id.to_owned(), body };
    faults::apply(&mut reply);
    let mut bytes = Vec::new();
    if let Err(e) = wire::encode_reply(&mut bytes, &reply) {
        load.failures.fetch_add(1, Ordering::Relaxed);
        refuse(query, id, format!("reply not encodable: {e}"));
        return;
    }
    faults::corrupt(&mut bytes);
    if query.reply(query.key_expr().clone(), bytes).wait().is_ok() {
        load.replies.fetch_add(1, Ordering::Relaxed);
    }
}

/// Answers `query` with a refusal saying `why`.
fn refuse(query: &Query, id: &str, why: String) {
    let reply = Reply { request_id: 0, frame_seq: 0, worker: id.to_owned(), body: ReplyBody::Refused(why) };
    let mut bytes = Vec::new();
    if wire::encode_reply(&mut bytes, &reply).is_ok() {
        let _ = query.reply(query.key_expr().clone(), bytes).wait();
    }
}

fn status_json(id: &str, serves: &Serves, load: &Load, workers: usize, prefixes: &[String]) -> serde_json::Value {
    let (p50, p99) = {
        let h = load.detect.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        (h.quantile_us(0.5) / 1e3, h.quantile_us(0.99) / 1e3)
    };
    let n = |c: &AtomicU64| c.load(Ordering::Relaxed);
    serde_json::json!({
        "id": id,
        "model": serves.kind,
        "vocabulary": serves.vocabulary,
        "embeddings": serves.embeddings,
        "execution_provider": serves.execution_provider,
        "workers": workers,
        "serves": prefixes,
        "requests": n(&load.requests),
        "replies": n(&load.replies),
        "refusals": n(&load.refusals),
        "failures": n(&load.failures),
        "busy": n(&load.busy),
        "detect_p50_ms": p50,
        "detect_p99_ms": p99,
    })
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_owned())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "detectd".to_owned())
}

/// The frame source a worker has: none (its frames come in requests). The detectors the worker
/// runs never read their source.
struct NoFrames;

impl FrameSource for NoFrames {
    fn intrinsics(&self) -> Intrinsics {
        Intrinsics::d435i_640x480()
    }
    fn kind(&self) -> SourceKind {
        SourceKind::Other
    }
    fn next_frame(&mut self, _frame: &mut Frame) -> Result<SourceStatus, SourceError> {
        Ok(SourceStatus::EndOfStream)
    }
    fn describe(&self) -> String {
        "keyframes from Zenoh requests".to_owned()
    }
}

/// Test faults (`--features fault-hooks` only): `OP3DSG_DETECTD_FAULT` = `garbage` (bytes that
/// are no reply), `wrong_id`, `mask_size`, `embedding_dim`, or `late` (replies after
/// `OP3DSG_DETECTD_FAULT_DELAY_MS`, default 2000).
#[cfg(feature = "fault-hooks")]
mod faults {
    use op3dsg_ipc_types::NodeKind;
    use op3dsg_runtime::perception::remote::wire::{Reply, ReplyBody};
    use op3dsg_runtime::perception::{Detection, Mask};

    /// A small detection in the image's corner.
    fn bogus() -> Detection {
        let mask = Mask { x0: 0, y0: 0, width: 2, height: 2, data: vec![1; 4] };
        Detection { label: "chair".into(), kind: NodeKind::Object, score: 0.9, mask, semantic_feature: None }
    }

    fn fault() -> String {
        std::env::var("OP3DSG_DETECTD_FAULT").unwrap_or_default()
    }

    pub fn apply(reply: &mut Reply) {
        match fault().as_str() {
            "wrong_id" => reply.request_id += 1000,
            "embedding_dim" => {
                if let ReplyBody::Detections { embedding_dim, detections, .. } = &mut reply.body {
                    *embedding_dim = 7;
                    detections.push(bogus());
                    detections.iter_mut().for_each(|d| d.semantic_feature = Some(vec![0.5; 7]));
                }
            }
            "mask_size" => {
                if let ReplyBody::Detections { detections, .. } = &mut reply.body {
                    detections.push(Detection { mask: Mask { x0: 100_000, ..bogus().mask }, ..bogus() });
                }
            }
            "late" => {
                let ms =
                    std::env::var("OP3DSG_DETECTD_FAULT_DELAY_MS").ok().and_then(|v| v.parse().ok()).unwrap_or(2000);
                std::thread::sleep(std::time::Duration::from_millis(ms));
            }
            _ => {}
        }
    }

    pub fn corrupt(bytes: &mut Vec<u8>) {
        if fault() == "garbage" {
            bytes.truncate(bytes.len() / 2);
            bytes.extend_from_slice(b"garbage");
        }
    }
}

#[cfg(not(feature = "fault-hooks"))]
mod faults {
    use op3dsg_runtime::perception::remote::wire::Reply;

    pub fn apply(_reply: &mut Reply) {}
    pub fn corrupt(_bytes: &mut [u8]) {}
}
