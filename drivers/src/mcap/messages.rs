//! The messages of the raw input and of the LLM refiner: `foxglove.RawImage`,
//! `.CompressedImage` and `.CameraCalibration` in the `foxglove` crate's generated types
//! (protobuf), read also from the JSON of earlier recordings; `op3dsg.Frame`, `.InputPose` and
//! `.LlmExchange` (JSON).
//!
//! Numbers round-trip exactly: protobuf carries `f64` as its bits, `f32` intrinsics and depth
//! scales are written widened to `f64`, poses are `f64`, and the workspace's `serde_json` parses
//! floats exactly (`float_roundtrip`), so a replayed frame equals the recorded one bit for bit.

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use foxglove::bytes::Bytes;
use foxglove::messages::{CameraCalibration, CompressedImage, RawImage, Timestamp};
use foxglove::{Decode, Encode};
use serde::{Deserialize, Serialize};

use super::schemas;

use crate::frame::Intrinsics;
// `op3dsg.InputPose`: defined with the poses, where the frame-source interface takes it from.
use crate::pose::Isometry;
pub use crate::pose::{InputPose, InputPoseKind};

/// A Foxglove `time` as JSON (earlier recordings' `foxglove.*` messages).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: u64,
    /// Nanoseconds, < 1e9.
    pub nsec: u32,
}

impl Time {
    /// From nanoseconds.
    pub fn from_ns(stamp_ns: u64) -> Self {
        Self { sec: stamp_ns / 1_000_000_000, nsec: (stamp_ns % 1_000_000_000) as u32 }
    }

    /// To nanoseconds.
    pub fn to_ns(self) -> u64 {
        self.sec.saturating_mul(1_000_000_000).saturating_add(u64::from(self.nsec))
    }
}

/// `world_from_camera` as written in `op3dsg.Frame`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IsometryJson {
    /// Translation, metres.
    pub translation_m: [f64; 3],
    /// Unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
}

impl From<&Isometry> for IsometryJson {
    fn from(pose: &Isometry) -> Self {
        let q = pose.rotation;
        Self { translation_m: pose.translation.to_array(), rotation_xyzw: [q.x, q.y, q.z, q.w] }
    }
}

impl From<&IsometryJson> for Isometry {
    fn from(pose: &IsometryJson) -> Self {
        let [x, y, z, w] = pose.rotation_xyzw;
        // As recorded: the source's quaternion was unit already, and normalising it again could
        // change its last bits (a replay must give the same pose to the bit).
        Isometry {
            rotation: glam::DQuat::from_xyzw(x, y, z, w),
            translation: glam::DVec3::from_array(pose.translation_m),
        }
    }
}

/// `op3dsg.Frame`: what a frame carries besides its pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameMeta {
    /// The source's sequence number.
    pub seq: u64,
    /// Sensor stamp, nanoseconds.
    pub stamp_ns: u64,
    /// Depth units per metre.
    pub depth_units_per_m: f64,
    /// The pose the source delivered with the frame.
    pub world_from_camera: Option<IsometryJson>,
}

/// One message of a chat prompt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChatMessage {
    /// `system` or `user`.
    pub role: String,
    /// The text sent.
    pub content: String,
}

/// What the verification gate made of an answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LlmVerdict {
    /// Whether the answer held a JSON object the gate could read (`false`: the agent's last
    /// accepted result stays as it was).
    pub parsed: bool,
    /// Items accepted.
    pub accepted: u64,
    /// Items rejected, by reason (`op3dsg_ipc_types::REFINER_REJECTIONS`; reasons with none
    /// are left out).
    pub rejected: std::collections::BTreeMap<String, u64>,
}

