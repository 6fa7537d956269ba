//! Navigation targets from a running `op3dsgd` (real iceoryx2 between processes, no text encoder
//! needed for node ids):
//!
//! - the daemon publishes its occupancy map on `<prefix>/occupancy` with the documented QoS and
//!   header, and the map fills while it maps;
//! - this test process is the planner: for every node of the graph it reads over `graph` it asks
//!   `<prefix>/query` for that node by id, and every approach pose it gets lies on a free cell of
//!   the map the daemon published, within the standoff band of the node's box, facing the node's
//!   centre; nodes without a pose say why (no free cell within the band, unreachable);
//! - an unknown node id gets a "bad request" naming `node_id`;
//! - `op3dsg goal <id> --json`, a process of its own, prints the same pose; `op3dsg goal TEXT`
//!   without the text encoder fails naming it;
//! - the map is saved beside the map snapshot at shutdown and a restarted daemon publishes it
//!   again (its keyframe count goes on).
//!
//! Whether the poses are right in the true geometry of the room is `op3dsg bench nav`'s check
//! (`daemon/sim/src/eval/nav_bench.rs`, and its test on every room).

use std::process::Command;
use std::time::{Duration, Instant};

use op3dsg_ipc_types::iceoryx2::prelude::{NodeBuilder, PortFactory as _};
use op3dsg_ipc_types::services::{
    IpcService, OCCUPANCY_HISTORY_SIZE, OCCUPANCY_MAX_NODES, OCCUPANCY_MAX_PUBLISHERS, OCCUPANCY_MAX_SUBSCRIBERS,
    OCCUPANCY_SUBSCRIBER_BUFFER,
};
use op3dsg_ipc_types::{
    ApproachStatus, Graph, NodeView, OCCUPANCY_FREE_MAX_PERCENT, OCCUPANCY_OCCUPIED_MIN_PERCENT,
    OCCUPANCY_SCHEMA_VERSION, OccupancyHeader, QueryClient, QueryHit, QueryStatus,
};
use op3dsg_tests::{Daemon, binary, latest_map, open_occupancy_service, unique_prefix, wait_for};

#[test]
fn a_planner_gets_approach_poses_on_free_cells_of_the_published_map() {
    let prefix = unique_prefix("goal");
    let daemon = Daemon::start(&prefix, &["--set", "source.rate_hz=15"]);
    let mut graphs = daemon.graph_subscriber("goal-planner-graph");
    let client = QueryClient::open_wait(&prefix, "goal-planner", Duration::from_secs(60)).expect("query service");

    // The occupancy service, opened as any client opens it, with the documented QoS.
    let node = NodeBuilder::new()
        .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
        .create::<IpcService>()
        .expect("a plain iceoryx2 node");
    let service = open_occupancy_service(&node, &prefix);
    let config = service.static_config();
    assert_eq!(
        (config.history_size(), config.subscriber_max_buffer_size(), config.max_publishers()),
        (OCCUPANCY_HISTORY_SIZE, OCCUPANCY_SUBSCRIBER_BUFFER, OCCUPANCY_MAX_PUBLISHERS)
    );
    assert_eq!((config.max_subscribers(), config.max_nodes()), (OCCUPANCY_MAX_SUBSCRIBERS, OCCUPANCY_MAX_NODES));
    let subscriber = service.subscriber_builder().create().expect("occupancy subscriber");

    // Map, graph and the poses of every node, once the map has seen a good part of the room.
    let mut map: Option<(OccupancyHeader, Vec<i8>)> = None;
    let deadline = Instant::now() + Duration::from_secs(180);
    let (mut checked_ok, mut checked_none, mut rounds) = (0usize, 0usize, 0usize);
    while Instant::now() < deadline && (checked_ok < 8 || rounds < 2) {
        std::thread::sleep(Duration::from_millis(300));
        latest_map(&subscriber, &mut map);
        let Some((header, cells)) = map.as_ref() else { continue };
        assert_eq!(header.schema_version, OCCUPANCY_SCHEMA_VERSION);
        assert_eq!(cells.len(), header.cell_count(), "payload = width x height cells");
        if header.keyframes_integrated < 10 || header.robot_pose_valid != 1 {
            continue;
        }
        let Ok(Some(graph)) = graphs.latest() else { continue };
        if graph.node_count() < 5 {
            continue;
        }
        rounds += 1;
        let (header, cells) = (*header, cells.clone());
        assert!(header.free_cells > 100 && header.occupied_cells > 10, "the map fills: {header:?}");
        for view in graph.nodes() {
            match check_node_query(&client, graph, &view, &header, &cells) {
                Checked::ApproachPose => checked_ok += 1,
                Checked::NoApproachPose => checked_none += 1,
                Checked::MergedAway => {}
            }
        }
    }
    eprintln!("goal: {checked_ok} approach poses checked, {checked_none} nodes without one, over {rounds} graphs");
    assert!(checked_ok >= 8, "only {checked_ok} approach poses ({checked_none} nodes without one)");

    // An unknown node: a clear refusal naming the field.
    let unknown = client.query_node(9_999_999, Duration::from_secs(10)).expect("a reply");
    assert_eq!(unknown.query_status(), Some(QueryStatus::BadRequest));
    assert!(unknown.message_str().starts_with("node_id:"), "{}", unknown.message_str());

    let graph = graphs.latest().ok().flatten().expect("a graph");
    assert_cli_prints_a_goal(&prefix, graph);
    assert_cli_goal_from_text_needs_the_encoder(&prefix);
    drop(daemon);
}

