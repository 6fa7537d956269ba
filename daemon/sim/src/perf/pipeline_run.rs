//! One run of the real pipeline for `op3dsg bench perf`: per-stage latency over the whole run,
//! keyframes per second, capture → published-graph latency, and resident memory over time.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context as _, anyhow};
use serde::{Deserialize, Serialize};

use super::{Percentiles, PerfOptions};
use op3dsg_runtime::pipeline::{Counters, Pipeline};
use op3dsg_runtime::stats::LatencyHistogram;

/// How the source delivers frames in a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mode {
    /// `source.rate_hz = 0` and blocking `frames` / `keyframes` queues (as
    /// `profiles/sim-batch.toml`): every frame is processed, as fast as the machine goes.
    AsFastAsPossible,
    /// `source.rate_hz` = this rate, the profile's queues (latest-wins in the base profile).
    CameraRate(f64),
}

impl Mode {
    /// Short name for tables.
    pub fn describe(&self) -> String {
        match self {
            Mode::AsFastAsPossible => "as fast as possible".to_owned(),
            Mode::CameraRate(hz) => format!("camera rate {hz} Hz"),
        }
    }

    fn overrides(&self) -> Vec<String> {
        match self {
            Mode::AsFastAsPossible => vec![
                "source.rate_hz=0".to_owned(),
                "queues.frames.capacity=4".to_owned(),
                "queues.frames.policy=block".to_owned(),
                "queues.keyframes.capacity=4".to_owned(),
                "queues.keyframes.policy=block".to_owned(),
            ],
            Mode::CameraRate(hz) => vec![format!("source.rate_hz={hz}")],
        }
    }
}

/// Latency of one stage over a whole run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageRow {
    /// `capture`, `keyframe`, `detection` (all workers), `fusion`, `prior`, `publish`, `end_to_end`.
    pub name: String,
    /// Its latencies.
    pub latency: Percentiles,
}

/// Resident memory of the process at one moment of a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RssSample {
    /// Seconds since the run started.
    pub t_s: f64,
    /// Resident set (`VmRSS`), MiB: heap, code and touched shared memory.
    pub rss_mib: f64,
    /// Anonymous resident memory (`RssAnon`), MiB: mostly the heap.
    pub anon_mib: f64,
}

/// What one pipeline run measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PipelineRun {
    /// [`Mode::describe`].
    pub mode: String,
    /// The profile overrides of this run (after the profile file, if any).
    pub overrides: Vec<String>,
    /// `source.kind`.
    pub source: String,
    /// `detector.kind`.
    pub detector: String,
    /// `detector.workers`.
    pub detection_workers: usize,
    /// Frames the source delivered.
    pub frames: u64,
    /// Keyframes fused.
    pub keyframes: u64,
    /// Seconds from start until every stage ended.
    pub elapsed_s: f64,
    /// Frames per second over the run.
    pub frames_per_s: f64,
    /// Keyframes per second over the run.
    pub keyframes_per_s: f64,
    /// Graph versions published.
    pub graph_versions: u64,
    /// Nodes in the map at the end.
    pub map_nodes: u64,
    /// Keyframe capture → graph sent.
    pub end_to_end: Percentiles,
    /// Per-stage latencies, in pipeline order.
    pub stages: Vec<StageRow>,
    /// Resident memory over the run.
    pub rss: Vec<RssSample>,
}

impl PipelineRun {
    /// RSS of the first sample, MiB (0 without samples).
    pub fn rss_start_mib(&self) -> f64 {
        self.rss.first().map_or(0.0, |r| r.rss_mib)
    }

    /// Largest RSS sampled, MiB.
    pub fn rss_peak_mib(&self) -> f64 {
        self.rss.iter().map(|r| r.rss_mib).fold(0.0, f64::max)
    }

    /// Largest anonymous resident memory (mostly the heap) sampled, MiB.
    pub fn anon_peak_mib(&self) -> f64 {
        self.rss.iter().map(|r| r.anon_mib).fold(0.0, f64::max)
    }

    /// RSS of the last sample, MiB.
    pub fn rss_end_mib(&self) -> f64 {
        self.rss.last().map_or(0.0, |r| r.rss_mib)
    }
}

/// Reads `VmRSS` and `RssAnon` of this process (kB in `/proc/self/status`) as MiB; `None` where
/// `/proc` is not available.
pub fn read_rss_mib() -> Option<(f64, f64)> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
            .map(|kib| kib / 1024.0)
    };
    Some((field("VmRSS:")?, field("RssAnon:").unwrap_or(0.0)))
}

/// Samples [`read_rss_mib`] every `period` on its own thread until dropped.
struct RssSampler {
    stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<Vec<RssSample>>>,
}

impl RssSampler {
    fn start(period: Duration) -> anyhow::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::Builder::new()
            .name("op3dsg-bench-rss".to_owned())
            .spawn(move || {
                let started = Instant::now();
                let mut samples = Vec::new();
                let sample = |samples: &mut Vec<RssSample>| {
                    if let Some((rss_mib, anon_mib)) = read_rss_mib() {
                        samples.push(RssSample { t_s: started.elapsed().as_secs_f64(), rss_mib, anon_mib });
                    }
                };
                while !flag.load(Ordering::Relaxed) {
                    sample(&mut samples);
                    let next = started + period * samples.len().max(1) as u32;
                    while !flag.load(Ordering::Relaxed) && Instant::now() < next {
                        std::thread::sleep(Duration::from_millis(5).min(next - Instant::now()));
                    }
                }
                sample(&mut samples);
                samples
            })
            .context("starting the RSS sampler thread")?;
        Ok(Self { stop, handle: Some(handle) })
    }

    fn finish(mut self) -> Vec<RssSample> {
        self.stop.store(true, Ordering::Relaxed);
        self.handle.take().and_then(|h| h.join().ok()).unwrap_or_default()
    }
}