/// `op3dsg.LlmExchange`: one call of an LLM agent of the refiner (all its retries): the prompt
/// sent, the answer, what the gate accepted and rejected, the time it took. Never the API key
/// and never a request header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LlmExchange {
    /// The graph version the prompt was built from.
    pub graph_version: u64,
    /// `local_relations`, `remote_relations` or `affordances`.
    pub agent: String,
    /// `reasoner.llm.model`.
    pub model: String,
    /// The prompt's messages, in the order sent.
    pub messages: Vec<ChatMessage>,
    /// HTTP requests made for this call (1 + retries; 0 when the breaker or the budget refused
    /// it).
    pub attempts: u32,
    /// Time of the last request, milliseconds (0 when none was made).
    pub latency_ms: f64,
    /// Time from the first request to the answer or the final failure, milliseconds.
    pub total_ms: f64,
    /// The answer's text (the message content), `None` when the call failed.
    pub answer: Option<String>,
    /// Why the call finally failed (`timeout`, `http_status: HTTP status 503`, `breaker_open`,
    /// `budget_exhausted`, ...), `None` when it answered.
    pub error: Option<String>,
    /// The gate's verdict on the answer, `None` when there was none.
    pub verdict: Option<LlmVerdict>,
}

/// A stamp as Foxglove's `Timestamp` (seconds past 2106 saturate).
pub fn timestamp(stamp_ns: u64) -> Timestamp {
    let sec = u32::try_from(stamp_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (stamp_ns % 1_000_000_000) as u32)
}

/// A Foxglove `Timestamp` in nanoseconds (`None`, an unset field, is 0).
pub fn stamp_ns(t: Option<Timestamp>) -> u64 {
    t.map_or(0, |t| u64::from(t.sec()) * 1_000_000_000 + u64::from(t.nsec()))
}

/// Encodes a `foxglove.*` message (protobuf) into `out` (cleared first).
pub fn encode<T: Encode>(message: &T, out: &mut Vec<u8>) -> Result<(), String> {
    out.clear();
    if let Some(len) = message.encoded_len() {
        out.reserve(len);
    }
    message.encode(out).map_err(|e| e.to_string())
}

/// The message encodings a `foxglove.*` channel may have: `protobuf`, or `json` in files written
/// before the recorder used the `foxglove` crate's types.
pub const FOXGLOVE_ENCODINGS: [&str; 2] = [schemas::PROTOBUF, schemas::MESSAGE_ENCODING];

fn decode_protobuf<T: Decode>(bytes: &[u8], name: &str) -> Result<T, String> {
    T::decode(bytes).map_err(|e| format!("not a {name} (protobuf): {e}"))
}

fn unknown_encoding(message_encoding: &str) -> String {
    format!(
        "message encoding \"{message_encoding}\", expected \"protobuf\" (or \"json\", as earlier recordings have it)"
    )
}

/// The `foxglove.CameraCalibration` of `k` at `stamp_ns` (pinhole, no distortion: depth is
/// aligned to colour).
pub fn calibration(k: &Intrinsics, stamp_ns: u64) -> CameraCalibration {
    let (fx, fy, cx, cy) = (f64::from(k.fx), f64::from(k.fy), f64::from(k.cx), f64::from(k.cy));
    CameraCalibration {
        timestamp: Some(timestamp(stamp_ns)),
        frame_id: super::CAMERA_FRAME.to_owned(),
        width: k.width,
        height: k.height,
        distortion_model: String::new(),
        d: Vec::new(),
        k: vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }
}

/// A `foxglove.CameraCalibration` as JSON, as earlier recordings hold it.
#[derive(Debug, Deserialize)]
#[allow(non_snake_case)]
struct CalibrationJson {
    width: u32,
    height: u32,
    K: [f64; 9],
}

/// The pinhole intrinsics of a recorded `foxglove.CameraCalibration` (`message_encoding`
/// `protobuf` or `json`), or what is wrong with it.
pub fn calibration_intrinsics(bytes: &[u8], message_encoding: &str) -> Result<Intrinsics, String> {
    let (width, height, k) = match message_encoding {
        schemas::PROTOBUF => {
            let c: CameraCalibration = decode_protobuf(bytes, schemas::CAMERA_CALIBRATION)?;
            let k: [f64; 9] =
                c.k.as_slice().try_into().map_err(|_| format!("K has {} values, expected 9", c.k.len()))?;
            (c.width, c.height, k)
        }
        schemas::MESSAGE_ENCODING => {
            let c: CalibrationJson = serde_json::from_slice(bytes)
                .map_err(|e| format!("not a {} (json): {e}", schemas::CAMERA_CALIBRATION))?;
            (c.width, c.height, c.K)
        }
        other => return Err(unknown_encoding(other)),
    };
    let k = Intrinsics { width, height, fx: k[0] as f32, fy: k[4] as f32, cx: k[2] as f32, cy: k[5] as f32 };
    crate::frame::check_intrinsics(&k).map_err(|e| format!("intrinsics{e}"))?;
    Ok(k)
}

