//! The sd_notify protocol of the real `op3dsgd`, against a test `NOTIFY_SOCKET` listener (a
//! Unix datagram socket bound here, as systemd binds its own): READY=1 once the graph service
//! exists, WATCHDOG=1 at the rate `WATCHDOG_USEC` asks for, no more pings once the fusion thread
//! stalls (the test-only fault hook `OP3DSG_TEST_STALL_FUSION_FILE`), STOPPING=1 on SIGTERM.

use std::ffi::OsStr;
use std::os::unix::net::UnixDatagram;
use std::path::Path;
use std::time::{Duration, Instant};

use op3dsg_ipc_types::GraphSubscriber;
use op3dsg_tests::{Daemon, unique_prefix};

/// The watchdog period handed to the daemon: it must ping every half of it.
const WATCHDOG: Duration = Duration::from_secs(2);

struct Listener {
    socket: UnixDatagram,
    /// Every message received, with its arrival time.
    messages: Vec<(Instant, String)>,
}

impl Listener {
    fn bind(path: &Path) -> Self {
        let socket = UnixDatagram::bind(path).expect("bind the notify socket");
        socket.set_read_timeout(Some(Duration::from_millis(50))).expect("read timeout");
        Self { socket, messages: Vec::new() }
    }

    /// Receives for `duration` (or until `until` matches a message); the new messages.
    fn collect(&mut self, duration: Duration, until: impl Fn(&str) -> bool) -> &[(Instant, String)] {
        let first = self.messages.len();
        let deadline = Instant::now() + duration;
        let mut buffer = [0u8; 4096];
        while Instant::now() < deadline {
            if let Ok(n) = self.socket.recv(&mut buffer) {
                let text = String::from_utf8_lossy(&buffer[..n]).into_owned();
                let stop = until(&text);
                self.messages.push((Instant::now(), text));
                if stop {
                    break;
                }
            }
        }
        &self.messages[first..]
    }

    fn wait_for(&mut self, what: &str, timeout: Duration) -> Instant {
        let found = self.collect(timeout, |m| m.lines().any(|l| l == what)).last().cloned();
        match found {
            Some((at, text)) if text.lines().any(|l| l == what) => at,
            _ => panic!("no {what} within {timeout:?}; received: {:?}", self.texts()),
        }
    }

    fn texts(&self) -> Vec<&str> {
        self.messages.iter().map(|(_, t)| t.as_str()).collect()
    }
}

fn pings(messages: &[(Instant, String)]) -> Vec<Instant> {
    messages.iter().filter(|(_, t)| t.lines().any(|l| l == "WATCHDOG=1")).map(|(at, _)| *at).collect()
}

fn start(prefix: &str, socket: &Path, extra_env: &[(&str, &OsStr)]) -> Daemon {
    let usec = WATCHDOG.as_micros().to_string();
    let mut env: Vec<(&str, &OsStr)> =
        vec![("NOTIFY_SOCKET", socket.as_os_str()), ("WATCHDOG_USEC", OsStr::new(&usec))];
    env.extend_from_slice(extra_env);
    // The synthetic kitchen at 30 Hz, the built-in default.
    Daemon::start_with_env(prefix, &["--set", "snapshot.enabled=false"], &env)
}

#[test]
fn ready_once_the_graph_service_exists_pings_at_the_rate_and_stopping_on_sigterm() {
    let dir = tempfile::tempdir().expect("temp dir");
    let socket = dir.path().join("notify.sock");
    let mut listener = Listener::bind(&socket);
    let prefix = unique_prefix("notify");
    let mut daemon = start(&prefix, &socket, &[]);

    listener.wait_for("READY=1", Duration::from_secs(60));
    assert!(pings(&listener.messages).is_empty(), "WATCHDOG=1 before READY=1: {:?}", listener.texts());
    // At READY the graph service must already exist: open it without waiting.
    let mut graphs = GraphSubscriber::open(&prefix, "notify-graph").expect("graph service exists at READY=1");

    // Pings for a few periods: every half period, so no gap reaches the period.
    let collected = listener.collect(WATCHDOG * 3, |_| false).to_vec();
    let pings = pings(&collected);
    assert!(
        pings.len() >= 4,
        "expected a ping every {:?}, got {} in {:?}: {:?}",
        WATCHDOG / 2,
        pings.len(),
        WATCHDOG * 3,
        listener.texts()
    );
    for pair in pings.windows(2) {
        let gap = pair[1] - pair[0];
        assert!(gap < WATCHDOG, "a {gap:?} gap between pings reaches the watchdog period {WATCHDOG:?}");
    }
    let status =
        collected.iter().rev().find_map(|(_, t)| t.lines().find(|l| l.starts_with("STATUS=")).map(str::to_owned));
    let status = status.expect("STATUS= with the pings");
    assert!(status.starts_with("STATUS=serving: graph v") && status.contains(" nodes, source delivering"), "{status}");
    assert!(graphs.latest().expect("read graph").is_some(), "the daemon serves a graph");

    daemon.sigterm();
    listener.wait_for("STOPPING=1", Duration::from_secs(10));
    let exit = daemon.wait_exit(Duration::from_secs(15)).expect("op3dsgd exits after SIGTERM");
    assert!(exit.success(), "op3dsgd exit status after SIGTERM: {exit}");
}

#[test]
fn a_stalled_fusion_thread_stops_the_pings_within_two_periods() {
    let dir = tempfile::tempdir().expect("temp dir");
    let socket = dir.path().join("notify.sock");
    let stall = dir.path().join("stall-fusion");
    let mut listener = Listener::bind(&socket);
    let prefix = unique_prefix("notify-stall");
    let _daemon = start(&prefix, &socket, &[("OP3DSG_TEST_STALL_FUSION_FILE", stall.as_os_str())]);

    listener.wait_for("READY=1", Duration::from_secs(60));
    listener.wait_for("WATCHDOG=1", WATCHDOG * 2);
    std::fs::write(&stall, b"").expect("create the stall file");
    let stalled_at = Instant::now();

    let after = listener.collect(WATCHDOG * 4, |_| false).to_vec();
    let pings = pings(&after);
    let last = pings.last().copied().unwrap_or(stalled_at);
    assert!(
        last.saturating_duration_since(stalled_at) <= WATCHDOG * 2,
        "pings went on {:?} after the fusion thread stalled (limit: two periods, {:?}); the stall is a test \
         fault hook: is op3dsgd built with --features op3dsgd/fault-hooks, as scripts/test.sh builds it?",
        last - stalled_at,
        WATCHDOG * 2
    );
    let said = after.iter().any(|(_, t)| t.lines().any(|l| l.starts_with("STATUS=stalled (fusion thread silent for")));
    assert!(said, "STATUS= names the stalled fusion thread: {:?}", listener.texts());
}
