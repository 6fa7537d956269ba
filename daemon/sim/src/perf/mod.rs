//! # `op3dsg bench perf`: the daemon's performance figures
//!
//! Five measurements, each a section of [`PerfReport`] (written as JSON) and of its Markdown
//! ([`PerfReport::to_markdown`]):
//!
//! 1. **Pipeline** ([`pipeline_run`]): the real pipeline of `op3dsgd` (named threads, bounded
//!    queues, the iceoryx2 publisher under a private prefix) on the synthetic scene of the
//!    profile with its detector (the oracle by default), twice: *as fast as possible*
//!    (`source.rate_hz = 0`, blocking queues, as `profiles/sim-batch.toml`) for keyframes per
//!    second, and *at camera rate* (`source.rate_hz = 30`, the profile's queues) for the latency
//!    a live robot sees. Per stage the p50 / p99 over the whole run (capture, keyframe gate,
//!    detection over all workers, fusion, prior graph + reasoner, publish), the `end_to_end`
//!    latency from a keyframe's capture to the send of the first graph version holding it, and
//!    the process's resident memory sampled over the run from `/proc/self/status`.
//! 2. **IPC** ([`ipc_latency`], the subscriber side in [`ipc_peer`]): graph publish → subscriber
//!    read between two processes (this one publishes, a child process of the same binary
//!    subscribes) for graphs of several sizes, read into the client library's owned `Graph` and
//!    through its zero-copy `GraphView`, next to raw iceoryx2 publish-subscribe of a byte slice of
//!    the same size measured in the same run, message for message interleaved. The ratios to raw
//!    are the figures.
//! 3. **Fusion cost against map size** ([`fusion_curve`]): one 40-detection step of a real
//!    kitchen keyframe into maps grown through several sizes (`fusion::workload`), with a PNG
//!    plot ([`fusion_curve::plot_png`]).
//! 4. **Fusion cost per keyframe next to the peer baseline's** ([`peer_fusion`]): the kitchen
//!    path's keyframes into OP3DSG's fusion and ConceptGraphs' (the `bench quality` peer row's),
//!    each call timed on one thread with the same input; skipped with the fusion curve.
//!
//! 5. **Zenoh** ([`zenoh_link`]): a full graph message over Zenoh (TCP loopback) next to a raw
//!    put of the same bytes, and the camera-rate pipeline without and with the Zenoh stage
//!    (fusion and publish latency, delta and full sizes, the stage's CPU).
//!
//! `op3dsg bench soak` ([`soak`]) runs the same pipeline for a long time with map snapshots on
//! and off: RSS slope, snapshot write and copy cost, and the fusion stage's latency.
//!
//! `op3dsg bench llm` ([`llm_hot_path`]) runs the pipeline twice more, without the LLM and with
//! a slow LLM server, for the fusion thread's p99 ratio.
//!
//! Nothing is assumed: every figure is measured in the run that reports it, and the report names
//! the machine (cores, build profile). Timings from a debug build or a shared machine are only
//! good for checking that the harness works.

pub mod fusion_curve;
pub mod ipc_latency;
pub mod ipc_peer;
pub mod llm_hot_path;
pub mod peer_fusion;
pub mod pipeline_run;
pub mod soak;
#[cfg(feature = "zenoh")]
pub mod zenoh_link;
pub mod zenoh_report;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

pub use fusion_curve::{FusionCurve, FusionPoint, fusion_curve};
pub use ipc_latency::{IpcLatency, IpcRow, ipc_latency};
pub use ipc_peer::{Receipts, ipc_peer};
pub use llm_hot_path::{LlmHotPath, SlowChatServer, StageComparison, llm_hot_path};
pub use peer_fusion::{FusionCost, PeerFusionCost, peer_fusion_cost};
pub use pipeline_run::{PipelineRun, RssSample, StageRow, pipeline_run};
pub use zenoh_report::{ZenohOptions, ZenohSection};

use op3dsg_runtime::stats::LatencyHistogram;

/// JSON schema name of [`PerfReport`].
pub const REPORT_SCHEMA: &str = "op3dsg.bench_perf/1";