/// What a `foxglove.RawImage` says of its pixels.
#[derive(Debug, Clone, Copy)]
pub struct RawImageHeader<'a> {
    /// Stamp, nanoseconds.
    pub stamp_ns: u64,
    /// The image's frame of reference.
    pub frame_id: &'a str,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `rgb8`, `16UC1`, ...
    pub encoding: &'a str,
    /// Bytes per row.
    pub step: u32,
}

/// The `foxglove.RawImage` of `data` (copied).
pub fn raw_image(header: RawImageHeader<'_>, data: &[u8]) -> RawImage {
    let RawImageHeader { stamp_ns, frame_id, width, height, encoding, step } = header;
    RawImage {
        timestamp: Some(timestamp(stamp_ns)),
        frame_id: frame_id.to_owned(),
        width,
        height,
        encoding: encoding.to_owned(),
        step,
        data: Bytes::copy_from_slice(data),
    }
}

/// The `foxglove.CompressedImage` of `data`, an encoded `jpeg` or `png` file (copied).
pub fn compressed_image(stamp_ns: u64, frame_id: &str, format: &str, data: &[u8]) -> CompressedImage {
    CompressedImage {
        timestamp: Some(timestamp(stamp_ns)),
        frame_id: frame_id.to_owned(),
        data: Bytes::copy_from_slice(data),
        format: format.to_owned(),
    }
}

/// An image's bytes as read: protobuf's bytes, or the base64 text of earlier JSON recordings.
#[derive(Debug)]
pub enum ImageData<'a> {
    /// The bytes themselves.
    Bytes(Bytes),
    /// Base64 of the bytes.
    Base64(&'a str),
}

impl ImageData<'_> {
    /// The bytes into `out` (cleared first).
    fn to_vec(&self, out: &mut Vec<u8>) -> Result<(), String> {
        out.clear();
        match self {
            ImageData::Bytes(b) => out.extend_from_slice(b),
            ImageData::Base64(text) => {
                STANDARD.decode_vec(text.as_bytes(), out).map_err(|e| format!("data: bad base64 ({e})"))?;
            }
        }
        Ok(())
    }

    /// The bytes into `out`, which must hold exactly as many.
    fn copy_exact(&self, out: &mut [u8]) -> Result<(), String> {
        let written = match self {
            ImageData::Bytes(b) => {
                if b.len() == out.len() {
                    out.copy_from_slice(b);
                }
                b.len()
            }
            ImageData::Base64(text) => {
                // A longer text would not fit: the decoder refuses it rather than write past `out`.
                STANDARD.decode_slice(text.as_bytes(), out).map_err(|e| format!("data: bad base64 ({e})"))?
            }
        };
        if written != out.len() {
            return Err(format!("data: {written} bytes, expected {}", out.len()));
        }
        Ok(())
    }
}

/// A `foxglove.CompressedImage` as JSON, as earlier recordings hold it.
#[derive(Debug, Deserialize)]
struct CompressedImageJson<'a> {
    timestamp: Time,
    format: String,
    #[serde(borrow)]
    data: &'a str,
}

/// A `foxglove.CompressedImage` as read.
#[derive(Debug)]
pub struct CompressedImageIn<'a> {
    /// Stamp, nanoseconds.
    pub stamp_ns: u64,
    /// `jpeg` or `png`.
    pub format: String,
    /// The encoded image.
    pub data: ImageData<'a>,
}

