//! How the health record is gathered: every stage's counters fill their own fields of it
//! ([`ReportHealth`]), and the composition hands the publisher one [`HealthSource`] that asks
//! them all, so no stage reads another's counters and the publisher knows none of them.

use op3dsg_ipc_types::Health;

/// A stage's counters that fill their part of a health record.
pub trait ReportHealth: Send + Sync {
    /// Writes this stage's fields of `health` (latency figures start a new period).
    fn report(&self, health: &mut Health);
}

/// The health record of this moment, as the publisher sends it every `health.period_ms`.
pub trait HealthSource: Send + Sync {
    /// The record now (starts a new latency period for every stage).
    fn health(&self) -> Health;
}