impl Drop for RssSampler {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Runs the pipeline of `options.profile` for `options.frames` frames in `mode`, serving under a
/// private iceoryx2 prefix, and collects its figures.
pub fn pipeline_run(options: &PerfOptions, mode: Mode) -> anyhow::Result<PipelineRun> {
    let tag = match mode {
        Mode::AsFastAsPossible => "fast",
        Mode::CameraRate(_) => "live",
    };
    pipeline_run_with(options, mode, tag, &[]).map(|(run, _)| run)
}

/// [`pipeline_run`] with `extra` overrides (after the mode's, before `options.overrides`) and a
/// prefix tag of its own; also returns the pipeline's counters as they were at the end.
pub(crate) fn pipeline_run_with(
    options: &PerfOptions,
    mode: Mode,
    tag: &str,
    extra: &[String],
) -> anyhow::Result<(PipelineRun, Arc<Counters>)> {
    pipeline_run_observed(options, mode, tag, extra, |_, _| ()).map(|(run, counters, ())| (run, counters))
}

/// [`pipeline_run_with`], and `observe` on a thread of its own while the pipeline runs: it gets
/// the pipeline's counters and a flag set once every stage has ended; its result is returned.
pub(crate) fn pipeline_run_observed<T: Send + 'static>(
    options: &PerfOptions,
    mode: Mode,
    tag: &str,
    extra: &[String],
    observe: impl FnOnce(Arc<Counters>, Arc<AtomicBool>) -> T + Send + 'static,
) -> anyhow::Result<(PipelineRun, Arc<Counters>, T)> {
    let mut overrides = vec![
        format!("run.max_frames={}", options.frames),
        "run.exit_at_end=true".to_owned(),
        "health.log_every_periods=0".to_owned(),
        format!("ipc.prefix=op3dsg-bench-{}-{tag}", std::process::id()),
    ];
    overrides.extend(mode.overrides());
    overrides.extend(extra.iter().cloned());
    overrides.extend(options.overrides.iter().cloned());
    let loaded =
        crate::load_profile(options.profile.as_deref(), &overrides).map_err(|e| anyhow!("bad profile: {e}"))?;
    let profile = loaded.profile;

    let sampler = RssSampler::start(options.rss_period)?;
    let stop = Arc::new(AtomicBool::new(false));
    let pipeline = Pipeline::start(&profile, &crate::backends(), stop).context("starting the pipeline")?;
    let stats = pipeline.counters().clone();
    let ended = Arc::new(AtomicBool::new(false));
    let observer = {
        let (stats, ended) = (stats.clone(), ended.clone());
        std::thread::Builder::new()
            .name("op3dsg-bench-observe".to_owned())
            .spawn(move || observe(stats, ended))
            .context("starting the observer thread")?
    };
    let stage_stats = stats.stages();
    let summary = pipeline.wait().map_err(|stuck| anyhow!("stages did not end: {}", stuck.join(", ")));
    ended.store(true, Ordering::Relaxed);
    let observed = observer.join().map_err(|_| anyhow!("the observer thread panicked"))?;
    let summary = summary?;
    let rss = sampler.finish();
    if summary.source_failed {
        return Err(anyhow!("the frame source failed (see the log)"));
    }

    let histogram = |name: &str| stage_stats.iter().find(|s| s.name == name).map(|s| s.since_start());
    let mut detection = LatencyHistogram::default();
    for stage in stage_stats.iter().filter(|s| s.name.starts_with("detect/")) {
        detection.merge(&stage.since_start());
    }
    let mut stages = Vec::new();
    for name in ["capture", "keyframe", "detection", "fusion", "prior", "publish", "end_to_end"] {
        let h = if name == "detection" { Some(detection.clone()) } else { histogram(name) };
        if let Some(h) = h {
            stages.push(StageRow { name: name.to_owned(), latency: Percentiles::from_histogram(&h) });
        }
    }
    let end_to_end = stages.iter().find(|s| s.name == "end_to_end").map(|s| s.latency).unwrap_or_default();
    let run = PipelineRun {
        mode: mode.describe(),
        overrides,
        source: profile.source.kind.clone(),
        detector: profile.detector.kind.clone(),
        detection_workers: profile.detector.workers,
        frames: summary.frames,
        keyframes: summary.keyframes,
        elapsed_s: summary.elapsed_s,
        frames_per_s: summary.frames as f64 / summary.elapsed_s.max(1e-9),
        keyframes_per_s: summary.keyframes_per_s(),
        graph_versions: summary.graph_version,
        map_nodes: summary.map_nodes,
        end_to_end,
        stages,
        rss,
    };
    Ok((run, stats, observed))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rss_is_read_on_linux() {
        if cfg!(target_os = "linux") {
            let (rss, _anon) = read_rss_mib().expect("/proc/self/status");
            assert!(rss > 0.0);
        }
    }
}
