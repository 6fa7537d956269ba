//! What the remote detection tests share: `op3dsg-detectd` workers as child processes, the
//! daemon's arguments for remote detection, and a Zenoh client of its `<prefix>/detect_status`.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use op3dsg_tests::{binary, wait_for};
use serde_json::Value;
use zenoh::Wait;

/// A free loopback port.
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("bind a free port").local_addr().expect("port").port()
}

/// `profiles/replay-icl.toml` (YOLOX-nano), when the shared development data is there.
pub fn profile() -> Option<PathBuf> {
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1/rgb.txt")?;
    op3dsg_shared_data::shared_data("models/yolox_nano/yolox_nano.onnx")?;
    Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles/replay-icl.toml"))
}

/// A running `op3dsg-detectd`, killed on drop.
pub struct Worker(Child);

impl Worker {
    /// A worker `id` connecting to the daemon's Zenoh `port` on loopback, serving `key_prefix`;
    /// `fault`: environment of the fault hooks.
    pub fn start(profile: &Path, port: u16, key_prefix: &str, id: &str, fault: &[(&str, &str)]) -> Self {
        Self::start_in(&[], profile, port, key_prefix, id, fault)
    }

    /// As [`Self::start`], with more `--set` overrides of the worker's profile.
    pub fn start_with(profile: &Path, port: u16, key_prefix: &str, id: &str, sets: &[&str]) -> Self {
        Self::start_full(&[], profile, port, key_prefix, id, &[], sets)
    }

    /// As [`Self::start`], run through `wrapper` (`ip netns exec NAME`).
    pub fn start_in(
        wrapper: &[&str],
        profile: &Path,
        port: u16,
        key_prefix: &str,
        id: &str,
        fault: &[(&str, &str)],
    ) -> Self {
        Self::start_full(wrapper, profile, port, key_prefix, id, fault, &[])
    }

    fn start_full(
        wrapper: &[&str],
        profile: &Path,
        port: u16,
        key_prefix: &str,
        id: &str,
        fault: &[(&str, &str)],
        sets: &[&str],
    ) -> Self {
        let detectd = binary("op3dsg-detectd");
        let mut command = match wrapper.split_first() {
            Some((program, args)) => {
                let mut c = Command::new(program);
                c.args(args).arg(&detectd);
                c
            }
            None => Command::new(&detectd),
        };
        let child = command
            .arg("--profile")
            .arg(profile)
            .args(["--set", &format!("zenoh.key_prefix=\"{key_prefix}\"")])
            .args(["--set", &format!("zenoh.connect=[\"tcp/127.0.0.1:{port}\"]")])
            .args(["--set", "detector.workers=1", "--id", id])
            .args(sets.iter().flat_map(|set| ["--set", set]))
            .env("OP3DSG_LOG", "warn")
            .envs(fault.iter().copied())
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn op3dsg-detectd");
        Self(child)
    }

    /// Kills it and reaps it.
    pub fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The daemon's arguments for remote detection to `workers` (ids) under `key_prefix`.
pub fn remote_args(port: u16, key_prefix: &str, workers: &[&str], extra: &[&str]) -> Vec<String> {
    let keys: Vec<String> = workers.iter().map(|w| format!("\"{key_prefix}/detect/{w}\"")).collect();
    let mut args: Vec<String> = [
        "detector.kind=\"remote\"".to_owned(),
        format!("zenoh.key_prefix=\"{key_prefix}\""),
        format!("zenoh.listen=[\"tcp/127.0.0.1:{port}\"]"),
        format!("detector.remote.workers=[{}]", keys.join(", ")),
        "detector.remote.wait_for_workers_ms=60000".to_owned(),
    ]
    .into_iter()
    .chain(extra.iter().map(|s| (*s).to_owned()))
    .flat_map(|set| ["--set".to_owned(), set])
    .collect();
    args.push("--log".to_owned());
    args.push("warn".to_owned());
    args
}

/// A Zenoh client of the daemon's session, to read `<prefix>/detect_status`.
pub struct Status {
    session: zenoh::Session,
    key: String,
}

impl Status {
    pub fn connect(port: u16, key_prefix: &str) -> Self {
        let mut config = zenoh::Config::default();
        for (key, value) in [
            ("mode", "\"client\"".to_owned()),
            ("connect/endpoints", format!("[\"tcp/127.0.0.1:{port}\"]")),
            ("scouting/multicast/enabled", "false".to_owned()),
        ] {
            config.insert_json5(key, &value).expect("zenoh config");
        }
        let session = wait_for("a Zenoh session to the daemon", Duration::from_secs(60), || {
            zenoh::open(config.clone()).wait().ok()
        });
        Self { session, key: format!("{key_prefix}/detect_status") }
    }

