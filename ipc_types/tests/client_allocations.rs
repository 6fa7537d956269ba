//! A warm client allocates nothing per graph: once a graph of a given size has been copied,
//! copying another of at most that size (and its indices) reuses every buffer. Counted with a
//! global allocator that counts the calls of the measuring thread only.

// A global allocator is an `unsafe impl`; it forwards to `System` unchanged.
#![allow(unsafe_code)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::Duration;

use common::{FakeDaemon, unique_prefix, write_kitchen, write_large};
use op3dsg_ipc_types::publish::GraphBuffer;
use op3dsg_ipc_types::{Graph, GraphSubscriber};

thread_local! {
    static MEASURING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

struct CountingAllocator;

fn count() {
    // `try_with`: the allocator also runs while thread-locals are torn down.
    if MEASURING.try_with(Cell::get).unwrap_or(false) {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
    }
}

// SAFETY: every method forwards to `System` with the caller's arguments, so `System`'s guarantees
// hold; counting touches only const-initialised thread-locals, which never allocate.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: forwarded unchanged (see the impl).
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: forwarded unchanged (see the impl).
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: forwarded unchanged (see the impl).
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged (see the impl).
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

/// Allocations `f` makes on this thread.
fn allocations_in<T>(f: impl FnOnce() -> T) -> (usize, T) {
    ALLOCATIONS.with(|n| n.set(0));
    MEASURING.with(|m| m.set(true));
    let result = f();
    MEASURING.with(|m| m.set(false));
    (ALLOCATIONS.with(Cell::get), result)
}

#[test]
fn copying_into_a_warm_graph_allocates_nothing() {
    let capacities = |s: &mut GraphBuffer| {
        s.header.node_capacity = op3dsg_ipc_types::MAX_NODES as u32;
        s.header.edge_capacity = op3dsg_ipc_types::MAX_EDGES as u32;
    };
    let mut large = GraphBuffer::new();
    capacities(&mut large);
    write_large(&mut large, 1, 2_000);
    let large = large.encode();
    let mut small = GraphBuffer::new();
    capacities(&mut small);
    write_kitchen(&mut small, 2);
    let small = small.encode();
    let mut graph = Graph::new();
    graph.copy_from(&large).expect("warm-up copy");

    let (allocations, result) = allocations_in(|| graph.copy_from(&small));
    result.expect("valid");
    assert_eq!(allocations, 0, "smaller graph after warm-up");
    assert_eq!(graph.node_count(), 7);
    let (allocations, result) = allocations_in(|| graph.copy_from(&large));
    result.expect("valid");
    assert_eq!(allocations, 0, "same size again");
    assert_eq!(graph.parts_of(10).map(|n| n.id()).collect::<Vec<_>>(), [11]);
    let (allocations, parts) = allocations_in(|| graph.parts().count() + graph.edges_from(11).count());
    assert_eq!((allocations, parts), (0, 2_001), "views allocate nothing");
}

#[test]
fn a_warm_subscriber_receives_a_graph_without_allocating() {
    let prefix = unique_prefix();
    let daemon = FakeDaemon::start(&prefix, 2);
    let mut graphs = GraphSubscriber::open(&prefix, "op3dsg-test-planner").expect("open graph");
    let mut receive = |version: u64| {
        daemon.publish_graph(|s| write_large(s, version, 1_000));
        assert!(graphs.wait_for_update(Duration::from_secs(5)).expect("wait"));
        allocations_in(|| graphs.latest().expect("read").map(|g| g.version()))
    };
    // Warm-up: the first copy sizes the buffers.
    assert_eq!(receive(1).1, Some(1));
    for version in 2..=4 {
        let (allocations, received) = receive(version);
        assert_eq!(received, Some(version));
        assert_eq!(allocations, 0, "version {version}");
    }
}

#[test]
fn reading_through_the_view_allocates_nothing_even_cold() {
    let prefix = unique_prefix();
    let daemon = FakeDaemon::start(&prefix, 2);
    let mut graphs = GraphSubscriber::open(&prefix, "op3dsg-test-view").expect("open graph");
    for version in 1..=3 {
        daemon.publish_graph(|s| write_large(s, version, 1_000));
        assert!(graphs.wait_for_update(Duration::from_secs(5)).expect("wait"));
        let (allocations, read) = allocations_in(|| {
            graphs
                .with_latest(|view| {
                    let handle = view.node(1).map(|n| (n.label().len(), n.parent().map(|p| p.id())));
                    (view.version(), handle, view.parts_of(10).count(), view.edges_to(0).count())
                })
                .expect("read")
        });
        assert_eq!(read, Some((version, Some((6, Some(0))), 1, 1)));
        assert_eq!(allocations, 0, "version {version}: no copy, no index, no buffer");
    }
}
