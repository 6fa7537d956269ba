//! The terminal under `op3dsg watch`'s full-screen view, watched for a hang-up: when it goes away
//! (its tmux session killed, an SSH connection dropped) the view must end instead of reading a
//! dead terminal for ever, as crossterm's reader does (a hung-up terminal is always readable and
//! each read returns nothing). The view waits for keys here first and asks crossterm only when
//! the terminal is alive; a guard thread ends the process if the view cannot end by itself.

use std::fs::File;
use std::io::{IsTerminal, Stdin};
use std::os::fd::{AsFd, BorrowedFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use nix::errno::Errno;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};

/// The terminal crossterm reads its keys from: standard input when it is one, else `/dev/tty`.
pub(super) enum Tty {
    Stdin(Stdin),
    DevTty(File),
}

/// What [`Tty::wait`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Readiness {
    /// Keys (or other input) to read.
    Input,
    /// Nothing within the timeout.
    Quiet,
    /// The terminal is gone (hang-up, error, closed).
    HungUp,
}

/// How long the view may take to end once it was told to (a signal, a hang-up) before the guard
/// ends the process.
const GRACE: Duration = Duration::from_secs(1);
/// How often the guard looks at the terminal and the stop flag.
const GUARD_TICK: Duration = Duration::from_millis(100);

impl Tty {
    pub(super) fn open() -> Result<Self> {
        let stdin = std::io::stdin();
        if stdin.is_terminal() {
            return Ok(Self::Stdin(stdin));
        }
        File::open("/dev/tty").map(Self::DevTty).context("opening the terminal (/dev/tty)")
    }

    fn fd(&self) -> BorrowedFd<'_> {
        match self {
            Self::Stdin(stdin) => stdin.as_fd(),
            Self::DevTty(file) => file.as_fd(),
        }
    }

    /// Waits up to `timeout` for input on the terminal, or for its hang-up.
    pub(super) fn wait(&self, timeout: Duration) -> Readiness {
        let mut fds = [PollFd::new(self.fd(), PollFlags::POLLIN)];
        let timeout = PollTimeout::try_from(timeout).unwrap_or(PollTimeout::MAX);
        match poll(&mut fds, timeout) {
            Ok(0) | Err(Errno::EINTR) => Readiness::Quiet,
            Ok(_) => {
                let revents = fds[0].revents().unwrap_or(PollFlags::empty());
                if revents.intersects(PollFlags::POLLHUP | PollFlags::POLLERR | PollFlags::POLLNVAL) {
                    Readiness::HungUp
                } else if revents.contains(PollFlags::POLLIN) {
                    Readiness::Input
                } else {
                    Readiness::Quiet
                }
            }
            Err(_) => Readiness::HungUp,
        }
    }

    /// Whether the terminal has hung up (without waiting).
    fn hung_up(&self) -> bool {
        let mut fds = [PollFd::new(self.fd(), PollFlags::empty())];
        matches!(poll(&mut fds, PollTimeout::ZERO), Ok(n) if n > 0)
    }

    /// Until `done`: sets `stop` when the terminal hangs up, and ends the process when the view
    /// has not ended within [`GRACE`] of `stop` (a read that never returns): with status 129
    /// after a hang-up (128 + SIGHUP; a dead terminal has nothing to restore), else 130 after
    /// restoring the terminal.
    pub(super) fn guard(&self, stop: &AtomicBool, done: &AtomicBool) {
        let mut stopping_since: Option<Instant> = None;
        let mut hung_up = false;
        while !done.load(Ordering::SeqCst) {
            if !hung_up && self.hung_up() {
                hung_up = true;
                stop.store(true, Ordering::SeqCst);
            }
            if stop.load(Ordering::SeqCst) {
                let since = *stopping_since.get_or_insert_with(Instant::now);
                if since.elapsed() >= GRACE && !done.load(Ordering::SeqCst) {
                    if !hung_up {
                        ratatui::restore();
                    }
                    std::process::exit(if hung_up { 129 } else { 130 });
                }
            }
            std::thread::sleep(GUARD_TICK);
        }
    }
}
