//! # `op3dsg bench soak`: a long run of the real pipeline with map snapshots on
//!
//! The daemon's pipeline (as [`pipeline_run`](super::pipeline_run), as fast as possible: every
//! frame processed, blocking queues) on the synthetic scene of the profile, looping its camera
//! path, for `frames` frames with map snapshots written every `snapshot_period_s` into a
//! temporary directory; then, for comparison, the same run with snapshots off. Reported per run:
//!
//! - resident memory sampled every `rss_period`, and its **slope over the second half** of the
//!   run (least squares, MiB per hour and per 100,000 frames; the sample taken after the
//!   pipeline stopped is left out): the map of a looping path stops growing, so a slope well
//!   above zero is a leak;
//! - the **snapshot writer**: writes, periods skipped (writer still busy), failures, the last
//!   file's size, and the write time per snapshot (encode, checksum, write, fsync, rename,
//!   fsync of the directory; on the writer thread) p50 / p99 / max;
//! - the **map copy on the fusion thread** per snapshot (what the hot path pays; between
//!   keyframes, so it is not inside the fusion stage's latency but delays the next keyframe);
//! - the **fusion stage** p50 / p99 per keyframe and the capture → published-graph (`end_to_end`)
//!   p99, with snapshots on and off.
//!
//! Every figure is measured in the run that reports it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context as _;
use serde::{Deserialize, Serialize};

use super::pipeline_run::{Mode, RssSample, pipeline_run_with};
use super::{Machine, Percentiles, PerfOptions, PipelineRun, ms};

/// JSON schema name of [`SoakReport`].
pub const SOAK_SCHEMA: &str = "op3dsg.bench_soak/1";

/// What to run.
#[derive(Debug, Clone)]
pub struct SoakOptions {
    /// Frames of the run with snapshots on.
    pub frames: u64,
    /// Frames of the comparison run with snapshots off (0: no comparison run).
    pub compare_frames: u64,
    /// Seconds between snapshots (the profile's `snapshot.period_s`; the daemon's default is 30).
    pub snapshot_period_s: f64,
    /// Period of the resident-memory samples.
    pub rss_period: Duration,
    /// Profile the runs start from (`None`: the built-in base profile).
    pub profile: Option<PathBuf>,
    /// `section.key=value` overrides applied after the soak's own.
    pub overrides: Vec<String>,
    /// The command line, recorded in the report.
    pub command: String,
}

/// A least-squares line through resident-memory samples.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RssSlope {
    /// Samples the line was fitted to.
    pub samples: usize,
    /// First and last sample's time, seconds since the run started.
    pub from_s: f64,
    /// Last sample's time, seconds.
    pub to_s: f64,
    /// Slope of `VmRSS`, MiB per hour.
    pub rss_mib_per_hour: f64,
    /// Slope of `RssAnon` (mostly the heap), MiB per hour.
    pub anon_mib_per_hour: f64,
    /// Slope of `VmRSS` per 100,000 frames at the run's frame rate, MiB.
    pub rss_mib_per_100k_frames: f64,
}

/// The snapshot figures of a run with snapshots on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SnapshotFigures {
    /// `snapshot.period_s`.
    pub period_s: f64,
    /// Snapshots written (the final one at the end included).
    pub written: u64,
    /// Periods skipped because the previous write was still going on.
    pub skipped: u64,
    /// Writes that failed.
    pub failures: u64,
    /// Size of the last snapshot, bytes.
    pub last_bytes: u64,
    /// Time per write on the writer thread.
    pub write: Percentiles,
    /// Time per map copy on the fusion thread.
    pub copy: Percentiles,
}

/// One soak run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SoakRun {
    /// Whether snapshots were on.
    pub snapshots_on: bool,
    /// The pipeline figures (stages, RSS samples).
    pub pipeline: PipelineRun,
    /// RSS slope over the second half of the run (`None` with fewer than 3 samples there).
    pub rss_second_half: Option<RssSlope>,
    /// The snapshot figures (runs with snapshots on).
    pub snapshot: Option<SnapshotFigures>,
}

