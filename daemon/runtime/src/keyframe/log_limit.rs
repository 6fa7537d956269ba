//! [`LogLimit`]: at most one warning per reason per period, with the count of what was not
//! logged in between, so a broken pose stream cannot flood the journal.

use std::time::{Duration, Instant};

/// Period of the per-reason warnings of the keyframe gate.
pub(crate) const LOG_PERIOD: Duration = Duration::from_secs(10);

/// Per-reason rate limit over `N` reasons.
#[derive(Debug)]
pub(crate) struct LogLimit<const N: usize> {
    period: Duration,
    last: [Option<Instant>; N],
    suppressed: [u64; N],
}

impl<const N: usize> LogLimit<N> {
    pub(crate) fn new(period: Duration) -> Self {
        Self { period, last: [None; N], suppressed: [0; N] }
    }

    /// `Some(n)` when reason `reason` may be logged now (`n` occurrences were not logged since its
    /// last line); `None` when it is counted as suppressed. The first occurrence always logs.
    pub(crate) fn allow(&mut self, reason: usize, now: Instant) -> Option<u64> {
        let reason = reason.min(N.saturating_sub(1));
        let due = self.last[reason].is_none_or(|at| now.saturating_duration_since(at) >= self.period);
        if due {
            self.last[reason] = Some(now);
            Some(std::mem::take(&mut self.suppressed[reason]))
        } else {
            self.suppressed[reason] += 1;
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_per_reason_per_period_with_the_count_in_between() {
        let mut limit = LogLimit::<2>::new(Duration::from_secs(10));
        let t0 = Instant::now();
        assert_eq!(limit.allow(0, t0), Some(0));
        assert_eq!(limit.allow(0, t0 + Duration::from_secs(1)), None);
        assert_eq!(limit.allow(0, t0 + Duration::from_secs(2)), None);
        // Another reason has its own budget.
        assert_eq!(limit.allow(1, t0 + Duration::from_secs(2)), Some(0));
        assert_eq!(limit.allow(0, t0 + Duration::from_secs(10)), Some(2));
        assert_eq!(limit.allow(0, t0 + Duration::from_secs(11)), None);
    }
}
