//! The zero-copy graph view and the occupancy client against the real daemon (synthetic kitchen):
//! on every sample of a live run the view and the owned decode of the same sample agree field
//! for field; a view held for a while does not stall the daemon's publisher; the occupancy map
//! the client reads is the one the daemon counted.

use std::time::{Duration, Instant};

use op3dsg_ipc_types::{
    EdgeRef, EdgeView, Graph, GraphView, Health, NodeRef, NodeView, OccupancyMap, OccupancySubscriber,
};
use op3dsg_tests::{Daemon, health_where, unique_prefix, wait_for};

/// A fast synthetic kitchen: 60 Hz and short health periods so the tests move quickly.
const FAST: &[&str] = &["--set", "source.rate_hz=60", "--set", "health.period_ms=100"];

/// Every field of a node, read through the owned graph's view.
fn owned_node(n: NodeView<'_>) -> String {
    format!(
        "{} {:?} {:?} {} {:?} {:?} {:?} {:?} {:?} {} {} {} {:?} {:?} {:?} {:?} parts {:?} out {:?} in {:?}",
        n.id(),
        n.kind(),
        n.label(),
        n.confidence(),
        n.centre_m(),
        n.box_min_m(),
        n.box_max_m(),
        n.size_m(),
        n.oriented_box(),
        n.observation_count(),
        n.last_seen_stamp_ns(),
        n.affordance_bits(),
        n.affordance_origins().collect::<Vec<_>>(),
        n.footprint_z_up_m(),
        n.parent_id(),
        n.parent().map(|p| p.id()),
        n.parts().map(|p| p.id()).collect::<Vec<_>>(),
        n.edges_from().map(|e| e.target_id()).collect::<Vec<_>>(),
        n.edges_to().map(|e| e.source_id()).collect::<Vec<_>>(),
    )
}

/// The same fields, read through the zero-copy view.
fn view_node(n: NodeRef<'_>) -> String {
    format!(
        "{} {:?} {:?} {} {:?} {:?} {:?} {:?} {:?} {} {} {} {:?} {:?} {:?} {:?} parts {:?} out {:?} in {:?}",
        n.id(),
        n.kind(),
        n.label(),
        n.confidence(),
        n.centre_m(),
        n.box_min_m(),
        n.box_max_m(),
        n.size_m(),
        n.oriented_box(),
        n.observation_count(),
        n.last_seen_stamp_ns(),
        n.affordance_bits(),
        n.affordance_origins().collect::<Vec<_>>(),
        n.footprint_z_up_m(),
        n.parent_id(),
        n.parent().map(|p| p.id()),
        n.parts().map(|p| p.id()).collect::<Vec<_>>(),
        n.edges_from().map(|e| e.target_id()).collect::<Vec<_>>(),
        n.edges_to().map(|e| e.source_id()).collect::<Vec<_>>(),
    )
}

fn owned_edge(e: EdgeView<'_>) -> String {
    let ends = (e.source().map(|n| n.id()), e.target().map(|n| n.id()));
    format!(
        "{} {} {:?} {:?} {} {:?} {} {ends:?}",
        e.source_id(),
        e.target_id(),
        e.kind(),
        e.origin(),
        e.relation_id(),
        e.phrase(),
        e.confidence()
    )
}

fn view_edge(e: EdgeRef<'_>) -> String {
    let ends = (e.source().map(|n| n.id()), e.target().map(|n| n.id()));
    format!(
        "{} {} {:?} {:?} {} {:?} {} {ends:?}",
        e.source_id(),
        e.target_id(),
        e.kind(),
        e.origin(),
        e.relation_id(),
        e.phrase(),
        e.confidence()
    )
}

/// Compares the view of one sample with the owned decode of the same bytes, field for field and
/// lookup for lookup; returns the node count.
fn agree(view: GraphView<'_>) -> usize {
    let owned = Graph::from_message(&view.message()).expect("the owned decode accepts what the view accepted");
    view.check_records().expect("the daemon writes only known kinds and origins");
    let version = view.version();
    assert_eq!(view.header(), owned.header(), "version {version}: header");
    assert_eq!(
        (view.instance_id(), view.stamp_ns(), view.source_kind(), view.world_frame()),
        (owned.instance_id(), owned.stamp_ns(), owned.source_kind(), owned.world_frame())
    );
    assert_eq!((view.node_count(), view.edge_count()), (owned.node_count(), owned.edge_count()));
    for (v, o) in view.nodes().zip(owned.nodes()) {
        assert_eq!(view_node(v), owned_node(o), "version {version}: node {}", o.id());
        assert_eq!(view.node(o.id()).map(|n| n.index()), Some(v.index()), "version {version}: node {} by id", o.id());
        assert_eq!(
            view.find_by_label(o.label()).map(|n| n.id()).collect::<Vec<_>>(),
            owned.find_by_label(o.label()).map(|n| n.id()).collect::<Vec<_>>()
        );
        assert_eq!(
            view.parts_of(o.id()).map(|n| n.id()).collect::<Vec<_>>(),
            owned.parts_of(o.id()).map(|n| n.id()).collect::<Vec<_>>()
        );
    }
    for (v, o) in view.edges().zip(owned.edges()) {
        assert_eq!(view_edge(v), owned_edge(o), "version {version}: edge");
    }
    for name in op3dsg_ipc_types::AFFORDANCES {
        let v: Vec<u32> = view.find_by_affordance(name).expect("canonical").map(|n| n.id()).collect();
        let o: Vec<u32> = owned.find_by_affordance(name).expect("canonical").map(|n| n.id()).collect();
        assert_eq!(v, o, "version {version}: {name}");
    }
    assert!(view.node(u32::MAX - 1).is_none() && owned.node(u32::MAX - 1).is_none());
    view.node_count()
}

