//! `op3dsg record info FILE` (what a recording holds) and `op3dsg bench record` (the recorder's
//! throughput on the robot's raw stream).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use op3dsg_drivers::mcap::reader::{Item, McapReader};
use op3dsg_drivers::mcap::{METADATA_PROFILE, METADATA_RECORDER};
use op3dsg_runtime::record::{ColourEncoding, RecordCompression, RecordConfig, Recorder};

use super::bench_args::RecordBenchArgs;

#[derive(Debug, Default, serde::Serialize)]
struct ChannelSummary {
    topic: String,
    schema: String,
    encoding: String,
    messages: u64,
    first_log_time_ns: Option<u64>,
    last_log_time_ns: Option<u64>,
}

#[derive(Debug, Default, serde::Serialize)]
struct FileSummary {
    file: String,
    bytes: u64,
    channels: Vec<ChannelSummary>,
    messages: u64,
    first_log_time_ns: Option<u64>,
    last_log_time_ns: Option<u64>,
    /// `None`: the file was not finished (no `op3dsg.recorder` metadata).
    recorder_dropped: Option<u64>,
    recorder_metadata: BTreeMap<String, String>,
    profile_recorded: bool,
    /// What the pipeline dropped after the keyframe gate while recording (`None`: the file does
    /// not say, an earlier recorder or an unfinished file).
    pipeline_dropped: Option<u64>,
    /// The recorded profile's settings that make a replay's graph differ (one per entry).
    #[serde(skip)]
    profile_reasons: Vec<String>,
    /// `graph_version` of the file's first `/op3dsg/graph` message (1: the map started empty
    /// with this file).
    first_graph_version: Option<u64>,
    /// Why reading stopped early (a truncated or damaged file), if it did.
    error: Option<String>,
    /// How `/camera/colour` is stored: `raw`, `png` or `jpeg` (`None`: no colour channel).
    colour: Option<String>,
    /// Whether a replay of this file makes the recorded graph bit for bit: the file finished,
    /// complete (no read error), no message dropped by the recorder nor keyframe by the pipeline,
    /// the profile recorded with nothing in it that a replay cannot repeat, lossless colour, and
    /// the map started empty with the file.
    replays_bit_for_bit: bool,
    /// Why it would not, when it would not (one reason per entry).
    not_bit_for_bit: Vec<String>,
}

impl FileSummary {
    /// The reasons a replay of this file would not be bit for bit (none: it would).
    fn not_bit_for_bit(&self) -> Vec<String> {
        let mut why = Vec::new();
        match self.recorder_dropped {
            None => why.push("the recorder did not finish the file (drops unknown)".to_owned()),
            Some(0) => {}
            Some(dropped) => {
                let channels = op3dsg_drivers::mcap::dropped_channels(&self.recorder_metadata);
                let per_channel =
                    if channels.is_empty() { String::new() } else { format!(": {}", channels.join(", ")) };
                why.push(format!("{dropped} messages dropped while recording{per_channel}"));
            }
        }
        if self.recorder_dropped.is_some() {
            match op3dsg_drivers::mcap::pipeline_drops(&self.recorder_metadata) {
                None => why.push(
                    "the file does not say whether the pipeline dropped keyframes while recording (an earlier \
                     recorder)"
                        .to_owned(),
                ),
                Some((0, _)) => {}
                Some((dropped, queues)) => why.push(format!(
                    "the pipeline dropped {dropped} keyframes or results after the gate while recording ({}; \
                     [queues] latest_wins under load), which a replay processes",
                    queues.join(", ")
                )),
            }
        }
        if let Some(error) = &self.error {
            why.push(format!("the file is damaged ({error})"));
        }
        if !self.profile_recorded {
            why.push("no profile recorded (op3dsg.profile metadata)".to_owned());
        }
        why.extend(self.profile_reasons.iter().cloned());
        if let Some(version) = self.first_graph_version.filter(|v| *v != 1) {
            why.push(format!(
                "its first graph is version {version}: the map did not start empty with this file (a restored \
                 snapshot, or an earlier file of the same run: replay the folder), and a replay starts empty"
            ));
        }
        match self.colour.as_deref() {
            None => why.push("no /camera/colour channel".to_owned()),
            Some("raw" | "png") => {}
            Some(other) => why.push(format!("colour stored as {other}, lossy")),
        }
        why
    }
}

