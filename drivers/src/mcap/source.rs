//! [`McapSource`]: plays the raw input of recordings the recorder wrote.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use tracing::{info, warn};

use super::messages::{
    CompressedImageIn, FOXGLOVE_ENCODINGS, FrameMeta, InputPose, RawImageIn, calibration_intrinsics,
};
use super::reader::{ChannelInfo, Item, McapReader, MessageAt, ReadError};
use super::{McapReplayConfig, TOPIC_CALIBRATION, TOPIC_COLOUR, TOPIC_DEPTH, TOPIC_FRAME, TOPIC_INPUT_POSE, schemas};
use crate::frame::{Frame, Intrinsics};
use crate::pose::Isometry;
use crate::source::{
    FrameSource, MAX_BLOCK, PlaybackMode, SourceError, SourceKind, SourceStatus, StampClock, StepControl,
};

/// Receives a side channel's message of each frame (the message's bytes and its channel's
/// message encoding) after the frame's pixels and meta are in place; an error stops the replay
/// naming the channel.
pub type SideChannelHandler = Box<dyn FnMut(&mut Frame, &[u8], &str) -> Result<(), String> + Send>;

struct SideChannel {
    topic: String,
    handler: SideChannelHandler,
    data: Vec<u8>,
    message_encoding: String,
    present: bool,
}

/// The messages of the next frame, read ahead of its delivery.
#[derive(Default)]
struct Staged {
    meta: Option<FrameMeta>,
    colour: Vec<u8>,
    colour_at: Option<MessageAt>,
    /// The colour came as a `foxglove.CompressedImage` (jpeg or png).
    colour_compressed: bool,
    /// The colour's message encoding (`protobuf`, or `json` in earlier recordings).
    colour_encoding: &'static str,
    depth: Vec<u8>,
    depth_encoding: &'static str,
    depth_at: Option<MessageAt>,
    /// Input poses read before this frame.
    poses: Vec<InputPose>,
}

/// A [`FrameSource`] over recordings of the recorder (`source.kind = "mcap"`, [the
/// module](super)): frames as the keyframe gate received them while recording, with their seqs,
/// stamps, poses and depth scale, the intrinsics from `/camera/calibration`.
///
/// Errors name the file, the channel and the message index: a channel whose schema or encoding
/// is not the recorder's, a frame without a calibration before it, an image of another size, a
/// frame whose colour or depth is missing, a file cut off (after a crash or a full disk: the
/// frames before the cut are delivered first, then the stream ends with the error).
///
/// A file of a folder that is gone by the time its turn comes (deleted after the replay listed
/// the folder) is skipped with a warning naming it and counted in
/// [`FrameSource::bad_data_skipped`] (capture errors in the daemon's health); the replay goes on
/// with the next file. A file that is there but unreadable still ends the stream with its error.
pub struct McapSource {
    config: McapReplayConfig,
    files: Vec<PathBuf>,
    next_file: usize,
    reader: Option<McapReader>,
    intrinsics: Intrinsics,
    has_poses: bool,
    side_channels: Vec<SideChannel>,
    staged: Staged,
    ready: bool,
    scratch: Vec<u8>,
    /// Encoded bytes of a compressed colour image on the way to its pixels.
    decode_scratch: Vec<u8>,
    step: Option<StepControl>,
    origin: Option<(Instant, u64)>,
    delivered: u64,
    /// Files of the folder that vanished after it was listed (skipped, each logged at warn).
    vanished_files: u64,
    finished: bool,
    /// Input poses that came before the frames delivered so far, not yet taken.
    poses: Vec<InputPose>,
    poses_replayed: u64,
}

impl std::fmt::Debug for McapSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapSource").field("files", &self.files).field("delivered", &self.delivered).finish()
    }
}

fn source_error(e: ReadError) -> SourceError {
    SourceError::File { path: e.path, reason: e.reason }
}

