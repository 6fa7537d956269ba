//! Building a [`GraphSnapshot`] without the stack: in place in a sample loaned from shared memory
//! (the daemon, test publishers), or on the heap (tools, planner tests).

use core::mem::MaybeUninit;

use iceoryx2::port::LoanError;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::PlacementDefault;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::sample_mut_uninit::SampleMutUninit;

use crate::GraphSnapshot;

/// Initialises a loaned snapshot in place (every field to its placement default: ids
/// [`NO_NODE`](crate::NO_NODE), counts and text zero), without ever materialising the 3.9 MiB
/// value on the stack. The caller then writes the header and the valid nodes and edges.
///
/// iceoryx2 0.10 offers no safe in-place initialisation for such a type: `Publisher::loan` needs
/// `Default` and moves a stack value into the sample.
#[allow(unsafe_code)]
pub fn init_snapshot_in_place<S: iceoryx2::service::Service>(
    mut sample: SampleMutUninit<S, MaybeUninit<GraphSnapshot>, ()>,
) -> SampleMut<S, GraphSnapshot, ()> {
    let ptr = sample.payload_mut().as_mut_ptr();
    // SAFETY: `ptr` points to the loaned chunk, sized and aligned for `GraphSnapshot` and owned
    // exclusively by this sample. The derived `PlacementDefault` writes every field of the header
    // and every element of both arrays (all plain data, no padding-dependent invariants), so the
    // payload is fully initialised before `assume_init`.
    unsafe {
        GraphSnapshot::placement_default(ptr);
        sample.assume_init()
    }
}

/// Loans one snapshot from `publisher` and initialises it with [`init_snapshot_in_place`].
pub fn loan_snapshot<S: iceoryx2::service::Service>(
    publisher: &Publisher<S, GraphSnapshot, ()>,
) -> Result<SampleMut<S, GraphSnapshot, ()>, LoanError> {
    publisher.loan_uninit().map(init_snapshot_in_place)
}

/// A snapshot on the heap with every field at its placement default, built without passing
/// through the stack: for tools and tests that fill a [`GraphSnapshot`] outside shared memory
/// (for example to test a planner against [`Graph::from_snapshot`](crate::Graph::from_snapshot)).
#[allow(unsafe_code)]
pub fn boxed_snapshot() -> Box<GraphSnapshot> {
    let mut snapshot = Box::<GraphSnapshot>::new_uninit();
    // SAFETY: the box holds uninitialised memory sized and aligned for `GraphSnapshot`;
    // `placement_default` writes every field (see `init_snapshot_in_place`), so the value is
    // fully initialised before `assume_init`.
    unsafe {
        GraphSnapshot::placement_default(snapshot.as_mut_ptr());
        snapshot.assume_init()
    }
}
