//! `op3dsg bench`: `perf` (the pipeline, IPC and fusion-cost benchmark of `op3dsg_sim::perf`),
//! its hidden subscriber process `ipc-peer`, `soak` (the long run with map snapshots of
//! `op3dsg_sim::perf::soak`), `llm` (the hot path with a slow LLM server against none), and
//! `quality` (the synthetic quality benchmark).

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use super::bench_args::{LlmBenchArgs, PerfArgs, SoakArgs};
use super::write_output;
use crate::eval::load_text_encoder;

/// `op3dsg bench llm`.
pub(super) fn llm(args: LlmBenchArgs) -> Result<()> {
    use op3dsg_sim::perf;
    if !(args.delay_s.is_finite() && (0.0..=590.0).contains(&args.delay_s)) {
        bail!("--delay-s {}: must be within [0, 590] seconds", args.delay_s);
    }
    let delay = Duration::from_secs_f64(args.delay_s);
    if let Some(address) = &args.serve {
        let server = perf::SlowChatServer::start(address, delay)?;
        println!("serving {}/chat/completions, answers after {} s; interrupt to stop", server.base_url(), args.delay_s);
        loop {
            std::thread::sleep(Duration::from_secs(3600));
        }
    }
    let options = perf::PerfOptions {
        frames: args.frames,
        profile: args.profile,
        overrides: args.overrides,
        live_rate_hz: 0.0,
        rss_period: Duration::from_millis(500),
        ipc_nodes: Vec::new(),
        ipc_messages: 0,
        ipc_warmup: 0,
        peer_exe: std::path::PathBuf::new(),
        fusion_sizes: Vec::new(),
        fusion_steps: 0,
        fusion_keyframes: 0,
        zenoh: Default::default(),
        command: command_line(),
    };
    let report = perf::llm_hot_path(&options, delay)?;
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report).context("serialising the report")?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    write_output(None, &report.to_text())
}

/// `op3dsg bench perf`.
pub(super) fn perf(args: PerfArgs) -> Result<()> {
    use op3dsg_sim::perf;
    if !(args.live_rate_hz.is_finite() && args.live_rate_hz >= 0.0) {
        bail!("--live-rate-hz {}: must be 0 or a positive rate", args.live_rate_hz);
    }
    let (ipc_nodes, fusion_sizes, zenoh_nodes) = (args.ipc_nodes.0, args.fusion_sizes.0, args.zenoh_nodes.0);
    for (flag, sizes) in [("--ipc-nodes", &ipc_nodes), ("--zenoh-nodes", &zenoh_nodes)] {
        if let Some(&n) = sizes.iter().find(|&&n| n == 0 || n > op3dsg_ipc_types::MAX_NODES) {
            bail!("{flag} {n}: each size must be between 1 and {}", op3dsg_ipc_types::MAX_NODES);
        }
    }
    if let Some(&n) = fusion_sizes.iter().find(|&&n| n == 0) {
        bail!("--fusion-sizes {n}: each size must be at least 1");
    }
    if args.plot.is_some() && fusion_sizes.is_empty() {
        bail!("--plot needs the fusion curve: give --fusion-sizes");
    }
    let options = perf::PerfOptions {
        frames: args.frames,
        profile: args.profile,
        overrides: args.overrides,
        live_rate_hz: args.live_rate_hz,
        rss_period: Duration::from_millis(args.rss_period_ms),
        ipc_nodes,
        ipc_messages: args.ipc_messages as usize,
        ipc_warmup: args.ipc_warmup,
        peer_exe: std::env::current_exe().context("finding this executable (the IPC subscriber)")?,
        fusion_sizes,
        fusion_steps: args.fusion_steps as usize,
        fusion_keyframes: args.fusion_keyframes as usize,
        zenoh: perf::ZenohOptions {
            nodes: zenoh_nodes,
            messages: args.zenoh_messages as usize,
            warmup: args.zenoh_warmup,
            stage: args.zenoh_stage,
        },
        command: command_line(),
    };
    let report = perf::run(&options)?;
    if let Some(path) = &args.plot
        && let Some(curve) = &report.fusion
    {
        perf::fusion_curve::plot_png(curve, path)?;
    }
    let plot_link = args.plot.as_ref().map(|p| p.display().to_string());
    let markdown = report.to_markdown(plot_link.as_deref());
    write_output(None, &markdown)?;
    if let Some(path) = &args.markdown {
        write_output(Some(path), &markdown)?;
    }
    if let Some(path) = &args.json {
        report.write_json(path)?;
    }
    Ok(())
}