impl CompressedImageIn<'_> {
    /// Parses the message (`message_encoding` `protobuf` or `json`).
    pub fn parse<'a>(bytes: &'a [u8], message_encoding: &str) -> Result<CompressedImageIn<'a>, String> {
        match message_encoding {
            schemas::PROTOBUF => {
                let m: CompressedImage = decode_protobuf(bytes, schemas::COMPRESSED_IMAGE)?;
                Ok(CompressedImageIn {
                    stamp_ns: stamp_ns(m.timestamp),
                    format: m.format,
                    data: ImageData::Bytes(m.data),
                })
            }
            schemas::MESSAGE_ENCODING => {
                let m: CompressedImageJson<'a> = serde_json::from_slice(bytes)
                    .map_err(|e| format!("not a {} (json): {e}", schemas::COMPRESSED_IMAGE))?;
                Ok(CompressedImageIn {
                    stamp_ns: m.timestamp.to_ns(),
                    format: m.format,
                    data: ImageData::Base64(m.data),
                })
            }
            other => Err(unknown_encoding(other)),
        }
    }

    /// Decodes the image (jpeg or png, 8-bit RGB) into `out`, which holds `width * height * 3`
    /// bytes; `scratch` holds the encoded bytes on the way.
    pub fn decode_rgb_into(
        &self,
        width: u32,
        height: u32,
        scratch: &mut Vec<u8>,
        out: &mut [u8],
    ) -> Result<(), String> {
        let format = match self.format.as_str() {
            "jpeg" | "jpg" => image::ImageFormat::Jpeg,
            "png" => image::ImageFormat::Png,
            other => return Err(format!("format \"{other}\", expected jpeg or png")),
        };
        let encoded: &[u8] = match &self.data {
            ImageData::Bytes(b) => b,
            base64 => {
                base64.to_vec(scratch)?;
                scratch
            }
        };
        let decoded = image::load_from_memory_with_format(encoded, format)
            .map_err(|e| format!("data: not a {} image: {e}", self.format))?;
        if (decoded.width(), decoded.height()) != (width, height) {
            return Err(format!("{}x{} image, but the stream is {width}x{height}", decoded.width(), decoded.height()));
        }
        let rgb = decoded.into_rgb8();
        let pixels = rgb.as_raw();
        if out.len() != pixels.len() {
            return Err(format!("{} bytes decoded, the frame holds {}", pixels.len(), out.len()));
        }
        out.copy_from_slice(pixels);
        Ok(())
    }
}

/// A `foxglove.RawImage` as JSON, as earlier recordings hold it.
#[derive(Debug, Deserialize)]
struct RawImageJson<'a> {
    timestamp: Time,
    width: u32,
    height: u32,
    encoding: String,
    step: u32,
    #[serde(borrow)]
    data: &'a str,
}

/// A `foxglove.RawImage` as read.
#[derive(Debug)]
pub struct RawImageIn<'a> {
    /// Stamp, nanoseconds.
    pub stamp_ns: u64,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixel encoding.
    pub encoding: String,
    /// Bytes per row.
    pub step: u32,
    /// The pixels.
    pub data: ImageData<'a>,
}

