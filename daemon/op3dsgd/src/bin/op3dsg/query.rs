//! `op3dsg query`: asks the daemon's `<prefix>/query` service for the nodes that serve a need in
//! words, and `op3dsg bench query`: the query benchmark on the synthetic rooms.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
#[cfg(feature = "zenoh")]
use op3dsg_ipc_types::client::RemoteRequester;
use op3dsg_ipc_types::{QueryClient, QueryRequest, QueryResponse, QueryStatus};
use serde::Serialize;

use super::DaemonAt;
use super::{node_name, write_output};

#[derive(Serialize)]
struct HitJson<'a> {
    node_id: u32,
    parent_id: Option<u32>,
    kind: &'static str,
    label: &'a str,
    score: f32,
    matched: &'static str,
    matched_text: &'a str,
    /// `ok` or why there is no approach pose (`no_free_cell`, `unreachable`, `no_map`, ...).
    approach_status: &'static str,
    /// Where to stand, with `ok`.
    approach: Option<ApproachJson>,
}

#[derive(Serialize)]
struct ApproachJson {
    x_m: f32,
    y_m: f32,
    yaw_rad: f32,
    standoff_m: f32,
    path_m: f32,
}

#[derive(Serialize)]
struct ReplyJson<'a> {
    schema: &'static str,
    text: &'a str,
    graph_version: u64,
    instance_id: String,
    scored_nodes: u32,
    encode_us: u32,
    score_us: u32,
    hits: Vec<HitJson<'a>>,
}

/// Opens the daemon's query service within `timeout`; returns the client and the time left of
/// `timeout` for the request (at least 100 ms). Not serving: the error says how to fix it.
pub(super) fn open_client(prefix: &str, timeout: Duration) -> Result<(QueryClient, Duration)> {
    let started = Instant::now();
    let client = QueryClient::open_wait(prefix, &node_name(), timeout).map_err(|e| {
        if e.is_not_serving() {
            anyhow::anyhow!("{e}; start it (op3dsgd) or pass the prefix it serves (--prefix / OP3DSG_PREFIX)")
        } else {
            anyhow::Error::new(e)
        }
    })?;
    Ok((client, timeout.saturating_sub(started.elapsed()).max(Duration::from_millis(100))))
}

/// Sends `request` to the service of `from`; the response and the service's name (for errors).
pub(super) fn ask(from: &DaemonAt<'_>, request: &QueryRequest, timeout: Duration) -> Result<(QueryResponse, String)> {
    match *from {
        DaemonAt::Iceoryx2 { prefix } => {
            let (client, left) = open_client(prefix, timeout)?;
            Ok((client.request(request, left)?, client.service_name().to_owned()))
        }
        #[cfg(feature = "zenoh")]
        DaemonAt::Zenoh { endpoint, key_prefix } => {
            let remote = RemoteRequester::connect(endpoint, key_prefix)?;
            let response = remote.query(request, timeout)?;
            Ok((response, format!("{} on {endpoint}", remote.key("query"))))
        }
    }
}

/// The response when its status is `Ok`, else an error with the daemon's message.
pub(super) fn check_status(response: &QueryResponse, service: &str) -> Result<()> {
    match response.query_status() {
        Some(QueryStatus::Ok) => Ok(()),
        Some(status) => bail!("{service}: {} ({})", response.message_str(), status.as_str()),
        None => bail!("{service}: unknown status {} in the reply", response.status),
    }
}

/// `op3dsg query TEXT`: prints the top-k nodes (a table, or JSON); exits with an error naming
/// the cause when the daemon is not running, has no text encoder, refuses (busy) or times out.
pub(super) fn query(from: DaemonAt<'_>, text: &str, k: u32, json: bool, timeout: Duration) -> Result<()> {
    let Some(request) = QueryRequest::new(text, k) else {
        bail!("TEXT: longer than {} bytes", op3dsg_ipc_types::QUERY_TEXT_CAPACITY_BYTES);
    };
    let (response, service) = ask(&from, &request, timeout)?;
    check_status(&response, &service)?;
    let hits: Vec<HitJson<'_>> = response
        .hits()
        .iter()
        .map(|h| HitJson {
            node_id: h.node_id,
            parent_id: (h.parent_id != op3dsg_ipc_types::NO_NODE).then_some(h.parent_id),
            kind: h.node_kind().map_or("unknown", |k| k.as_str()),
            label: h.label_str(),
            score: h.score,
            matched: h.query_match().map_or("unknown", |m| m.as_str()),
            matched_text: h.matched_text_str(),
            approach_status: h.approach().map_or("unknown", |a| a.as_str()),
            approach: (h.approach() == Some(op3dsg_ipc_types::ApproachStatus::Ok)).then_some(ApproachJson {
                x_m: h.approach_x_m,
                y_m: h.approach_y_m,
                yaw_rad: h.approach_yaw_rad,
                standoff_m: h.approach_standoff_m,
                path_m: h.approach_path_m,
            }),
        })
        .collect();
    let mut out = String::new();
    if json {
        let reply = ReplyJson {
            schema: "op3dsg.query/1",
            text,
            graph_version: response.graph_version,
            instance_id: format!("{:#018x}", response.instance_id),
            scored_nodes: response.scored_node_count,
            encode_us: response.encode_us,
            score_us: response.score_us,
            hits,
        };
        out = serde_json::to_string_pretty(&reply).context("serialising the reply")?;
        out.push('\n');
    } else {
        use std::fmt::Write as _;
        let _ = writeln!(
            out,
            "graph version {} ({} nodes scored; encode {} us, score {} us)",
            response.graph_version, response.scored_node_count, response.encode_us, response.score_us
        );
        let _ = writeln!(
            out,
            "{:>4}  {:>6}  {:<6}  {:<24}  {:>6}  {:<26}  why",
            "rank", "id", "kind", "label", "score", "approach (x, y m, yaw °)"
        );
        for (rank, h) in hits.iter().enumerate() {
            let approach = match &h.approach {
                Some(a) => format!("{:.2}, {:.2}, {:.0}", a.x_m, a.y_m, a.yaw_rad.to_degrees()),
                None => h.approach_status.to_owned(),
            };
            let _ = writeln!(
                out,
                "{:>4}  {:>6}  {:<6}  {:<24}  {:>6.3}  {:<26}  {}: {}",
                rank + 1,
                h.node_id,
                h.kind,
                h.label,
                h.score,
                approach,
                h.matched,
                h.matched_text
            );
        }
    }
    write_output(None, &out)
}

/// `op3dsg bench query`.
pub(super) fn bench(profile_path: Option<&Path>, overrides: &[String], seed: u64, json: Option<&Path>) -> Result<()> {
    use op3dsg_sim::eval::query_bench;
    let started = Instant::now();
    let loaded = op3dsg_sim::load_profile(profile_path, overrides).map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
    let mut encoder = super::eval::load_text_encoder(profile_path)?;
    let mut graphs = Vec::new();
    for room in op3dsg_synthetic::RoomKind::ALL {
        eprintln!("mapping {} (seed {seed}) ...", room.as_str());
        graphs.push(query_bench::room_graph(&loaded.profile, room, seed).map_err(|e| anyhow::anyhow!(e))?);
    }
    let report = query_bench::run(&graphs, &mut encoder).map_err(|e| anyhow::anyhow!("query benchmark: {e}"))?;
    let mut text = format!(
        "{} queries on 4 synthetic rooms (seed {seed}), {:.1} s\n",
        query_bench::QUERIES.len(),
        started.elapsed().as_secs_f64()
    );
    text.push_str(&query_bench::text(&report));
    super::write_report(&text, json, &report)
}
