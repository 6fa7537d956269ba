//! A minimal planner: waits for op3dsgd, then prints each new graph version with its counts and
//! every part with its parent object and affordances, each with its origin (`hook_pull:knowledge+llm`).
//!
//! `cargo run -p op3dsg-ipc-types --example planner -- [PREFIX | --prefix P] [--versions N]`
//! The prefix is the first argument or `--prefix`, else `$OP3DSG_PREFIX`, else `op3dsg`; with `--versions N` (or
//! `$OP3DSG_VERSIONS`) it exits after N graph versions, otherwise it runs until interrupted.

use std::time::Duration;

use op3dsg_ipc_types::GraphSubscriber;
use op3dsg_ipc_types::iceoryx2;
use op3dsg_ipc_types::services::DEFAULT_PREFIX;

fn main() -> std::process::ExitCode {
    // A planner prints its errors for a person: what failed and what to do (their Display), not
    // the Debug form `main` returning an error would print.
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("planner: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |flag: &str, env: &str| {
        let value = args.iter().position(|a| a == flag).and_then(|i| args.get(i + 1)).cloned();
        value.or_else(|| std::env::var(env).ok())
    };
    let positional = args.first().filter(|a| !a.starts_with("--")).cloned();
    let prefix = positional.or_else(|| arg("--prefix", "OP3DSG_PREFIX")).unwrap_or_else(|| DEFAULT_PREFIX.to_owned());
    let versions: Option<u64> = arg("--versions", "OP3DSG_VERSIONS")
        .map(|n| n.parse().map_err(|e| format!("--versions / OP3DSG_VERSIONS {n:?}: {e}; give a whole number")))
        .transpose()?;

    // iceoryx2 warns at start when it finds no config file and uses its defaults (fine here).
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let mut graphs = GraphSubscriber::open_wait(&prefix, "op3dsg-example-planner", Duration::from_secs(60))?;
    let (mut last_seen, mut printed) = (0, 0);
    while versions.is_none_or(|n| printed < n) {
        // Also read after a timeout: a late joiner's first graph comes without an event.
        graphs.wait_for_update(Duration::from_millis(500))?;
        let Some(graph) = graphs.latest_if_newer(last_seen)? else { continue };
        (last_seen, printed) = (graph.version(), printed + 1);
        let (objects, parts) = (graph.objects().count(), graph.parts().count());
        println!("version {} objects {objects} parts {parts} edges {}", graph.version(), graph.edge_count());
        for part in graph.parts() {
            let parent = part.parent().map_or("(none)", |p| p.label());
            // Each affordance with where it came from: knowledge, llm or knowledge+llm.
            let affordances: Vec<String> =
                part.affordance_origins().map(|(name, origin)| format!("{name}:{}", origin.as_str())).collect();
            println!(
                "  part {} {:?} of {parent:?} at {:?} m affords {affordances:?}",
                part.id(),
                part.label(),
                part.centre_m()
            );
        }
    }
    Ok(())
}