impl RawImageIn<'_> {
    /// Parses the message (`message_encoding` `protobuf` or `json`).
    pub fn parse<'a>(bytes: &'a [u8], message_encoding: &str) -> Result<RawImageIn<'a>, String> {
        match message_encoding {
            schemas::PROTOBUF => {
                let m: RawImage = decode_protobuf(bytes, schemas::RAW_IMAGE)?;
                Ok(RawImageIn {
                    stamp_ns: stamp_ns(m.timestamp),
                    width: m.width,
                    height: m.height,
                    encoding: m.encoding,
                    step: m.step,
                    data: ImageData::Bytes(m.data),
                })
            }
            schemas::MESSAGE_ENCODING => {
                let m: RawImageJson<'a> =
                    serde_json::from_slice(bytes).map_err(|e| format!("not a {} (json): {e}", schemas::RAW_IMAGE))?;
                Ok(RawImageIn {
                    stamp_ns: m.timestamp.to_ns(),
                    width: m.width,
                    height: m.height,
                    encoding: m.encoding,
                    step: m.step,
                    data: ImageData::Base64(m.data),
                })
            }
            other => Err(unknown_encoding(other)),
        }
    }

    /// Checks the encoding and size and decodes the pixels into `out` (exactly
    /// `width * height * bytes_per_pixel` bytes).
    pub fn decode_into(&self, encoding: &[&str], bytes_per_pixel: u32, out: &mut [u8]) -> Result<(), String> {
        if !encoding.contains(&self.encoding.as_str()) {
            return Err(format!("encoding \"{}\", expected {}", self.encoding, encoding.join(" or ")));
        }
        if u64::from(self.step) != u64::from(self.width) * u64::from(bytes_per_pixel) {
            return Err(format!("step {} for width {} at {bytes_per_pixel} bytes per pixel", self.step, self.width));
        }
        let expected = self.step as usize * self.height as usize;
        if out.len() != expected {
            return Err(format!(
                "{}x{} image, but the stream is {} bytes per frame",
                self.width,
                self.height,
                out.len()
            ));
        }
        self.data.copy_exact(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PROTOBUF: &str = schemas::PROTOBUF;

    #[test]
    fn raw_image_round_trips() {
        let pixels: Vec<u8> = (0..=255).cycle().take(4 * 3 * 3).collect();
        let header = RawImageHeader {
            stamp_ns: 1_500_000_001,
            frame_id: "camera",
            width: 4,
            height: 3,
            encoding: "rgb8",
            step: 12,
        };
        let mut out = Vec::new();
        encode(&raw_image(header, &pixels), &mut out).unwrap();
        let image = RawImageIn::parse(&out, PROTOBUF).unwrap();
        assert_eq!(image.stamp_ns, 1_500_000_001);
        let mut back = vec![0u8; pixels.len()];
        image.decode_into(&["rgb8"], 3, &mut back).unwrap();
        assert_eq!(back, pixels);
        assert!(image.decode_into(&["16UC1"], 2, &mut back).unwrap_err().contains("encoding \"rgb8\""));
        let mut short = vec![0u8; 3];
        assert!(image.decode_into(&["rgb8"], 3, &mut short).unwrap_err().contains("4x3 image"));
        // Fewer bytes than the header promises.
        let mut cut = raw_image(header, &pixels);
        cut.data = cut.data.slice(..30);
        encode(&cut, &mut out).unwrap();
        let e = RawImageIn::parse(&out, PROTOBUF).unwrap().decode_into(&["rgb8"], 3, &mut back).unwrap_err();
        assert_eq!(e, "data: 30 bytes, expected 36");
        assert!(
            RawImageIn::parse(b"\xff\xff", PROTOBUF).unwrap_err().starts_with("not a foxglove.RawImage (protobuf)")
        );
        assert!(RawImageIn::parse(&out, "cdr").unwrap_err().starts_with("message encoding \"cdr\""));
    }

    #[test]
    fn raw_images_of_earlier_json_recordings_still_read() {
        let pixels: Vec<u8> = (0..24).collect();
        let text = format!(
            r#"{{"timestamp":{{"sec":1,"nsec":5}},"frame_id":"camera","width":4,"height":3,"encoding":"16UC1","step":8,"data":"{}"}}"#,
            STANDARD.encode(&pixels)
        );
        let image = RawImageIn::parse(text.as_bytes(), schemas::MESSAGE_ENCODING).unwrap();
        assert_eq!(image.stamp_ns, 1_000_000_005);
        let mut back = vec![0u8; 24];
        image.decode_into(&["16UC1"], 2, &mut back).unwrap();
        assert_eq!(back, pixels);
        let long = text.replace(&STANDARD.encode(&pixels), &STANDARD.encode([0u8; 30]));
        let e = RawImageIn::parse(long.as_bytes(), "json").unwrap().decode_into(&["16UC1"], 2, &mut back).unwrap_err();
        assert!(e.starts_with("data: bad base64"), "a longer text is refused, never written past the frame: {e}");
    }

    #[test]
    fn calibration_and_pose_round_trip_exactly() {
        let k = Intrinsics { width: 848, height: 480, fx: 421.123_45, fy: 420.987_6, cx: 424.3, cy: 239.7 };
        let mut bytes = Vec::new();
        encode(&calibration(&k, 7), &mut bytes).unwrap();
        assert_eq!(calibration_intrinsics(&bytes, PROTOBUF).unwrap(), k);
        let mut bad = calibration(&k, 7);
        bad.k.pop();
        encode(&bad, &mut bytes).unwrap();
        assert_eq!(calibration_intrinsics(&bytes, PROTOBUF).unwrap_err(), "K has 8 values, expected 9");
        bad.k = vec![0.0; 9];
        encode(&bad, &mut bytes).unwrap();
        assert!(calibration_intrinsics(&bytes, PROTOBUF).unwrap_err().starts_with("intrinsics"));
        // The JSON of earlier recordings.
        let json = br#"{"timestamp":{"sec":0,"nsec":7},"frame_id":"camera","width":848,"height":480,"distortion_model":"","D":[],"K":[421.1234436035156,0.0,424.29998779296875,0.0,420.98760986328125,239.6999969482422,0.0,0.0,1.0],"R":[1,0,0,0,1,0,0,0,1],"P":[0,0,0,0,0,0,0,0,0,0,1,0]}"#;
        assert_eq!(calibration_intrinsics(json, "json").unwrap(), k);
        let pose = Isometry::new(
            glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.1, -0.7, 2.9),
            glam::DVec3::new(1.0 / 3.0, -2.718_281_828_459_1, 1e-17),
        );
        let meta =
            FrameMeta { seq: 3, stamp_ns: 9, depth_units_per_m: 1000.0, world_from_camera: Some((&pose).into()) };
        let back: FrameMeta = serde_json::from_str(&serde_json::to_string(&meta).unwrap()).unwrap();
        let pose_back = Isometry::from(&back.world_from_camera.unwrap());
        assert_eq!(pose_back.translation.to_array().map(f64::to_bits), pose.translation.to_array().map(f64::to_bits));
        assert_eq!(pose_back.rotation.to_array().map(f64::to_bits), pose.rotation.to_array().map(f64::to_bits));
    }

    #[test]
    fn a_png_compressed_image_decodes_to_the_same_pixels_and_bad_ones_name_the_fault() {
        use image::ImageEncoder as _;
        let (w, h) = (7u32, 5u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 37 % 251) as u8).collect();
        let mut png = Vec::new();
        image::codecs::png::PngEncoder::new(&mut png).write_image(&rgb, w, h, image::ExtendedColorType::Rgb8).unwrap();
        let mut msg = Vec::new();
        encode(&compressed_image(1_500_000_000, "camera", "png", &png), &mut msg).unwrap();
        let image = CompressedImageIn::parse(&msg, PROTOBUF).unwrap();
        assert_eq!(image.stamp_ns, 1_500_000_000);
        let (mut scratch, mut out) = (Vec::new(), vec![0u8; rgb.len()]);
        image.decode_rgb_into(w, h, &mut scratch, &mut out).unwrap();
        assert_eq!(out, rgb, "png is lossless");
        let e = image.decode_rgb_into(w + 1, h, &mut scratch, &mut vec![0u8; ((w + 1) * h * 3) as usize]).unwrap_err();
        assert!(e.contains("7x5 image, but the stream is 8x5"), "{e}");
        encode(&compressed_image(0, "camera", "webp", &png), &mut msg).unwrap();
        let e = CompressedImageIn::parse(&msg, PROTOBUF)
            .unwrap()
            .decode_rgb_into(w, h, &mut scratch, &mut out)
            .unwrap_err();
        assert!(e.contains("format \"webp\", expected jpeg or png"), "{e}");
        encode(&compressed_image(0, "camera", "jpeg", &png), &mut msg).unwrap();
        let e = CompressedImageIn::parse(&msg, PROTOBUF)
            .unwrap()
            .decode_rgb_into(w, h, &mut scratch, &mut out)
            .unwrap_err();
        assert!(e.starts_with("data: not a jpeg image"), "{e}");
        // The JSON of earlier recordings.
        let json = format!(
            r#"{{"timestamp":{{"sec":2,"nsec":0}},"frame_id":"camera","format":"png","data":"{}"}}"#,
            STANDARD.encode(&png)
        );
        let image = CompressedImageIn::parse(json.as_bytes(), "json").unwrap();
        assert_eq!(image.stamp_ns, 2_000_000_000);
        image.decode_rgb_into(w, h, &mut scratch, &mut out).unwrap();
        assert_eq!(out, rgb);
    }
}