/// The settings of a recorded profile that keep a replay from making the recorded graph bit for
/// bit, one sentence each: the channels the replay needs, limited or off; a publish interval,
/// which numbers versions by the clock; the LLM refiner, whose answers arrive when they arrive.
fn profile_reasons(toml_text: &str) -> Vec<String> {
    let Ok(profile) = toml::from_str::<toml::Table>(toml_text) else {
        return vec!["the recorded profile is not valid TOML".to_owned()];
    };
    let get = |path: &str| {
        let (tables, key) = path.rsplit_once('.').unwrap_or(("", path));
        let table = tables
            .split('.')
            .filter(|t| !t.is_empty())
            .try_fold(&profile, |table, name| table.get(name)?.as_table())?;
        table.get(key)
    };
    let is = |path: &str, value: &str| get(path).and_then(toml::Value::as_str) == Some(value);
    let mut why = Vec::new();
    let mut needed = vec!["colour", "depth", "frame", "calibration"];
    if is("pose.source", "ipc") {
        needed.push("input_poses");
    }
    if is("source.kind", "synthetic") {
        needed.push("side_channels");
    }
    for channel in needed {
        let key = format!("record.channels.{channel}");
        if get(&format!("{key}.enabled")).and_then(toml::Value::as_bool) == Some(false) {
            why.push(format!("{key} was off: the replay has no such input"));
        } else if let Some(rate) =
            get(&format!("{key}.max_rate_hz")).and_then(toml::Value::as_float).filter(|r| *r > 0.0)
        {
            why.push(format!("{key} was limited to {rate} Hz: the replay refuses a frame without it"));
        }
    }
    if let Some(ms) = get("run.min_publish_interval_ms").and_then(toml::Value::as_integer).filter(|ms| *ms > 0) {
        why.push(format!(
            "run.min_publish_interval_ms = {ms}: versions were published by the clock, so a replay's graph has the \
             same content but other version numbers"
        ));
    }
    if is("reasoner.kind", "llm") {
        why.push("reasoner.kind = \"llm\": the LLM's refinements arrive when they arrive".to_owned());
    }
    why
}

/// What `record info` says of the colour's storage.
fn colour_note(colour: &str) -> &'static str {
    match colour {
        "jpeg" | "jpg" => {
            "LOSSY: a replay sees other pixels, its graph is close to but not identical with the recorded run's"
        }
        "png" | "raw" => "lossless",
        _ => "unknown format: the replay refuses it",
    }
}

