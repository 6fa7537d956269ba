//! `op3dsg watch`: a live view of the daemon, read with the client library's subscribers on the
//! daemon's computer or over Zenoh from another ([`feed`]).
//!
//! On a terminal it is a full-screen view redrawn in place ([`screen`], drawn by [`view`]; the
//! [`warnings`] it lists are derived from the health records). Otherwise (a pipe, a log file, a
//! script) it prints one compact line every `--interval-ms` ([`watch_line`]), the form scripts read.

mod feed;
mod screen;
mod tty;
mod view;
mod warnings;

use std::fmt::Write as _;
use std::io::{IsTerminal, Write as _};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use op3dsg_ipc_types::Graph;
use op3dsg_runtime::ipc::HealthReport;

use super::DaemonAt;
use feed::Feed;

/// The line `watch` prints when standard output is not a terminal: `v<version> <source> in <frame>
/// objects N parts N edges N`, then `|`-separated frames, poses, stages and queues (scripts and
/// tests read it; keep its form).
fn watch_line(graph: Option<&Graph>, health: Option<&HealthReport>) -> String {
    let mut s = String::new();
    match graph {
        Some(g) => {
            let _ = write!(
                s,
                "v{} {} in {} objects {} parts {} edges {}{}{}",
                g.version(),
                g.source_kind().as_str(),
                if g.world_frame().is_empty() { "?" } else { g.world_frame() },
                g.objects().count(),
                g.parts().count(),
                g.edge_count(),
                if g.capacity_exceeded() { " CAPACITY EXCEEDED" } else { "" },
                if g.restarted() { " DAEMON RESTARTED" } else { "" }
            );
        }
        None => s.push_str("no graph yet"),
    }
    if let Some(h) = health {
        let _ =
            write!(s, " | frames {} keyframes {} no pose {}", h.frames_captured, h.keyframes, h.frames_without_pose);
        let accepted = h.poses.get("accepted").copied().unwrap_or(0);
        let refused: u64 = h.poses.iter().filter(|(outcome, _)| *outcome != "accepted").map(|(_, n)| n).sum();
        if accepted + refused > 0 {
            let _ = write!(s, " | poses ok {accepted} refused {refused}");
        }
        for st in &h.stages {
            let _ = write!(
                s,
                " | {} {:.1}Hz p50 {:.1}ms p99 {:.1}ms",
                st.name,
                st.rate_hz,
                st.latency_p50_us / 1000.0,
                st.latency_p99_us / 1000.0
            );
        }
        for q in &h.queues {
            let _ = write!(s, " | q {} {}/{} drop {}", q.name, q.depth, q.capacity, q.dropped);
        }
        if let Some(r) = &h.remote {
            let _ = write!(s, " | remote fallback {}", if r.fallback_active { "ON" } else { "off" });
            for w in &r.workers {
                let _ = write!(
                    s,
                    " | w {} {}req {} ok {} timeout {} rejected {} rtt p50 {:.1}ms p99 {:.1}ms {}kB/kf",
                    w.key.rsplit('/').next().unwrap_or(&w.key),
                    if w.alive { "" } else { "GONE " },
                    w.requests,
                    w.replies,
                    w.timeouts,
                    w.rejections.values().sum::<u64>(),
                    w.round_trip_p50_ms,
                    w.round_trip_p99_ms,
                    w.bytes_per_keyframe / 1000
                );
            }
        }
    }
    s
}

/// `op3dsg watch`: the full-screen view when standard output is a terminal, else a line every
/// `interval`; until `q` (the view) or Ctrl-C / SIGTERM.
pub(super) fn watch(from: DaemonAt<'_>, interval: Duration) -> Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst)).context("installing the Ctrl-C handler")?;
    }
    let mut feed = Feed::open(from)?;
    if std::io::stdout().is_terminal() {
        screen::run(&mut feed, interval, &stop)
    } else {
        lines(&mut feed, interval, &stop)
    }
}

/// How long the line form waits for a new health record before it marks its line stale (or
/// three times the time between the last two records, if longer): three periods of the default
/// `health.period_ms` (1 s).
const STALE_AFTER: Duration = Duration::from_secs(3);

/// The line form: waits for the daemon (saying so once on standard error), then prints the line
/// at once and every `interval` after.
fn lines(feed: &mut Feed<'_>, interval: Duration, stop: &AtomicBool) -> Result<()> {
    #[cfg(feature = "zenoh")]
    if let Feed::Remote { endpoint, key_prefix, .. } = feed {
        eprintln!("following {key_prefix}/graph on zenoh endpoint {endpoint} (Ctrl-C to quit)");
    }
    let mut announced = false;
    let mut next: Option<Instant> = None;
    let mut connected = Instant::now();
    // The newest health record's stamp, when it came, and the time between the last two.
    let (mut last_stamp, mut fresh_at, mut period) = (None, Instant::now(), Duration::ZERO);
    let mut stdout = std::io::stdout().lock();
    while !stop.load(Ordering::SeqCst) {
        feed.poll()?;
        if !feed.connected() {
            if !announced {
                eprintln!("waiting for {}...", feed.describe());
                announced = true;
            }
            feed.wait(Duration::from_millis(100))?;
            continue;
        }
        let now = Instant::now();
        let due = *next.get_or_insert_with(|| {
            // The only kind of feed without the feature `zenoh`.
            #[cfg_attr(not(feature = "zenoh"), allow(irrefutable_let_patterns))]
            if let Feed::Local { prefix, .. } = feed {
                eprintln!("connected to op3dsgd under prefix {prefix} (Ctrl-C to quit)");
            }
            connected = now;
            now
        });
        // The first line waits for the graph and the health record, one interval at most.
        let complete = feed.graph().is_some() && feed.health().is_some();
        if now >= due && (complete || now.saturating_duration_since(connected) >= interval) {
            // A daemon that went away leaves its last graph and health held: say so on the line.
            let stamp = feed.health().map(|h| h.stamp_ns);
            if stamp != last_stamp {
                if last_stamp.is_some() {
                    period = now.saturating_duration_since(fresh_at);
                }
                (last_stamp, fresh_at) = (stamp, now);
            }
            let silent = now.saturating_duration_since(fresh_at);
            let line = watch_line(feed.graph(), feed.health());
            if silent >= STALE_AFTER.max(period * 3) {
                let seconds = silent.as_secs();
                writeln!(stdout, "STALE: nothing new from the daemon for {seconds} s (stopped or restarting?) | {line}")
            } else {
                writeln!(stdout, "{line}")
            }
            .context("writing to standard output")?;
            stdout.flush().context("writing to standard output")?;
            // Every interval from the first line; after a stall, from now.
            let late = now.saturating_duration_since(due) >= interval;
            next = Some(if late { now } else { due } + interval);
        }
        let until = next.map_or(Duration::ZERO, |t| t.saturating_duration_since(Instant::now()));
        feed.wait(until.clamp(Duration::from_millis(5), Duration::from_millis(100)))?;
    }
    Ok(())
}