/// What to measure and how much.
#[derive(Debug, Clone)]
pub struct PerfOptions {
    /// Frames per pipeline run.
    pub frames: u64,
    /// Profile the pipeline runs start from (`None`: the built-in base profile).
    pub profile: Option<PathBuf>,
    /// `section.key=value` overrides applied after each run's own settings.
    pub overrides: Vec<String>,
    /// Rate of the camera-rate run, Hz; 0 skips that run.
    pub live_rate_hz: f64,
    /// Period of the resident-memory samples.
    pub rss_period: Duration,
    /// Graph sizes (nodes) of the IPC measurement; empty skips it.
    pub ipc_nodes: Vec<usize>,
    /// Timed messages per IPC size and kind (graph, raw).
    pub ipc_messages: usize,
    /// Untimed messages per IPC size and kind before the timed ones.
    pub ipc_warmup: usize,
    /// The executable started as the IPC subscriber (`<exe> --prefix P bench ipc-peer ...`).
    pub peer_exe: PathBuf,
    /// Map sizes (nodes) of the fusion curve; empty skips it.
    pub fusion_sizes: Vec<usize>,
    /// Timed fusion steps per map size.
    pub fusion_steps: usize,
    /// Keyframes of the kitchen path the fusion maps are built from.
    pub fusion_keyframes: usize,
    /// The Zenoh section.
    pub zenoh: ZenohOptions,
    /// The command line, recorded in the report.
    pub command: String,
}

/// The machine and build a report was measured on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    /// CPUs this process may use.
    pub cores: usize,
    /// `release` or `debug` (debug timings only check the harness).
    pub build: String,
    /// Operating system and architecture.
    pub platform: String,
}

impl Machine {
    /// This machine and build.
    pub fn current() -> Self {
        Self {
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            build: if cfg!(debug_assertions) { "debug" } else { "release" }.to_owned(),
            platform: format!("{}-{}", std::env::consts::OS, std::env::consts::ARCH),
        }
    }
}

/// Everything `op3dsg bench perf` measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PerfReport {
    /// [`REPORT_SCHEMA`].
    pub schema: String,
    /// Where it was measured.
    pub machine: Machine,
    /// The command that made it.
    pub command: String,
    /// Pipeline runs (as fast as possible, then at camera rate).
    pub pipeline: Vec<PipelineRun>,
    /// Graph vs raw iceoryx2 latency between two processes (`None` when skipped).
    pub ipc: Option<IpcLatency>,
    /// Fusion step cost against map size (`None` when skipped).
    pub fusion: Option<FusionCurve>,
    /// Per-keyframe cost of OP3DSG's fusion and of the peer baseline's (ConceptGraphs) on the
    /// same keyframes (`None` when skipped, with the fusion curve).
    #[serde(default)]
    pub peer_fusion: Option<PeerFusionCost>,
    /// The graph over Zenoh and the Zenoh stage's cost (`None` when skipped).
    #[serde(default)]
    pub zenoh: Option<ZenohSection>,
}

/// Runs every measurement `options` asks for, printing progress to standard error.
pub fn run(options: &PerfOptions) -> anyhow::Result<PerfReport> {
    use anyhow::Context as _;
    let mut pipeline = Vec::new();
    let mut modes = vec![pipeline_run::Mode::AsFastAsPossible];
    if options.live_rate_hz > 0.0 {
        modes.push(pipeline_run::Mode::CameraRate(options.live_rate_hz));
    }
    for mode in modes {
        eprintln!("bench perf: pipeline, {}, {} frames ...", mode.describe(), options.frames);
        let run = pipeline_run(options, mode).with_context(|| format!("pipeline run {}", mode.describe()))?;
        eprintln!(
            "bench perf:   {} keyframes in {:.1} s ({:.2} keyframes/s)",
            run.keyframes, run.elapsed_s, run.keyframes_per_s
        );
        pipeline.push(run);
    }
    let ipc = if options.ipc_nodes.is_empty() {
        None
    } else {
        eprintln!(
            "bench perf: IPC latency, graphs of {:?} nodes, {} messages each ...",
            options.ipc_nodes, options.ipc_messages
        );
        Some(ipc_latency(options).context("IPC latency")?)
    };
    let fusion = if options.fusion_sizes.is_empty() {
        None
    } else {
        eprintln!("bench perf: fusion cost, maps of {:?} nodes ...", options.fusion_sizes);
        Some(fusion_curve(options).context("fusion cost against map size")?)
    };
    let peer_fusion = if options.fusion_sizes.is_empty() {
        None
    } else {
        eprintln!(
            "bench perf: fusion cost per keyframe, OP3DSG and ConceptGraphs, {} keyframes ...",
            options.fusion_keyframes
        );
        Some(peer_fusion_cost(options).context("peer fusion cost")?)
    };
    let zenoh = if options.zenoh.nodes.is_empty() && !options.zenoh.stage { None } else { zenoh_section(options)? };
    Ok(PerfReport {
        schema: REPORT_SCHEMA.to_owned(),
        machine: Machine::current(),
        command: options.command.clone(),
        pipeline,
        ipc,
        fusion,
        peer_fusion,
        zenoh,
    })
}

