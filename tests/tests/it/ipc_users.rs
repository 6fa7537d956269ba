//! Who can attach to the daemon, with real processes of four identities made with `setpriv`
//! (no accounts needed; the test runs as root, as CI does):
//!
//! - the daemon runs as uid A in its own IPC root (made 0700 for A, as the unit's
//!   `RuntimeDirectory=` does);
//! - a planner as A in other processes reads the graph (equal to `op3dsg dump --json` run as A),
//!   sends poses the daemon adopts (the stand-in navigation stack `op3dsg-test-nav`; the daemon
//!   takes poses only from `<prefix>/pose`), and gets query answers; the Python client as A does
//!   the same;
//! - uid B, in A's group, and uid C, outside it, are refused with a message naming the root's
//!   owner: iceoryx2 0.10 gives every file and segment an owner-only mode fixed in its code, so a
//!   group cannot share a graph (`op3dsg_ipc_types::access`); root is refused too, so it never
//!   leaves root-owned files that would block A;
//! - nothing of A's in the root or in `/dev/shm` is open to other users, but iceoryx2's 16-byte
//!   node counter (`*.global_mgmt`, 0666 by design);
//! - `kill -9` and a restart as A: the attached planner sees the new instance;
//! - a daemon uid D started by hand serves in D's per-user root `/tmp/op3dsg-<D>`: a planner of
//!   C (the command line, the Python client) finds none in its own root and is told of D's.
//!
//! The binaries, the ONNX Runtime library, the text-encoder model, the librealsense libraries
//! and the Python packages are linked (or copied) into a scratch folder every identity can read,
//! since the checkout may live where uid A cannot look.

use std::io::{BufRead, BufReader};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{binary, is_root, unique_prefix};

/// The daemon's user, a member of its group, an outsider (no accounts: bare ids).
const A: u32 = 47_101;
const B: u32 = 47_102;
const C: u32 = 47_103;
/// A user who starts a daemon by hand, in its per-user root `/tmp/op3dsg-<uid>`.
const D: u32 = 47_104;

const REPO: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/..");

#[test]
fn only_the_daemons_user_attaches_and_nothing_is_open_to_others() {
    let scratch = Scratch::new();
    let prefix = unique_prefix("users");
    let mut daemon = Killed(scratch.daemon(&prefix));
    let _nav = Killed(scratch.spawn_as(A, &[&scratch.bin("op3dsg-test-nav"), "--prefix", &prefix], Stdio::piped()));

    // A planner of A reads the graph the daemon built from A's poses, equal to the dump.
    let (planner, dumped) = scratch.meet_at_one_version(&prefix);
    let nodes: Vec<&str> = planner.lines().filter(|l| l.starts_with("node ")).collect();
    assert!(!nodes.is_empty(), "{planner}");
    assert_eq!(nodes.len(), dumped["nodes"].as_array().expect("test set-up").len(), "{planner}");
    for (line, node) in nodes.iter().zip(dumped["nodes"].as_array().expect("test set-up")) {
        let parent = node["parent"].as_u64().map_or(-1, |p| p as i64);
        let expected = format!(
            "node {} {} {parent} {}",
            node["id"],
            node["kind"].as_str().expect("test set-up"),
            node["label"].as_str().expect("test set-up")
        );
        assert_eq!(*line, expected);
    }
    let health = scratch.run_as(A, &[&scratch.bin("op3dsg"), "--prefix", &prefix, "health", "--json"]);
    let health: serde_json::Value = serde_json::from_str(&health.stdout).expect("health JSON");
    assert!(health["poses"]["accepted"].as_u64().unwrap_or(0) > 0, "the daemon adopted A's poses: {health}");

    let hits = scratch.run_as(A, &[&scratch.bin("op3dsg-test-planner"), "--prefix", &prefix, "query", "wash my hands"]);
    assert!(hits.ok && hits.stdout.lines().any(|l| l.starts_with("hit ")), "{hits:?}");

    scratch.python_as_a(&prefix, &dumped);
    let refused_poses = || {
        let out = scratch.run_as(A, &[&scratch.bin("op3dsg"), "--prefix", &prefix, "health", "--json"]);
        let health: serde_json::Value = serde_json::from_str(&out.stdout).expect("health JSON");
        (health["poses"]["non_finite"].as_u64().unwrap_or(0), health["poses"].to_string())
    };
    let counted = Instant::now();
    loop {
        let (refused, poses) = refused_poses();
        if refused > 0 {
            break;
        }
        assert!(counted.elapsed() < Duration::from_secs(30), "the daemon counts the Python client's NaN pose: {poses}");
        std::thread::sleep(Duration::from_millis(300));
    }

    // B (in A's group) and C are refused, naming the owner; so is root.
    for (uid, groups) in [(B, Some(A)), (C, None)] {
        let refused = scratch.run_as_with(
            uid,
            groups,
            &[&scratch.bin("op3dsg"), "--prefix", &prefix, "dump", "--timeout-s", "2"],
        );
        assert!(!refused.ok, "uid {uid} must be refused: {refused:?}");
        let expected = format!(
            "no permission: IPC root {} belongs to uid {A}, this process runs as uid {uid}",
            scratch.root.display()
        );
        assert!(refused.stderr.contains(&expected), "uid {uid}: {}", refused.stderr);
        assert!(refused.stderr.contains("make this user the service user"), "{}", refused.stderr);
    }
    let as_root = Command::new(binary("op3dsg"))
        .env("OP3DSG_IPC_ROOT", &scratch.root)
        .args(["--prefix", &prefix, "dump", "--timeout-s", "2"])
        .output()
        .expect("op3dsg as root");
    let stderr = String::from_utf8_lossy(&as_root.stderr);
    assert!(
        !as_root.status.success() && stderr.contains(&format!("belongs to uid {A}, this process runs as 'root'")),
        "{stderr}"
    );

    assert_nothing_open_to_others(&scratch.root);

    // kill -9, restart as A: the planner attached before sees the new instance.
    let mut follower = Killed(scratch.spawn_as(
        A,
        &[&scratch.bin("op3dsg-test-planner"), "--prefix", &prefix, "follow", "120"],
        Stdio::piped(),
    ));
    let mut lines = BufReader::new(follower.0.stdout.take().expect("test set-up")).lines();
    let first = lines.next().expect("the follower's first line").expect("read");
    assert!(first.starts_with("instance "), "{first}");
    daemon.kill_9();
    let _restarted = Killed(scratch.daemon(&prefix));
    let next = lines.next().expect("the follower's second line").expect("read");
    assert!(next.starts_with("restarted ") && next != first.replace("instance", "restarted"), "{first} / {next}");
    assert!(follower.0.wait().expect("follower").success());
}