fn summarise(path: &Path) -> Result<FileSummary> {
    let mut reader = McapReader::open(path).map_err(|e| anyhow::anyhow!("{e}"))?;
    let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let mut summary = FileSummary { file: path.display().to_string(), bytes, ..FileSummary::default() };
    let mut by_channel: BTreeMap<u16, ChannelSummary> = BTreeMap::new();
    let mut data = Vec::new();
    loop {
        match reader.next(&mut data) {
            Ok(None) => break,
            Ok(Some(Item::Message(at))) => {
                if summary.first_graph_version.is_none()
                    && reader.channel(at.channel_id).is_some_and(|c| c.topic == op3dsg_drivers::mcap::TOPIC_GRAPH)
                {
                    summary.first_graph_version = serde_json::from_slice::<serde_json::Value>(&data)
                        .ok()
                        .and_then(|graph| graph["graph_version"].as_u64());
                }
                if summary.colour.is_none()
                    && let Some(channel) = reader.channel(at.channel_id)
                    && channel.topic == op3dsg_drivers::mcap::TOPIC_COLOUR
                {
                    summary.colour = Some(if channel.schema_name == op3dsg_drivers::mcap::schemas::COMPRESSED_IMAGE {
                        op3dsg_drivers::mcap::messages::CompressedImageIn::parse(&data, &channel.message_encoding)
                            .map_or_else(|e| format!("unreadable ({e})"), |image| image.format)
                    } else {
                        "raw".to_owned()
                    });
                }
                let entry = by_channel.entry(at.channel_id).or_default();
                entry.messages += 1;
                entry.first_log_time_ns.get_or_insert(at.log_time);
                entry.last_log_time_ns = Some(at.log_time);
                summary.messages += 1;
                summary.first_log_time_ns = Some(summary.first_log_time_ns.map_or(at.log_time, |t| t.min(at.log_time)));
                summary.last_log_time_ns = Some(summary.last_log_time_ns.map_or(at.log_time, |t| t.max(at.log_time)));
            }
            Ok(Some(Item::Metadata { name, entries })) => {
                if name == METADATA_RECORDER {
                    summary.recorder_dropped = entries.get("dropped_total").and_then(|v| v.parse().ok());
                    summary.pipeline_dropped = op3dsg_drivers::mcap::pipeline_drops(&entries).map(|(n, _)| n);
                    summary.recorder_metadata = entries;
                } else if name == METADATA_PROFILE {
                    summary.profile_recorded = true;
                    summary.profile_reasons = entries.get("toml").map_or_else(Vec::new, |t| profile_reasons(t));
                }
            }
            Err(e) => {
                summary.error = Some(e.to_string());
                break;
            }
        }
    }
    for channel in reader.channels() {
        let entry = by_channel.entry(channel.id).or_default();
        entry.topic = channel.topic.clone();
        entry.schema = channel.schema_name.clone();
        entry.encoding = channel.message_encoding.clone();
    }
    summary.channels = by_channel.into_values().collect();
    summary.channels.sort_by(|a, b| a.topic.cmp(&b.topic));
    summary.not_bit_for_bit = summary.not_bit_for_bit();
    summary.replays_bit_for_bit = summary.not_bit_for_bit.is_empty();
    Ok(summary)
}

fn seconds_between(a: Option<u64>, b: Option<u64>) -> f64 {
    match (a, b) {
        (Some(a), Some(b)) => b.saturating_sub(a) as f64 / 1e9,
        _ => 0.0,
    }
}

/// `op3dsg record info`.
pub(super) fn info(files: &[PathBuf], json: bool) -> Result<()> {
    let mut summaries = Vec::new();
    for file in files {
        summaries.push(summarise(file)?);
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&summaries)?);
        return Ok(());
    }
    for s in &summaries {
        println!("{} ({:.1} MiB)", s.file, s.bytes as f64 / (1 << 20) as f64);
        let range = seconds_between(s.first_log_time_ns, s.last_log_time_ns);
        match (s.first_log_time_ns, s.last_log_time_ns) {
            (Some(first), Some(last)) => {
                println!("  time      {first} .. {last} ns (log time, Unix), {range:.2} s, {} messages", s.messages)
            }
            _ => println!("  no messages"),
        }
        match s.recorder_dropped {
            Some(dropped) => println!("  recorder  finished; dropped {dropped} messages while recording"),
            None => println!("  recorder  not finished (no op3dsg.recorder metadata): drops unknown"),
        }
        match s.pipeline_dropped {
            Some(0) => println!("  pipeline  dropped nothing after the keyframe gate while recording"),
            Some(n) => println!("  pipeline  dropped {n} keyframes or results after the keyframe gate while recording"),
            None => {}
        }
        if let Some(colour) = &s.colour {
            println!("  colour    {colour} ({})", colour_note(colour));
        }
        if s.profile_recorded {
            println!("  profile   recorded (op3dsg.profile metadata: replay with it)");
        } else {
            println!("  profile   missing (no op3dsg.profile metadata)");
        }
        if s.replays_bit_for_bit {
            println!(
                "  replay    bit for bit: complete channels, no drops, the profile recorded, lossless colour (with \
                 source.mcap.lossless, the default)"
            );
        } else {
            println!("  replay    NOT bit for bit: {}", s.not_bit_for_bit.join("; "));
        }
        if let Some(error) = &s.error {
            println!("  read up to: {error}");
        }
        println!(
            "  {:<22} {:<28} {:<9} {:>9} {:>8} {:>8}",
            "channel", "schema", "encoding", "messages", "rate Hz", "dropped"
        );
        for c in &s.channels {
            let span = seconds_between(c.first_log_time_ns, c.last_log_time_ns);
            let rate = if span > 0.0 { (c.messages.saturating_sub(1)) as f64 / span } else { 0.0 };
            // Per-channel drops are in the metadata of a finished file only.
            let dropped = s.recorder_metadata.get(&format!("{}.dropped", c.topic)).map_or("-", String::as_str);
            println!(
                "  {:<22} {:<28} {:<9} {:>9} {:>8.1} {:>8}",
                c.topic, c.schema, c.encoding, c.messages, rate, dropped
            );
        }
        // Channels with drops but no message in the file.
        for (key, value) in &s.recorder_metadata {
            if let Some(topic) = key.strip_suffix(".dropped")
                && value != "0"
                && !s.channels.iter().any(|c| c.topic == topic)
            {
                println!("  {topic:<22} {:<28} {:<9} {:>9} {:>8} {value:>8}", "(none written)", "-", 0, "-");
            }
        }
    }
    Ok(())
}

