//! Link faults for the cross-process tests: a fault-injecting TCP proxy on loopback (latency
//! with jitter, stalls, outages, resets) and a network namespace whose loopback is limited by
//! `tc tbf` (`netem` is missing from these kernels). Loopback addresses only.

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

/// Chunks read but not yet written, per direction of a connection through the proxy.
pub const IN_FLIGHT: usize = 16;

/// What the proxy's connections share: the faults to inject and the open connections.
#[derive(Debug, Default)]
pub struct Link {
    /// Added to every chunk in either direction, milliseconds.
    pub latency_ms: AtomicU64,
    /// Up to this much more, drawn per chunk (0: none), milliseconds.
    pub jitter_ms: AtomicU64,
    /// Nothing is forwarded before this instant.
    pub stalled_until: Mutex<Option<Instant>>,
    /// New connections are refused (reset at once).
    pub down: AtomicBool,
    /// Both sockets of every open connection, for resets.
    pub open: Mutex<Vec<[TcpStream; 2]>>,
    /// Connections forwarded since start.
    pub accepted: AtomicU64,
    /// Connections refused while the link was down.
    pub refused: AtomicU64,
    /// State of the jitter's random numbers.
    seed: AtomicU64,
}

impl Link {
    /// Resets every open connection: SO_LINGER 0, so closing sends RST, and both directions shut.
    pub fn reset_all(&self) {
        for pair in self.open.lock().expect("lock").drain(..) {
            for stream in &pair {
                let _ = socket2::SockRef::from(stream).set_linger(Some(Duration::ZERO));
                let _ = stream.shutdown(Shutdown::Both);
            }
        }
    }

    /// This chunk's delay: the latency plus a draw of the jitter (xorshift, seeded per link).
    fn delay_ms(&self) -> u64 {
        let latency = self.latency_ms.load(Ordering::SeqCst);
        let jitter = self.jitter_ms.load(Ordering::SeqCst);
        if jitter == 0 {
            return latency;
        }
        let mut x = self.seed.load(Ordering::Relaxed) | 1;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.seed.store(x, Ordering::Relaxed);
        latency + x % (jitter + 1)
    }

    /// Returns once no stall holds the link.
    pub fn wait_stall(&self) {
        loop {
            let until = *self.stalled_until.lock().expect("lock");
            match until {
                Some(until) if Instant::now() < until => thread::sleep(Duration::from_millis(5)),
                _ => return,
            }
        }
    }
}

/// A TCP proxy on a loopback port that forwards to `upstream` with the faults of its [`Link`].
#[derive(Debug)]
pub struct Proxy {
    /// The loopback port it accepts on.
    pub port: u16,
    /// Its faults and counters.
    pub link: Arc<Link>,
}

impl Proxy {
    /// Starts accepting on a free loopback port.
    pub fn start(upstream: u16) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind the proxy");
        let port = listener.local_addr().expect("proxy port").port();
        let link = Arc::new(Link::default());
        let shared = link.clone();
        thread::Builder::new()
            .name("proxy-accept".into())
            .spawn(move || {
                for client in listener.incoming().flatten() {
                    if shared.down.load(Ordering::SeqCst) {
                        let _ = socket2::SockRef::from(&client).set_linger(Some(Duration::ZERO));
                        shared.refused.fetch_add(1, Ordering::SeqCst);
                        continue;
                    }
                    let Ok(server) = TcpStream::connect(("127.0.0.1", upstream)) else { continue };
                    shared.accepted.fetch_add(1, Ordering::SeqCst);
                    forward(&shared, client, server);
                }
            })
            .expect("spawn the proxy");
        Self { port, link }
    }

    /// Delays every chunk by `latency`.
    pub fn set_latency(&self, latency: Duration) {
        self.link.latency_ms.store(latency.as_millis() as u64, Ordering::SeqCst);
    }

    /// Delays every chunk by `latency` plus up to `jitter` more, drawn per chunk (a connection's
    /// chunks stay in order: one that would overtake its predecessor waits for it).
    pub fn set_latency_jitter(&self, latency: Duration, jitter: Duration) {
        self.link.jitter_ms.store(jitter.as_millis() as u64, Ordering::SeqCst);
        self.set_latency(latency);
    }

    /// Forwards nothing either way for `stall`; the connections stay open.
    pub fn stall(&self, stall: Duration) {
        *self.link.stalled_until.lock().expect("lock") = Some(Instant::now() + stall);
    }

    /// The link is down for `outage`: open connections are reset, new ones refused.
    pub fn outage(&self, outage: Duration) {
        self.link.down.store(true, Ordering::SeqCst);
        self.link.reset_all();
        thread::sleep(outage);
        self.link.down.store(false, Ordering::SeqCst);
    }

    /// Resets every open connection (they may reconnect at once).
    pub fn reset(&self) {
        self.link.reset_all();
    }
}

