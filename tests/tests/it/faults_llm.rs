//! LLM outages the daemon must survive (`reasoner.kind = "llm"`): an endpoint where nothing
//! listens (connection refused) and one that accepts connections and never answers (a local
//! server that holds every socket open). The daemon keeps publishing graphs while the refiner
//! fails, and health shows the refiner's calls, failures, last error and open breaker.

use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use op3dsg_ipc_types::{Health, HealthSubscriber, REFINER_ERRORS, REFINER_STATES};
use op3dsg_tests::{Daemon, health_where, health_with_frames_above, unique_prefix};

fn state(health: &Health) -> &'static str {
    REFINER_STATES.get(health.refiner.state as usize).copied().unwrap_or("?")
}

fn last_error(health: &Health) -> &'static str {
    REFINER_ERRORS.get(health.refiner.last_error as usize).copied().unwrap_or("?")
}

/// `op3dsgd` on the synthetic kitchen with the LLM refiner pointed at `base_url`: no retries, a
/// breaker that opens after one refresh's three failed calls and stays open for the test.
fn start_daemon(name: &str, base_url: &str, request_timeout_s: f64) -> Daemon {
    let prefix = unique_prefix(name);
    let base_url = format!("reasoner.llm.base_url={base_url:?}");
    let timeout = format!("reasoner.llm.request_timeout_s={request_timeout_s}");
    Daemon::start(
        &prefix,
        &[
            "--set",
            "source.rate_hz=30",
            "--set",
            "health.period_ms=100",
            "--set",
            "reasoner.kind=\"llm\"",
            "--set",
            &base_url,
            "--set",
            "reasoner.llm.model=\"test-model\"",
            "--set",
            "reasoner.llm.api_key_env=\"\"",
            "--set",
            "reasoner.llm.api_key_credential=\"\"",
            "--set",
            &timeout,
            "--set",
            "reasoner.llm.connect_timeout_s=1.0",
            "--set",
            "reasoner.llm.max_retries=0",
            "--set",
            "reasoner.llm.breaker_failures=3",
            "--set",
            "reasoner.llm.breaker_cooldown_s=600.0",
            "--set",
            "reasoner.llm.refresh_min_changed_nodes=1",
            "--set",
            "reasoner.llm.refresh_period_s=0.5",
        ],
    )
}

/// After the refiner's breaker opened, graph versions and frames keep coming.
fn assert_publishing_goes_on(health: &mut HealthSubscriber, since: &Health) {
    let after = health_with_frames_above(health, since.frames_captured + 60, Duration::from_secs(60));
    assert!(
        after.graph_version > since.graph_version,
        "graph versions keep rising while the LLM is unreachable: {} then {}",
        since.graph_version,
        after.graph_version
    );
    assert_eq!(state(&after), "breaker_open", "the breaker stays open through its cool-down");
}

#[test]
fn llm_endpoint_refusing_connections_opens_the_breaker_and_the_graph_goes_on() {
    // A port where nothing listens: bound once to get a free number, then closed.
    let port = TcpListener::bind("127.0.0.1:0").expect("bind a free port").local_addr().expect("port").port();
    let mut daemon = start_daemon("llm-down", &format!("http://127.0.0.1:{port}/v1"), 5.0);
    let mut health = daemon.health_subscriber("llm-down-health");

    let open = health_where(&mut health, "the refiner's breaker to open", Duration::from_secs(90), |h| {
        h.refiner.breaker_open == 1
    });
    assert_eq!(state(&open), "breaker_open");
    assert_eq!(last_error(&open), "refused", "the failure is named: nothing listens on port {port}");
    assert!(open.refiner.calls >= 3 && open.refiner.failures >= 3, "{:?}", open.refiner);
    assert_eq!(open.refiner.timeouts, 0, "refused at once, not timed out: {:?}", open.refiner);
    assert_eq!(open.refiner.accepted, 0);
    assert!(open.graph_version > 0, "graphs were published before the breaker opened");

    assert_publishing_goes_on(&mut health, &open);
    let calls_when_open = open.refiner.calls;
    let later = health.latest().expect("health").expect("a record");
    assert_eq!(later.refiner.calls, calls_when_open, "an open breaker sends no calls");
    assert!(daemon.child.try_wait().expect("daemon status").is_none(), "the daemon is still running");
}

/// A server that accepts every connection and never reads or answers (a hung LLM host).
struct SilentServer {
    port: u16,
    accepted: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl SilentServer {
    fn start() -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind the silent server");
        listener.set_nonblocking(true).expect("non-blocking accept");
        let port = listener.local_addr().expect("port").port();
        let accepted = Arc::new(AtomicUsize::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (accepted, stop) = (accepted.clone(), stop.clone());
            std::thread::Builder::new()
                .name("silent-llm".into())
                .spawn(move || {
                    // Held open, never read: the request sits in the socket buffer unanswered.
                    let held: Mutex<Vec<TcpStream>> = Mutex::new(Vec::new());
                    while !stop.load(Ordering::Relaxed) {
                        match listener.accept() {
                            Ok((stream, _)) => {
                                accepted.fetch_add(1, Ordering::SeqCst);
                                held.lock().expect("held sockets").push(stream);
                            }
                            Err(_) => std::thread::sleep(Duration::from_millis(10)),
                        }
                    }
                })
                .expect("spawn the silent server")
        };
        Self { port, accepted, stop, thread: Some(thread) }
    }
}

impl Drop for SilentServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[test]
fn llm_endpoint_that_never_answers_times_out_while_the_graph_goes_on() {
    let server = SilentServer::start();
    let request_timeout_s = 8.0;
    let mut daemon = start_daemon("llm-hang", &format!("http://127.0.0.1:{}/v1", server.port), request_timeout_s);
    let mut health = daemon.health_subscriber("llm-hang-health");

    // While the calls hang, fusion and publishing go on: versions rise during one "calling" spell.
    let calling = health_where(&mut health, "the refiner calling the silent server", Duration::from_secs(90), |h| {
        state(h) == "calling"
    });
    let during = health_where(&mut health, "a newer graph or the call's end", Duration::from_secs(60), |h| {
        h.graph_version > calling.graph_version || state(h) != "calling"
    });
    assert!(
        state(&during) == "calling" && during.refiner.failures == calling.refiner.failures,
        "the graph should move on while the call hangs: calling at v{}, v{} only once the call ended ({:?})",
        calling.graph_version,
        during.graph_version,
        during.refiner
    );
    assert!(server.accepted.load(Ordering::SeqCst) >= 1, "the daemon connected to the silent server");

    let open = health_where(&mut health, "the refiner's breaker to open", Duration::from_secs(60), |h| {
        h.refiner.breaker_open == 1
    });
    assert_eq!(last_error(&open), "timeout", "the failure is named: {:?}", open.refiner);
    assert!(open.refiner.timeouts >= 3 && open.refiner.failures >= 3, "{:?}", open.refiner);
    assert!(
        open.refiner.last_latency_us as f64 >= request_timeout_s * 0.9e6,
        "a timed-out call lasted the request timeout: {} us",
        open.refiner.last_latency_us
    );

    assert_publishing_goes_on(&mut health, &open);
    assert!(daemon.child.try_wait().expect("daemon status").is_none(), "the daemon is still running");
}