/// `op3dsg bench record`.
pub(super) fn bench(args: RecordBenchArgs) -> Result<()> {
    if !(args.seconds > 0.0 && args.rate_hz > 0.0) {
        bail!("--seconds and --rate-hz must be > 0");
    }
    let compressions = compressions(&args.compression)?;
    let colour = colour_encoding(&args.colour)?;
    if !(1..=100).contains(&args.jpeg_quality) {
        bail!("--jpeg-quality {}: must be within [1, 100]", args.jpeg_quality);
    }
    let frames = synthetic_frames(args.width, args.height, args.distinct_frames)?;
    let graph = bench_graph(args.graph_nodes);
    let dir = args
        .dir
        .clone()
        .unwrap_or_else(|| std::env::temp_dir().join(format!("op3dsg-bench-record-{}", std::process::id())));
    println!(
        "recorder: {}x{} colour ({}) + depth (16UC1) at {} Hz for {} s, a {}-node graph every {} frames, JSON \
         messages, chunk {} KiB; files in {}\n",
        args.width,
        args.height,
        if colour == ColourEncoding::Jpeg { format!("jpeg q{}", args.jpeg_quality) } else { colour.name().to_owned() },
        args.rate_hz,
        args.seconds,
        args.graph_nodes,
        args.graph_every,
        args.chunk_size_kib,
        dir.display()
    );
    println!(
        "| compression | frames offered | messages written | dropped | raw input MB/s | file MB/s | recorder CPU (share of one core) |"
    );
    println!("|---|---|---|---|---|---|---|");
    let bench = RecordBench { args: &args, colour, frames, graph, dir };
    for (name, compression) in compressions {
        bench.run(name, compression)?;
    }
    if !args.keep {
        let _ = std::fs::remove_dir(&bench.dir);
    }
    println!("\nCPU: the recorder thread's own time (/proc/thread-self/schedstat) over the run's wall time.");
    Ok(())
}

/// `--compression`: the compressions to run, each with its name.
fn compressions(name: &str) -> Result<Vec<(&'static str, RecordCompression)>> {
    Ok(match name {
        "all" => vec![("zstd", RecordCompression::Zstd), ("lz4", RecordCompression::Lz4)],
        "zstd" => vec![("zstd", RecordCompression::Zstd)],
        "lz4" => vec![("lz4", RecordCompression::Lz4)],
        "none" => vec![("none", RecordCompression::None)],
        other => bail!("--compression {other}: expected zstd, lz4, none or all"),
    })
}

/// `--colour`.
fn colour_encoding(name: &str) -> Result<ColourEncoding> {
    Ok(match name {
        "raw" => ColourEncoding::Raw,
        "png" => ColourEncoding::Png,
        "jpeg" => ColourEncoding::Jpeg,
        other => bail!("--colour {other}: expected raw, png or jpeg"),
    })
}

/// What every compression of `op3dsg bench record` records: the same frames and graph, into a
/// folder of its own under `dir`.
struct RecordBench<'a> {
    args: &'a RecordBenchArgs,
    colour: ColourEncoding,
    /// Replayed in a loop.
    frames: Vec<op3dsg_drivers::frame::Frame>,
    graph: op3dsg_runtime::graph::SceneGraph,
    dir: PathBuf,
}