/// Starts both directions of one connection and registers it for resets.
fn forward(link: &Arc<Link>, client: TcpStream, server: TcpStream) {
    let clones = (client.try_clone(), server.try_clone(), client.try_clone(), server.try_clone());
    let (Ok(c_write), Ok(s_write), Ok(c_keep), Ok(s_keep)) = clones else { return };
    link.open.lock().expect("lock").push([c_keep, s_keep]);
    pump(link.clone(), client, s_write, "proxy-up");
    pump(link.clone(), server, c_write, "proxy-down");
}

/// One direction: a reader stamps each chunk with the time it is due, a writer delivers it then
/// (after any stall). The reader holds at most [`IN_FLIGHT`] chunks, so a stall fills the
/// sender's socket as a stalled link would. Either side ending shuts both sockets.
fn pump(link: Arc<Link>, mut from: TcpStream, mut to: TcpStream, name: &str) {
    let (tx, rx) = mpsc::sync_channel::<(Instant, Vec<u8>)>(IN_FLIGHT);
    let reader_link = link.clone();
    let (reader_from, reader_to) = (from.try_clone(), to.try_clone());
    thread::Builder::new()
        .name(format!("{name}-read"))
        .spawn(move || {
            let mut buf = vec![0u8; 16 << 10];
            loop {
                match from.read(&mut buf) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => {
                        let due = Instant::now() + Duration::from_millis(reader_link.delay_ms());
                        if tx.send((due, buf[..n].to_vec())).is_err() {
                            break;
                        }
                    }
                }
            }
            if let (Ok(a), Ok(b)) = (&reader_from, &reader_to) {
                let _ = a.shutdown(Shutdown::Both);
                let _ = b.shutdown(Shutdown::Both);
            }
        })
        .expect("spawn a proxy reader");
    thread::Builder::new()
        .name(format!("{name}-write"))
        .spawn(move || {
            for (due, chunk) in rx {
                if let Some(wait) = due.checked_duration_since(Instant::now()) {
                    thread::sleep(wait);
                }
                link.wait_stall();
                if to.write_all(&chunk).is_err() {
                    let _ = to.shutdown(Shutdown::Both);
                    break;
                }
            }
        })
        .expect("spawn a proxy writer");
}

/// Runs `program args`, panicking with its stderr when it fails.
pub fn run(program: &str, args: &[&str]) {
    let output = Command::new(program)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("run {program}: {e} (ip and tc: Debian's iproute2)"));
    assert!(
        output.status.success(),
        "{program} {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&output.stderr).trim()
    );
}

/// A network namespace of a test with its own loopback limited by `tc tbf`; deleted on drop.
/// Needs root (see [`crate::is_root`]).
#[derive(Debug)]
pub struct Netns {
    /// Its name (`ip netns exec NAME ...`).
    pub name: String,
}

impl Netns {
    /// A namespace `op3dsg-<tag>-<pid>` whose loopback carries at most `rate` (tc's syntax:
    /// `10mbit`, `100mbit`) with the burst tbf needs at that rate.
    pub fn create(tag: &str, rate: &str, burst: &str) -> Self {
        let name = format!("op3dsg-{tag}-{}", std::process::id());
        let _ = Command::new("ip").args(["netns", "del", &name]).output(); // a leftover of a killed run
        run("ip", &["netns", "add", &name]);
        let netns = Self { name };
        netns.run("ip", &["link", "set", "lo", "up"]);
        // An Ethernet-sized MTU: with loopback's 64 KiB, TCP segments outgrow the 4 KiB burst
        // and tbf drops every one of them.
        netns.run("ip", &["link", "set", "lo", "mtu", "1500"]);
        netns
            .run("tc", &["qdisc", "add", "dev", "lo", "root", "tbf", "rate", rate, "burst", burst, "latency", "400ms"]);
        netns
    }

    /// The command prefix that runs a program inside the namespace.
    pub fn exec(&self) -> [&str; 4] {
        ["ip", "netns", "exec", &self.name]
    }

    /// Runs `program args` inside the namespace, panicking with its stderr when it fails.
    pub fn run(&self, program: &str, args: &[&str]) {
        let mut all = self.exec()[1..].to_vec();
        all.push(program);
        all.extend_from_slice(args);
        run("ip", &all);
    }

    /// The `overlimits` count of the tbf qdisc: packets it had to hold back for the rate.
    pub fn overlimits(&self) -> u64 {
        let output = Command::new("ip")
            .args(["netns", "exec", &self.name, "tc", "-s", "qdisc", "show", "dev", "lo"])
            .output()
            .expect("run tc -s qdisc show");
        let text = String::from_utf8_lossy(&output.stdout);
        let count = text.split("overlimits ").nth(1).and_then(|rest| rest.split_whitespace().next());
        count.and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("no overlimits in tc's statistics: {text}"))
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = Command::new("ip").args(["netns", "del", &self.name]).output();
    }
}
