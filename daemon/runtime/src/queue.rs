//! Bounded queues between pipeline stages, with a named overflow policy and counters, and the
//! latest-wins slot [`Latest`]. A leaf: it imports nothing of the stages.
//!
//! Every arrow of the pipeline is one [`Queue`]: its capacity and [`OverflowPolicy`] come from
//! the profile, every item dropped is counted in [`QueueStats`] (published in `health`).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError, bounded};
use serde::{Deserialize, Serialize};

/// What a full queue does with a new item.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OverflowPolicy {
    /// Drop the oldest waiting item to make room (camera frames: the newest view matters).
    LatestWins,
    /// The producer waits until there is room (results that must not be lost). The wait is
    /// interrupted by shutdown.
    Block,
}

/// Capacity and policy of one queue (a profile entry).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueueConfig {
    /// Items the queue holds, at least 1.
    pub capacity: usize,
    /// What happens when it is full.
    pub policy: OverflowPolicy,
}

impl QueueConfig {
    /// Checks the capacity; `path` names the profile field for the message.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(1..=1024).contains(&self.capacity) {
            return Err(format!("{path}.capacity: must be within [1, 1024], got {}", self.capacity));
        }
        Ok(())
    }
}

/// Counters of one queue, shared with the health reporter.
pub struct QueueStats {
    /// Queue name as reported in health.
    pub name: &'static str,
    /// Capacity.
    pub capacity: usize,
    /// Items pushed.
    pub pushed: AtomicU64,
    /// Items dropped (overwritten under latest-wins, or lost at shutdown while blocked).
    pub dropped: AtomicU64,
    depth: Box<dyn Fn() -> usize + Send + Sync>,
}

impl std::fmt::Debug for QueueStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QueueStats").field("name", &self.name).field("depth", &self.depth()).finish_non_exhaustive()
    }
}

impl QueueStats {
    /// Items waiting now.
    pub fn depth(&self) -> usize {
        (self.depth)()
    }
}

/// Result of a push.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pushed {
    /// Queued without loss.
    Queued,
    /// Queued, and an older item was dropped to make room.
    QueuedDroppingOldest,
    /// Not queued: shutdown was requested while waiting, or every consumer is gone.
    Closed,
}

/// Sending half of a bounded queue.
#[derive(Debug)]
pub struct QueueSender<T> {
    tx: Sender<T>,
    // Held so the sender can evict the oldest item under latest-wins.
    evict: Receiver<T>,
    policy: OverflowPolicy,
    stats: Arc<QueueStats>,
    stop: Arc<AtomicBool>,
}

// Manual impls: cloning a handle must not require `T: Clone`.
impl<T> Clone for QueueSender<T> {
    fn clone(&self) -> Self {
        Self {
            tx: self.tx.clone(),
            evict: self.evict.clone(),
            policy: self.policy,
            stats: self.stats.clone(),
            stop: self.stop.clone(),
        }
    }
}

/// Receiving half of a bounded queue.
#[derive(Debug)]
pub struct QueueReceiver<T> {
    rx: Receiver<T>,
}

impl<T> Clone for QueueReceiver<T> {
    fn clone(&self) -> Self {
        Self { rx: self.rx.clone() }
    }
}

/// Creates a queue. `stop` interrupts a blocked producer (the shutdown flag).
pub fn queue<T: Send + 'static>(
    name: &'static str,
    config: QueueConfig,
    stop: Arc<AtomicBool>,
) -> (QueueSender<T>, QueueReceiver<T>, Arc<QueueStats>) {
    let (tx, rx) = bounded::<T>(config.capacity.max(1));
    let probe_rx = rx.clone();
    let stats = Arc::new(QueueStats {
        name,
        capacity: config.capacity,
        pushed: AtomicU64::new(0),
        dropped: AtomicU64::new(0),
        depth: Box::new(move || probe_rx.len()),
    });
    let sender = QueueSender { tx, evict: rx.clone(), policy: config.policy, stats: stats.clone(), stop };
    (sender, QueueReceiver { rx }, stats)
}

impl<T> QueueSender<T> {
    /// Pushes an item according to the queue's policy. Never blocks under latest-wins; under
    /// block waits for room, checking the stop flag every 20 ms.
    pub fn push(&self, mut item: T) -> Pushed {
        let mut outcome = Pushed::Queued;
        loop {
            match self.tx.try_send(item) {
                Ok(()) => {
                    self.stats.pushed.fetch_add(1, Ordering::Relaxed);
                    return outcome;
                }
                Err(TrySendError::Disconnected(_)) => {
                    self.stats.dropped.fetch_add(1, Ordering::Relaxed);
                    return Pushed::Closed;
                }
                Err(TrySendError::Full(back)) => match self.policy {
                    OverflowPolicy::LatestWins => {
                        if self.evict.try_recv().is_ok() {
                            self.stats.dropped.fetch_add(1, Ordering::Relaxed);
                            outcome = Pushed::QueuedDroppingOldest;
                        }
                        item = back;
                    }
                    OverflowPolicy::Block => match self.tx.send_timeout(back, Duration::from_millis(20)) {
                        Ok(()) => {
                            self.stats.pushed.fetch_add(1, Ordering::Relaxed);
                            return outcome;
                        }
                        Err(crossbeam_channel::SendTimeoutError::Timeout(back)) => {
                            if self.stop.load(Ordering::Relaxed) {
                                self.stats.dropped.fetch_add(1, Ordering::Relaxed);
                                return Pushed::Closed;
                            }
                            item = back;
                        }
                        Err(crossbeam_channel::SendTimeoutError::Disconnected(_)) => {
                            self.stats.dropped.fetch_add(1, Ordering::Relaxed);
                            return Pushed::Closed;
                        }
                    },
                },
            }
        }
    }