impl RecordBench<'_> {
    /// Records `args.seconds` of the stream at `args.rate_hz` with `compression` into `dir/name`
    /// and prints its row of the table.
    fn run(&self, name: &str, compression: RecordCompression) -> Result<()> {
        let args = self.args;
        let run_dir = self.dir.join(name);
        let config = RecordConfig {
            enabled: true,
            dir: run_dir.clone(),
            compression,
            colour: self.colour,
            jpeg_quality: args.jpeg_quality,
            chunk_size_kib: args.chunk_size_kib,
            ..RecordConfig::default()
        };
        let intrinsics = self.frames[0].intrinsics;
        let world = op3dsg_runtime::world::WorldConfig::default();
        let recorder = Recorder::start(&config, String::new(), intrinsics, &world)
            .with_context(|| format!("starting the recorder in {}", run_dir.display()))?;
        let mut sender = recorder.sender().context("recorder sender")?;
        let period = Duration::from_secs_f64(1.0 / args.rate_hz);
        let total = (args.seconds * args.rate_hz).round() as u64;
        let started = Instant::now();
        let mut raw_bytes = 0u64;
        let mut version = 0;
        for i in 0..total {
            let due = started + period * i as u32;
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
            let mut frame = self.frames[i as usize % self.frames.len()].clone();
            frame.seq = i;
            frame.stamp_ns = i * period.as_nanos() as u64;
            sender.offer_frame(&frame, &mut []);
            raw_bytes += (frame.rgb.len() + frame.depth.len() * 2) as u64;
            if args.graph_every > 0 && i % args.graph_every == 0 {
                if let Some(pose) = frame.world_from_camera {
                    sender.offer_keyframe(frame.stamp_ns, &pose);
                }
                version += 1;
                let mut g = self.graph.clone();
                g.version = version;
                g.stamp_ns = frame.stamp_ns;
                sender.offer_graph(g);
            }
        }
        drop(sender);
        let produced_s = started.elapsed().as_secs_f64();
        let health = recorder.finish();
        let wall_s = started.elapsed().as_secs_f64();
        println!(
            "| {name} | {total} | {} | {} | {:.1} | {:.1} | {:.0} % ({:.2} s CPU over {:.2} s) |",
            health.messages_written,
            health.messages_dropped,
            raw_bytes as f64 / 1e6 / produced_s,
            health.bytes_written as f64 / 1e6 / produced_s,
            100.0 * health.cpu_ns as f64 / 1e9 / wall_s,
            health.cpu_ns as f64 / 1e9,
            wall_s
        );
        if !args.keep {
            let _ = std::fs::remove_dir_all(&run_dir);
        }
        Ok(())
    }
}

/// Frames of the synthetic kitchen at the bench's size (rendered once, replayed in a loop).
fn synthetic_frames(width: u32, height: u32, count: u64) -> Result<Vec<op3dsg_drivers::frame::Frame>> {
    use op3dsg_drivers::frame::{Frame, Intrinsics};
    use op3dsg_drivers::source::{FrameSource, SourceStatus};
    let mut profile = op3dsg_sim::load_profile(None, &[]).map_err(|e| anyhow::anyhow!("{e}"))?.profile;
    let scale = width as f32 / 640.0;
    op3dsg_sim::backends::edit_synthetic(&mut profile, |s| {
        s.intrinsics = Intrinsics {
            width,
            height,
            fx: 615.0 * scale,
            fy: 615.0 * scale,
            cx: width as f32 / 2.0,
            cy: height as f32 / 2.0,
        };
        s.frame_count = Some(count * 10);
    })?;
    let config = op3dsg_sim::backends::synthetic_config(&profile)?;
    let mut source = op3dsg_synthetic::SyntheticSource::new(&config)?;
    let mut frames = Vec::new();
    let mut frame = Frame::new(source.intrinsics());
    // Every 10th frame of the path, so consecutive frames differ like a moving camera's.
    for i in 0..count * 10 {
        if source.next_frame(&mut frame)? != SourceStatus::Frame {
            break;
        }
        if i % 10 == 0 {
            frames.push(frame.clone());
        }
    }
    if frames.is_empty() {
        bail!("the synthetic source gave no frame");
    }
    Ok(frames)
}