/// `op3dsg bench soak`.
pub(super) fn soak(args: SoakArgs) -> Result<()> {
    use op3dsg_sim::perf::soak;
    let options = soak::SoakOptions {
        frames: args.frames,
        compare_frames: args.compare_frames.unwrap_or(args.frames),
        snapshot_period_s: args.snapshot_period_s,
        rss_period: Duration::from_millis(args.rss_period_ms),
        profile: args.profile,
        overrides: args.overrides,
        command: command_line(),
    };
    let report = soak::run(&options)?;
    let markdown = report.to_markdown();
    write_output(None, &markdown)?;
    if let Some(path) = &args.markdown {
        write_output(Some(path), &markdown)?;
    }
    if let Some(path) = &args.json {
        report.write_json(path)?;
    }
    Ok(())
}

/// The command line as typed, program name shortened to `op3dsg`.
fn command_line() -> String {
    let mut words = vec!["op3dsg".to_owned()];
    words.extend(std::env::args().skip(1).map(|a| {
        if a.is_empty() || a.contains(|c: char| c.is_whitespace() || c == '"' || c == '\'') {
            format!("'{a}'")
        } else {
            a
        }
    }));
    words.join(" ")
}

/// `op3dsg bench ipc-peer`: the subscriber process of `bench perf`'s IPC measurement; prints its
/// receipts as one JSON line.
pub(super) fn ipc_peer(prefix: &str, rounds: usize) -> Result<()> {
    let receipts = op3dsg_sim::perf::ipc_peer(prefix, rounds)?;
    let mut text = serde_json::to_string(&receipts).context("serialising the receipts")?;
    text.push('\n');
    write_output(None, &text)
}

/// `op3dsg bench quality`.
/// With `detector.oracle.confusion_rate` above 0, the confusion table over the labels of the
/// first `scenes` benchmark scenes, one line per label.
fn confusion_lines(
    profile: &op3dsg_runtime::config::Profile,
    scenes: usize,
) -> Result<(String, Option<op3dsg_sim::oracle::ConfusionTable>)> {
    let mut instances = Vec::new();
    for i in 0..scenes {
        let (room, seed) = op3dsg_sim::eval::benchmark::scene(i);
        instances.extend(op3dsg_synthetic::Scene::generate(room, seed).instances().iter().cloned());
    }
    let Some(table) = op3dsg_sim::backends::confusion_table(profile, &instances)? else {
        return Ok((String::new(), None));
    };
    let mut out = format!(
        "confusable neighbours (MiniLM cosine >= {}, at most {}, against the knowledge base's names; a part's word is replaced in its label):\n",
        op3dsg_sim::oracle::CONFUSION_MIN_COSINE,
        op3dsg_sim::oracle::CONFUSION_MAX_NEIGHBOURS
    );
    for (word, near) in table.entries() {
        let near: Vec<String> = near.iter().map(|(n, c)| format!("{n} {c:.2}")).collect();
        out.push_str(&format!("    {word:<22} -> {}\n", near.join(", ")));
    }
    Ok((out, Some(table)))
}

