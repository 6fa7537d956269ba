//! # op3dsg cross-process test support
//!
//! Starts the real `op3dsgd` binary as a child process under an isolated iceoryx2 prefix and
//! kills it when the handle drops, so a failing test never leaves a daemon behind.
//!
//! ```no_run
//! let daemon = op3dsg_tests::Daemon::start("op3dsg-doc", &["--set", "source.rate_hz=60"]);
//! let mut graphs = daemon.graph_subscriber("doc-graphs");
//! let mut health = daemon.health_subscriber("doc-health");
//! ```
//!
//! The subscribers are the planner client library's (`op3dsg_ipc_types::client`), so these
//! tests read the daemon exactly as a planner does.

pub mod netfaults;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use op3dsg_ipc_types::iceoryx2::node::Node;
use op3dsg_ipc_types::iceoryx2::port::subscriber::Subscriber;
use op3dsg_ipc_types::iceoryx2::prelude::ServiceName;
use op3dsg_ipc_types::iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use op3dsg_ipc_types::services::{IpcService, occupancy_service_name};
use op3dsg_ipc_types::{GraphSubscriber, Health, HealthSubscriber, OccupancyHeader};

static NEXT: AtomicUsize = AtomicUsize::new(0);

/// Whether this process runs as root (the tests that switch users, install into a scratch root or
/// make a network namespace need it; CI runs as root).
pub fn is_root() -> bool {
    op3dsg_ipc_types::access::effective_uid() == 0
}

/// Runs the calling test in a child process of its own iceoryx2 root, for tests whose daemon must
/// be the only one in its root (a daemon cleans up the dead nodes of its whole root, so a daemon of
/// a test running beside it could clean up first). Returns `true` in that child, which then runs
/// the test's body; in the test runner's process it starts the child (this test binary,
/// `--exact <test>`, `$OP3DSG_IPC_ROOT` a scratch folder), asserts that it passed and returns
/// `false`. `test` is the test's path in its binary (`faults_planner::the_test`).
pub fn in_own_ipc_root(test: &str) -> bool {
    const CHILD: &str = "OP3DSG_TEST_OWN_ROOT";
    if std::env::var_os(CHILD).is_some() {
        return true;
    }
    let root = tempfile::tempdir().expect("a scratch iceoryx2 root");
    // Only its owner may use an iceoryx2 root (op3dsg_ipc_types::access).
    std::fs::set_permissions(root.path(), std::os::unix::fs::PermissionsExt::from_mode(0o700))
        .expect("chmod 0700 the scratch root");
    let status = Command::new(std::env::current_exe().expect("test binary path"))
        .args(["--exact", test, "--nocapture", "--test-threads=1"])
        .env(CHILD, "1")
        .env(op3dsg_ipc_types::access::IPC_ROOT_ENV, root.path())
        .status()
        .expect("start the test in its own iceoryx2 root");
    assert!(status.success(), "{test} in its own iceoryx2 root {}: {status}", root.path().display());
    false
}

/// A prefix no other test or test run uses.
pub fn unique_prefix(name: &str) -> String {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    format!("op3dsg-x-{name}-{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::SeqCst))
}

/// Path of a workspace binary built next to this test executable (`target/<profile>/<name>`).
pub fn binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test> → target/<profile>/<name>
    let dir = exe.parent().and_then(|d| d.parent()).expect("target directory");
    let path = dir.join(name);
    assert!(path.exists(), "{} not built; run `cargo build --workspace` first", path.display());
    path
}

/// A running `op3dsgd`, killed on drop.
#[derive(Debug)]
pub struct Daemon {
    /// The child process.
    pub child: Child,
    /// Its iceoryx2 prefix.
    pub prefix: String,
}

impl Daemon {
    /// Starts `op3dsgd --prefix <prefix> <args>` with logs at warn.
    pub fn start(prefix: &str, args: &[&str]) -> Self {
        Self::start_with_env(prefix, args, &[])
    }

