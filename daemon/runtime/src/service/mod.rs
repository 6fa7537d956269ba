//! Running as a system service: what `systemd/op3dsgd.service` relies on.
//!
//! * [`notify`]: the sd_notify protocol (`READY=1` once the pipeline runs and the graph service
//!   exists, `STATUS=` lines, `WATCHDOG=1` only while the stages are alive, `STOPPING=1` on the
//!   shutdown ladder), and the stage heartbeats ([`Liveness`]) the watchdog decision is made
//!   from.
//! * [`snapshot`]: periodic, atomic, checksummed snapshots of the map, written by their own
//!   thread, and their restoration at start, so a restarted daemon serves the map it had.

pub mod notify;
pub mod snapshot;

pub use notify::{Liveness, ServiceNotifier};