/// What `bench quality` writes and checks besides the printed table.
pub(super) struct QualityOutputs<'a> {
    /// The report as JSON.
    pub(super) json: Option<&'a Path>,
    /// The tables as Markdown.
    pub(super) markdown: Option<&'a Path>,
    /// Fail when a target is missed.
    pub(super) check: bool,
    /// With `--curves`, where the curves' PNG goes.
    pub(super) curves_png: Option<&'a Path>,
}

/// Label word → confusable neighbours with their cosines, as the JSON carries them.
type ConfusionEntries<'a> = Vec<(&'a str, &'a [(String, f32)])>;

pub(super) fn quality(
    profile_path: Option<&Path>,
    overrides: &[String],
    scenes: usize,
    threads: usize,
    outputs: QualityOutputs<'_>,
) -> Result<()> {
    let QualityOutputs { json, markdown, check, curves_png } = outputs;
    use op3dsg_sim::eval::{benchmark, curves};
    let started = Instant::now();
    let loaded = op3dsg_sim::load_profile(profile_path, overrides).map_err(|e| anyhow::anyhow!("bad profile: {e}"))?;
    let mut encoder = load_text_encoder(profile_path)?;
    let bar = indicatif::ProgressBar::new(scenes as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} scenes {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let progress = |scene: &str| {
        bar.set_message(scene.to_owned());
        bar.inc(1);
    };
    let runs = benchmark::run_scenes(&loaded.profile, scenes, threads, &progress).map_err(|e| anyhow::anyhow!(e))?;
    bar.finish_and_clear();
    let report = benchmark::score(&runs, &mut encoder).map_err(|e| anyhow::anyhow!("scoring: {e}"))?;
    let wall_s = started.elapsed().as_secs_f64();
    let frames = op3dsg_sim::backends::synthetic_config(&loaded.profile)?.frame_count.unwrap_or(0);
    let mut text = format!(
        "{} scenes x {frames} frames ({} keyframes), {threads} threads, {:.1} s\n",
        report.scenes.len(),
        report.keyframes,
        wall_s
    );
    text.push_str(&benchmark::text(&report));
    let (confusion_text, confusions) = confusion_lines(&loaded.profile, scenes)?;
    text.push_str(&confusion_text);
    write_output(None, &text)?;
    let curves = match curves_png {
        None => None,
        Some(png) => {
            let progress = |line: &str| eprintln!("curves: {line} done");
            let curves = curves::run(&loaded.profile, scenes, threads, &mut encoder, &progress)
                .map_err(|e| anyhow::anyhow!("curves: {e}"))?;
            write_output(None, &curves::text(&curves))?;
            curves::plot_png(&curves, png)?;
            println!("curves drawn to {}", png.display());
            Some(curves)
        }
    };
    if let Some(path) = json {
        #[derive(serde::Serialize)]
        struct Out<'a> {
            overrides: &'a [String],
            frames: u64,
            threads: usize,
            wall_s: f64,
            report: &'a benchmark::QualityReport,
            #[serde(skip_serializing_if = "Option::is_none")]
            curves: Option<&'a curves::Curves>,
            /// Label word → confusable neighbours with their cosines.
            #[serde(skip_serializing_if = "Option::is_none")]
            confusions: Option<ConfusionEntries<'a>>,
        }
        let out = Out {
            overrides,
            frames,
            threads,
            wall_s,
            report: &report,
            curves: curves.as_ref(),
            confusions: confusions.as_ref().map(|t| t.entries()),
        };
        let mut out = serde_json::to_string_pretty(&out).context("serialising the report")?;
        out.push('\n');
        write_output(Some(path), &out)?;
    }
    if let Some(path) = markdown {
        let mut md = benchmark::markdown(&report);
        if let Some(curves) = &curves {
            md.push_str(&curves::markdown(curves));
        }
        write_output(Some(path), &md)?;
    }
    if check && !benchmark::missed_targets(&report).is_empty() {
        bail!("quality targets missed");
    }
    Ok(())
}
