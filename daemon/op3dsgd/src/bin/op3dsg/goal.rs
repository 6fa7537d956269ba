//! `op3dsg goal`: a navigation target for a node (by id) or for a need in words (the query's top
//! hit), from the daemon's `<prefix>/query` service; and `op3dsg bench nav`: the navigation check
//! on the synthetic rooms.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use op3dsg_ipc_types::{ApproachStatus, QueryRequest};
use serde::Serialize;

use super::DaemonAt;
use super::query::{ask, check_status};
use super::write_output;

#[derive(Serialize)]
struct GoalJson<'a> {
    schema: &'static str,
    /// What was asked: `node <id>` or the text.
    asked: String,
    graph_version: u64,
    node_id: u32,
    kind: &'static str,
    label: &'a str,
    /// `ok`, or why there is no pose.
    status: &'static str,
    reason: &'static str,
    /// On the floor plane (world x, y with z up), metres.
    x_m: Option<f32>,
    y_m: Option<f32>,
    yaw_rad: Option<f32>,
    standoff_m: Option<f32>,
    path_m: Option<f32>,
}

/// `op3dsg goal TARGET`: TARGET all digits is a node id, anything else a query whose top hit is
/// the node. Prints the approach pose (or JSON); exits 1 with the reason when there is none
/// (no free cell within the standoff band, unreachable, no map) or the daemon cannot answer.
pub(super) fn goal(from: DaemonAt<'_>, target: &str, json: bool, timeout: Duration) -> Result<()> {
    let target = target.trim();
    let node_id = target.parse::<u32>().ok();
    let request = match node_id {
        Some(id) => QueryRequest::for_node(id),
        None if target.is_empty() => bail!("TARGET: empty; give a node id or a need in words"),
        None => QueryRequest::new(target, 1)
            .with_context(|| format!("TARGET: longer than {} bytes", op3dsg_ipc_types::QUERY_TEXT_CAPACITY_BYTES))?,
    };
    let (response, service) = ask(&from, &request, timeout)?;
    check_status(&response, &service)?;
    let Some(hit) = response.hits().first() else {
        bail!("{service}: the graph (version {}) has no node to answer {target:?}", response.graph_version);
    };
    let status = hit.approach();
    let ok = status == Some(ApproachStatus::Ok);
    let asked = match node_id {
        Some(id) => format!("node {id}"),
        None => target.to_owned(),
    };
    let kind = hit.node_kind().map_or("unknown", |k| k.as_str());
    let reason = status.map_or("unknown approach status", ApproachStatus::explain);
    if json {
        let out = GoalJson {
            schema: "op3dsg.goal/1",
            asked,
            graph_version: response.graph_version,
            node_id: hit.node_id,
            kind,
            label: hit.label_str(),
            status: status.map_or("unknown", ApproachStatus::as_str),
            reason,
            x_m: ok.then_some(hit.approach_x_m),
            y_m: ok.then_some(hit.approach_y_m),
            yaw_rad: ok.then_some(hit.approach_yaw_rad),
            standoff_m: ok.then_some(hit.approach_standoff_m),
            path_m: ok.then_some(hit.approach_path_m),
        };
        let mut text = serde_json::to_string_pretty(&out).context("serialising the goal")?;
        text.push('\n');
        write_output(None, &text)?;
    } else if ok {
        write_output(
            None,
            &format!(
                "node {} ({kind} {:?}, graph version {}): stand at x {:.2} m, y {:.2} m, yaw {:.1}° ({:.3} rad); {:.2} m \
                 from the node, A* path {:.2} m\n",
                hit.node_id,
                hit.label_str(),
                response.graph_version,
                hit.approach_x_m,
                hit.approach_y_m,
                hit.approach_yaw_rad.to_degrees(),
                hit.approach_yaw_rad,
                hit.approach_standoff_m,
                hit.approach_path_m
            ),
        )?;
    }
    if !ok {
        bail!(
            "node {} ({kind} {:?}, graph version {}): no approach pose: {reason}",
            hit.node_id,
            hit.label_str(),
            response.graph_version
        );
    }
    Ok(())
}

/// `op3dsg bench nav`.
pub(super) fn bench(profile_path: Option<&Path>, overrides: &[String], seed: u64, json: Option<&Path>) -> Result<()> {
    use op3dsg_sim::eval::nav_bench;
    let started = Instant::now();
    let loaded = op3dsg_sim::load_profile(profile_path, overrides).map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
    let mut rooms = Vec::new();
    for room in op3dsg_synthetic::RoomKind::ALL {
        eprintln!("mapping {} (seed {seed}) ...", room.as_str());
        rooms.push(nav_bench::room_nav(&loaded.profile, room, seed).map_err(|e| anyhow::anyhow!(e))?);
    }
    let report = nav_bench::report(&loaded.profile, rooms);
    let mut text =
        format!("navigation check on 4 synthetic rooms (seed {seed}), {:.1} s\n", started.elapsed().as_secs_f64());
    text.push_str(&nav_bench::text(&report));
    super::write_report(&text, json, &report)
}