#[test]
fn the_view_and_the_owned_decode_agree_on_every_sample_of_a_live_run() {
    let prefix = unique_prefix("view-agree");
    let daemon = Daemon::start(&prefix, FAST);
    let mut graphs = daemon.graph_subscriber("view-agree");
    let (mut samples, mut largest, mut versions) = (0, 0, Vec::new());
    let deadline = Instant::now() + Duration::from_secs(120);
    while (samples < 20 || largest < 10) && Instant::now() < deadline {
        graphs.wait_for_update(Duration::from_millis(200)).expect("wait");
        if let Some((version, nodes)) = graphs.with_latest(|view| (view.version(), agree(view))).expect("read") {
            samples += 1;
            largest = largest.max(nodes);
            versions.push(version);
        }
    }
    assert!(samples >= 20 && largest >= 10, "{samples} samples, the largest of {largest} nodes");
    assert!(versions.windows(2).all(|w| w[0] < w[1]), "each sample is a newer version: {versions:?}");
}

/// The `publish` stage of a health record: (graphs published, publish errors).
fn publish_stage(health: &Health) -> (u64, u32) {
    let stage = health.valid_stages().iter().find(|s| op3dsg_ipc_types::fixed_str(&s.name) == "publish");
    stage.map(|s| (s.processed, s.errors)).expect("a publish stage in health")
}

#[test]
fn holding_a_view_does_not_stall_the_daemon() {
    let prefix = unique_prefix("view-hold");
    let daemon = Daemon::start(&prefix, FAST);
    let mut graphs = daemon.graph_subscriber("view-hold");
    let mut health = daemon.health_subscriber("view-hold-health");
    wait_for("a first graph", Duration::from_secs(60), || graphs.latest().ok().flatten().map(|g| g.version()));
    graphs.wait_for_update(Duration::from_secs(10)).expect("wait");

    // Hold one sample: sleep, then wait (in the closure) until the daemon has published three
    // more graph versions and its publish stage has counted them, without an error.
    let (held_version, before, during) = wait_for("a view to hold", Duration::from_secs(30), || {
        graphs
            .with_latest(|view| {
                let before = publish_stage(&health_where(&mut health, "health", Duration::from_secs(30), |_| true));
                std::thread::sleep(Duration::from_millis(300));
                let during = health_where(
                    &mut health,
                    "three graph versions while the view is held",
                    Duration::from_secs(60),
                    |h| h.graph_version >= view.version() + 3 && publish_stage(h).0 >= before.0 + 3,
                );
                // The sample held is unchanged: the daemon writes new versions into other samples.
                assert_eq!(view.header().graph_version, view.version());
                (view.version(), before, publish_stage(&during))
            })
            .expect("read")
    });
    assert_eq!(during.1, before.1, "no publish error while a sample was held");

    // Released: the subscriber's buffer holds the newest versions published meanwhile.
    let after = wait_for("the next graph after the hold", Duration::from_secs(30), || {
        graphs.wait_for_update(Duration::from_millis(100)).ok()?;
        graphs.with_latest(|view| view.version()).expect("read")
    });
    assert!(after >= held_version + 3, "read version {after} after holding {held_version}");
}

#[test]
fn the_occupancy_map_is_read_as_the_daemon_counted_it() {
    let prefix = unique_prefix("occupancy-client");
    let daemon = Daemon::start(&prefix, FAST);
    let mut maps = OccupancySubscriber::open_wait(&prefix, "occupancy-client", Duration::from_secs(60))
        .expect("the occupancy service appears");
    let map = wait_for("a map with keyframes integrated", Duration::from_secs(60), || {
        maps.latest().expect("read").filter(|m| m.header().keyframes_integrated > 0).cloned()
    });
    let h = *map.header();
    assert_eq!(map.cells().len(), h.width_cells as usize * h.height_cells as usize);
    let free = map.cells().iter().filter(|&&v| OccupancyMap::is_free(v)).count();
    let occupied = map.cells().iter().filter(|&&v| OccupancyMap::is_occupied(v)).count();
    assert_eq!((free, occupied), (h.free_cells as usize, h.occupied_cells as usize), "the header counts these cells");
    assert!(free > 0, "the floor the camera saw is free");
    let (x, y, _) = map.robot_pose().expect("a keyframe was integrated");
    let (row, col) = map.cell_of(x, y).expect("the robot is on its map");
    assert!(map.cell(row, col).is_some_and(OccupancyMap::is_free), "the robot stands on a free cell");
    drop(daemon);
}