impl SoakRun {
    /// The fusion stage's latencies.
    pub fn fusion(&self) -> Percentiles {
        self.stage("fusion")
    }

    /// A stage's latencies (zero when the run has no such stage).
    pub fn stage(&self, name: &str) -> Percentiles {
        self.pipeline.stages.iter().find(|s| s.name == name).map(|s| s.latency).unwrap_or_default()
    }
}

/// What `op3dsg bench soak` measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SoakReport {
    /// [`SOAK_SCHEMA`].
    pub schema: String,
    /// Where it was measured.
    pub machine: Machine,
    /// The command that made it.
    pub command: String,
    /// The run with snapshots on, then (when asked) the one with them off.
    pub runs: Vec<SoakRun>,
}

/// The least-squares slope of the samples from the middle of the run on; `frames_per_s` converts
/// it to MiB per 100,000 frames.
pub fn second_half_slope(samples: &[RssSample], frames_per_s: f64) -> Option<RssSlope> {
    let end = samples.last()?.t_s;
    let half: Vec<&RssSample> = samples.iter().filter(|s| s.t_s >= end / 2.0).collect();
    fit(&half, frames_per_s)
}

/// [`second_half_slope`] of a run's samples: the sampler's last sample is taken after the
/// pipeline stopped and freed its map, queues and pools, so it is left out.
fn run_slope(samples: &[RssSample], frames_per_s: f64) -> Option<RssSlope> {
    second_half_slope(&samples[..samples.len().saturating_sub(1)], frames_per_s)
}

fn fit(half: &[&RssSample], frames_per_s: f64) -> Option<RssSlope> {
    let end = half.last()?.t_s;
    if half.len() < 3 {
        return None;
    }
    let n = half.len() as f64;
    let mean_t = half.iter().map(|s| s.t_s).sum::<f64>() / n;
    let var_t: f64 = half.iter().map(|s| (s.t_s - mean_t).powi(2)).sum();
    if var_t <= 0.0 {
        return None;
    }
    let slope = |value: fn(&RssSample) -> f64| {
        let mean_v = half.iter().map(|s| value(s)).sum::<f64>() / n;
        half.iter().map(|s| (s.t_s - mean_t) * (value(s) - mean_v)).sum::<f64>() / var_t
    };
    let rss_per_s = slope(|s| s.rss_mib);
    Some(RssSlope {
        samples: half.len(),
        from_s: half[0].t_s,
        to_s: end,
        rss_mib_per_hour: rss_per_s * 3600.0,
        anon_mib_per_hour: slope(|s| s.anon_mib) * 3600.0,
        rss_mib_per_100k_frames: if frames_per_s > 0.0 { rss_per_s * 1e5 / frames_per_s } else { 0.0 },
    })
}

/// A snapshot directory of its own, removed when dropped.
struct ScratchDir(PathBuf);

