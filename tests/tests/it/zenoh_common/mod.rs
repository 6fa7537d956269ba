//! What the Zenoh tests share: the Python consumer (`tests/python/zenoh_consumer.py`) driven
//! over its stdin and stdout, `op3dsg dump --json`, and the comparison of two graphs.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{Daemon, binary, wait_for};
use serde_json::{Value, json};

pub fn python() -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    assert!(path.exists(), "{} missing: run ./scripts/setup-python.sh (scripts/test.sh does)", path.display());
    path
}

pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("bind a free port").local_addr().expect("port").port()
}

/// A consumer process, driven over its stdin and stdout; killed on drop.
pub struct Consumer {
    pub child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

impl Consumer {
    pub fn start(port: u16, key_prefix: &str) -> Self {
        Self::start_in(&[], port, key_prefix)
    }

    /// [`Self::start`] under `wrapper`, a command that runs the one after it (`ip netns exec
    /// NAME`); none: directly.
    pub fn start_in(wrapper: &[&str], port: u16, key_prefix: &str) -> Self {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/zenoh_consumer.py");
        let mut command = match wrapper.split_first() {
            Some((program, args)) => {
                let mut command = Command::new(program);
                command.args(args).arg(python());
                command
            }
            None => Command::new(python()),
        };
        let mut child = command
            .arg(script)
            .args(["--connect", &format!("tcp/127.0.0.1:{port}"), "--prefix", key_prefix])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("run zenoh_consumer.py");
        let stdin = child.stdin.take().expect("stdin");
        let stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let mut consumer = Self { child, stdin, stdout };
        assert_eq!(consumer.read()["ready"], json!(true), "the consumer connects");
        consumer
    }

    pub fn read(&mut self) -> Value {
        let mut line = String::new();
        self.stdout.read_line(&mut line).expect("read the consumer's answer");
        assert!(!line.is_empty(), "the consumer ended (its stderr is above)");
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("consumer answer {line:?}: {e}"))
    }

    /// The consumer's graph once it holds one of `instance_id` at `min_version` or later.
    pub fn state(&mut self, instance_id: u64, min_version: u64) -> Value {
        let command = json!({"cmd": "state", "instance_id": instance_id, "min_version": min_version, "timeout_s": 120});
        writeln!(self.stdin, "{command}").expect("write to the consumer");
        let answer = self.read();
        assert!(answer.get("error").is_none(), "consumer: {answer}");
        answer
    }
}

impl Drop for Consumer {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "{}", json!({"cmd": "quit"}));
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The instance id of the daemon's graphs, from its iceoryx2 graph service.
pub fn instance_of(daemon: &Daemon) -> u64 {
    let mut graphs = daemon.graph_subscriber("zenoh-test-instance");
    wait_for("a first graph over iceoryx2", Duration::from_secs(60), || {
        graphs.latest().ok().flatten().map(op3dsg_ipc_types::Graph::instance_id)
    })
}

pub fn dump(prefix: &str) -> Value {
    dump_with(&["--prefix", prefix, "dump", "--json", "--timeout-s", "30"])
}

pub fn dump_with(args: &[&str]) -> Value {
    let output = Command::new(binary("op3dsg")).args(args).output().expect("run op3dsg dump");
    assert!(output.status.success(), "op3dsg dump: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("dump JSON")
}

/// `op3dsg dump --json` and the consumer's graph at the same version: the daemon's versions stop
/// once its 300 frames are fused, so the two meet.
pub fn same_version(daemon: &Daemon, consumer: &mut Consumer, instance_id: u64) -> (Value, Value) {
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        let dumped = dump(&daemon.prefix);
        let version = dumped["graph_version"].as_u64().expect("graph_version");
        let held = consumer.state(instance_id, version);
        if held["graph_version"].as_u64() == Some(version) {
            return (dumped, held);
        }
        assert!(Instant::now() < deadline, "dump and consumer never met at one version");
    }
}

pub fn assert_same_graph(dumped: &Value, held: &Value) {
    let nodes = |g: &Value| -> Vec<(u64, String, String, Value, Vec<f64>)> {
        g["nodes"]
            .as_array()
            .expect("nodes")
            .iter()
            .map(|n| {
                let centre = n["centre_m"].as_array().expect("centre").iter().map(|v| v.as_f64().expect("f")).collect();
                let label = n["label"].as_str().expect("label").to_owned();
                (
                    n["id"].as_u64().expect("id"),
                    label,
                    n["kind"].as_str().expect("kind").to_owned(),
                    n["parent"].clone(),
                    centre,
                )
            })
            .collect()
    };
    let (a, b) = (nodes(dumped), nodes(held));
    assert!(!a.is_empty(), "the daemon's graph has nodes");
    assert_eq!(a.len(), b.len(), "node count");
    for (x, y) in a.iter().zip(&b) {
        assert_eq!((&x.0, &x.1, &x.2, &x.3), (&y.0, &y.1, &y.2, &y.3), "node {}", x.0);
        for (u, v) in x.4.iter().zip(&y.4) {
            assert!((u - v).abs() <= 1e-5 * u.abs().max(1.0), "node {} centre {:?} vs {:?}", x.0, x.4, y.4);
        }
    }
    let edges = |g: &Value| -> Vec<(u64, u64, String, String, String)> {
        let mut edges: Vec<_> = g["edges"]
            .as_array()
            .expect("edges")
            .iter()
            .map(|e| {
                let text = |k: &str| e[k].as_str().expect("text").to_owned();
                (
                    e["source"].as_u64().expect("s"),
                    e["target"].as_u64().expect("t"),
                    text("kind"),
                    text("relation"),
                    text("origin"),
                )
            })
            .collect();
        edges.sort();
        edges
    };
    assert_eq!(edges(dumped), edges(held), "edges");
}