/// A daemon another user started by hand serves in that user's per-user root
/// (`/tmp/op3dsg-<uid>`); a planner of this user finds nothing in its own and is told where to
/// look: the Rust command line and the Python client both name the other user's root and the fix.
#[test]
fn a_planner_of_another_user_is_told_whose_root_serves() {
    let scratch = Scratch::new();
    let home = scratch.path.join("home");
    std::os::unix::fs::chown(&home, Some(D), Some(D)).expect("test set-up");
    let _cleanup = [D, C].map(|uid| RemoveOnDrop(PathBuf::from(format!("/tmp/op3dsg-{uid}"))));
    let prefix = unique_prefix("byhand");
    let in_own_root = |uid: u32, argv: &[&str]| {
        let mut command = scratch.command_as(uid, None, argv);
        command.env_remove("OP3DSG_IPC_ROOT");
        command
    };
    let _daemon = Killed(
        in_own_root(D, &[&scratch.bin("op3dsgd"), "--prefix", &prefix])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .expect("start op3dsgd as uid D"),
    );
    // The daemon serves in D's own root.
    let started = Instant::now();
    loop {
        let out = in_own_root(D, &[&scratch.bin("op3dsg"), "--prefix", &prefix, "dump", "--timeout-s", "2"])
            .output()
            .expect("setpriv");
        if out.status.success() {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "{}", String::from_utf8_lossy(&out.stderr));
        std::thread::sleep(Duration::from_millis(300));
    }
    let expected = "other users' roots exist (";
    let names_d = format!("/tmp/op3dsg-{D} of uid {D}");
    let service_root_exists = Path::new("/run/op3dsg").exists();

    let out = in_own_root(C, &[&scratch.bin("op3dsg"), "--prefix", &prefix, "dump", "--timeout-s", "2"])
        .output()
        .expect("setpriv");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "uid {C} has no daemon in its own root: {stderr}");
    assert!(
        stderr.contains(&format!("no op3dsgd is serving under prefix '{prefix}' in IPC root /tmp/op3dsg-{C}")),
        "{stderr}"
    );
    if service_root_exists {
        assert!(stderr.contains("the installed service's root /run/op3dsg belongs to"), "{stderr}");
    } else {
        assert!(stderr.contains(expected) && stderr.contains(&names_d), "{stderr}");
        assert!(stderr.contains(&format!("sudo -u #{D}")), "{stderr}");
    }

    let python = python();
    let script = format!("import op3dsg; op3dsg.GraphClient({prefix:?}, timeout=2)");
    let out = in_own_root(C, &[&python, "-c", &script]).output().expect("setpriv");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("NotServingError"), "{stderr}");
    assert!(stderr.contains(&format!("in IPC root /tmp/op3dsg-{C}")), "{stderr}");
    if service_root_exists {
        assert!(stderr.contains("the installed service's root /run/op3dsg belongs to"), "{stderr}");
    } else {
        assert!(stderr.contains(expected) && stderr.contains(&names_d), "{stderr}");
        assert!(stderr.contains(&format!("sudo -u #{D}")), "{stderr}");
    }
}

