//! The recorder thread: files, channels, rotation, flushing, and giving up cleanly when the
//! disk fails.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};
use op3dsg_drivers::frame::Intrinsics;
use op3dsg_drivers::mcap::messages::{FrameMeta, RawImageHeader, calibration, compressed_image, encode, raw_image};
use op3dsg_drivers::mcap::{self as topics, CAMERA_FRAME, schemas};
use op3dsg_ipc_types::{Health, RECORDER_STATES, fixed_str};
use tracing::{info, warn};

use super::scene::{frame_transform, scene_update};
use super::{
    Channel, ColourEncoding, Event, RawFrame, RawInput, RecordCompression, RecordConfig, RecordThread, RecorderState,
    RecorderStats,
};
use crate::world::UpAxis;

type McapWriter = mcap::Writer<BufWriter<File>>;

struct OpenFile {
    writer: McapWriter,
    path: PathBuf,
    opened_at: Instant,
    schemas: HashMap<&'static str, u16>,
    channels: HashMap<String, u16>,
    written: BTreeMap<String, u64>,
    dropped_at_open: u64,
    dropped_by_at_open: [(Channel, u64); super::CHANNEL_COUNT],
    /// What each of the pipeline's queues after the gate had dropped when the file opened.
    pipeline_dropped_at_open: Vec<u64>,
    calibration: Option<Intrinsics>,
}

/// The messages of `raw` by channel (for counting them dropped).
fn frame_messages(raw: &RawFrame) -> [(Channel, u64); 4] {
    let sides = raw.sides.iter().filter(|(_, filled)| *filled).count() as u64;
    [
        (Channel::Colour, u64::from(raw.has_colour)),
        (Channel::Depth, u64::from(raw.has_depth)),
        (Channel::Frame, u64::from(raw.has_meta)),
        (Channel::SideChannels, sides),
    ]
}

/// The messages of `event` by channel.
fn event_messages(event: &Event) -> [(Channel, u64); 2] {
    match event {
        Event::Graph { json, scene, .. } => [(Channel::Graph, u64::from(*json)), (Channel::Scene, u64::from(*scene))],
        Event::Keyframe { .. } => [(Channel::Transforms, 1), (Channel::Graph, 0)],
        Event::Health { .. } => [(Channel::Health, 1), (Channel::Graph, 0)],
        Event::Detections { .. } => [(Channel::Detections, 1), (Channel::Graph, 0)],
        Event::NodePoints { .. } => [(Channel::NodePoints, 1), (Channel::Graph, 0)],
        Event::LlmExchange { .. } => [(Channel::LlmExchanges, 1), (Channel::Graph, 0)],
    }
}

/// Encodes an rgb8 image as jpeg or png into `out` (cleared first). PNG uses fast compression:
/// the chunks are compressed again anyway.
fn encode_colour(
    encoding: ColourEncoding,
    jpeg_quality: u8,
    k: Intrinsics,
    rgb: &[u8],
    out: &mut Vec<u8>,
) -> Result<(), image::ImageError> {
    use image::ImageEncoder as _;
    out.clear();
    match encoding {
        ColourEncoding::Jpeg => image::codecs::jpeg::JpegEncoder::new_with_quality(&mut *out, jpeg_quality)
            .write_image(rgb, k.width, k.height, image::ExtendedColorType::Rgb8),
        ColourEncoding::Png | ColourEncoding::Raw => image::codecs::png::PngEncoder::new_with_quality(
            &mut *out,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Sub,
        )
        .write_image(rgb, k.width, k.height, image::ExtendedColorType::Rgb8),
    }
}

/// Counts one message of `channel` dropped; the total dropped so far.
fn count_drops_of(stats: &RecorderStats, channel: Channel) -> u64 {
    stats.count_drop(channel, 1)
}

fn count_drops(stats: &RecorderStats, drops: &[(Channel, u64)]) {
    for &(channel, n) in drops {
        if n > 0 {
            stats.count_drop(channel, n);
        }
    }
}

