//! Running as a system service: what `systemd/op3dsgd.service` relies on. The sd_notify protocol
//! ([`ServiceNotifier`]): `READY=1` once the pipeline runs and the graph service exists,
//! `STATUS=` lines, `WATCHDOG=1` only while the watched stages beat
//! ([`crate::stats::Liveness`]), `STOPPING=1` on the shutdown ladder. Map snapshots are fusion's
//! own (`crate::fusion::snapshot`).

pub mod notify;

pub use notify::{ServiceNotifier, status_line};
