//! What `op3dsg bench perf`'s Zenoh section asks for and reports ([`ZenohSection`], measured by
//! `zenoh_link` in a build with the feature `zenoh`), and its Markdown tables.

use serde::{Deserialize, Serialize};

use super::Percentiles;

/// What the Zenoh section measures.
#[derive(Debug, Clone, Default)]
pub struct ZenohOptions {
    /// Graph sizes (nodes) of the latency rows; empty skips them.
    pub nodes: Vec<usize>,
    /// Timed messages per size and kind.
    pub messages: usize,
    /// Untimed messages per size and kind before the timed ones.
    pub warmup: usize,
    /// Run the camera-rate pipeline without and with the Zenoh stage (at
    /// [`PerfOptions::live_rate_hz`]).
    pub stage: bool,
}

/// The Zenoh section of the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZenohSection {
    /// Publish → receive latency per graph size (`None` when skipped).
    pub latency: Option<ZenohLatency>,
    /// The stage inside the pipeline at camera rate (`None` when skipped).
    pub stage: Option<ZenohStage>,
}

/// Graph publish → receive over Zenoh next to a raw put of the same bytes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZenohLatency {
    /// The two ends and the link between them.
    pub link: String,
    /// Timed messages per size and kind.
    pub messages: usize,
    /// Untimed messages per size and kind before them.
    pub warmup: usize,
    /// One row per graph size.
    pub rows: Vec<ZenohRow>,
}

/// One graph size of [`ZenohLatency`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZenohRow {
    /// Nodes in the graph.
    pub nodes: usize,
    /// Edges in the graph.
    pub edges: usize,
    /// Bytes of the full graph message (envelope, header, records): the raw put's size too.
    pub bytes: usize,
    /// Encode and put → the follower holds the owned `Graph`.
    pub graph: Percentiles,
    /// Raw put → bytes copied out on the other side.
    pub raw: Percentiles,
    /// `graph.p50_ms / raw.p50_ms`.
    pub ratio_p50: f64,
    /// `graph.p99_ms / raw.p99_ms`.
    pub ratio_p99: f64,
    /// Messages that never arrived (graph, raw), timed or not.
    pub lost: [u64; 2],
}

/// The pipeline at camera rate without and with the Zenoh stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZenohStage {
    /// Camera rate of both runs, Hz.
    pub rate_hz: f64,
    /// Frames per run.
    pub frames: u64,
    /// Who read the graph in the run with Zenoh.
    pub consumer: String,
    /// Fusion and publish latency, without Zenoh and with it.
    pub stages: Vec<StageWithAndWithout>,
    /// Graph versions the Zenoh stage sent (each as a delta or, the first, as a full graph).
    pub versions_sent: u64,
    /// Full graph and delta messages over the whole run.
    pub whole_run: MessageSizes,
    /// The same over the run's second half (the map no longer grows much).
    pub second_half: MessageSizes,
    /// Keyframes fused in the run with Zenoh.
    pub keyframes: u64,
    /// CPU of the Zenoh stage.
    pub cpu: ZenohCpu,
}

/// One stage's latency in the runs without and with Zenoh.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageWithAndWithout {
    /// `fusion` or `publish`.
    pub name: String,
    /// Without Zenoh.
    pub without: Percentiles,
    /// With Zenoh.
    pub with: Percentiles,
    /// `with.p99_ms / without.p99_ms`.
    pub p99_ratio: f64,
}

/// Counts and mean sizes of the messages of a stretch of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct MessageSizes {
    /// Full graph messages.
    pub fulls: u64,
    /// Mean bytes of a full graph message.
    pub full_bytes_mean: f64,
    /// Delta messages.
    pub deltas: u64,
    /// Mean bytes of a delta message.
    pub delta_bytes_mean: f64,
    /// `delta_bytes_mean / full_bytes_mean`.
    pub delta_over_full: f64,
}