/// A folder removed (with what is in it) when dropped, also when the test fails.
struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A child process killed (SIGKILL) and reaped when dropped, also when the test fails.
struct Killed(Child);

impl Killed {
    fn kill_9(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for Killed {
    fn drop(&mut self) {
        self.kill_9();
    }
}

/// Every entry under the root, and every `/dev/shm/op3dsg_*` of uid A, has no permission bit for
/// other users; the only exception is iceoryx2's node counter.
fn assert_nothing_open_to_others(root: &Path) {
    let mut seen = 0;
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("read the root") {
            let path = entry.expect("entry").path();
            let meta = std::fs::symlink_metadata(&path).expect("metadata");
            assert_eq!(meta.mode() & 0o007, 0, "{} is open to others: {:o}", path.display(), meta.mode());
            assert_eq!(meta.uid(), A, "{} belongs to uid {}", path.display(), meta.uid());
            seen += 1;
            if meta.is_dir() {
                stack.push(path);
            }
        }
    }
    assert!(seen > 3, "the root holds the daemon's files");
    let mut segments = 0;
    for entry in std::fs::read_dir("/dev/shm").expect("read /dev/shm") {
        let entry = entry.expect("entry");
        let name = entry.file_name().to_string_lossy().into_owned();
        let meta = entry.metadata().expect("metadata");
        if !name.starts_with(op3dsg_ipc_types::access::ICEORYX2_PREFIX) || meta.uid() != A {
            continue;
        }
        segments += 1;
        if name.ends_with(".global_mgmt") {
            assert!(meta.len() <= 64, "{name}: iceoryx2's node counter holds no data ({} bytes)", meta.len());
            continue;
        }
        assert_eq!(meta.mode() & 0o077, 0, "/dev/shm/{name} is open to others: {:o}", meta.mode());
    }
    assert!(segments > 3, "uid {A}'s segments are in /dev/shm");
}

#[derive(Debug)]
struct Output {
    ok: bool,
    stdout: String,
    stderr: String,
}

/// The scratch folder every identity can read: binaries, libraries, models, Python packages,
/// and uid A's IPC root.
struct Scratch {
    _dir: tempfile::TempDir,
    path: PathBuf,
    root: PathBuf,
}

impl Scratch {
    /// The scratch folder; the tests that use one start processes as other users, so they
    /// must run as root.
    fn new() -> Self {
        assert!(
            is_root(),
            "this test starts processes as other users with setpriv and must run as root (CI does); \
             run it with sudo, or leave it out with --skip ipc_users"
        );
        let dir = tempfile::tempdir().expect("scratch folder");
        let path = dir.path().to_path_buf();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).expect("test set-up");
        for name in ["op3dsgd", "op3dsg", "op3dsg-test-nav", "op3dsg-test-planner"] {
            link_tree(&binary(name), &path.join("bin").join(name));
        }
        let repo = Path::new(REPO);
        link_tree(&repo.join(".models/minilm"), &path.join(".models/minilm"));
        link_tree(&repo.join(".models/onnxruntime"), &path.join(".models/onnxruntime"));
        link_tree(&repo.join(".deps/realsense/lib"), &path.join("lib"));
        link_tree(&repo.join("ipc_types/python/op3dsg"), &path.join("python/op3dsg"));
        let site = site_packages(&repo.join(".venv"));
        for package in ["numpy", "numpy.libs", "iceoryx2", "flatbuffers"] {
            link_tree(&site.join(package), &path.join("python").join(package));
        }
        // A's root, as the unit's RuntimeDirectory= makes it: owned by A, 0700.
        let root = path.join("run");
        std::fs::create_dir(&root).expect("test set-up");
        std::os::unix::fs::chown(&root, Some(A), Some(A)).expect("test set-up");
        std::fs::set_permissions(&root, std::fs::Permissions::from_mode(0o700)).expect("test set-up");
        // A's home, for what libraries keep there (ONNX Runtime's telemetry id).
        let home = path.join("home");
        std::fs::create_dir(&home).expect("test set-up");
        std::os::unix::fs::chown(&home, Some(A), Some(A)).expect("test set-up");
        Self { _dir: dir, path, root }
    }