    /// [`Self::start`] with extra environment variables (`NOTIFY_SOCKET`, test fault hooks).
    pub fn start_with_env(prefix: &str, args: &[&str], env: &[(&str, &std::ffi::OsStr)]) -> Self {
        let child = Command::new(binary("op3dsgd"))
            .arg("--prefix")
            .arg(prefix)
            .args(args)
            .env("OP3DSG_LOG", std::env::var("OP3DSG_LOG").unwrap_or_else(|_| "warn".into()))
            .envs(env.iter().map(|(k, v)| (*k, *v)))
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn op3dsgd");
        Self { child, prefix: prefix.to_owned() }
    }

    /// Sends SIGTERM (the orderly shutdown ladder) through `kill(1)`.
    pub fn sigterm(&self) {
        let status = Command::new("kill").arg("-TERM").arg(self.child.id().to_string()).status().expect("run kill");
        assert!(status.success(), "kill -TERM {} failed", self.child.id());
    }

    /// Waits up to `timeout` for the process to exit; its status, `None` when it is still running.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// A graph subscriber (`graph` and `graph_updated`) on this daemon's services, waiting up to
    /// 30 s for them.
    pub fn graph_subscriber(&self, node: &str) -> GraphSubscriber {
        GraphSubscriber::open_wait(&self.prefix, node, Duration::from_secs(30)).expect("daemon graph services appear")
    }

    /// A health subscriber on this daemon's `health` service, waiting up to 30 s for it.
    pub fn health_subscriber(&self, node: &str) -> HealthSubscriber {
        HealthSubscriber::open_wait(&self.prefix, node, Duration::from_secs(30)).expect("daemon health service appears")
    }

    /// Sends SIGKILL and reaps the process.
    pub fn kill_9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.kill_9();
        }
    }
}

/// The `.mcap` files directly in `dir`, sorted by name (the recorder names them by start time);
/// none when `dir` does not exist.
pub fn mcap_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|entries| entries.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| p.extension().is_some_and(|e| e == "mcap"));
    files.sort();
    files
}

/// Polls `f` every 20 ms until it returns `Some`, or panics with `what` after `timeout`.
pub fn wait_for<T>(what: &str, timeout: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out after {timeout:?} waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The first health record `pick` accepts, polled every 20 ms; panics naming `what` after
/// `timeout`.
pub fn health_where(
    health: &mut HealthSubscriber,
    what: &str,
    timeout: Duration,
    pick: impl Fn(&Health) -> bool,
) -> Health {
    wait_for(what, timeout, || health.latest().ok().flatten().filter(|h| pick(h)))
}

/// The newest health record once its `frames_captured` is above `above`.
pub fn health_with_frames_above(health: &mut HealthSubscriber, above: u64, timeout: Duration) -> Health {
    wait_for(&format!("health with frames_captured > {above}"), timeout, || {
        health.latest().ok().flatten().filter(|h| h.frames_captured > above)
    })
}

/// `<prefix>/occupancy`, opened as any client opens it, once the daemon has created it.
pub fn open_occupancy_service(node: &Node<IpcService>, prefix: &str) -> PortFactory<IpcService, [i8], OccupancyHeader> {
    let name = ServiceName::new(&occupancy_service_name(prefix)).expect("service name");
    wait_for("the occupancy service", Duration::from_secs(60), || {
        node.service_builder(&name).publish_subscribe::<[i8]>().user_header::<OccupancyHeader>().open().ok()
    })
}

/// Takes every occupancy sample `subscriber` holds; the newest (header and cells) lands in `last`.
pub fn latest_map(
    subscriber: &Subscriber<IpcService, [i8], OccupancyHeader>,
    last: &mut Option<(OccupancyHeader, Vec<i8>)>,
) {
    while let Ok(Some(sample)) = subscriber.receive() {
        *last = Some((*sample.user_header(), sample.payload().to_vec()));
    }
}