fn bench_graph(nodes: usize) -> op3dsg_runtime::graph::SceneGraph {
    use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};
    use op3dsg_runtime::graph::{GraphEdge, GraphNode, SceneGraph};
    let mut graph = SceneGraph::default();
    for i in 0..nodes as u32 {
        let x = (i % 10) as f32 * 0.5;
        let y = (i / 10) as f32 * 0.5;
        graph.nodes.push(GraphNode {
            id: i + 1,
            kind: if i % 3 == 2 { NodeKind::Part } else { NodeKind::Object },
            parent_id: (i % 3 == 2).then_some(i),
            label: format!("object {i}"),
            confidence: 0.9,
            centre_m: [x, y, 0.5],
            box_min_m: [x - 0.2, y - 0.2, 0.3],
            box_max_m: [x + 0.2, y + 0.2, 0.7],
            observation_count: 5,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            missing: false,
            obb: Default::default(),
            ..Default::default()
        });
        if i > 0 {
            graph.edges.push(GraphEdge {
                source_id: i + 1,
                target_id: i,
                kind: if i % 2 == 0 { EdgeKind::Spatial } else { EdgeKind::Functional },
                relation_id: 0,
                confidence: 0.8,
                origin: EdgeOrigin::Geometry,
            });
        }
    }
    graph
}

#[cfg(test)]
mod tests {
    use super::*;

    fn finished(metadata: &[(&str, &str)]) -> FileSummary {
        FileSummary {
            recorder_dropped: metadata.iter().find(|(k, _)| *k == "dropped_total").and_then(|(_, v)| v.parse().ok()),
            recorder_metadata: metadata.iter().map(|(k, v)| ((*k).to_owned(), (*v).to_owned())).collect(),
            profile_recorded: true,
            colour: Some("raw".to_owned()),
            first_graph_version: Some(1),
            ..FileSummary::default()
        }
    }

    #[test]
    fn a_complete_recording_replays_bit_for_bit_and_each_loss_is_named() {
        let clean = [("dropped_total", "0"), ("pipeline_dropped_total", "0"), ("pipeline_dropped.keyframes", "0")];
        assert_eq!(finished(&clean).not_bit_for_bit(), Vec::<String>::new());

        let lossy = finished(&[
            ("dropped_total", "3"),
            ("/camera/colour.dropped", "3"),
            ("pipeline_dropped_total", "2"),
            ("pipeline_dropped.keyframes", "2"),
            ("pipeline_dropped.detections", "0"),
        ]);
        let why = lossy.not_bit_for_bit().join("; ");
        assert!(why.contains("3 messages dropped while recording: /camera/colour 3"), "{why}");
        assert!(
            why.contains("the pipeline dropped 2 keyframes or results after the gate while recording (keyframes 2;"),
            "{why}"
        );

        // A file of an earlier recorder does not say what the pipeline dropped: not claimed.
        let earlier = finished(&[("dropped_total", "0")]);
        assert!(earlier.not_bit_for_bit().join("; ").contains("does not say whether the pipeline dropped"));

        // A file that continues a map (a restored snapshot, a later file of a rotation).
        let continued = FileSummary { first_graph_version: Some(41), ..finished(&clean) };
        assert!(continued.not_bit_for_bit().join("; ").contains("its first graph is version 41"));
    }

    #[test]
    fn the_recorded_profile_names_what_a_replay_cannot_repeat() {
        assert_eq!(profile_reasons("[run]\nmin_publish_interval_ms = 0\n"), Vec::<String>::new());
        let text = "[pose]\nsource = \"ipc\"\n[run]\nmin_publish_interval_ms = 200\n[reasoner]\nkind = \"llm\"\n\
                    [record.channels]\ncolour = { enabled = true, max_rate_hz = 5.0 }\n\
                    input_poses = { enabled = false, max_rate_hz = 0.0 }\n";
        let why = profile_reasons(text).join("; ");
        assert!(why.contains("record.channels.colour was limited to 5 Hz"), "{why}");
        assert!(why.contains("record.channels.input_poses was off"), "{why}");
        assert!(why.contains("run.min_publish_interval_ms = 200"), "{why}");
        assert!(why.contains("reasoner.kind = \"llm\""), "{why}");
        assert_eq!(profile_reasons("not = [toml"), vec!["the recorded profile is not valid TOML".to_owned()]);
    }
}