impl ScratchDir {
    fn new() -> anyhow::Result<Self> {
        let dir = std::env::temp_dir().join(format!("op3dsg-bench-soak-{}", std::process::id()));
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| format!("clearing {}", dir.display()))?;
        }
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        Ok(Self(dir))
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn run_one(options: &SoakOptions, frames: u64, snapshot_dir: Option<&Path>) -> anyhow::Result<SoakRun> {
    let perf = PerfOptions {
        frames,
        profile: options.profile.clone(),
        overrides: options.overrides.clone(),
        live_rate_hz: 0.0,
        rss_period: options.rss_period,
        ipc_nodes: Vec::new(),
        ipc_messages: 0,
        ipc_warmup: 0,
        peer_exe: PathBuf::new(),
        fusion_sizes: Vec::new(),
        fusion_steps: 0,
        fusion_keyframes: 0,
        zenoh: Default::default(),
        command: options.command.clone(),
    };
    let extra = match snapshot_dir {
        Some(dir) => vec![
            "snapshot.enabled=true".to_owned(),
            format!("snapshot.dir={:?}", dir.display().to_string()),
            format!("snapshot.period_s={}", options.snapshot_period_s),
        ],
        None => vec!["snapshot.enabled=false".to_owned()],
    };
    let tag = if snapshot_dir.is_some() { "soak-on" } else { "soak-off" };
    let (pipeline, stats) = pipeline_run_with(&perf, Mode::AsFastAsPossible, tag, &extra)?;
    let snapshot = snapshot_dir.map(|_| {
        use std::sync::atomic::Ordering::Relaxed;
        let s = &stats.fusion.snapshot;
        SnapshotFigures {
            period_s: options.snapshot_period_s,
            written: s.written.load(Relaxed),
            skipped: s.skipped.load(Relaxed),
            failures: s.failures.load(Relaxed),
            last_bytes: s.last_bytes.load(Relaxed),
            write: Percentiles::from_histogram(&s.write.since_start()),
            copy: Percentiles::from_histogram(&s.copy.since_start()),
        }
    });
    if let Some(s) = &snapshot
        && s.written == 0
    {
        anyhow::bail!("snapshots were on but none was written ({} failures): see the log", s.failures);
    }
    let rss_second_half = run_slope(&pipeline.rss, pipeline.frames_per_s);
    Ok(SoakRun { snapshots_on: snapshot_dir.is_some(), pipeline, rss_second_half, snapshot })
}

/// Runs the soak (snapshots on), then the comparison (snapshots off), printing progress to
/// standard error.
pub fn run(options: &SoakOptions) -> anyhow::Result<SoakReport> {
    if !(options.snapshot_period_s.is_finite() && options.snapshot_period_s > 0.0) {
        anyhow::bail!("snapshot period {} s: must be a positive number of seconds", options.snapshot_period_s);
    }
    let mut runs = Vec::new();
    {
        let dir = ScratchDir::new()?;
        eprintln!(
            "bench soak: {} frames, snapshots every {} s into {} ...",
            options.frames,
            options.snapshot_period_s,
            dir.0.display()
        );
        let run = run_one(options, options.frames, Some(&dir.0)).context("the run with snapshots on")?;
        eprintln!("bench soak:   {:.1} s, {:.1} frames/s", run.pipeline.elapsed_s, run.pipeline.frames_per_s);
        runs.push(run);
    }
    if options.compare_frames > 0 {
        eprintln!("bench soak: {} frames, snapshots off ...", options.compare_frames);
        let run = run_one(options, options.compare_frames, None).context("the run with snapshots off")?;
        eprintln!("bench soak:   {:.1} s, {:.1} frames/s", run.pipeline.elapsed_s, run.pipeline.frames_per_s);
        runs.push(run);
    }
    Ok(SoakReport {
        schema: SOAK_SCHEMA.to_owned(),
        machine: Machine::current(),
        command: options.command.clone(),
        runs,
    })
}

impl SoakReport {
    /// Writes the JSON form to `path`.
    pub fn write_json(&self, path: &Path) -> anyhow::Result<()> {
        let mut text = serde_json::to_string_pretty(self).context("serialising the report")?;
        text.push('\n');
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
    }