    fn bin(&self, name: &str) -> String {
        self.path.join("bin").join(name).to_string_lossy().into_owned()
    }

    fn command_as(&self, uid: u32, group: Option<u32>, argv: &[&str]) -> Command {
        let mut command = Command::new("setpriv");
        command.args(["--reuid", &uid.to_string(), "--regid", &uid.to_string()]);
        match group {
            Some(group) => command.args(["--groups", &group.to_string()]),
            None => command.arg("--clear-groups"),
        };
        command
            .arg("--")
            .args(argv)
            .current_dir(&self.path)
            .env("OP3DSG_IPC_ROOT", &self.root)
            .env("LD_LIBRARY_PATH", self.path.join("lib"))
            .env("HOME", self.path.join("home"))
            .env("OP3DSG_LOG", "warn")
            .env("PYTHONPATH", self.path.join("python"))
            .env_remove("OP3DSG_PREFIX");
        command
    }

    fn spawn_as(&self, uid: u32, argv: &[&str], stdout: Stdio) -> Child {
        self.command_as(uid, None, argv).stdin(Stdio::piped()).stdout(stdout).spawn().expect("setpriv")
    }

    fn run_as(&self, uid: u32, argv: &[&str]) -> Output {
        self.run_as_with(uid, None, argv)
    }

    fn run_as_with(&self, uid: u32, group: Option<u32>, argv: &[&str]) -> Output {
        let out = self.command_as(uid, group, argv).output().expect("setpriv");
        Output {
            ok: out.status.success(),
            stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
            stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        }
    }

    /// The daemon as A: the synthetic kitchen with poses only from `<prefix>/pose`, stopping
    /// capture after 120 frames so that clients and the dump meet at one version.
    fn daemon(&self, prefix: &str) -> Child {
        let sets = [
            "pose.source=\"ipc\"",
            "pose.max_wait_ms=3000",
            "source.rate_hz=30",
            "health.period_ms=100",
            "run.max_frames=120",
            "text_encoder.enabled=true",
        ];
        let mut argv = vec![self.bin("op3dsgd"), "--prefix".to_owned(), prefix.to_owned()];
        for set in sets {
            argv.push("--set".to_owned());
            argv.push(set.to_owned());
        }
        let argv: Vec<&str> = argv.iter().map(String::as_str).collect();
        self.command_as(A, None, &argv).stdout(Stdio::null()).spawn().expect("start op3dsgd as uid A")
    }

    /// The planner's graph lines and `op3dsg dump --json`, both run as A, at one version that
    /// stays (capture has ended: the Python client reads the same version after them).
    fn meet_at_one_version(&self, prefix: &str) -> (String, serde_json::Value) {
        let deadline = Instant::now() + Duration::from_secs(180);
        let mut last_version = None;
        loop {
            let planner =
                self.run_as(A, &[&self.bin("op3dsg-test-planner"), "--prefix", prefix, "graph", "--min-nodes", "3"]);
            assert!(planner.ok, "the planner of uid A reads the graph: {planner:?}");
            let dump = self.run_as(A, &[&self.bin("op3dsg"), "--prefix", prefix, "dump", "--json"]);
            assert!(dump.ok, "op3dsg dump as uid A: {dump:?}");
            let dumped: serde_json::Value = serde_json::from_str(&dump.stdout).expect("dump JSON");
            let version: Option<u64> = planner.stdout.split_whitespace().nth(1).and_then(|v| v.parse().ok());
            if dumped["graph_version"].as_u64() == version && version == last_version {
                return (planner.stdout, dumped);
            }
            last_version = version;
            assert!(Instant::now() < deadline, "planner and dump never met at one final version");
            std::thread::sleep(Duration::from_secs(1));
        }
    }