/// What the query of one node gave.
enum Checked {
    /// An approach pose, and it passed the checks.
    ApproachPose,
    /// No approach pose, for a reason the planner can act on.
    NoApproachPose,
    /// The node is of an older graph version, merged away since.
    MergedAway,
}

/// Asks `client` for `view`, a node of `graph`, by id and checks the approach pose against the
/// map (`header`, `cells`) published about now and against the node's box.
fn check_node_query(
    client: &QueryClient,
    graph: &Graph,
    view: &NodeView<'_>,
    header: &OccupancyHeader,
    cells: &[i8],
) -> Checked {
    let response = client.query_node(view.id(), Duration::from_secs(10)).expect("a reply");
    match response.query_status() {
        Some(QueryStatus::Ok) => {}
        // A node of an older graph version the daemon has merged away since.
        Some(QueryStatus::BadRequest) if response.graph_version > graph.version() => return Checked::MergedAway,
        other => panic!("node {}: status {other:?}: {}", view.id(), response.message_str()),
    }
    assert_eq!(response.hit_count, 1);
    let hit = &response.hits()[0];
    assert_eq!((hit.node_id, hit.label_str()), (view.id(), view.label()));
    match hit.approach() {
        Some(ApproachStatus::Ok) => {}
        Some(ApproachStatus::NoFreeCell | ApproachStatus::Unreachable) => return Checked::NoApproachPose,
        other => panic!("node {} ({}): approach {other:?}", view.id(), view.label()),
    }
    assert_on_a_free_cell(view, hit, header, cells);
    // Exactly when the reply comes from the graph version read here, within 0.15 m / 0.2 rad of
    // it when the daemon has refined the node since.
    let same = response.graph_version == graph.version();
    let (tolerance_m, tolerance_rad) = if same { (1e-3, 1e-3) } else { (0.15, 0.2) };
    assert_in_band_facing_the_centre(view, hit, tolerance_m, tolerance_rad);
    assert!(hit.approach_path_m >= 0.0 && hit.approach_path_m.is_finite());
    Checked::ApproachPose
}

/// The approach pose lies on a free cell of the map published about now (the worker uses the
/// newest map; the cell may have changed since this copy, so occupied is what must not be).
fn assert_on_a_free_cell(view: &NodeView<'_>, hit: &QueryHit, header: &OccupancyHeader, cells: &[i8]) {
    let col = ((hit.approach_x_m - header.origin_x_m) / header.cell_size_m).floor() as usize;
    let row = ((hit.approach_y_m - header.origin_y_m) / header.cell_size_m).floor() as usize;
    assert!(col < header.width_cells as usize && row < header.height_cells as usize, "pose on the map");
    let cell = cells[row * header.width_cells as usize + col];
    assert!(
        cell < OCCUPANCY_OCCUPIED_MIN_PERCENT,
        "node {} ({}): approach ({:.2}, {:.2}) on cell {cell} %, free <= {OCCUPANCY_FREE_MAX_PERCENT}",
        view.id(),
        view.label(),
        hit.approach_x_m,
        hit.approach_y_m
    );
}