/// Percentiles of a set of latencies, milliseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Percentiles {
    /// Samples.
    pub count: u64,
    /// Median, ms.
    pub p50_ms: f64,
    /// 99th percentile, ms.
    pub p99_ms: f64,
    /// Mean, ms.
    pub mean_ms: f64,
    /// Largest, ms.
    pub max_ms: f64,
}

impl Percentiles {
    /// From a histogram (percentiles to within its 3 % resolution).
    pub fn from_histogram(h: &LatencyHistogram) -> Self {
        Self {
            count: h.count(),
            p50_ms: h.quantile_us(0.5) / 1e3,
            p99_ms: h.quantile_us(0.99) / 1e3,
            mean_ms: h.mean_us() / 1e3,
            max_ms: h.max_us() / 1e3,
        }
    }

    /// Exact, from samples in milliseconds (sorted here; nearest rank).
    pub fn from_samples_ms(samples: &mut [f64]) -> Self {
        if samples.is_empty() {
            return Self::default();
        }
        samples.sort_by(f64::total_cmp);
        let at = |q: f64| samples[((samples.len() - 1) as f64 * q).round() as usize];
        Self {
            count: samples.len() as u64,
            p50_ms: at(0.5),
            p99_ms: at(0.99),
            mean_ms: samples.iter().sum::<f64>() / samples.len() as f64,
            max_ms: at(1.0),
        }
    }
}

impl PerfReport {
    /// Writes the JSON form to `path`.
    pub fn write_json(&self, path: &Path) -> anyhow::Result<()> {
        use anyhow::Context as _;
        let mut text = serde_json::to_string_pretty(self).context("serialising the report")?;
        text.push('\n');
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
    }

    /// The report as Markdown tables (a `### Performance` section); `plot` is the fusion plot's
    /// path as the Markdown should link it, when one was written.
    pub fn to_markdown(&self, plot: Option<&str>) -> String {
        let mut s = String::new();
        let m = &self.machine;
        let _ = writeln!(s, "### Performance\n");
        let _ = writeln!(
            s,
            "Measured by `{}` on {} CPU core{} ({}, {} build). Rerun it to refresh these tables.\n",
            self.command,
            m.cores,
            if m.cores == 1 { "" } else { "s" },
            m.platform,
            m.build
        );
        if !self.pipeline.is_empty() {
            pipeline_markdown(&mut s, &self.pipeline);
        }
        if let Some(ipc) = &self.ipc {
            ipc_markdown(&mut s, ipc);
        }
        if let Some(fusion) = &self.fusion {
            fusion_markdown(&mut s, fusion, plot);
        }
        if let Some(peer) = &self.peer_fusion {
            peer_fusion_markdown(&mut s, peer);
        }
        if let Some(zenoh) = &self.zenoh {
            zenoh.markdown(&mut s);
        }
        s
    }
}