fn at_error(path: &Path, channel: &ChannelInfo, at: MessageAt, reason: impl std::fmt::Display) -> SourceError {
    SourceError::File {
        path: path.display().to_string(),
        reason: format!("channel {} message {}: {reason}", channel.topic, at.index),
    }
}

/// A channel the replay reads must have a schema and encoding the recorder writes: `foxglove.*`
/// protobuf (or JSON, as earlier recordings hold them), `op3dsg.*` JSON.
fn check_schema(path: &Path, channel: &ChannelInfo, at: MessageAt) -> Result<(), SourceError> {
    let Some(allowed) = expected_schema(&channel.topic) else { return Ok(()) };
    let encodings: &[&str] =
        if channel.schema_name.starts_with("foxglove.") { &FOXGLOVE_ENCODINGS } else { &[schemas::MESSAGE_ENCODING] };
    if !allowed.contains(&channel.schema_name.as_str()) || !encodings.contains(&channel.message_encoding.as_str()) {
        return Err(at_error(
            path,
            channel,
            at,
            format!(
                "schema \"{}\" encoded \"{}\", expected \"{}\" encoded \"{}\"",
                channel.schema_name,
                channel.message_encoding,
                allowed.join("\" or \""),
                if allowed[0].starts_with("foxglove.") {
                    FOXGLOVE_ENCODINGS.join("\" or \"")
                } else {
                    schemas::MESSAGE_ENCODING.to_owned()
                }
            ),
        ));
    }
    Ok(())
}

/// The message encoding of a checked `foxglove.*` channel, as one of [`FOXGLOVE_ENCODINGS`].
fn foxglove_encoding(message_encoding: &str) -> &'static str {
    FOXGLOVE_ENCODINGS.into_iter().find(|e| *e == message_encoding).unwrap_or(schemas::PROTOBUF)
}

/// The schemas a raw-input topic may have (colour: raw, or compressed with `record.colour`).
fn expected_schema(topic: &str) -> Option<&'static [&'static str]> {
    match topic {
        TOPIC_COLOUR => Some(&[schemas::RAW_IMAGE, schemas::COMPRESSED_IMAGE]),
        TOPIC_DEPTH => Some(&[schemas::RAW_IMAGE]),
        TOPIC_CALIBRATION => Some(&[schemas::CAMERA_CALIBRATION]),
        TOPIC_FRAME => Some(&[schemas::FRAME]),
        TOPIC_INPUT_POSE => Some(&[schemas::INPUT_POSE]),
        _ => None,
    }
}

/// The `.mcap` files of `path`: the file itself, or a folder's `*.mcap` in name order.
fn recording_files(path: &Path) -> Result<Vec<PathBuf>, SourceError> {
    let file_error = |reason: String| SourceError::File { path: path.display().to_string(), reason };
    if path.is_file() {
        return Ok(vec![path.to_owned()]);
    }
    if !path.is_dir() {
        return Err(file_error("no such file or folder (expected an .mcap recording)".to_owned()));
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| file_error(format!("cannot list: {e}")))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|ext| ext == "mcap") && p.is_file())
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(file_error("no .mcap files in this folder".to_owned()));
    }
    Ok(files)
}

/// Warns when `file` lost messages while it was recorded (the recorder's metadata, read from the
/// summary), naming the channels and counts, or when the recorder did not finish it: the replay
/// then sees less than the robot did, and its graph is not the recorded one bit for bit.
fn warn_of_drops(file: &Path) {
    match super::reader::summary_metadata(file, super::METADATA_RECORDER) {
        Ok(Some(entries)) => {
            let dropped: u64 = entries.get("dropped_total").and_then(|v| v.parse().ok()).unwrap_or(0);
            if let Some((lost, queues)) = super::pipeline_drops(&entries).filter(|(n, _)| *n > 0) {
                warn!(
                    file = %file.display(),
                    dropped = lost,
                    queues = %queues.join(", "),
                    "the pipeline dropped keyframes or results after the keyframe gate while this was recorded: the \
                     replay processes them, so its graph is not the recorded one bit for bit (op3dsg record info FILE)"
                );
            }
            if dropped > 0 {
                let channels = super::dropped_channels(&entries);
                warn!(
                    file = %file.display(),
                    dropped,
                    channels = %channels.join(", "),
                    "this recording dropped messages while recording: the replay sees less than the robot did and \
                     its graph is not the recorded one bit for bit (op3dsg record info FILE)"
                );
            }
        }
        Ok(None) => warn!(
            file = %file.display(),
            "the recorder did not finish this file (no summary): what it dropped is unknown, and the replay may \
             not make the recorded graph bit for bit"
        ),
        Err(e) => warn!(error = %e, "cannot read the recorder's metadata"),
    }
}