    /// The Python client as A: the graph equal to the dump, a query answered, a pose (NaN: the
    /// daemon counts it on receipt, whether or not frames still come) sent; as C it is refused with the owner's name.
    fn python_as_a(&self, prefix: &str, dumped: &serde_json::Value) {
        let python = python();
        let script = format!(
            r#"
import json, sys, time, op3dsg
client = op3dsg.GraphClient({prefix:?}, timeout=30)
deadline = time.monotonic() + 60
view = None
while time.monotonic() < deadline:
    client.wait_for_update(0.2)
    view = client.latest()
    if view is not None and view.version == {version}:
        break
print(json.dumps({{"version": view.version, "ids": [int(i) for i in view.nodes["id"]],
                   "labels": [view.label(i) for i in range(view.node_count)]}}))
hits = op3dsg.query("wash my hands", prefix={prefix:?}, timeout=30)
print("hits", len(hits.hits))
poses = op3dsg.PosePublisher({prefix:?})
deadline = time.monotonic() + 30
bad = op3dsg.make_pose(1, [float("nan"), 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
while poses.publish_unchecked(bad) == 0:  # until the daemon is connected
    assert time.monotonic() < deadline, "the daemon never received the pose"
    time.sleep(0.2)
time.sleep(1.0)  # the sample lives in this publisher's segment: stay until the daemon took it
print("pose sent")
"#,
            version = dumped["graph_version"],
        );
        let out = self.run_as(A, &[&python, "-c", &script]);
        assert!(out.ok, "the Python client of uid A: {out:?}");
        let first: serde_json::Value =
            serde_json::from_str(out.stdout.lines().next().expect("test set-up")).expect("JSON line");
        assert_eq!(first["version"], dumped["graph_version"]);
        let ids: Vec<u64> = dumped["nodes"]
            .as_array()
            .expect("test set-up")
            .iter()
            .map(|n| n["id"].as_u64().expect("test set-up"))
            .collect();
        let labels: Vec<&str> = dumped["nodes"]
            .as_array()
            .expect("test set-up")
            .iter()
            .map(|n| n["label"].as_str().expect("test set-up"))
            .collect();
        assert_eq!(first["ids"], serde_json::json!(ids));
        assert_eq!(first["labels"], serde_json::json!(labels));
        assert!(out.stdout.contains("pose sent") && !out.stdout.contains("hits 0"), "{out:?}");

        let refused =
            self.run_as(C, &[&python, "-c", &format!("import op3dsg; op3dsg.GraphClient({prefix:?}, timeout=2)")]);
        assert!(!refused.ok && refused.stderr.contains("AccessDeniedError"), "{refused:?}");
        assert!(refused.stderr.contains(&format!("belongs to uid {A}")), "{}", refused.stderr);
    }
}

/// A Python every identity can run: the system's, else the project venv's.
fn python() -> String {
    if Path::new("/usr/bin/python3").exists() {
        "/usr/bin/python3".to_owned()
    } else {
        Path::new(REPO).join(".venv/bin/python").to_string_lossy().into_owned()
    }
}

/// The site-packages folder of a venv.
fn site_packages(venv: &Path) -> PathBuf {
    let lib = venv.join("lib");
    let python = std::fs::read_dir(&lib)
        .unwrap_or_else(|e| panic!("{}: {e} (run ./scripts/setup-python.sh)", lib.display()))
        .filter_map(Result::ok)
        .find(|e| e.file_name().to_string_lossy().starts_with("python"))
        .expect("a python folder in the venv");
    python.path().join("site-packages")
}

/// Hard-links (or, across file systems, copies) `from` to `to`, folders recursively; folders are
/// made 0755.
fn link_tree(from: &Path, to: &Path) {
    let meta = std::fs::metadata(from).unwrap_or_else(|e| panic!("{}: {e}", from.display()));
    if meta.is_dir() {
        std::fs::create_dir_all(to).expect("test set-up");
        std::fs::set_permissions(to, std::fs::Permissions::from_mode(0o755)).expect("test set-up");
        for entry in std::fs::read_dir(from).expect("test set-up") {
            let entry = entry.expect("test set-up");
            link_tree(&entry.path(), &to.join(entry.file_name()));
        }
    } else {
        if let Some(parent) = to.parent() {
            std::fs::create_dir_all(parent).expect("test set-up");
            std::fs::set_permissions(parent, std::fs::Permissions::from_mode(0o755)).expect("test set-up");
        }
        if std::fs::hard_link(from, to).is_err() {
            std::fs::copy(from, to).unwrap_or_else(|e| panic!("copy {}: {e}", from.display()));
        }
    }
}