/// Milliseconds for a table: three significant figures at most.
pub(crate) fn ms(v: f64) -> String {
    if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

fn us(v_ms: f64) -> String {
    let v = v_ms * 1e3;
    if v >= 100.0 { format!("{v:.0}") } else { format!("{v:.1}") }
}

fn pipeline_markdown(s: &mut String, runs: &[PipelineRun]) {
    let _ = writeln!(
        s,
        "**Pipeline** (`{}` source, `{}` detector, {} detection worker(s); the whole run per stage):\n",
        runs[0].source, runs[0].detector, runs[0].detection_workers
    );
    let _ = writeln!(
        s,
        "| run | frames | keyframes | frames/s | keyframes/s | graph versions | map nodes | end-to-end p50 / p99 ms | RSS start / peak / end MiB | heap (anon) peak MiB |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
    for r in runs {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.1} | {:.2} | {} | {} | {} / {} | {:.0} / {:.0} / {:.0} | {:.0} |",
            r.mode,
            r.frames,
            r.keyframes,
            r.frames_per_s,
            r.keyframes_per_s,
            r.graph_versions,
            r.map_nodes,
            ms(r.end_to_end.p50_ms),
            ms(r.end_to_end.p99_ms),
            r.rss_start_mib(),
            r.rss_peak_mib(),
            r.rss_end_mib(),
            r.anon_peak_mib()
        );
    }
    let _ = writeln!(s);
    let _ = write!(s, "| stage |");
    for r in runs {
        let _ = write!(s, " {}: items | p50 ms | p99 ms |", r.mode);
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "|---|{}", "---|---|---|".repeat(runs.len()));
    for (i, row) in runs[0].stages.iter().enumerate() {
        let _ = write!(s, "| {} |", row.name);
        for r in runs {
            match r.stages.get(i) {
                Some(st) => {
                    let _ =
                        write!(s, " {} | {} | {} |", st.latency.count, ms(st.latency.p50_ms), ms(st.latency.p99_ms));
                }
                None => s.push_str(" | | |"),
            }
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(
        s,
        "\n`detection` merges the workers; `prior` is the prior graph + knowledge reasoner on each \
         published version; `end_to_end` runs from a keyframe's capture to the send of the first \
         graph version holding it (queueing included). RSS is the whole process: the iceoryx2 \
         graph segment counts once its pages are touched, the heap is the anonymous part.\n"
    );
    for r in runs {
        let _ = writeln!(s, "RSS over the {} run (s: MiB): {}\n", r.mode, rss_series(&r.rss, 12));
    }
}

/// Up to `n` evenly spaced samples as `t: MiB` pairs.
fn rss_series(samples: &[RssSample], n: usize) -> String {
    if samples.is_empty() {
        return "no samples".to_owned();
    }
    let step = samples.len().div_ceil(n).max(1);
    let mut picked: Vec<&RssSample> = samples.iter().step_by(step).collect();
    if let Some(last) = samples.last()
        && !std::ptr::eq(*picked.last().unwrap_or(&last), last)
    {
        picked.push(last);
    }
    picked.iter().map(|r| format!("{:.1}: {:.0}", r.t_s, r.rss_mib)).collect::<Vec<_>>().join(", ")
}

fn ipc_markdown(s: &mut String, ipc: &IpcLatency) {
    let _ = writeln!(
        s,
        "**IPC**: publish → read in another process, {} timed messages per row after {} warm-up \
         ones, the three reads interleaved message by message; the subscriber waits on an iceoryx2 \
         event listener for each. Graph publish: `GraphServer::publish_graph` (select, loan an \
         uninitialised sample of the graph's size (at most {:.1} MiB), write the records in place, \
         send, notify). Owned `Graph`: the client library's `GraphSubscriber::latest_if_newer` \
         returning the owned `Graph` (receive, check, copy). View: `GraphSubscriber::with_latest` \
         until the first node's id and label were read through the `GraphView` (receive, the \
         header checked against the payload's length, records cast in place; nothing copied or \
         scanned). Raw: loan a byte slice of the graph sample's size, copy, \
         send, notify; receive, copy out.\n",
        ipc.messages,
        ipc.warmup,
        op3dsg_runtime::stats::mib(ipc.max_sample_bytes as u64)
    );
    let _ = writeln!(
        s,
        "| graph nodes | edges | bytes | read | p50 / p99 µs | ratio to raw p50 / p99 | publish call p50 µs | read call p50 µs |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for r in &ipc.rows {
        let size = format!("| {} | {} | {} |", r.nodes, r.edges, r.bytes);
        let _ = writeln!(
            s,
            "{size} raw iceoryx2 (copy out) | {} / {} | 1.0 / 1.0 | {} | – |",
            us(r.raw.p50_ms),
            us(r.raw.p99_ms),
            us(r.raw_publish_call.p50_ms)
        );
        let _ = writeln!(
            s,
            "{size} owned `Graph` | {} / {} | {:.2} / {:.2} | {} | {} (index build {}) |",
            us(r.graph.p50_ms),
            us(r.graph.p99_ms),
            r.ratio_p50,
            r.ratio_p99,
            us(r.graph_publish_call.p50_ms),
            us(r.graph_read_call.p50_ms),
            us(r.graph_index_build.p50_ms)
        );
        let _ = writeln!(
            s,
            "{size} view, first node | {} / {} | {:.2} / {:.2} | {} | {} |",
            us(r.view.p50_ms),
            us(r.view.p99_ms),
            r.view_ratio_p50,
            r.view_ratio_p99,
            us(r.view_publish_call.p50_ms),
            us(r.view_read_call.p50_ms)
        );
    }
    let _ = writeln!(
        s,
        "\nPublish call: the publisher's call alone, notify included; read call: the subscriber's \
         `latest_if_newer` (owned) or `with_latest` up to the first node read (view); the rest is \
         the wake-up. Index build: the owned graph's first id lookup, timed after the receipt and \
         not part of the latency (the indices are built on first use; the view needs none). With \
         few cores the woken subscriber may run before the notify returns, so for large payloads \
         the publish call can include the subscriber's work too.\n"
    );
}

fn fusion_markdown(s: &mut String, fusion: &FusionCurve, plot: Option<&str>) {
    let _ = writeln!(
        s,
        "**Fusion cost against map size**: one step of {} detections ({} objects, {} parts) of a \
         640x480 kitchen view into maps grown from copies of the kitchen 20 m apart; {} timed steps \
         per size after {} warm-up ones, one thread. Each timed step runs twice on the same map, \
         with change handling (`[fusion.change]`) on and then off; the evidence step is the part of \
         the step with it on that reads the depth for removals.\n",
        fusion.detections, fusion.objects, fusion.parts, fusion.steps, fusion.warmup_steps
    );
    let _ = writeln!(
        s,
        "| map nodes | kitchen copies | map MiB | step p50 ms | step p99 ms | evidence p50 ms | evidence p99 ms | \
         step p99 ms, change handling off | p99 on / off |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    for p in &fusion.points {
        let ratio =
            if p.step_off.p99_ms > 0.0 { format!("{:.2}", p.step.p99_ms / p.step_off.p99_ms) } else { "-".to_owned() };
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} | {} | {} | {:.3} | {:.3} | {} | {ratio} |",
            p.nodes,
            p.copies,
            p.memory_mib,
            ms(p.step.p50_ms),
            ms(p.step.p99_ms),
            p.evidence.p50_ms,
            p.evidence.p99_ms,
            ms(p.step_off.p99_ms),
        );
    }
    if let Some(path) = plot {
        let _ = writeln!(s, "\n![fusion step cost against map size]({path})");
    }
    let _ = writeln!(s);
}