impl McapSource {
    /// Opens the recording and reads up to its first frame for the intrinsics (from
    /// `/camera/calibration`) and whether frames carry poses.
    pub fn new(config: &McapReplayConfig) -> Result<Self, SourceError> {
        config.validate("source.mcap").map_err(SourceError::Config)?;
        let files = recording_files(&config.path)?;
        let mut source = Self {
            config: config.clone(),
            files,
            next_file: 0,
            reader: None,
            intrinsics: Intrinsics::d435i_640x480(),
            has_poses: false,
            side_channels: Vec::new(),
            staged: Staged::default(),
            ready: false,
            scratch: Vec::new(),
            decode_scratch: Vec::new(),
            step: (config.mode == PlaybackMode::Stepped).then(StepControl::new),
            origin: None,
            delivered: 0,
            vanished_files: 0,
            finished: false,
            poses: Vec::new(),
            poses_replayed: 0,
        };
        // The intrinsics are needed before the first frame (the frame pool is sized by them).
        source.intrinsics = source.probe()?;
        source.next_file = 0;
        source.reader = None;
        source.staged = Staged::default();
        source.ready = false;
        info!(path = %config.path.display(), files = source.files.len(), "mcap recording opened");
        for file in &source.files {
            warn_of_drops(file);
        }
        Ok(source)
    }

    /// Whether the recording declares a channel `topic` (in its first file).
    pub fn has_channel(&self, topic: &str) -> Result<bool, SourceError> {
        let mut reader = McapReader::open(&self.files[0]).map_err(source_error)?;
        let mut data = Vec::new();
        loop {
            if reader.channels().any(|c| c.topic == topic) {
                return Ok(true);
            }
            match reader.next(&mut data) {
                Ok(Some(Item::Message(at)))
                    if reader.channel(at.channel_id).is_some_and(|c| c.topic == TOPIC_FRAME) =>
                {
                    // The recorder declares every channel of a frame before its meta.
                    return Ok(reader.channels().any(|c| c.topic == topic));
                }
                Ok(Some(_)) => {}
                Ok(None) | Err(_) => return Ok(reader.channels().any(|c| c.topic == topic)),
            }
        }
    }

    /// The effective profile the recording was made with (metadata `op3dsg.profile`, key
    /// `toml`), from the first file.
    pub fn recorded_profile(&self) -> Result<Option<String>, SourceError> {
        let mut reader = McapReader::open(&self.files[0]).map_err(source_error)?;
        let mut data = Vec::new();
        loop {
            match reader.next(&mut data) {
                Ok(Some(Item::Metadata { name, mut entries })) if name == super::METADATA_PROFILE => {
                    return Ok(entries.remove("toml"));
                }
                Ok(Some(Item::Message(at)))
                    if reader.channel(at.channel_id).is_some_and(|c| c.topic == TOPIC_FRAME) =>
                {
                    return Ok(None);
                }
                Ok(Some(_)) => {}
                Ok(None) => return Ok(None),
                Err(e) => return Err(source_error(e)),
            }
        }
    }

    /// Hands each frame's message on `topic` to `handler` (a side channel of the source that
    /// recorded, e.g. the simulator's instance ids). A frame without one is delivered without
    /// calling it.
    pub fn with_side_channel(mut self, topic: &str, handler: SideChannelHandler) -> Self {
        self.side_channels.push(SideChannel {
            topic: topic.to_owned(),
            handler,
            data: Vec::new(),
            message_encoding: String::new(),
            present: false,
        });
        self
    }