/// The approach pose is within the standoff band of the node's box and faces its centre (z up:
/// x, y), within the tolerances.
fn assert_in_band_facing_the_centre(view: &NodeView<'_>, hit: &QueryHit, tolerance_m: f32, tolerance_rad: f32) {
    let (min, max) = (view.box_min_m(), view.box_max_m());
    let dx = (min[0] - hit.approach_x_m).max(hit.approach_x_m - max[0]).max(0.0);
    let dy = (min[1] - hit.approach_y_m).max(hit.approach_y_m - max[1]).max(0.0);
    let standoff = dx.hypot(dy);
    assert!(
        (0.4 - tolerance_m..=0.8 + tolerance_m).contains(&standoff)
            && (standoff - hit.approach_standoff_m).abs() <= tolerance_m,
        "node {}: standoff {standoff} (reply {})",
        view.id(),
        hit.approach_standoff_m
    );
    let centre = view.centre_m();
    let facing = (centre[1] - hit.approach_y_m).atan2(centre[0] - hit.approach_x_m);
    let error = (facing - hit.approach_yaw_rad).rem_euclid(std::f32::consts::TAU);
    assert!(
        error.min(std::f32::consts::TAU - error) <= tolerance_rad,
        "node {}: yaw {} vs {facing}",
        view.id(),
        hit.approach_yaw_rad
    );
}

/// `op3dsg goal <id> --json`, a process of its own, prints a pose for a node of `graph` that has
/// one; for nodes without one it exits 1 with the reason.
fn assert_cli_prints_a_goal(prefix: &str, graph: &Graph) {
    let mut printed = false;
    for view in graph.nodes() {
        let out = Command::new(binary("op3dsg"))
            .args(["--prefix", prefix, "goal", &view.id().to_string(), "--json"])
            .output()
            .expect("run op3dsg goal");
        let stdout = String::from_utf8_lossy(&out.stdout);
        let json: serde_json::Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: {stdout}"));
        assert_eq!(json["schema"], "op3dsg.goal/1");
        assert_eq!(json["node_id"], view.id());
        if out.status.success() {
            assert_eq!(json["status"], "ok", "{stdout}");
            assert!(json["x_m"].is_f64() && json["yaw_rad"].is_f64(), "{stdout}");
            printed = true;
            break;
        }
        // No pose: exit 1, the reason in the JSON and on stderr.
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(stderr.contains("no approach pose"), "{stderr}");
        assert!(json["x_m"].is_null() && json["reason"].is_string(), "{stdout}");
    }
    assert!(printed, "op3dsg goal printed no pose for any node");
}

/// Text needs the encoder: `op3dsg goal TEXT` says so.
fn assert_cli_goal_from_text_needs_the_encoder(prefix: &str) {
    let out = Command::new(binary("op3dsg"))
        .args(["--prefix", prefix, "goal", "somewhere to wash my hands"])
        .output()
        .expect("run op3dsg goal");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("encoder_off"), "{stderr}");
}

#[test]
fn the_occupancy_map_survives_a_restart_beside_the_map_snapshot() {
    let prefix = unique_prefix("goal-restart");
    let dir = tempfile::tempdir().expect("snapshot dir");
    let dir_arg = format!("snapshot.dir={}", dir.path().display());
    let args = ["--set", "source.rate_hz=15", "--set", &dir_arg];
    let node = NodeBuilder::new()
        .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
        .create::<IpcService>()
        .expect("a plain iceoryx2 node");
    let first_map = |what: &str, above: u64| -> OccupancyHeader {
        let service = open_occupancy_service(&node, &prefix);
        let subscriber = service.subscriber_builder().create().expect("occupancy subscriber");
        let mut map = None;
        wait_for(what, Duration::from_secs(120), || {
            latest_map(&subscriber, &mut map);
            map.as_ref().map(|(h, _)| *h).filter(|h| h.keyframes_integrated > above)
        })
    };

    let mut daemon = Daemon::start(&prefix, &args);
    let before = first_map("a map of 10 keyframes", 9);
    daemon.sigterm();
    assert!(daemon.wait_exit(Duration::from_secs(30)).is_some_and(|s| s.success()), "clean exit");
    let saved = dir.path().join("occupancy.snapshot");
    assert!(saved.exists(), "{} written at shutdown", saved.display());

    let daemon = Daemon::start(&prefix, &args);
    let after = first_map("the restored map", 0);
    assert!(
        after.keyframes_integrated >= before.keyframes_integrated,
        "restored: {} keyframes after, {} before",
        after.keyframes_integrated,
        before.keyframes_integrated
    );
    assert_eq!((after.origin_x_m, after.origin_y_m), (before.origin_x_m, before.origin_y_m), "same grid");
    drop(daemon);
}