    /// The daemon's remote-detection figures, once it answers.
    pub fn read(&self) -> Value {
        wait_for("the daemon's detect_status", Duration::from_secs(60), || self.try_read())
    }

    /// The figures, if the daemon answers now.
    pub fn try_read(&self) -> Option<Value> {
        let replies = self.session.get(&self.key).timeout(Duration::from_secs(2)).wait().ok()?;
        let reply = replies.recv().ok()?;
        let sample = reply.result().ok()?;
        serde_json::from_slice(&sample.payload().to_bytes()).ok()
    }

    pub fn worker(&self, key: &str, field: &str) -> u64 {
        self.read()["workers"][key][field].as_u64().unwrap_or(0)
    }

    /// Waits until `pick` holds for the figures; returns them and how long it took.
    pub fn until(&self, what: &str, timeout: Duration, pick: impl Fn(&Value) -> bool) -> (Value, Duration) {
        let started = Instant::now();
        let status = wait_for(what, timeout, || {
            std::thread::sleep(Duration::from_millis(50));
            Some(self.read()).filter(&pick)
        });
        (status, started.elapsed())
    }
}

/// The daemon's remote-detection figures read while it runs, the newest kept: its
/// `detect_status` queryable goes when the sequence's last keyframe is detected.
pub struct StatusWatch {
    latest: Arc<Mutex<Value>>,
    watching: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<()>,
}

impl StatusWatch {
    pub fn start(status: Status) -> Self {
        let latest = Arc::new(Mutex::new(Value::Null));
        let watching = Arc::new(AtomicBool::new(true));
        let thread = {
            let (latest, watching) = (latest.clone(), watching.clone());
            std::thread::Builder::new()
                .name("detect-status".to_owned())
                .spawn(move || {
                    while watching.load(Ordering::Relaxed) {
                        if let Some(figures) = status.try_read() {
                            *latest.lock().expect("lock") = figures;
                        }
                        std::thread::sleep(Duration::from_millis(100));
                    }
                })
                .expect("spawn the status watcher")
        };
        Self { latest, watching, thread }
    }

    /// Stops watching; the newest figures read.
    pub fn finish(self) -> Value {
        self.watching.store(false, Ordering::Relaxed);
        self.thread.join().expect("status watcher");
        self.latest.lock().expect("lock").clone()
    }
}

/// The final graph of a daemon on a finite recording: waits up to `timeout` until `frames`
/// frames are captured, then until the graph version holds still; `op3dsg dump --json` then.
pub fn final_graph(daemon: &op3dsg_tests::Daemon, frames: u64, timeout: Duration) -> Value {
    let mut health = daemon.health_subscriber("final-graph-health");
    op3dsg_tests::health_where(&mut health, "every frame of the recording captured", timeout, |h| {
        h.frames_captured >= frames
    });
    let mut last = crate::zenoh_common::dump(&daemon.prefix);
    loop {
        std::thread::sleep(Duration::from_secs(2));
        let now = crate::zenoh_common::dump(&daemon.prefix);
        if now["graph_version"] == last["graph_version"] {
            return now;
        }
        last = now;
    }
}
