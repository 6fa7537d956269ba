//! A stand-in planner for the cross-user tests: reads the graph, asks queries and follows
//! restarts through the client library only, and prints what it saw as plain lines the test
//! compares with `op3dsg dump --json`.
//!
//! ```text
//! op3dsg-test-planner --prefix P graph [--min-nodes N]   # the first graph with N nodes (default 1):
//!                                                       #   "graph <version> <instance> <nodes> <edges>",
//!                                                       #   then "node <id> <kind> <parent> <label>" per node
//! op3dsg-test-planner --prefix P query TEXT             # "hit <id> <label>" per hit of a text query
//! op3dsg-test-planner --prefix P follow SECONDS         # "instance <id>" for the first graph, then
//!                                                       #   "restarted <id>" when a new instance publishes
//! ```
//!
//! The daemon is waited for up to 30 s. Errors go to standard error (the client's message, which
//! names the IPC root and, when refused, its owner) with exit code 1.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use op3dsg_ipc_types::{GraphSubscriber, NodeKind, QueryClient};

const OPEN_TIMEOUT: Duration = Duration::from_secs(30);

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("op3dsg-test-planner: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &[String]) -> Result<(), String> {
    let prefix = flag(args, "--prefix").ok_or("--prefix is required")?;
    let node = format!("op3dsg-test-planner-{}", std::process::id());
    match positional(args).as_slice() {
        ["graph"] => {
            let min_nodes: usize =
                flag(args, "--min-nodes").map_or(Ok(1), |v| v.parse().map_err(|e| format!("{e}")))?;
            graph(&prefix, &node, min_nodes)
        }
        ["query", text] => query(&prefix, &node, text),
        ["follow", seconds] => follow(&prefix, &node, seconds.parse().map_err(|e| format!("{seconds}: {e}"))?),
        other => Err(format!("unknown command {other:?} (graph | query TEXT | follow SECONDS)")),
    }
}

fn flag(args: &[String], name: &str) -> Option<String> {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).cloned()
}

/// The arguments that are neither flags nor flag values.
fn positional(args: &[String]) -> Vec<&str> {
    let mut out = Vec::new();
    let mut skip = false;
    for arg in args {
        if std::mem::take(&mut skip) {
            continue;
        }
        if arg.starts_with("--") {
            skip = true;
        } else {
            out.push(arg.as_str());
        }
    }
    out
}

fn graph(prefix: &str, node: &str, min_nodes: usize) -> Result<(), String> {
    let mut graphs = GraphSubscriber::open_wait(prefix, node, OPEN_TIMEOUT).map_err(|e| e.to_string())?;
    let deadline = Instant::now() + OPEN_TIMEOUT;
    loop {
        graphs.wait_for_update(Duration::from_millis(200)).map_err(|e| e.to_string())?;
        if let Some(graph) = graphs.latest().map_err(|e| e.to_string())?
            && graph.node_count() >= min_nodes
        {
            println!("graph {} {} {} {}", graph.version(), graph.instance_id(), graph.node_count(), graph.edge_count());
            for n in graph.nodes() {
                let kind = if n.kind() == NodeKind::Part { "part" } else { "object" };
                let parent = graph.parent_of(n.id()).map_or(-1, |p| i64::from(p.id()));
                println!("node {} {kind} {parent} {}", n.id(), n.label());
            }
            return Ok(());
        }
        if Instant::now() > deadline {
            return Err(format!("no graph with {min_nodes} nodes within {OPEN_TIMEOUT:?}"));
        }
    }
}

fn query(prefix: &str, node: &str, text: &str) -> Result<(), String> {
    let client = QueryClient::open_wait(prefix, node, OPEN_TIMEOUT).map_err(|e| e.to_string())?;
    let response = client.query(text, 3, Duration::from_secs(20)).map_err(|e| e.to_string())?;
    if response.hits().is_empty() {
        return Err(format!("no hits: {}", response.message_str()));
    }
    for hit in response.hits() {
        println!("hit {} {}", hit.node_id, hit.label_str());
    }
    Ok(())
}

fn follow(prefix: &str, node: &str, seconds: f64) -> Result<(), String> {
    let mut graphs = GraphSubscriber::open_wait(prefix, node, OPEN_TIMEOUT).map_err(|e| e.to_string())?;
    let deadline = Instant::now() + Duration::from_secs_f64(seconds);
    let mut first = None;
    while Instant::now() < deadline {
        // A killed daemon's wake-ups stop; poll the sample as the docs ask.
        let _ = graphs.wait_for_update(Duration::from_millis(200));
        let Ok(Some(graph)) = graphs.latest_if_newer(0) else { continue };
        let instance = graph.instance_id();
        match first {
            None => {
                println!("instance {instance}");
                first = Some(instance);
            }
            Some(seen) if seen != instance => {
                println!("restarted {instance}");
                return Ok(());
            }
            Some(_) => {}
        }
        use std::io::Write as _;
        let _ = std::io::stdout().flush();
    }
    Err(format!("no restart seen within {seconds} s"))
}
