//! The ground-truth side channel: per-pixel instance ids of each rendered frame, handed from
//! the synthetic source to the oracle detector and the evaluation without passing through
//! [`Frame`].
//!
//! The runtime sees a [`Frame`] (colour, depth, intrinsics, stamp, pose) and nothing more. The
//! synthetic source renders each frame's instance-id image into an [`InstanceIdChannel`] slot
//! that belongs to the frame's buffer: pooled frames keep their buffers for life, so the slot
//! of a frame in flight is not overwritten until the frame is back in the pool and taken again.
//! A reader looks the slot up with the same frame and gets the ids only when the slot still
//! holds that frame's sequence number.
//!
//! Memory: one slot (`width * height` u16) per distinct frame buffer the source ever filled
//! (the frame pool's capacity in the pipeline, one frame in the batch runner), allocated when
//! a buffer is first filled and reused afterwards.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

use op3dsg_drivers::frame::Frame;

/// The instance-id images of the frames a [`crate::SyntheticSource`] delivered, keyed by
/// frame buffer. Cloning shares the channel (the source writes, detectors and evaluation read).
#[derive(Debug, Clone, Default)]
pub struct InstanceIdChannel {
    slots: Arc<Mutex<HashMap<usize, Arc<Mutex<Slot>>>>>,
}

#[derive(Debug, Default)]
struct Slot {
    /// Sequence number of the frame whose ids the slot holds.
    seq: u64,
    /// Whether `ids` holds anything yet.
    filled: bool,
    /// Row-major instance ids; 0 = background / structure.
    ids: Vec<u16>,
}

/// Identity of a frame's buffer: the address of its depth buffer, which never moves while the
/// frame lives (buffers are sized once and reused).
fn buffer_key(frame: &Frame) -> usize {
    frame.depth.as_ptr() as usize
}

impl InstanceIdChannel {
    /// An empty channel.
    pub fn new() -> Self {
        Self::default()
    }

    fn slot(&self, frame: &Frame, create: bool) -> Option<Arc<Mutex<Slot>>> {
        let mut slots = self.slots.lock().unwrap_or_else(PoisonError::into_inner);
        let key = buffer_key(frame);
        if create { Some(slots.entry(key).or_default().clone()) } else { slots.get(&key).cloned() }
    }

    /// Lets `fill` produce `frame` and its instance ids, written into the frame buffer's slot
    /// (replacing what the buffer's previous frame left there) and tagged with the `seq`
    /// `fill` leaves in the frame.
    pub fn write(&self, frame: &mut Frame, fill: impl FnOnce(&mut Frame, &mut Vec<u16>)) {
        let Some(slot) = self.slot(frame, true) else { return };
        let mut slot = slot.lock().unwrap_or_else(PoisonError::into_inner);
        fill(frame, &mut slot.ids);
        slot.seq = frame.seq;
        slot.filled = true;
    }

    /// Runs `read` on the instance ids of `frame`; `None` when the channel holds no ids for it
    /// (a frame this channel's source did not render, or a copy of one).
    pub fn with_ids<R>(&self, frame: &Frame, read: impl FnOnce(&[u16]) -> R) -> Option<R> {
        let slot = self.slot(frame, false)?;
        let slot = slot.lock().unwrap_or_else(PoisonError::into_inner);
        (slot.filled && slot.seq == frame.seq && slot.ids.len() == frame.depth.len()).then(|| read(&slot.ids))
    }

    /// Frame buffers with a slot.
    pub fn slot_count(&self) -> usize {
        self.slots.lock().unwrap_or_else(PoisonError::into_inner).len()
    }
}

/// What the simulator knows and the runtime never sees: the scene (instances, their boxes,
/// labels and relations) and the per-frame instance ids. The synthetic source backend hands it
/// to the oracle detector and to evaluation.
#[derive(Debug, Clone)]
pub struct GroundTruth {
    /// The room as the source ends it: after every change of the change script (the
    /// generated room without one). Its [`crate::Scene::instances`] hold every instance that
    /// ever existed (removed ones too), its ground truth only the present ones.
    pub scene: crate::Scene,
    /// Instance ids of each delivered frame.
    pub instance_ids: InstanceIdChannel,
    /// The generated room, before the first change; `None` without a change script.
    pub initial: Option<crate::Scene>,
    /// What each change of the script did, in the order applied (frame order).
    pub changes: Vec<crate::AppliedChange>,
}

#[cfg(test)]
mod tests {
    use op3dsg_drivers::frame::{FramePool, Intrinsics};

    use super::*;

    #[test]
    fn a_frame_reads_its_own_ids_until_its_buffer_is_reused() {
        let k = Intrinsics { width: 4, height: 2, fx: 4.0, fy: 4.0, cx: 2.0, cy: 1.0 };
        let pool = FramePool::new(2, k);
        let channel = InstanceIdChannel::new();
        let mut a = pool.try_take().unwrap();
        channel.write(&mut a, |frame, ids| {
            frame.seq = 7;
            ids.resize(8, 3);
        });
        let mut b = pool.try_take().unwrap();
        channel.write(&mut b, |frame, ids| {
            frame.seq = 8;
            ids.resize(8, 5);
        });
        assert_eq!(channel.with_ids(&a, |ids| ids[0]), Some(3));
        assert_eq!(channel.with_ids(&b, |ids| ids[0]), Some(5));
        // A copy has other buffers: no ids, rather than another frame's.
        let copy = (*a).clone();
        assert_eq!(channel.with_ids(&copy, |ids| ids[0]), None);
        // The buffer of `a` comes back for frame 9: frame 7's ids are gone, frame 9 has its own.
        drop(a);
        let mut c = pool.try_take().unwrap();
        channel.write(&mut c, |frame, ids| {
            frame.seq = 9;
            ids.fill(9);
        });
        assert_eq!(channel.with_ids(&c, |ids| ids[0]), Some(9));
        assert_eq!(channel.slot_count(), 2);
    }
}
