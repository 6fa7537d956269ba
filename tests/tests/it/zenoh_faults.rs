//! The graph off the robot over a bad link, between real processes. The daemon (synthetic default
//! scene) listens on a loopback port; the Python consumer (`tests/python/zenoh_consumer.py`)
//! reaches it through a fault-injecting TCP proxy of this file that adds latency, stalls the
//! link, takes it down for 3 s (connections dropped, new ones refused) and resets connections.
//! Through all of it the daemon keeps capturing, fusing and publishing (its health's stage
//! counters keep rising), and once the link is good again the consumer holds exactly what
//! `op3dsg dump --json` prints for the same version. Consumers that stop reading (SIGSTOP) or die
//! mid-transfer (SIGKILL) do not hold the daemon back either, and a fresh consumer converges.

use std::process::Command;
use std::sync::atomic::Ordering;
use std::thread;
use std::time::{Duration, Instant};

use op3dsg_tests::netfaults::{Netns, Proxy};
use op3dsg_tests::{Daemon, binary, is_root, unique_prefix, wait_for};
use serde_json::Value;

use crate::zenoh_common;
use zenoh_common::{Consumer, assert_same_graph, free_port, instance_of, same_version};

/// Frames of the synthetic camera per run (20 s at its 30 Hz): the faults happen while it runs,
/// the comparison once it has stopped and serves its last graph unchanged.
const FRAMES: u64 = 600;

fn start_daemon(prefix: &str, port: u16, key_prefix: &str, extra: &[&str]) -> Daemon {
    let listen = format!("zenoh.listen=[\"tcp/127.0.0.1:{port}\"]");
    let key = format!("zenoh.key_prefix=\"{key_prefix}\"");
    let frames = format!("run.max_frames={FRAMES}");
    let mut args = vec!["--set", "zenoh.enabled=true", "--set", &listen, "--set", &key, "--set", &frames];
    args.extend_from_slice(extra);
    Daemon::start(prefix, &args)
}