    /// The queue's counters.
    pub fn stats(&self) -> &Arc<QueueStats> {
        &self.stats
    }
}

/// What a timed pop produced.
#[derive(Debug)]
pub enum Popped<T> {
    /// An item.
    Item(T),
    /// Nothing within the timeout.
    Empty,
    /// Every sender is gone and the queue is drained: the upstream stage has finished.
    Finished,
}

impl<T> QueueReceiver<T> {
    /// Waits up to `timeout` for an item.
    pub fn pop_timeout(&self, timeout: Duration) -> Popped<T> {
        match self.rx.recv_timeout(timeout) {
            Ok(item) => Popped::Item(item),
            Err(RecvTimeoutError::Timeout) => Popped::Empty,
            Err(RecvTimeoutError::Disconnected) => Popped::Finished,
        }
    }

    /// Takes an item if one is waiting.
    pub fn try_pop(&self) -> Option<T> {
        self.rx.try_recv().ok()
    }
}

/// The newest value one thread produces for others to read: a slot, not a queue (latest wins,
/// nothing waits). The publisher's graph for the query worker and the occupancy map for it are
/// shared this way; `close` tells readers that no newer value will come.
#[derive(Debug)]
pub struct Latest<T> {
    slot: Mutex<Option<T>>,
    closed: AtomicBool,
}

impl<T> Default for Latest<T> {
    fn default() -> Self {
        Self { slot: Mutex::new(None), closed: AtomicBool::new(false) }
    }
}

impl<T> Latest<T> {
    /// An empty slot.
    pub fn new() -> Self {
        Self::default()
    }

    /// Replaces the value.
    pub fn set(&self, value: T) {
        *self.slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(value);
    }

    /// Changes the value in place (`None` before the first), e.g. a copy into a buffer kept from
    /// the last time.
    pub fn update(&self, change: impl FnOnce(&mut Option<T>)) {
        change(&mut self.slot.lock().unwrap_or_else(PoisonError::into_inner));
    }

    /// Reads the value under the slot's lock (keep it short: the producer waits for it).
    pub fn read<R>(&self, read: impl FnOnce(Option<&T>) -> R) -> R {
        read(self.slot.lock().unwrap_or_else(PoisonError::into_inner).as_ref())
    }

    /// A copy of the value.
    pub fn get(&self) -> Option<T>
    where
        T: Clone,
    {
        self.read(|value| value.cloned())
    }

    /// The producer has ended: no newer value will come.
    pub fn close(&self) {
        self.closed.store(true, Ordering::Relaxed);
    }

    /// Whether [`Latest::close`] was called.
    pub fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stop() -> Arc<AtomicBool> {
        Arc::new(AtomicBool::new(false))
    }

    #[test]
    fn latest_wins_drops_the_oldest_and_counts_it() {
        let (tx, rx, stats) =
            queue::<u32>("t", QueueConfig { capacity: 2, policy: OverflowPolicy::LatestWins }, stop());
        assert_eq!(tx.push(1), Pushed::Queued);
        assert_eq!(tx.push(2), Pushed::Queued);
        assert_eq!(tx.push(3), Pushed::QueuedDroppingOldest);
        assert_eq!(stats.dropped.load(Ordering::Relaxed), 1);
        assert_eq!(stats.depth(), 2);
        assert!(matches!(rx.pop_timeout(Duration::ZERO), Popped::Item(2)));
        assert!(matches!(rx.pop_timeout(Duration::ZERO), Popped::Item(3)));
        assert!(matches!(rx.pop_timeout(Duration::ZERO), Popped::Empty));
    }

    #[test]
    fn block_waits_for_room_and_gives_up_on_stop() {
        let stop_flag = stop();
        let (tx, rx, stats) =
            queue::<u32>("t", QueueConfig { capacity: 1, policy: OverflowPolicy::Block }, stop_flag.clone());
        assert_eq!(tx.push(1), Pushed::Queued);
        let consumer = std::thread::Builder::new()
            .name("consumer".into())
            .spawn(move || {
                std::thread::sleep(Duration::from_millis(50));
                let first = rx.pop_timeout(Duration::from_secs(1));
                (first, rx)
            })
            .unwrap();
        // Blocks until the consumer takes item 1.
        assert_eq!(tx.push(2), Pushed::Queued);
        let (first, rx) = consumer.join().unwrap();
        assert!(matches!(first, Popped::Item(1)));
        stop_flag.store(true, Ordering::Relaxed);
        // Full again and stop requested: the push gives up instead of hanging.
        assert_eq!(tx.push(3), Pushed::Closed);
        assert_eq!(stats.dropped.load(Ordering::Relaxed), 1);
        drop(tx);
        assert!(matches!(rx.pop_timeout(Duration::ZERO), Popped::Item(2)));
        assert!(matches!(rx.pop_timeout(Duration::ZERO), Popped::Finished));
    }

    #[test]
    fn latest_keeps_only_the_newest_value_and_says_when_it_is_closed() {
        let latest = Latest::new();
        assert_eq!(latest.get(), None);
        latest.set(vec![1]);
        latest.set(vec![2]);
        latest.update(|slot| slot.get_or_insert_with(Vec::new).push(3));
        assert_eq!(latest.read(|v| v.map(Vec::len)), Some(2));
        assert_eq!(latest.get(), Some(vec![2, 3]));
        assert!(!latest.is_closed());
        latest.close();
        assert!(latest.is_closed());
    }
}