struct Recorder {
    config: RecordConfig,
    up_axis: UpAxis,
    world_frame: String,
    profile_toml: String,
    side_topics: Vec<String>,
    stats: std::sync::Arc<RecorderStats>,
    pipeline_queues: Vec<std::sync::Arc<crate::queue::QueueStats>>,
    file: Option<OpenFile>,
    failed: bool,
    last_log_ns: u64,
    bytes_closed: u64,
    scratch: Vec<u8>,
    /// A colour image encoded as jpeg or png.
    encoded: Vec<u8>,
    bytes: Vec<u8>,
}

/// Civil UTC date and time of Unix nanoseconds, as `YYYYMMDDTHHMMSS.mmmZ`.
pub(crate) fn utc_stamp(unix_ns: u64) -> String {
    let secs = unix_ns / 1_000_000_000;
    let millis = (unix_ns / 1_000_000) % 1000;
    let (days, rem) = (secs / 86_400, secs % 86_400);
    // Howard Hinnant's days-to-civil algorithm.
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}{month:02}{day:02}T{:02}{:02}{:02}.{millis:03}Z", rem / 3600, (rem / 60) % 60, rem % 60)
}

/// CPU time of the calling thread, nanoseconds (Linux `schedstat`; 0 where unavailable).
pub(crate) fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|v| v.parse().ok()))
        .unwrap_or(0)
}

/// The health record as the recorder writes it (`op3dsg.Health`, JSON); the live view sends the same.
pub(crate) fn health_json(h: &Health) -> serde_json::Value {
    let stages: Vec<_> = h.stages[..h.stage_count as usize]
        .iter()
        .map(|s| {
            serde_json::json!({
                "name": fixed_str(&s.name), "processed": s.processed, "rate_hz": s.rate_hz,
                "latency_p50_us": s.latency_p50_us, "latency_p99_us": s.latency_p99_us, "errors": s.errors
            })
        })
        .collect();
    let queues: Vec<_> = h.queues[..h.queue_count as usize]
        .iter()
        .map(|q| {
            serde_json::json!({
                "name": fixed_str(&q.name), "depth": q.depth, "capacity": q.capacity,
                "dropped": q.dropped, "pushed": q.pushed
            })
        })
        .collect();
    let r = &h.recorder;
    serde_json::json!({
        "stamp_ns": h.stamp_ns,
        "uptime_ns": h.uptime_ns,
        "frames_captured": h.frames_captured,
        "keyframes": h.keyframes,
        "frames_without_pose": h.frames_without_pose,
        "detections_fused": h.detections_fused,
        "graph_version": h.graph_version,
        "map_node_count": h.map_node_count,
        "map_memory_bytes": h.map_memory_bytes,
        "source_connected": h.source_connected != 0,
        "source_kind": h.source_kind().as_str(),
        "world_frame": h.world_frame_str(),
        "graph_subscribers": h.graph_subscribers,
        "dead_nodes_cleaned": h.dead_nodes_cleaned,
        "stages": stages,
        "queues": queues,
        "pose": { "accepted": h.pose.accepted, "stale": h.pose.stale, "queue_full": h.pose.queue_full },
        "recorder": {
            "state": RECORDER_STATES.get(r.state as usize).copied().unwrap_or("unknown"),
            "files": r.files, "messages_written": r.messages_written, "messages_dropped": r.messages_dropped,
            "bytes_written": r.bytes_written, "cpu_ns": r.cpu_ns
        }
    })
}