    /// The report as Markdown (a `### Soak` section).
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        let m = &self.machine;
        let _ = writeln!(s, "### Soak\n");
        let _ = writeln!(
            s,
            "Measured by `{}` on {} CPU core{} ({}, {} build): the real pipeline as fast as possible \
             (every frame processed), the synthetic camera path looping.\n",
            self.command,
            m.cores,
            if m.cores == 1 { "" } else { "s" },
            m.platform,
            m.build
        );
        let _ = writeln!(
            s,
            "| snapshots | frames | s | frames/s | keyframes | map nodes | RSS start / peak / end MiB | RSS slope, 2nd half: MiB/h (MiB per 100k frames) | heap slope MiB/h | fusion p50 / p99 ms | end-to-end p99 ms |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
        for r in &self.runs {
            let p = &r.pipeline;
            let (slope, heap) = match &r.rss_second_half {
                Some(x) => (
                    format!(
                        "{:+.1} ({:+.2}) over {} samples",
                        x.rss_mib_per_hour, x.rss_mib_per_100k_frames, x.samples
                    ),
                    format!("{:+.1}", x.anon_mib_per_hour),
                ),
                None => ("too few samples".to_owned(), "-".to_owned()),
            };
            let fusion = r.fusion();
            let _ = writeln!(
                s,
                "| {} | {} | {:.0} | {:.1} | {} | {} | {:.0} / {:.0} / {:.0} | {} | {} | {} / {} | {} |",
                if r.snapshots_on { "on" } else { "off" },
                p.frames,
                p.elapsed_s,
                p.frames_per_s,
                p.keyframes,
                p.map_nodes,
                p.rss_start_mib(),
                p.rss_peak_mib(),
                p.rss_end_mib(),
                slope,
                heap,
                ms(fusion.p50_ms),
                ms(fusion.p99_ms),
                ms(r.stage("end_to_end").p99_ms),
            );
        }
        for r in &self.runs {
            if let Some(x) = &r.snapshot {
                let _ = writeln!(
                    s,
                    "\nSnapshots every {} s: {} written, {} periods skipped (writer busy), {} failed, last {:.0} KiB. \
                     Write (writer thread: encode, CRC, write, fsync, rename, fsync dir) p50 {} / p99 {} / max {} ms \
                     over {}; map copy on the fusion thread p50 {} / p99 {} / max {} ms over {}.",
                    x.period_s,
                    x.written,
                    x.skipped,
                    x.failures,
                    x.last_bytes as f64 / 1024.0,
                    ms(x.write.p50_ms),
                    ms(x.write.p99_ms),
                    ms(x.write.max_ms),
                    x.write.count,
                    ms(x.copy.p50_ms),
                    ms(x.copy.p99_ms),
                    ms(x.copy.max_ms),
                    x.copy.count,
                );
            }
        }
        let _ = writeln!(
            s,
            "\nThe fusion stage's latency is per keyframe; the map copy runs between keyframes on the same \
             thread, so its cost shows in end-to-end latency rather than in the fusion stage.\n"
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(f: impl Fn(f64) -> f64) -> Vec<RssSample> {
        (0..=20)
            .map(|i| f64::from(i) * 5.0)
            .map(|t| RssSample { t_s: t, rss_mib: f(t), anon_mib: f(t) / 2.0 })
            .collect()
    }

    #[test]
    fn the_slope_is_fitted_to_the_second_half_only() {
        // Growing at 1 MiB/s for the first half, flat after: the second half's slope is zero.
        let grows_then_flat = samples(|t| 100.0 + t.min(50.0));
        let flat = second_half_slope(&grows_then_flat, 10.0).unwrap();
        assert_eq!(flat.samples, 11);
        assert!(flat.rss_mib_per_hour.abs() < 1e-9, "{flat:?}");
        // A steady 0.01 MiB/s leak: 36 MiB/h, and at 10 frames/s 100k frames take 10,000 s → 100 MiB.
        let leaking = second_half_slope(&samples(|t| 100.0 + 0.01 * t), 10.0).unwrap();
        assert!((leaking.rss_mib_per_hour - 36.0).abs() < 1e-9, "{leaking:?}");
        assert!((leaking.anon_mib_per_hour - 18.0).abs() < 1e-9, "{leaking:?}");
        assert!((leaking.rss_mib_per_100k_frames - 100.0).abs() < 1e-9, "{leaking:?}");
        assert_eq!(second_half_slope(&samples(|_| 1.0)[..3], 10.0), None, "too few samples");
    }
}
