//! [`McapSource`] on files written here with the `mcap` crate: a good recording plays back
//! exactly; bad ones fail naming the file, the channel and the message index.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::Path;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;

use super::messages::{FrameMeta, RawImageHeader, calibration, encode, raw_image};
use super::{McapReplayConfig, McapSource, TOPIC_CALIBRATION, TOPIC_COLOUR, TOPIC_DEPTH, TOPIC_FRAME, schemas};
use crate::frame::{Frame, Intrinsics};
use crate::pose::Isometry;
use crate::replay::PlaybackMode;
use crate::source::{FrameSource, SourceStatus};

const K: Intrinsics = Intrinsics { width: 16, height: 16, fx: 20.0, fy: 20.0, cx: 8.0, cy: 8.0 };

struct Writer {
    writer: mcap::Writer<BufWriter<std::fs::File>>,
    channels: BTreeMap<&'static str, u16>,
    seq: u32,
    /// `foxglove.*` messages as JSON, as recordings before protobuf hold them.
    json: bool,
    /// The message encoding of the `foxglove.*` channels, when not the recorder's.
    encoding: Option<&'static str>,
}

impl Writer {
    fn new(path: &Path, chunk: u64) -> Self {
        let file = std::fs::File::create(path).unwrap();
        let writer = mcap::WriteOptions::new().chunk_size(Some(chunk)).create(BufWriter::new(file)).unwrap();
        Self { writer, channels: BTreeMap::new(), seq: 0, json: false, encoding: None }
    }

    fn write(&mut self, topic: &'static str, schema: &str, data: &[u8]) {
        let id = match self.channels.get(topic) {
            Some(id) => *id,
            None => {
                let foxglove = schema.starts_with("foxglove.");
                let (encoding, data, message_encoding) = match schemas::channel_schema(schema) {
                    Some(s) if !(self.json && foxglove) => (s.encoding, s.data.into_owned(), s.message_encoding),
                    _ => (schemas::SCHEMA_ENCODING, b"{}".to_vec(), schemas::MESSAGE_ENCODING),
                };
                let message_encoding = self.encoding.filter(|_| foxglove).unwrap_or(message_encoding);
                let schema_id = self.writer.add_schema(schema, encoding, &data).unwrap();
                let id = self.writer.add_channel(schema_id, topic, message_encoding, &BTreeMap::new()).unwrap();
                self.channels.insert(topic, id);
                id
            }
        };
        self.seq += 1;
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: self.seq,
            log_time: u64::from(self.seq),
            publish_time: u64::from(self.seq),
        };
        self.writer.write_to_known_channel(&header, data).unwrap();
    }

    fn calibration(&mut self) {
        let message = calibration(&K, 0);
        let bytes = if self.json {
            serde_json::to_vec(&serde_json::json!({
                "timestamp": { "sec": 0, "nsec": 0 }, "frame_id": "camera", "width": K.width, "height": K.height,
                "distortion_model": "", "D": [], "K": message.k, "R": message.r, "P": message.p
            }))
            .unwrap()
        } else {
            let mut out = Vec::new();
            encode(&message, &mut out).unwrap();
            out
        };
        self.write(TOPIC_CALIBRATION, schemas::CAMERA_CALIBRATION, &bytes);
    }

    /// A `foxglove.RawImage` as the recorder writes it, or as JSON in the earlier form.
    fn image(&self, header: RawImageHeader<'_>, data: &[u8]) -> Vec<u8> {
        if self.json {
            let t = header.stamp_ns;
            return serde_json::to_vec(&serde_json::json!({
                "timestamp": { "sec": t / 1_000_000_000, "nsec": t % 1_000_000_000 },
                "frame_id": header.frame_id, "width": header.width, "height": header.height,
                "encoding": header.encoding, "step": header.step, "data": STANDARD.encode(data)
            }))
            .unwrap();
        }
        let mut out = Vec::new();
        encode(&raw_image(header, data), &mut out).unwrap();
        out
    }

    fn frame(&mut self, seq: u64, colour_schema: &str) {
        let stamp_ns = 1_000_000 * seq;
        let rgb: Vec<u8> = (0..K.pixel_count() * 3).map(|i| (i as u64 + seq) as u8).collect();
        let depth: Vec<u16> = (0..K.pixel_count()).map(|i| (i as u64 * 7 + seq) as u16).collect();
        let out = self.image(
            RawImageHeader { stamp_ns, frame_id: "camera", width: 16, height: 16, encoding: "rgb8", step: 48 },
            &rgb,
        );
        self.write(TOPIC_COLOUR, colour_schema, &out);
        let out = self.image(
            RawImageHeader { stamp_ns, frame_id: "camera", width: 16, height: 16, encoding: "16UC1", step: 32 },
            bytemuck::cast_slice(&depth),
        );
        self.write(TOPIC_DEPTH, schemas::RAW_IMAGE, &out);
        let pose = Isometry::new(glam::DQuat::from_rotation_z(0.1 * seq as f64), glam::DVec3::new(0.1, 0.2, 0.3));
        let meta = FrameMeta { seq, stamp_ns, depth_units_per_m: 1000.0, world_from_camera: Some((&pose).into()) };
        self.write(TOPIC_FRAME, schemas::FRAME, &serde_json::to_vec(&meta).unwrap());
    }

    fn finish(mut self) {
        self.writer.finish().unwrap();
    }
}