/// `op3dsg health --json` of the daemon under `prefix`.
fn health(prefix: &str) -> Value {
    let output = Command::new(binary("op3dsg"))
        .args(["--prefix", prefix, "health", "--json", "--timeout-s", "30"])
        .output()
        .expect("run op3dsg health");
    assert!(output.status.success(), "op3dsg health: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("health JSON")
}

/// The `processed` count of the stage `name` in a health record.
fn processed(health: &Value, name: &str) -> u64 {
    health["stages"]
        .as_array()
        .expect("stages")
        .iter()
        .find(|s| s["name"] == name)
        .and_then(|s| s["processed"].as_u64())
        .unwrap_or_else(|| panic!("no stage {name} in {health}"))
}

/// Asserts the daemon moved on from `before` to `after`: frames, graph versions and the work of
/// the fusion, publish and zenoh stages.
fn assert_advanced(before: &Value, after: &Value, during: &str) {
    for key in ["frames_captured", "graph_version"] {
        assert!(after[key].as_u64() > before[key].as_u64(), "{key} did not advance {during}: {before} then {after}");
    }
    for stage in ["fusion", "publish", "zenoh"] {
        assert!(
            processed(after, stage) > processed(before, stage),
            "stage {stage} did not advance {during}: {} then {}",
            processed(before, stage),
            processed(after, stage)
        );
    }
}

/// Waits until the daemon has captured every frame of the run.
fn wait_run_end(prefix: &str) {
    wait_for("the daemon's run to end", Duration::from_secs(300), || {
        (health(prefix)["frames_captured"].as_u64() >= Some(FRAMES)).then_some(())
    });
}

/// Sends `signal` (`STOP`, `CONT`) to process `pid` through `kill(1)`.
fn signal(pid: u32, signal: &str) {
    let status = Command::new("kill").arg(format!("-{signal}")).arg(pid.to_string()).status().expect("run kill");
    assert!(status.success(), "kill -{signal} {pid} failed");
}

/// Bytes waiting in established loopback TCP connections to the daemon's `port` (IPv4): received
/// but not read by the consumers, and written by the daemon but not yet sent (a full window).
fn queued_bytes(port: u16) -> (u64, u64) {
    let table = std::fs::read_to_string("/proc/net/tcp").expect("read /proc/net/tcp");
    let port_of = |address: &str| address.rsplit(':').next().and_then(|p| u16::from_str_radix(p, 16).ok());
    let (mut unread, mut unsent) = (0, 0);
    for line in table.lines().skip(1) {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let [_, local, remote, state, queues, ..] = fields.as_slice() else { continue };
        let Some((tx, rx)) = queues.split_once(':') else { continue };
        let (tx, rx) = (u64::from_str_radix(tx, 16).unwrap_or(0), u64::from_str_radix(rx, 16).unwrap_or(0));
        if *state != "01" {
            continue; // not established
        }
        if port_of(remote) == Some(port) {
            unread += rx;
        } else if port_of(local) == Some(port) {
            unsent += tx;
        }
    }
    (unread, unsent)
}

#[test]
fn a_consumer_behind_latency_stalls_an_outage_and_resets_converges_and_the_daemon_never_waits() {
    let port = free_port();
    let key_prefix = format!("op3dsg/faults-{}", std::process::id());
    let prefix = unique_prefix("zenoh-faults");
    let started = Instant::now();
    let daemon = start_daemon(&prefix, port, &key_prefix, &[]);
    let proxy = Proxy::start(port);
    proxy.set_latency(Duration::from_millis(50));
    let mut consumer = Consumer::start(proxy.port, &key_prefix);
    let instance = instance_of(&daemon);
    let held = consumer.state(instance, 1);
    eprintln!("behind 50 ms each way the consumer holds version {}", held["graph_version"]);

    // Five stalls of 200 ms, 300 ms apart.
    for _ in 0..5 {
        proxy.stall(Duration::from_millis(200));
        thread::sleep(Duration::from_millis(300));
    }

    // A 3 s outage: the daemon goes on as before.
    let before = health(&prefix);
    let accepted = proxy.link.accepted.load(Ordering::SeqCst);
    proxy.outage(Duration::from_secs(3));
    let after = health(&prefix);
    assert_advanced(&before, &after, "during the 3 s outage");

    // The consumer comes back by itself, and then three resets, a second apart.
    wait_for("the consumer to reconnect after the outage", Duration::from_secs(60), || {
        (proxy.link.accepted.load(Ordering::SeqCst) > accepted).then_some(())
    });
    for _ in 0..3 {
        thread::sleep(Duration::from_secs(1));
        proxy.reset();
    }
    let cleared = Instant::now();
    let after_resets = health(&prefix);
    assert_advanced(&after, &after_resets, "through the resets");
    let faults_over = before["frames_captured"].as_u64().unwrap_or(0);
    assert!(faults_over < FRAMES, "the run ended before the faults did; nothing was tested under load");

    // The link stays slow (50 ms) but up: the consumer catches up with the daemon while it
    // runs, and converges on its last version.
    let version = after_resets["graph_version"].as_u64().expect("graph_version");
    consumer.state(instance, version);
    eprintln!(
        "after the last reset the consumer held version {version} within {:.1} s",
        cleared.elapsed().as_secs_f64()
    );
    wait_run_end(&prefix);
    let (dumped, held) = same_version(&daemon, &mut consumer, instance);
    assert_same_graph(&dumped, &held);
    let stats = &held["stats"];
    eprintln!(
        "zenoh faults: connections {} accepted, {} refused; consumer {stats}; {:.1} s",
        proxy.link.accepted.load(Ordering::SeqCst),
        proxy.link.refused.load(Ordering::SeqCst),
        started.elapsed().as_secs_f64()
    );
    assert!(proxy.link.accepted.load(Ordering::SeqCst) >= 5, "the consumer reconnected after each reset");
    assert_eq!(stats["restarts"].as_u64(), Some(0), "one daemon instance throughout: {stats}");
}

#[test]
fn stopped_and_killed_consumers_do_not_hold_the_daemon_back_and_a_fresh_one_converges() {
    let port = free_port();
    let key_prefix = format!("op3dsg/stalled-{}", std::process::id());
    let prefix = unique_prefix("zenoh-stalled");
    let started = Instant::now();
    // A full graph every 50 ms: enough traffic to fill the socket buffers of a consumer that
    // does not read.
    let daemon = start_daemon(&prefix, port, &key_prefix, &["--set", "zenoh.full_period_s=0.05"]);
    let mut stopped = Consumer::start(port, &key_prefix);
    let mut killed = Consumer::start(port, &key_prefix);
    let instance = instance_of(&daemon);
    stopped.state(instance, 1);
    killed.state(instance, 1);

    signal(stopped.child.id(), "STOP");
    killed.child.kill().expect("kill -9 the consumer");
    let _ = killed.child.wait();
    let mut last = health(&prefix);
    for second in 0..4 {
        thread::sleep(Duration::from_secs(2));
        let now = health(&prefix);
        assert_advanced(&last, &now, &format!("with a consumer stopped for {} s", 2 * (second + 1)));
        last = now;
    }
    assert!(last["frames_captured"].as_u64() < Some(FRAMES), "the run ended before the checks did");
    // The stopped consumer's socket is full of what it did not read, and the daemon holds more
    // that the window does not let through: the daemon went on with its link full.
    let (unread, unsent) = queued_bytes(port);
    eprintln!("stopped consumer: {unread} B unread in its socket, {unsent} B unsent in the daemon's");
    assert!(unread > 0, "the stopped consumer's socket has unread bytes");
    assert!(unsent > 0, "the daemon's socket to the stopped consumer holds bytes it could not send");

    // A fresh consumer while the stopped one still does not read.
    let mut fresh = Consumer::start(port, &key_prefix);
    fresh.state(instance, 1);
    wait_run_end(&prefix);
    let (dumped, held) = same_version(&daemon, &mut fresh, instance);
    assert_same_graph(&dumped, &held);

    // The stopped consumer, running again, catches up too.
    signal(stopped.child.id(), "CONT");
    let (dumped, held) = same_version(&daemon, &mut stopped, instance);
    assert_same_graph(&dumped, &held);
    eprintln!("zenoh stalled consumers: resumed consumer {}; {:.1} s", held["stats"], started.elapsed().as_secs_f64());
}

#[test]
fn a_consumer_behind_a_10_mbit_link_converges() {
    if !is_root() {
        let why = "this test makes a network namespace with a 10 Mbit/s `tc tbf` link, which needs root";
        assert!(std::env::var("CI").as_deref() != Ok("true"), "{why}; CI runs the tests as root");
        eprintln!("not run: {why}");
        return;
    }
    let netns = Netns::create("zt", "10mbit", "32kbit");
    let port = free_port();
    let key_prefix = format!("op3dsg/tbf-{}", std::process::id());
    let prefix = unique_prefix("zenoh-tbf");
    let started = Instant::now();
    let listen = format!("zenoh.listen=[\"tcp/127.0.0.1:{port}\"]");
    let key = format!("zenoh.key_prefix=\"{key_prefix}\"");
    let frames = format!("run.max_frames={FRAMES}");
    // The daemon and the consumer on the namespace's loopback; iceoryx2 (shared memory) still
    // reaches the daemon from here. Full graphs every 50 ms: bursts above the rate.
    let child = Command::new("ip")
        .args(["netns", "exec", &netns.name])
        .arg(binary("op3dsgd"))
        .args(["--prefix", &prefix, "--set", "zenoh.enabled=true", "--set", &listen, "--set", &key])
        .args(["--set", &frames, "--set", "zenoh.full_period_s=0.05"])
        .env("OP3DSG_LOG", std::env::var("OP3DSG_LOG").unwrap_or_else(|_| "warn".into()))
        .stdin(std::process::Stdio::null())
        .spawn()
        .expect("run op3dsgd in the namespace");
    let daemon = Daemon { child, prefix };
    let mut consumer = Consumer::start_in(&netns.exec(), port, &key_prefix);
    let instance = instance_of(&daemon);
    consumer.state(instance, 1);
    wait_run_end(&daemon.prefix);
    let (dumped, held) = same_version(&daemon, &mut consumer, instance);
    assert_same_graph(&dumped, &held);
    let overlimits = netns.overlimits();
    eprintln!(
        "zenoh over 10 Mbit/s: tbf held back {overlimits} packets; consumer {}; {:.1} s",
        held["stats"],
        started.elapsed().as_secs_f64()
    );
    assert!(overlimits > 0, "the 10 Mbit/s limit never held a packet back: the link was not the one tested");
}
