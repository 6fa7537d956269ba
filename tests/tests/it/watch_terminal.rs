//! `op3dsg watch` against a real daemon (the built-in synthetic profile): in a terminal (a
//! detached tmux session) it is a full-screen view redrawn in place: the screen never holds more
//! rows than the terminal, nothing scrolls into the history, it shows the stage table, it fits a
//! resized terminal, and `q` quits with status 0 and the terminal restored, as a panic does.
//! Into a pipe it prints one line per `--interval-ms`, as scripts read it.
//!
//! Needs tmux (Debian: apt-get install tmux).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{Daemon, binary, unique_prefix, wait_for};

/// A tmux server of its own (its socket in a temporary folder), killed on drop.
struct Tmux {
    socket: PathBuf,
}

impl Tmux {
    /// Starts `command` in a detached session "watch" of a `width` x `height` terminal, on a
    /// server whose socket lies in `dir`.
    fn session(dir: &Path, width: usize, height: usize, command: &str) -> Tmux {
        assert!(
            Command::new("tmux").arg("-V").output().is_ok_and(|o| o.status.success()),
            "tmux not found: this test runs op3dsg watch in a tmux terminal (Debian: apt-get install tmux)"
        );
        let tmux = Tmux { socket: dir.join("tmux.sock") };
        let (width, height) = (width.to_string(), height.to_string());
        tmux.run(&["new-session", "-d", "-s", "watch", "-x", &width, "-y", &height, command]);
        tmux
    }

    fn run(&self, args: &[&str]) -> String {
        let output = Command::new("tmux").arg("-S").arg(&self.socket).args(args).output().expect("run tmux");
        assert!(output.status.success(), "tmux {args:?}: {}", String::from_utf8_lossy(&output.stderr));
        String::from_utf8_lossy(&output.stdout).into_owned()
    }

    /// The pane's rows, scrolled-off history included.
    fn capture(&self) -> Vec<String> {
        self.run(&["capture-pane", "-p", "-t", "watch", "-S", "-", "-E", "-"]).lines().map(str::to_owned).collect()
    }

    /// A tmux format of the pane (`#{history_size}`, `#{alternate_on}`, ...).
    fn show(&self, format: &str) -> String {
        self.run(&["display-message", "-p", "-t", "watch", format]).trim().to_owned()
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = Command::new("tmux").arg("-S").arg(&self.socket).arg("kill-server").status();
    }
}

/// Asserts the screen was redrawn in place on a terminal `width` x `height`: no more rows than
/// it has, none wider, nothing in the scroll-back history, the alternate screen on.
fn assert_in_place(tmux: &Tmux, screen: &[String], width: usize, height: usize) {
    let text = screen.join("\n");
    assert!(screen.len() <= height, "{} rows on a terminal of {height}:\n{text}", screen.len());
    assert!(screen.iter().all(|row| row.chars().count() <= width), "a row wider than {width}:\n{text}");
    assert_eq!(tmux.show("#{history_size}"), "0", "rows scrolled into the history:\n{text}");
    assert_eq!(tmux.show("#{alternate_on}"), "1", "not on the alternate screen:\n{text}");
}

fn has_stage_table(screen: &[String]) -> bool {
    let header = screen.iter().any(|r| r.contains("stage") && r.contains("rate Hz") && r.contains("p99 ms"));
    let fusion = screen.iter().any(|r| r.contains("│fusion "));
    header && fusion
}