fn peer_fusion_markdown(s: &mut String, peer: &PeerFusionCost) {
    let _ = writeln!(
        s,
        "**Fusion cost per keyframe, OP3DSG and the peer baseline**: the {} keyframes of the kitchen \
         path ({} detections, realistic oracle), each integrated into both fusions in turn on one \
         thread (same frame, pose and detections); build graph is the final graph (for ConceptGraphs \
         it includes their final denoise, filter and merge).\n",
        peer.keyframes, peer.detections
    );
    let _ = writeln!(
        s,
        "| fusion | keyframe p50 ms | keyframe p99 ms | mean ms | build graph ms | map nodes | published nodes | map MiB |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for f in &peer.fusions {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {:.1} |",
            f.name,
            ms(f.keyframe.p50_ms),
            ms(f.keyframe.p99_ms),
            ms(f.keyframe.mean_ms),
            ms(f.build_graph_ms),
            f.map_nodes,
            f.graph_nodes,
            f.memory_mib
        );
    }
    let _ = writeln!(s);
}

/// The Zenoh section ([`zenoh_link`]).
#[cfg(feature = "zenoh")]
fn zenoh_section(options: &PerfOptions) -> anyhow::Result<Option<ZenohSection>> {
    use anyhow::Context as _;
    zenoh_link::zenoh_section(options).context("Zenoh").map(Some)
}

/// Without the cargo feature `zenoh` there is no Zenoh to measure: the section is left out, and
/// the report says so where it would be.
#[cfg(not(feature = "zenoh"))]
fn zenoh_section(_options: &PerfOptions) -> anyhow::Result<Option<ZenohSection>> {
    eprintln!("bench perf: no Zenoh section: this build leaves Zenoh out (cargo feature `zenoh`)");
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_percentiles_from_samples() {
        let mut v: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        let p = Percentiles::from_samples_ms(&mut v);
        assert_eq!((p.count, p.p50_ms, p.p99_ms, p.max_ms), (100, 51.0, 99.0, 100.0));
        assert!((p.mean_ms - 50.5).abs() < 1e-9);
        assert_eq!(Percentiles::from_samples_ms(&mut []), Percentiles::default());
    }

    #[test]
    fn rss_series_keeps_first_and_last() {
        let samples: Vec<RssSample> =
            (0..30).map(|i| RssSample { t_s: f64::from(i), rss_mib: f64::from(i), anon_mib: 0.0 }).collect();
        let text = rss_series(&samples, 4);
        assert!(text.starts_with("0.0: 0"), "{text}");
        assert!(text.ends_with("29.0: 29"), "{text}");
        assert_eq!(rss_series(&[], 4), "no samples");
    }
}