    fn probe(&mut self) -> Result<Intrinsics, SourceError> {
        match self.read_frame(None)? {
            true => {
                let meta = self.staged.meta.as_ref();
                self.has_poses = meta.is_some_and(|m| m.world_from_camera.is_some());
                Ok(self.intrinsics)
            }
            false => Err(SourceError::File {
                path: self.files[0].display().to_string(),
                reason: format!("no frame in the recording (no message on {TOPIC_FRAME})"),
            }),
        }
    }

    /// Reads messages until the next complete frame is staged; `false` at the end of the last
    /// file. `expected` is the intrinsics every calibration must match (`None` while probing).
    fn read_frame(&mut self, expected: Option<Intrinsics>) -> Result<bool, SourceError> {
        self.staged.meta = None;
        self.staged.colour_at = None;
        self.staged.depth_at = None;
        for side in &mut self.side_channels {
            side.present = false;
        }
        let mut calibration: Option<Intrinsics> = expected;
        loop {
            if self.reader.is_none() {
                match self.open_next_file()? {
                    None => return Ok(false),
                    Some(false) => continue,
                    Some(true) => {}
                }
                if expected.is_none() {
                    calibration = None;
                }
            }
            let Some(reader) = self.reader.as_mut() else { return Ok(false) };
            let item = match reader.next(&mut self.scratch) {
                Ok(Some(item)) => item,
                Ok(None) => {
                    self.reader = None;
                    continue;
                }
                Err(e) => return Err(source_error(e)),
            };
            let Item::Message(at) = item else { continue };
            let path = reader.path().to_owned();
            let Some(channel) = reader.channel(at.channel_id).cloned() else { continue };
            check_schema(&path, &channel, at)?;
            match channel.topic.as_str() {
                TOPIC_CALIBRATION => {
                    let k = calibration_intrinsics(&self.scratch, &channel.message_encoding)
                        .map_err(|e| at_error(&path, &channel, at, e))?;
                    if let Some(expected) = expected
                        && k != expected
                    {
                        return Err(at_error(
                            &path,
                            &channel,
                            at,
                            format!("intrinsics changed to {k:?} from {expected:?}; a replay has one camera"),
                        ));
                    }
                    calibration = Some(k);
                    self.intrinsics = k;
                }
                TOPIC_INPUT_POSE => {
                    let pose: InputPose = serde_json::from_slice(&self.scratch)
                        .map_err(|e| at_error(&path, &channel, at, format!("not an op3dsg.InputPose: {e}")))?;
                    self.staged.poses.push(pose);
                }
                TOPIC_COLOUR => {
                    std::mem::swap(&mut self.staged.colour, &mut self.scratch);
                    self.staged.colour_at = Some(at);
                    self.staged.colour_compressed = channel.schema_name == schemas::COMPRESSED_IMAGE;
                    self.staged.colour_encoding = foxglove_encoding(&channel.message_encoding);
                }
                TOPIC_DEPTH => {
                    std::mem::swap(&mut self.staged.depth, &mut self.scratch);
                    self.staged.depth_at = Some(at);
                    self.staged.depth_encoding = foxglove_encoding(&channel.message_encoding);
                }
                TOPIC_FRAME => {
                    let meta: FrameMeta = serde_json::from_slice(&self.scratch)
                        .map_err(|e| at_error(&path, &channel, at, format!("not an op3dsg.Frame: {e}")))?;
                    self.check_frame(&path, &channel, at, &meta, calibration.is_some())?;
                    self.staged.meta = Some(meta);
                    return Ok(true);
                }
                topic => {
                    if let Some(side) = self.side_channels.iter_mut().find(|s| s.topic == topic) {
                        std::mem::swap(&mut side.data, &mut self.scratch);
                        side.message_encoding.clone_from(&channel.message_encoding);
                        side.present = true;
                    }
                }
            }
        }
    }