impl Recorder {
    fn open(&mut self) -> Result<(), (PathBuf, String)> {
        let now_ns = super::now_ns();
        let stem = format!("op3dsg_{}", utc_stamp(now_ns));
        let mut path = self.config.dir.join(format!("{stem}.mcap"));
        let mut n = 1;
        while path.exists() {
            path = self.config.dir.join(format!("{stem}_{n}.mcap"));
            n += 1;
        }
        let file = File::create(&path).map_err(|e| (path.clone(), format!("cannot create: {e}")))?;
        let compression = match self.config.compression {
            RecordCompression::Zstd => Some(mcap::Compression::Zstd),
            RecordCompression::Lz4 => Some(mcap::Compression::Lz4),
            RecordCompression::None => None,
        };
        let mut writer = mcap::WriteOptions::new()
            .compression(compression)
            .compression_threads(0)
            .chunk_size(Some(self.config.chunk_size_kib << 10))
            .profile("op3dsg")
            .library(concat!("op3dsg ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| (path.clone(), e.to_string()))?;
        let metadata = Metadata {
            name: topics::METADATA_PROFILE.to_owned(),
            metadata: BTreeMap::from([
                ("toml".to_owned(), self.profile_toml.clone()),
                ("started_utc".to_owned(), utc_stamp(now_ns)),
            ]),
        };
        writer.write_metadata(&metadata).map_err(|e| (path.clone(), e.to_string()))?;
        info!(file = %path.display(), "recording");
        self.stats.files.fetch_add(1, Ordering::Relaxed);
        self.file = Some(OpenFile {
            writer,
            path,
            opened_at: Instant::now(),
            schemas: HashMap::new(),
            channels: HashMap::new(),
            written: BTreeMap::new(),
            dropped_at_open: self.stats.dropped.load(Ordering::Relaxed),
            dropped_by_at_open: self.stats.dropped_by_channel(),
            pipeline_dropped_at_open: self.pipeline_queues.iter().map(|q| q.dropped.load(Ordering::Relaxed)).collect(),
            calibration: None,
        });
        Ok(())
    }

    fn fail(&mut self, path: &Path, error: &str) {
        warn!(
            file = %path.display(),
            error,
            "recording stopped: a write failed (disk full or failing?); the pipeline goes on without recording"
        );
        self.failed = true;
        self.stats.set_state(RecorderState::Failed);
        // Dropping the writer tries to finish the file; what was flushed before stays readable.
        self.file = None;
    }

    fn write(&mut self, topic: &str, schema: &'static str, log_time_ns: u64) -> Result<(), String> {
        let Some(file) = self.file.as_mut() else { return Ok(()) };
        let channel_id = match file.channels.get(topic) {
            Some(id) => *id,
            None => {
                let declared = schemas::channel_schema(schema).ok_or_else(|| format!("no schema named {schema}"))?;
                let schema_id = match file.schemas.get(schema) {
                    Some(id) => *id,
                    None => {
                        let id = file
                            .writer
                            .add_schema(schema, declared.encoding, &declared.data)
                            .map_err(|e| e.to_string())?;
                        file.schemas.insert(schema, id);
                        id
                    }
                };
                let id = file
                    .writer
                    .add_channel(schema_id, topic, declared.message_encoding, &BTreeMap::new())
                    .map_err(|e| e.to_string())?;
                file.channels.insert(topic.to_owned(), id);
                id
            }
        };
        let log_time = log_time_ns.max(self.last_log_ns);
        self.last_log_ns = log_time;
        let count = file.written.entry(topic.to_owned()).or_default();
        let header = MessageHeader { channel_id, sequence: *count as u32, log_time, publish_time: log_time };
        file.writer.write_to_known_channel(&header, &self.bytes).map_err(|e| e.to_string())?;
        *count += 1;
        self.stats.written.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }

    fn write_frame(&mut self, raw: &RawFrame) -> Result<(), String> {
        let t = raw.log_time_ns;
        let k = raw.intrinsics;
        let calibrate =
            self.config.channels.calibration.enabled && self.file.as_ref().is_some_and(|f| f.calibration != Some(k));
        if calibrate {
            encode(&calibration(&k, raw.stamp_ns), &mut self.bytes)?;
            self.write(topics::TOPIC_CALIBRATION, schemas::CAMERA_CALIBRATION, t)?;
            if let Some(file) = self.file.as_mut() {
                file.calibration = Some(k);
            }
        }
        if raw.has_colour
            && let Some(colour) = &raw.colour
            && self.config.colour != ColourEncoding::Raw
        {
            match encode_colour(self.config.colour, self.config.jpeg_quality, k, colour, &mut self.encoded) {
                Ok(()) => {
                    let image = compressed_image(raw.stamp_ns, CAMERA_FRAME, self.config.colour.name(), &self.encoded);
                    encode(&image, &mut self.bytes)?;
                    self.write(topics::TOPIC_COLOUR, schemas::COMPRESSED_IMAGE, t)?;
                }
                Err(e) => {
                    // Not the disk's fault: this image is dropped and counted, recording goes on.
                    let dropped = count_drops_of(&self.stats, Channel::Colour);
                    if dropped.is_power_of_two() {
                        warn!(seq = raw.seq, error = %e, dropped, "colour image could not be encoded; dropped");
                    }
                }
            }
        } else if raw.has_colour
            && let Some(colour) = &raw.colour
        {
            encode(&raw_image(image_header(raw, "rgb8", 3), colour), &mut self.bytes)?;
            self.write(topics::TOPIC_COLOUR, schemas::RAW_IMAGE, t)?;
        }
        if raw.has_depth
            && let Some(depth) = &raw.depth
        {
            let bytes: &[u8] = bytemuck::cast_slice(depth);
            encode(&raw_image(image_header(raw, "16UC1", 2), bytes), &mut self.bytes)?;
            self.write(topics::TOPIC_DEPTH, schemas::RAW_IMAGE, t)?;
        }
        for i in 0..raw.sides.len().min(self.side_topics.len()) {
            let (ids, filled) = &raw.sides[i];
            if !filled {
                continue;
            }
            let bytes: &[u8] = bytemuck::cast_slice(ids);
            encode(&raw_image(image_header(raw, "16UC1", 2), bytes), &mut self.bytes)?;
            let topic = self.side_topics[i].clone();
            self.write(&topic, schemas::RAW_IMAGE, t)?;
        }
        if raw.has_meta {
            let meta = FrameMeta {
                seq: raw.seq,
                stamp_ns: raw.stamp_ns,
                depth_units_per_m: f64::from(raw.depth_units_per_m),
                world_from_camera: raw.world_from_camera.as_ref().map(Into::into),
            };
            self.bytes.clear();
            serde_json::to_writer(&mut self.bytes, &meta).map_err(|e| e.to_string())?;
            self.write(topics::TOPIC_FRAME, schemas::FRAME, t)?;
        }
        Ok(())
    }

    fn write_input_pose(
        &mut self,
        log_time_ns: u64,
        pose: &op3dsg_drivers::mcap::messages::InputPose,
    ) -> Result<(), String> {
        self.bytes.clear();
        serde_json::to_writer(&mut self.bytes, pose).map_err(|e| e.to_string())?;
        self.write(topics::TOPIC_INPUT_POSE, schemas::INPUT_POSE, log_time_ns)
    }

    fn write_event(&mut self, event: Event) -> Result<(), String> {
        match event {
            Event::Graph { log_time_ns, graph, json, scene } => {
                if json {
                    self.bytes.clear();
                    serde_json::to_writer(&mut self.bytes, &graph.to_json("op3dsgd")).map_err(|e| e.to_string())?;
                    self.write(topics::TOPIC_GRAPH, schemas::GRAPH, log_time_ns)?;
                }
                if scene {
                    encode(&scene_update(&graph, self.up_axis, &self.world_frame), &mut self.bytes)?;
                    self.write(topics::TOPIC_SCENE, schemas::SCENE_UPDATE, log_time_ns)?;
                }
            }
            Event::Keyframe { log_time_ns, stamp_ns, world_from_camera } => {
                let transform = frame_transform(stamp_ns, &world_from_camera, &self.world_frame, CAMERA_FRAME);
                encode(&transform, &mut self.bytes)?;
                self.write(topics::TOPIC_TF, schemas::FRAME_TRANSFORM, log_time_ns)?;
            }
            Event::Detections { log_time_ns, stamp_ns, boxes } => {
                encode(&super::annotations::detections(stamp_ns, &boxes), &mut self.bytes)?;
                self.write(topics::TOPIC_DETECTIONS, schemas::IMAGE_ANNOTATIONS, log_time_ns)?;
            }
            Event::NodePoints { log_time_ns, stamp_ns, points } => {
                let cloud = super::annotations::node_points(stamp_ns, &points, &self.world_frame, &mut self.scratch);
                encode(&cloud, &mut self.bytes)?;
                self.write(topics::TOPIC_NODE_POINTS, schemas::POINT_CLOUD, log_time_ns)?;
            }
            Event::LlmExchange { log_time_ns, exchange } => {
                self.bytes.clear();
                serde_json::to_writer(&mut self.bytes, &*exchange).map_err(|e| e.to_string())?;
                self.write(topics::TOPIC_LLM, schemas::LLM_EXCHANGE, log_time_ns)?;
            }
            Event::Health { log_time_ns, health } => {
                let mut health = *health;
                health.recorder = self.stats.health();
                self.bytes.clear();
                serde_json::to_writer(&mut self.bytes, &health_json(&health)).map_err(|e| e.to_string())?;
                self.write(topics::TOPIC_HEALTH, schemas::HEALTH, log_time_ns)?;
            }
        }
        Ok(())
    }

    /// Closes the current chunk and flushes; starts a new file when this one is big or old
    /// enough.
    fn flush(&mut self) -> Result<(), (PathBuf, String)> {
        let Some(file) = self.file.as_mut() else { return Ok(()) };
        file.writer.flush().map_err(|e| (file.path.clone(), e.to_string()))?;
        let size = std::fs::metadata(&file.path).map(|m| m.len()).unwrap_or(0);
        self.stats.bytes.store(self.bytes_closed + size, Ordering::Relaxed);
        let too_big = size >= self.config.max_file_mib << 20;
        let too_old = file.opened_at.elapsed() >= Duration::from_secs_f64(self.config.max_file_s);
        if too_big || too_old {
            self.close()?;
            self.open()?;
        }
        Ok(())
    }

    /// Writes the drop counts and the summary, and closes the file.
    fn close(&mut self) -> Result<(), (PathBuf, String)> {
        let Some(mut file) = self.file.take() else { return Ok(()) };
        let path = file.path.clone();
        let dropped = self.stats.dropped.load(Ordering::Relaxed) - file.dropped_at_open;
        let mut entries: BTreeMap<String, String> =
            file.written.iter().map(|(topic, n)| (format!("{topic}.written"), n.to_string())).collect();
        // Drops per channel: every channel written in this file or with drops gets its count.
        let now = self.stats.dropped_by_channel();
        for ((channel, total), (_, at_open)) in now.iter().zip(file.dropped_by_at_open.iter()) {
            let n = total - at_open;
            let topics: Vec<&str> = match channel.topic() {
                Some(topic) => vec![topic],
                None => self.side_topics.iter().map(String::as_str).collect(),
            };
            let per_topic = n / (topics.len().max(1) as u64);
            for topic in topics {
                if per_topic > 0 || file.written.contains_key(topic) {
                    entries.insert(format!("{topic}.dropped"), per_topic.to_string());
                }
            }
        }
        entries.insert("dropped_total".to_owned(), dropped.to_string());
        // What the pipeline lost after the gate while this file was open: keyframes a replay
        // would process, so the recorded graph is not one it reproduces.
        if !self.pipeline_queues.is_empty() {
            let mut total = 0;
            for (queue, at_open) in self.pipeline_queues.iter().zip(&file.pipeline_dropped_at_open) {
                let n = queue.dropped.load(Ordering::Relaxed).saturating_sub(*at_open);
                total += n;
                entries
                    .insert(format!("{}{}", op3dsg_drivers::mcap::PIPELINE_DROPPED_PREFIX, queue.name), n.to_string());
            }
            entries.insert(op3dsg_drivers::mcap::PIPELINE_DROPPED_TOTAL.to_owned(), total.to_string());
        }
        entries.insert("finished_utc".to_owned(), utc_stamp(super::now_ns()));
        let metadata = Metadata { name: topics::METADATA_RECORDER.to_owned(), metadata: entries };
        let err = |e: String| (path.clone(), e);
        file.writer.write_metadata(&metadata).map_err(|e| err(e.to_string()))?;
        file.writer.finish().map_err(|e| err(e.to_string()))?;
        let buffered = file.writer.into_inner();
        buffered.into_inner().map_err(|e| err(e.error().to_string()))?;
        let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        self.bytes_closed += size;
        self.stats.bytes.store(self.bytes_closed, Ordering::Relaxed);
        info!(file = %path.display(), bytes = size, dropped, "recording finished");
        Ok(())
    }
}

pub(super) fn recorder_loop(thread: RecordThread) {
    let RecordThread {
        config,
        up_axis,
        world_frame,
        profile_toml,
        side_topics,
        frames_rx,
        events_rx,
        pool_tx,
        stats,
        pipeline_queues,
    } = thread;
    let flush_every = Duration::from_millis(config.flush_interval_ms);
    let mut rec = Recorder {
        config,
        up_axis,
        world_frame,
        profile_toml,
        side_topics,
        stats,
        pipeline_queues,
        file: None,
        failed: false,
        last_log_ns: 0,
        bytes_closed: 0,
        scratch: Vec::new(),
        encoded: Vec::new(),
        bytes: Vec::new(),
    };
    rec.scratch.shrink_to_fit();
    if let Err((path, e)) = rec.open() {
        rec.fail(&path, &e);
    }
    let never_frames = crossbeam_channel::never();
    let never_events = crossbeam_channel::never();
    let mut frames_rx = Some(frames_rx);
    let mut events_rx = Some(events_rx);
    let mut next_flush = Instant::now() + flush_every;
    while frames_rx.is_some() || events_rx.is_some() {
        let timeout = next_flush.saturating_duration_since(Instant::now());
        let result = crossbeam_channel::select! {
            recv(frames_rx.as_ref().unwrap_or(&never_frames)) -> msg => match msg {
                Ok(RawInput::Frame(raw)) => {
                    let result = if rec.failed {
                        count_drops(&rec.stats, &frame_messages(&raw));
                        Ok(())
                    } else {
                        rec.write_frame(&raw)
                    };
                    let _ = pool_tx.try_send(raw);
                    result
                }
                Ok(RawInput::Pose { log_time_ns, pose }) => if rec.failed {
                    count_drops(&rec.stats, &[(Channel::InputPoses, 1)]);
                    Ok(())
                } else {
                    rec.write_input_pose(log_time_ns, &pose)
                },
                Err(_) => { frames_rx = None; Ok(()) }
            },
            recv(events_rx.as_ref().unwrap_or(&never_events)) -> msg => match msg {
                Ok(event) => if rec.failed {
                    count_drops(&rec.stats, &event_messages(&event));
                    Ok(())
                } else {
                    rec.write_event(event)
                },
                Err(_) => { events_rx = None; Ok(()) }
            },
            default(timeout) => Ok(()),
        };
        if let Err(e) = result {
            let path = rec.file.as_ref().map(|f| f.path.clone()).unwrap_or_default();
            rec.fail(&path, &e);
        }
        if Instant::now() >= next_flush {
            next_flush = Instant::now() + flush_every;
            rec.stats.cpu_ns.store(thread_cpu_ns(), Ordering::Relaxed);
            if !rec.failed
                && let Err((path, e)) = rec.flush()
            {
                rec.fail(&path, &e);
            }
        }
    }
    if !rec.failed {
        match rec.close() {
            Ok(()) => rec.stats.set_state(RecorderState::Finished),
            Err((path, e)) => rec.fail(&path, &e),
        }
    }
    rec.stats.cpu_ns.store(thread_cpu_ns(), Ordering::Relaxed);
}

/// The `foxglove.RawImage` header of one of `raw`'s images (`bytes_per_pixel` wide pixels).
fn image_header(raw: &RawFrame, encoding: &'static str, bytes_per_pixel: u32) -> RawImageHeader<'static> {
    let k = raw.intrinsics;
    RawImageHeader {
        stamp_ns: raw.stamp_ns,
        frame_id: CAMERA_FRAME,
        width: k.width,
        height: k.height,
        encoding,
        step: k.width * bytes_per_pixel,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamps_are_civil_dates() {
        assert_eq!(utc_stamp(0), "19700101T000000.000Z");
        // 2026-12-01 12:06:49.123 UTC
        assert_eq!(utc_stamp(1_796_126_809_123_000_000), "20261201T120649.123Z");
        assert_eq!(utc_stamp(951_782_400_000_000_000), "20000229T000000.000Z");
    }
}