fn open(path: &Path) -> Result<McapSource, crate::source::SourceError> {
    McapSource::new(&McapReplayConfig { path: path.to_owned(), mode: PlaybackMode::Fast, lossless: true })
}

fn play(source: &mut McapSource) -> (Vec<Frame>, Option<String>) {
    let mut frames = Vec::new();
    let mut frame = Frame::new(source.intrinsics());
    loop {
        match source.next_frame(&mut frame) {
            Ok(SourceStatus::Frame) => frames.push(frame.clone()),
            Ok(SourceStatus::Pending) => {}
            Ok(SourceStatus::EndOfStream) => return (frames, None),
            Err(e) => return (frames, Some(e.to_string())),
        }
    }
}

#[test]
fn a_recording_plays_back_exactly() {
    for json in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("good.mcap");
        let mut w = Writer::new(&path, 4096);
        w.json = json;
        w.calibration();
        for seq in 0..5 {
            w.frame(seq, schemas::RAW_IMAGE);
        }
        w.finish();
        plays_back_exactly(&path);
    }
}

fn plays_back_exactly(path: &Path) {
    let mut source = open(path).unwrap();
    assert_eq!(source.intrinsics(), K);
    assert!(source.has_poses());
    let (frames, error) = play(&mut source);
    assert_eq!(error, None);
    assert_eq!(frames.len(), 5);
    let f = &frames[3];
    assert_eq!((f.seq, f.stamp_ns), (3, 3_000_000));
    assert_eq!(f.rgb[10], 13);
    assert_eq!(f.depth[10], 73);
    let written = Isometry::new(glam::DQuat::from_rotation_z(0.1 * 3.0), glam::DVec3::new(0.1, 0.2, 0.3));
    assert_eq!(f.world_from_camera.unwrap(), written, "the pose as written, to the bit");
}

#[test]
fn a_folder_file_that_vanishes_mid_replay_is_skipped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    for (file, seqs) in [("a.mcap", 0..3), ("b.mcap", 3..6), ("c.mcap", 6..9)] {
        let mut w = Writer::new(&dir.path().join(file), 4096);
        w.calibration();
        for seq in seqs {
            w.frame(seq, schemas::RAW_IMAGE);
        }
        w.finish();
    }
    let mut source = open(dir.path()).unwrap();
    let mut frame = Frame::new(source.intrinsics());
    assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
    std::fs::remove_file(dir.path().join("b.mcap")).unwrap();
    let (frames, error) = play(&mut source);
    assert_eq!(error, None, "the files that are left play to the end");
    let seqs: Vec<u64> = frames.iter().map(|f| f.seq).collect();
    assert_eq!(seqs, [1, 2, 6, 7, 8], "a.mcap's rest, then c.mcap");
    assert_eq!(source.bad_data_skipped(), 1, "the vanished file is counted");

    // A file that is there but unreadable still stops the replay, naming it.
    let mut source = open(dir.path()).unwrap();
    std::fs::write(dir.path().join("c.mcap"), b"not an mcap file").unwrap();
    let (_, error) = play(&mut source);
    let error = error.expect("an unreadable file ends the stream");
    assert!(error.starts_with(&dir.path().join("c.mcap").display().to_string()), "{error}");
}

