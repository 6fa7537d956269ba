//! The terminal side of `op3dsg watch`'s full-screen view: raw mode and the alternate screen
//! while it runs, restored on every way out (`q`, Esc, Ctrl-C, SIGTERM, an error, a panic);
//! redrawn in place on each new graph or health record, on a resize, and at least every
//! `--interval-ms`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use ratatui::DefaultTerminal;
use ratatui::crossterm::event::{self, Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers};

use super::feed::Feed;
use super::tty::{Readiness, Tty};
use super::view::{self, View};
use super::warnings::Warnings;

/// How long one turn waits for a key: also how often the feed is read.
const TICK: Duration = Duration::from_millis(100);

/// The terminal in raw mode on the alternate screen; restored when dropped (an error path or an
/// unwinding panic) and, through the panic hook, before a panic's message (release builds abort).
struct Screen {
    terminal: DefaultTerminal,
}

impl Screen {
    fn enter() -> Result<Self> {
        // Installs a panic hook that leaves raw mode and the alternate screen first.
        let terminal = ratatui::try_init().context("setting up the terminal (raw mode, alternate screen)")?;
        let restore = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let _ = ratatui::crossterm::execute!(std::io::stdout(), ratatui::crossterm::cursor::Show);
            restore(info);
        }));
        Ok(Self { terminal })
    }
}

impl Drop for Screen {
    fn drop(&mut self) {
        let _ = self.terminal.show_cursor();
        ratatui::restore();
    }
}

/// Whether a key quits: `q`, Esc, or Ctrl-C (raw mode delivers it as a key, not as SIGINT).
fn quits(key: &KeyEvent) -> bool {
    key.kind == KeyEventKind::Press
        && match key.code {
            KeyCode::Char('q' | 'Q') | KeyCode::Esc => true,
            KeyCode::Char('c') => key.modifiers.contains(KeyModifiers::CONTROL),
            _ => false,
        }
}

/// Runs the view until a quitting key, `stop` (SIGINT, SIGTERM or SIGHUP from another process)
/// or the terminal's hang-up; a guard thread ends the process if the view cannot end by itself
/// within a second of being told to ([`Tty::guard`]).
pub(super) fn run(feed: &mut Feed<'_>, interval: Duration, stop: &AtomicBool) -> Result<()> {
    let tty = Tty::open()?;
    let done = AtomicBool::new(false);
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("op3dsg-watch-tty".into())
            .spawn_scoped(scope, || tty.guard(stop, &done))
            .context("starting the terminal guard thread")?;
        // Set however the view ends, a panic included: the scope waits for the guard to end.
        let _done = SetOnDrop(&done);
        view_loop(feed, interval, stop, &tty)
    })
}

/// Sets its flag when dropped.
struct SetOnDrop<'a>(&'a AtomicBool);

impl Drop for SetOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::SeqCst);
    }
}

fn view_loop(feed: &mut Feed<'_>, interval: Duration, stop: &AtomicBool, tty: &Tty) -> Result<()> {
    let source = feed.describe();
    let mut screen = Screen::enter()?;
    let mut warnings = Warnings::default();
    let mut health_seen = None;
    let mut graph_seen = None;
    let mut redraw = true;
    let mut drawn = Instant::now();
    while !stop.load(Ordering::SeqCst) {
        redraw |= feed.poll()?;
        let now = Instant::now();
        if let Some(h) = feed.health()
            && health_seen != Some(h.stamp_ns)
        {
            warnings.observe(h, now);
            health_seen = Some(h.stamp_ns);
            redraw = true;
        }
        if let Some(g) = feed.graph()
            && graph_seen != Some((g.instance_id(), g.version()))
        {
            warnings.observe_graph(g, now);
            graph_seen = Some((g.instance_id(), g.version()));
        }
        if redraw || drawn.elapsed() >= interval {
            let now_unix_ns =
                std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
            let view = View {
                source: &source,
                connected: feed.connected(),
                graph: feed.graph(),
                health: feed.health(),
                warnings: &warnings,
                now,
                now_unix_ns,
            };
            screen.terminal.draw(|frame| view::draw(frame, &view)).context("drawing the screen")?;
            (redraw, drawn) = (false, Instant::now());
            // Test fault (`--features fault-hooks` only): a panic once a graph is on the screen,
            // to show the terminal restored on that way out too.
            #[cfg(feature = "fault-hooks")]
            if feed.graph().is_some() && std::env::var_os("OP3DSG_WATCH_FAULT").is_some_and(|v| v == "panic") {
                panic!("injected by OP3DSG_WATCH_FAULT=panic");
            }
        }
        // Keys are read through crossterm only while the terminal is alive: on a hung-up one its
        // reader never returns. A resize (SIGWINCH) comes through crossterm too, input or not.
        if tty.wait(TICK) == Readiness::HungUp {
            break;
        }
        while event::poll(Duration::ZERO).context("reading the terminal's keys")? {
            match event::read().context("reading the terminal's keys")? {
                Event::Key(key) if quits(&key) => return Ok(()),
                // Drawing fits the new size; the next draw repaints the whole screen.
                Event::Resize(..) => redraw = true,
                _ => {}
            }
        }
    }
    Ok(())
}