/// CPU time of the Zenoh stage in the run with Zenoh.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZenohCpu {
    /// Seconds the run took.
    pub elapsed_s: f64,
    /// CPU seconds of the stage's thread (`op3dsg-zenoh`: encoding, deltas, puts).
    pub stage_thread_s: f64,
    /// CPU seconds of Zenoh's runtime threads (its network I/O, shared by the process's
    /// sessions: the daemon's alone here).
    pub runtime_threads_s: f64,
    /// CPU seconds of the whole process over the run.
    pub process_s: f64,
    /// `(stage_thread_s + runtime_threads_s) / elapsed_s`: share of one core.
    pub share_of_one_core: f64,
    /// `(stage_thread_s + runtime_threads_s) / process_s`: share of the daemon's CPU.
    pub share_of_process: f64,
    /// The threads counted, by name (Zenoh's runtime threads as Zenoh names them).
    pub threads: Vec<String>,
}

impl ZenohSection {
    /// The section as Markdown tables.
    pub fn markdown(&self, s: &mut String) {
        use std::fmt::Write as _;
        let ms = super::ms;
        if let Some(l) = &self.latency {
            let _ = writeln!(
                s,
                "**Zenoh** (graph publish → receive, {}; {} timed messages per size and kind after {} untimed; the graph: encoded as the Zenoh stage encodes it and put, until the client library's follower holds the owned `Graph`; raw: a put of as many bytes, copied out on arrival):\n",
                l.link, l.messages, l.warmup
            );
            let _ = writeln!(
                s,
                "| nodes | edges | message bytes | graph p50 / p99 ms | raw p50 / p99 ms | ratio p50 / p99 | lost graph / raw |"
            );
            let _ = writeln!(s, "|---|---|---|---|---|---|---|");
            for r in &l.rows {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} / {} | {} / {} | {:.2} / {:.2} | {} / {} |",
                    r.nodes,
                    r.edges,
                    r.bytes,
                    ms(r.graph.p50_ms),
                    ms(r.graph.p99_ms),
                    ms(r.raw.p50_ms),
                    ms(r.raw.p99_ms),
                    r.ratio_p50,
                    r.ratio_p99,
                    r.lost[0],
                    r.lost[1]
                );
            }
            let _ = writeln!(s);
        }
        if let Some(st) = &self.stage {
            let _ = writeln!(
                s,
                "**The Zenoh stage in the pipeline** (camera rate {} Hz, {} frames per run, without and with `[zenoh]`; consumer: {}):\n",
                st.rate_hz, st.frames, st.consumer
            );
            let _ = writeln!(s, "| stage | without p50 / p99 ms | with p50 / p99 ms | p99 with / without |");
            let _ = writeln!(s, "|---|---|---|---|");
            for r in &st.stages {
                let _ = writeln!(
                    s,
                    "| {} | {} / {} | {} / {} | {:.2} |",
                    r.name,
                    ms(r.without.p50_ms),
                    ms(r.without.p99_ms),
                    ms(r.with.p50_ms),
                    ms(r.with.p99_ms),
                    r.p99_ratio
                );
            }
            let _ =
                writeln!(s, "\n| messages | fulls | full bytes (mean) | deltas | delta bytes (mean) | delta / full |");
            let _ = writeln!(s, "|---|---|---|---|---|---|");
            for (name, m) in [("whole run", &st.whole_run), ("second half (steady state)", &st.second_half)] {
                let _ = writeln!(
                    s,
                    "| {name} | {} | {:.0} | {} | {:.0} | {:.3} |",
                    m.fulls, m.full_bytes_mean, m.deltas, m.delta_bytes_mean, m.delta_over_full
                );
            }
            let c = &st.cpu;
            let _ = writeln!(
                s,
                "\nCPU of the Zenoh stage over the {:.1} s run: its thread {:.2} s, Zenoh's runtime threads {:.2} s ({}): **{:.1} % of one core**, {:.1} % of the daemon's {:.2} CPU s; {} graph versions sent, {} keyframes.\n",
                c.elapsed_s,
                c.stage_thread_s,
                c.runtime_threads_s,
                c.threads.join(", "),
                100.0 * c.share_of_one_core,
                100.0 * c.share_of_process,
                c.process_s,
                st.versions_sent,
                st.keyframes
            );
        }
    }
}