#[test]
fn a_truncated_file_delivers_what_it_holds_then_names_where_it_ends() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.mcap");
    let mut w = Writer::new(&path, 1024);
    w.calibration();
    for seq in 0..8 {
        w.frame(seq, schemas::RAW_IMAGE);
    }
    w.finish();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let mut source = open(&path).unwrap();
    let (frames, error) = play(&mut source);
    let error = error.expect("a cut file ends with an error");
    assert!(!frames.is_empty() && frames.len() < 8, "{} frames", frames.len());
    assert!(error.starts_with(&path.display().to_string()), "{error}");
    assert!(error.contains("truncated") && error.contains("after message"), "{error}");
}

#[test]
fn a_wrong_schema_names_file_channel_and_message() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("schema.mcap");
    let mut w = Writer::new(&path, 4096);
    w.calibration();
    w.frame(0, "foxglove.PointCloud");
    w.finish();
    let error = open(&path).unwrap_err().to_string();
    assert!(error.starts_with(&path.display().to_string()), "{error}");
    assert!(error.contains("channel /camera/colour message 0: schema \"foxglove.PointCloud\""), "{error}");
}

#[test]
fn a_foxglove_channel_in_another_encoding_or_a_bad_message_names_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cdr.mcap");
    let mut w = Writer::new(&path, 4096);
    w.encoding = Some("cdr");
    w.calibration();
    w.frame(0, schemas::RAW_IMAGE);
    w.finish();
    let error = open(&path).unwrap_err().to_string();
    assert!(
        error.contains(
            "channel /camera/calibration message 0: schema \"foxglove.CameraCalibration\" encoded \"cdr\", \
             expected \"foxglove.CameraCalibration\" encoded \"protobuf\" or \"json\""
        ),
        "{error}"
    );

    // A depth image that is not protobuf: the frame and channel named.
    let path = dir.path().join("bad.mcap");
    let mut w = Writer::new(&path, 4096);
    w.calibration();
    w.frame(0, schemas::RAW_IMAGE);
    let colour = w.image(
        RawImageHeader { stamp_ns: 1_000_000, frame_id: "camera", width: 16, height: 16, encoding: "rgb8", step: 48 },
        &[0; 16 * 16 * 3],
    );
    w.write(TOPIC_COLOUR, schemas::RAW_IMAGE, &colour);
    w.write(TOPIC_DEPTH, schemas::RAW_IMAGE, b"\xff\xff\xff");
    w.write(
        TOPIC_FRAME,
        schemas::FRAME,
        br#"{"seq":1,"stamp_ns":1000000,"depth_units_per_m":1000.0,"world_from_camera":null}"#,
    );
    w.finish();
    let mut source = open(&path).unwrap();
    let (frames, error) = play(&mut source);
    assert_eq!(frames.len(), 1);
    let error = error.unwrap();
    assert!(
        error.contains("channel /camera/depth message 1: frame seq 1: not a foxglove.RawImage (protobuf)"),
        "{error}"
    );
}

#[test]
fn a_missing_calibration_names_the_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nocal.mcap");
    let mut w = Writer::new(&path, 4096);
    w.frame(0, schemas::RAW_IMAGE);
    w.finish();
    let error = open(&path).unwrap_err().to_string();
    assert!(
        error.contains("channel /op3dsg/frame message 0: frame seq 0 has no /camera/calibration before it"),
        "{error}"
    );
}

#[test]
fn the_recorders_metadata_is_read_from_the_summary_and_an_unfinished_file_has_none() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("finished.mcap");
    let mut writer = mcap::WriteOptions::new().create(BufWriter::new(std::fs::File::create(&path).unwrap())).unwrap();
    let entries: BTreeMap<String, String> =
        [("dropped_total", "5"), ("/camera/colour.dropped", "5")].map(|(k, v)| (k.to_owned(), v.to_owned())).into();
    writer.write_metadata(&mcap::records::Metadata { name: "other".into(), metadata: BTreeMap::new() }).unwrap();
    writer
        .write_metadata(&mcap::records::Metadata { name: super::METADATA_RECORDER.into(), metadata: entries.clone() })
        .unwrap();
    writer.finish().unwrap();
    drop(writer);
    assert_eq!(super::reader::summary_metadata(&path, super::METADATA_RECORDER).unwrap(), Some(entries));
    assert_eq!(super::reader::summary_metadata(&path, "missing").unwrap(), None);
    // Cut before its summary: what a recorder that did not finish leaves.
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    assert_eq!(super::reader::summary_metadata(&cut, super::METADATA_RECORDER).unwrap(), None);
}