    /// Opens the next file of the recording: `None` after the last, `Some(false)` when it
    /// vanished since the replay opened (skipped, counted, warned), `Some(true)` when open.
    fn open_next_file(&mut self) -> Result<Option<bool>, SourceError> {
        let Some(path) = self.files.get(self.next_file) else { return Ok(None) };
        let opened = McapReader::open(path);
        self.next_file += 1;
        match opened {
            Ok(reader) => {
                self.reader = Some(reader);
                Ok(Some(true))
            }
            // Listed when the replay opened, gone now (a retention job, an operator tidying up):
            // the rest of the recording is still worth playing.
            Err(e) if !path.exists() => {
                self.vanished_files += 1;
                warn!(
                    path = %path.display(),
                    error = %e.reason,
                    vanished_files = self.vanished_files,
                    "recording file vanished during replay; skipped, going on with the next file"
                );
                Ok(Some(false))
            }
            Err(e) => Err(source_error(e)),
        }
    }

    /// A frame message needs a calibration before it in its file and the frame's colour and
    /// depth staged.
    fn check_frame(
        &self,
        path: &Path,
        channel: &ChannelInfo,
        at: MessageAt,
        meta: &FrameMeta,
        calibrated: bool,
    ) -> Result<(), SourceError> {
        if !calibrated {
            return Err(at_error(
                path,
                channel,
                at,
                format!("frame seq {} has no {TOPIC_CALIBRATION} before it in this file", meta.seq),
            ));
        }
        for (topic, present) in
            [(TOPIC_COLOUR, self.staged.colour_at.is_some()), (TOPIC_DEPTH, self.staged.depth_at.is_some())]
        {
            if !present {
                return Err(at_error(
                    path,
                    channel,
                    at,
                    format!(
                        "frame seq {} has no {topic} message before it (was the channel off or \
                         rate-limited while recording? replay needs every frame's colour and depth)",
                        meta.seq
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Decodes the staged frame into `frame`.
    fn deliver(&mut self, frame: &mut Frame) -> Result<(), SourceError> {
        let path = self.files[self.next_file.saturating_sub(1)].clone();
        let Some(meta) = self.staged.meta.take() else {
            return Err(SourceError::Frame { seq: self.delivered, reason: "no staged frame".to_owned() });
        };
        let image_error = |topic: &str, at: Option<MessageAt>, reason: String| SourceError::File {
            path: path.display().to_string(),
            reason: format!("channel {topic} message {}: frame seq {}: {reason}", at.map_or(0, |a| a.index), meta.seq),
        };
        if self.staged.colour_compressed {
            let at = self.staged.colour_at;
            let image = CompressedImageIn::parse(&self.staged.colour, self.staged.colour_encoding)
                .map_err(|e| image_error(TOPIC_COLOUR, at, e))?;
            if image.stamp_ns != meta.stamp_ns {
                return Err(image_error(
                    TOPIC_COLOUR,
                    at,
                    format!("image stamp {} ns, the frame's is {} ns", image.stamp_ns, meta.stamp_ns),
                ));
            }
            let k = self.intrinsics;
            image
                .decode_rgb_into(k.width, k.height, &mut self.decode_scratch, &mut frame.rgb)
                .map_err(|e| image_error(TOPIC_COLOUR, at, e))?;
        }
        let colour_raw = !self.staged.colour_compressed;
        let staged = &self.staged;
        for (topic, bytes, message_encoding, at, encodings, bpp) in [
            (TOPIC_COLOUR, &staged.colour, staged.colour_encoding, staged.colour_at, &["rgb8"][..], 3u32),
            (TOPIC_DEPTH, &staged.depth, staged.depth_encoding, staged.depth_at, &["16UC1", "mono16"][..], 2u32),
        ]
        .into_iter()
        .filter(|(topic, ..)| colour_raw || *topic != TOPIC_COLOUR)
        {
            let image = RawImageIn::parse(bytes, message_encoding).map_err(|e| image_error(topic, at, e))?;
            if image.stamp_ns != meta.stamp_ns {
                return Err(image_error(
                    topic,
                    at,
                    format!("image stamp {} ns, the frame's is {} ns", image.stamp_ns, meta.stamp_ns),
                ));
            }
            let out: &mut [u8] =
                if bpp == 3 { &mut frame.rgb } else { bytemuck::cast_slice_mut(frame.depth.as_mut_slice()) };
            image.decode_into(encodings, bpp, out).map_err(|e| image_error(topic, at, e))?;
        }
        self.poses.append(&mut self.staged.poses);
        frame.seq = meta.seq;
        frame.stamp_ns = meta.stamp_ns;
        frame.intrinsics = self.intrinsics;
        frame.depth_units_per_m = meta.depth_units_per_m as f32;
        frame.world_from_camera = meta.world_from_camera.as_ref().map(Isometry::from);
        for side in &mut self.side_channels {
            if side.present {
                (side.handler)(frame, &side.data, &side.message_encoding).map_err(|e| SourceError::File {
                    path: path.display().to_string(),
                    reason: format!("channel {}: frame seq {}: {e}", side.topic, meta.seq),
                })?;
            }
        }
        Ok(())
    }

    fn wait_for_due(&self, stamp_ns: u64, at_most: Duration) -> bool {
        crate::source::wait_until_due(self.origin, stamp_ns, at_most)
    }
}

impl FrameSource for McapSource {
    fn kind(&self) -> SourceKind {
        SourceKind::Replay
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn stamp_clock(&self) -> StampClock {
        StampClock::Recording
    }

    fn has_poses(&self) -> bool {
        self.has_poses
    }

    fn lossless(&self) -> bool {
        self.config.lossless
    }

    fn next_frame(&mut self, frame: &mut Frame) -> Result<SourceStatus, SourceError> {
        if self.finished {
            return Ok(SourceStatus::EndOfStream);
        }
        crate::source::check_frame_buffers(frame, &self.intrinsics, self.delivered)?;
        if !self.ready {
            match self.read_frame(Some(self.intrinsics)) {
                Ok(true) => self.ready = true,
                Ok(false) => {
                    // Poses after the last frame (the one it waited for, often) still go.
                    self.poses.append(&mut self.staged.poses);
                    self.finished = true;
                    return Ok(SourceStatus::EndOfStream);
                }
                Err(e) => {
                    self.finished = true;
                    return Err(e);
                }
            }
        }
        let stamp_ns = self.staged.meta.as_ref().map_or(0, |m| m.stamp_ns);
        match self.config.mode {
            PlaybackMode::Recorded => {
                if !self.wait_for_due(stamp_ns, MAX_BLOCK) {
                    return Ok(SourceStatus::Pending);
                }
            }
            PlaybackMode::Stepped => {
                if !self.step.as_ref().is_some_and(|step| step.take(MAX_BLOCK)) {
                    return Ok(SourceStatus::Pending);
                }
            }
            PlaybackMode::Fast => {}
        }
        self.ready = false;
        if let Err(e) = self.deliver(frame) {
            self.finished = true;
            return Err(e);
        }
        self.origin.get_or_insert((Instant::now(), stamp_ns));
        self.delivered += 1;
        Ok(SourceStatus::Frame)
    }

    fn take_input_poses(&mut self, out: &mut Vec<InputPose>) {
        if !self.poses.is_empty() && self.poses_replayed == 0 {
            info!(
                "the recording holds poses of the pose input (/op3dsg/input_pose): replaying them to the keyframe gate"
            );
        }
        self.poses_replayed += self.poses.len() as u64;
        out.append(&mut self.poses);
    }

    fn describe(&self) -> String {
        format!("mcap {}", self.config.path.display())
    }

    fn stops_on_error(&self) -> bool {
        true
    }

    fn bad_data_skipped(&self) -> u64 {
        self.vanished_files
    }

    fn step_control(&self) -> Option<StepControl> {
        self.step.clone()
    }
}
