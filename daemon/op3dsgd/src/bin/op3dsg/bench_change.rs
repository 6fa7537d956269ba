//! `op3dsg bench change`: the change benchmark ([`op3dsg_sim::eval::change_bench`]).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use op3dsg_sim::eval::change_bench;

use super::write_output;

#[derive(Debug, clap::Args)]
pub(super) struct ChangeBenchArgs {
    /// Oracle noise presets, comma separated (clean, realistic, field).
    #[arg(long, value_delimiter = ',', default_value = "clean,realistic,field")]
    presets: Vec<String>,
    /// Scenes per preset (scene i: room i mod 4, seed i / 4 + 1).
    #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u64).range(1..=400))]
    scenes: u64,
    /// Scenes run in parallel (default: the machine's cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Profile to start from (default: the built-in base).
    #[arg(long)]
    profile: Option<PathBuf>,
    /// Profile overrides, section.key=value (a `fusion.change.*` key changes the runs with
    /// change handling on; `fusion.change.enabled` is set per side).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Write the report (every scene's changes, additions and controls) as JSON to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Exit with code 1 when a goal is missed.
    #[arg(long)]
    check: bool,
}

pub(super) fn run(args: ChangeBenchArgs) -> Result<()> {
    let threads = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    for preset in &args.presets {
        if !op3dsg_sim::oracle::OracleConfig::PRESETS.contains(&preset.as_str()) {
            bail!(
                "--presets: unknown preset '{preset}'; choose from {}",
                op3dsg_sim::oracle::OracleConfig::PRESETS.join(", ")
            );
        }
    }
    let started = Instant::now();
    let mut reports = Vec::new();
    for preset in &args.presets {
        let mut sets = vec![format!("detector.oracle.preset={preset}")];
        sets.extend(args.overrides.iter().cloned());
        let loaded = op3dsg_sim::load_profile(args.profile.as_deref(), &sets)
            .map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
        let progress = |scene: &str| eprintln!("bench change: {preset}: {scene} done");
        let runs = change_bench::run_scenes(&loaded.profile, args.scenes as usize, threads, &progress)
            .map_err(anyhow::Error::msg)?;
        let scenes = runs.iter().map(change_bench::score_scene).collect();
        reports.push(change_bench::PresetReport { preset: preset.clone(), scenes });
    }
    let mut text = format!(
        "{} scenes per preset, two laps each (the script at lap 1), {threads} threads, {:.1} s\n",
        args.scenes,
        started.elapsed().as_secs_f64()
    );
    text.push_str(&change_bench::text(&reports));
    write_output(None, &text)?;
    if let Some(path) = &args.json {
        let json = serde_json::to_string_pretty(&reports)?;
        std::fs::write(path, json + "\n").map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))?;
    }
    if args.check && !change_bench::goals_met(&reports) {
        std::process::exit(1);
    }
    Ok(())
}