#[test]
fn watch_on_a_terminal_redraws_in_place_fits_a_resize_and_quits_on_q() {
    let prefix = unique_prefix("watch-tty");
    let _daemon = Daemon::start(&prefix, &["--set", "health.period_ms=250"]);
    let dir = tempfile::tempdir().expect("temporary folder");
    let status = dir.path().join("status");
    // The shell stays after watch exits, so the restored screen can be read.
    let command = format!(
        "{} --prefix {prefix} watch --interval-ms 200; echo $? > {}; sleep 600",
        binary("op3dsg").display(),
        status.display()
    );
    let (width, height) = (110, 32);
    let tmux = Tmux::session(dir.path(), width, height, &command);

    let deadline = Instant::now() + Duration::from_secs(90);
    let first = loop {
        let screen = tmux.capture();
        if has_stage_table(&screen) && screen.iter().any(|r| r.contains("graph version")) {
            break screen;
        }
        assert!(Instant::now() < deadline, "no stage table and graph on the screen in 90 s:\n{}", screen.join("\n"));
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_in_place(&tmux, &first, width, height);
    let text = first.join("\n");
    for shown in ["objects", "queues", "pose", "tf", "llm", "snapshots", "warnings", "daemon up"] {
        assert!(text.contains(shown), "'{shown}' not on the screen:\n{text}");
    }
    // Some seconds of redraws: always in place, and the screen changes (the daemon's uptime
    // at least).
    let mut screens = vec![first.clone()];
    for _ in 0..8 {
        std::thread::sleep(Duration::from_millis(400));
        let screen = tmux.capture();
        assert_in_place(&tmux, &screen, width, height);
        screens.push(screen);
    }
    assert!(screens.iter().any(|s| *s != first), "the screen never changed:\n{}", first.join("\n"));

    // A smaller terminal: the view fits it.
    let (width, height) = (72, 20);
    tmux.run(&["resize-window", "-t", "watch", "-x", &width.to_string(), "-y", &height.to_string()]);
    let resized = wait_for("the view redrawn for 72x20", Duration::from_secs(10), || {
        let screen = tmux.capture();
        (screen.iter().any(|r| r.contains(" stages ")) && screen.iter().all(|r| r.chars().count() <= width))
            .then_some(screen)
    });
    assert_in_place(&tmux, &resized, width, height);

    tmux.run(&["send-keys", "-t", "watch", "q"]);
    let deadline = Instant::now() + Duration::from_secs(10);
    let code = loop {
        if let Some(code) = std::fs::read_to_string(&status).ok().filter(|s| s.ends_with('\n')) {
            break code;
        }
        assert!(Instant::now() < deadline, "watch still runs 10 s after q:\n{}", tmux.capture().join("\n"));
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(code.trim(), "0", "watch's exit status after q");
    assert_eq!(tmux.show("#{alternate_on}"), "0", "the terminal left the alternate screen");
    let after = tmux.capture().join("\n");
    assert!(!after.contains("op3dsg watch"), "the view is gone after q:\n{after}");
}

/// A panic inside the view (injected: `OP3DSG_WATCH_FAULT=panic`, a fault-hooks build) leaves
/// the terminal as it found it: off the alternate screen, out of raw mode, cursor shown, and the
/// panic's message readable.
#[test]
fn a_panic_in_watch_restores_the_terminal() {
    let prefix = unique_prefix("watch-panic");
    let _daemon = Daemon::start(&prefix, &["--set", "health.period_ms=250"]);
    let dir = tempfile::tempdir().expect("temporary folder");
    let (status, modes) = (dir.path().join("status"), dir.path().join("stty"));
    let command = format!(
        "OP3DSG_WATCH_FAULT=panic {} --prefix {prefix} watch --interval-ms 200; echo $? > {}; stty -a > {}; sleep 600",
        binary("op3dsg").display(),
        status.display(),
        modes.display()
    );
    let tmux = Tmux::session(dir.path(), 100, 30, &command);
    let code = wait_for(
        "watch to end with the injected panic (op3dsg built with --features op3dsgd/fault-hooks, as scripts/test.sh builds it)",
        Duration::from_secs(90),
        || std::fs::read_to_string(&status).ok().filter(|s| s.ends_with('\n')),
    );
    let modes = wait_for("stty's report", Duration::from_secs(10), || {
        std::fs::read_to_string(&modes).ok().filter(|s| s.contains("icanon"))
    });
    let screen = tmux.capture().join("\n");
    assert_eq!(code.trim(), "101", "a panic's exit status:\n{screen}");
    assert!(screen.contains("injected by OP3DSG_WATCH_FAULT=panic"), "the panic's message is readable:\n{screen}");
    assert_eq!(tmux.show("#{alternate_on}"), "0", "the terminal left the alternate screen:\n{screen}");
    assert_eq!(tmux.show("#{cursor_flag}"), "1", "the cursor is shown");
    let flags: Vec<&str> = modes.split_whitespace().collect();
    for cooked in ["icanon", "echo", "isig"] {
        assert!(flags.contains(&cooked), "raw mode left on: no {cooked} in stty -a:\n{modes}");
    }
}

#[test]
fn watch_into_a_pipe_prints_one_line_per_interval() {
    let prefix = unique_prefix("watch-pipe");
    let _daemon = Daemon::start(&prefix, &[]);
    let mut watch = Command::new(binary("op3dsg"))
        .args(["--prefix", &prefix, "watch", "--interval-ms", "500"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start op3dsg watch");
    let stdout = BufReader::new(watch.stdout.take().expect("stdout"));
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::Builder::new()
        .name("watch-pipe".into())
        .spawn(move || {
            for line in stdout.lines().map_while(Result::ok) {
                if tx.send((Instant::now(), line)).is_err() {
                    break;
                }
            }
        })
        .expect("spawn the reader");
    // From the first line with a graph, four seconds of lines.
    let (start, first) = wait_for("a graph line", Duration::from_secs(90), || {
        rx.recv_timeout(Duration::from_secs(1)).ok().filter(|(_, line)| line.starts_with('v'))
    });
    let mut lines = vec![first];
    while start.elapsed() < Duration::from_secs(4) {
        if let Ok((_, line)) = rx.recv_timeout(Duration::from_millis(100)) {
            lines.push(line);
        }
    }
    let _ = watch.kill();
    let _ = watch.wait();
    let _ = reader.join();
    // 4 s at one line per 500 ms: 8 after the first (fewer when the machine stalls the reader;
    // a line per graph version would be many more).
    assert!((4..=10).contains(&lines.len()), "{} lines in 4 s:\n{}", lines.len(), lines.join("\n"));
    for line in &lines {
        assert!(line.contains(" objects ") && line.contains("| frames ") && line.contains("| fusion "), "{line}");
        assert!(!line.contains('\u{1b}'), "no terminal control sequences into a pipe: {line:?}");
    }
}

/// The full-screen `watch` started in a tmux session of its own, its pid written to `pid`.
fn watch_in_tmux(dir: &Path, prefix: &str) -> (Tmux, u32) {
    let pid = dir.join("pid");
    let command = format!(
        "sh -c 'echo $$ > {}; exec {} --prefix {prefix} watch --interval-ms 200'",
        pid.display(),
        binary("op3dsg").display()
    );
    let tmux = Tmux::session(dir, 100, 30, &command);
    // The pane stays after watch ends, so what it left on the terminal can be read.
    tmux.run(&["set-option", "-g", "remain-on-exit", "on"]);
    let pid = wait_for("watch's pid", Duration::from_secs(10), || {
        std::fs::read_to_string(&pid).ok().and_then(|s| s.trim().parse::<u32>().ok())
    });
    wait_for("the view on the screen", Duration::from_secs(90), || has_stage_table(&tmux.capture()).then_some(()));
    (tmux, pid)
}

/// How long process `pid` took to end, up to `limit` (`None`: still running).
fn ended_within(pid: u32, limit: Duration) -> Option<Duration> {
    let started = Instant::now();
    while started.elapsed() < limit {
        // A zombie (not yet reaped by tmux) has ended too.
        match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
            Err(_) => return Some(started.elapsed()),
            Ok(stat) if stat.rsplit(')').next().is_some_and(|rest| rest.trim_start().starts_with('Z')) => {
                return Some(started.elapsed());
            }
            Ok(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
    None
}

/// A terminal that goes away (its tmux session killed, as an SSH drop does on a robot) ends the
/// view: it must not stay behind reading the dead terminal.
#[test]
fn watch_ends_when_its_terminal_goes_away() {
    let prefix = unique_prefix("watch-hangup");
    let _daemon = Daemon::start(&prefix, &["--set", "health.period_ms=250"]);
    let dir = tempfile::tempdir().expect("temporary folder");
    let (tmux, pid) = watch_in_tmux(dir.path(), &prefix);
    tmux.run(&["kill-session", "-t", "watch"]);
    let took = ended_within(pid, Duration::from_secs(2));
    if took.is_none() {
        let _ = Command::new("kill").args(["-KILL", &pid.to_string()]).status();
    }
    assert!(took.is_some(), "op3dsg watch (pid {pid}) still runs 2 s after its terminal went away");
}

/// SIGHUP, SIGTERM and SIGINT from another process end the view on a live terminal, which it
/// leaves restored (off the alternate screen).
#[test]
fn watch_ends_on_sighup_sigterm_and_sigint() {
    let prefix = unique_prefix("watch-signals");
    let _daemon = Daemon::start(&prefix, &["--set", "health.period_ms=250"]);
    for signal in ["HUP", "TERM", "INT"] {
        let dir = tempfile::tempdir().expect("temporary folder");
        let (tmux, pid) = watch_in_tmux(dir.path(), &prefix);
        let sent = Command::new("kill").args([&format!("-{signal}"), &pid.to_string()]).status().expect("run kill");
        assert!(sent.success(), "kill -{signal} {pid}");
        let took = ended_within(pid, Duration::from_secs(2));
        if took.is_none() {
            let _ = Command::new("kill").args(["-KILL", &pid.to_string()]).status();
        }
        assert!(took.is_some(), "op3dsg watch still runs 2 s after SIG{signal}");
        // The pane stays (remain-on-exit) with what the view left behind.
        assert_eq!(tmux.show("#{alternate_on}"), "0", "SIG{signal}: the terminal was left on the alternate screen");
    }
}

/// Into a pipe, a daemon that went away is marked on each line instead of its last graph
/// repeated as if current.
#[test]
fn watch_into_a_pipe_marks_a_daemon_that_went_away() {
    let prefix = unique_prefix("watch-stale");
    let mut daemon = Daemon::start(&prefix, &["--set", "health.period_ms=250"]);
    let mut watch = Command::new(binary("op3dsg"))
        .args(["--prefix", &prefix, "watch", "--interval-ms", "500"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start op3dsg watch");
    let mut stdout = BufReader::new(watch.stdout.take().expect("stdout")).lines();
    let mut next = || stdout.next().and_then(Result::ok).expect("a line from watch");
    let fresh = (0..200).map(|_| next()).find(|line| line.starts_with('v')).expect("a graph line");
    assert!(!fresh.contains("STALE"), "{fresh}");
    daemon.kill_9();
    // Health came every 250 ms; after 3 s without, the lines say so.
    let stale = (0..20).map(|_| next()).find(|line| line.starts_with("STALE"));
    let _ = watch.kill();
    let _ = watch.wait();
    let stale = stale.expect("no STALE line within 10 s of the daemon's end");
    assert!(stale.contains("nothing new from the daemon for") && stale.contains(" v"), "{stale}");
}
