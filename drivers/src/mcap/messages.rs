//! Encoding and decoding of the raw-input messages: `foxglove.RawImage` (written by hand into a
//! reused buffer: a 848x480 frame is ~1.6 MB of base64 and must not go through a `Value`),
//! `foxglove.CameraCalibration` and `op3dsg.Frame`.
//!
//! Numbers round-trip exactly: `f32` intrinsics and depth scales are written widened to `f64`
//! and poses are `f64`, and the workspace's `serde_json` parses floats exactly
//! (`float_roundtrip`), so a replayed frame equals the recorded one bit for bit.

use std::io::Write as _;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde::{Deserialize, Serialize};

use crate::frame::Intrinsics;
// `op3dsg.InputPose`: defined with the poses, where the frame-source interface takes it from.
use crate::pose::Isometry;
pub use crate::pose::{InputPose, InputPoseKind};

/// A Foxglove `time`.
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

/// `foxglove.CameraCalibration` (pinhole, no distortion: depth is aligned to colour).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[allow(non_snake_case)]
pub struct CameraCalibration {
    /// Stamp of the first frame with these intrinsics.
    pub timestamp: Time,
    /// Always [`super::CAMERA_FRAME`].
    pub frame_id: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Empty: rectified, no distortion.
    pub distortion_model: String,
    /// Distortion coefficients (none).
    pub D: Vec<f64>,
    /// Intrinsic matrix, row-major 3x3.
    pub K: [f64; 9],
    /// Rectification (identity).
    pub R: [f64; 9],
    /// Projection, row-major 3x4.
    pub P: [f64; 12],
}

impl CameraCalibration {
    /// The calibration of `k` at `stamp_ns`.
    pub fn new(k: &Intrinsics, stamp_ns: u64) -> Self {
        let (fx, fy, cx, cy) = (f64::from(k.fx), f64::from(k.fy), f64::from(k.cx), f64::from(k.cy));
        Self {
            timestamp: Time::from_ns(stamp_ns),
            frame_id: super::CAMERA_FRAME.to_owned(),
            width: k.width,
            height: k.height,
            distortion_model: String::new(),
            D: Vec::new(),
            K: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            R: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            P: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        }
    }

    /// The pinhole intrinsics, or what is wrong with them.
    pub fn intrinsics(&self) -> Result<Intrinsics, String> {
        let k = Intrinsics {
            width: self.width,
            height: self.height,
            fx: self.K[0] as f32,
            fy: self.K[4] as f32,
            cx: self.K[2] as f32,
            cy: self.K[5] as f32,
        };
        crate::frame::check_intrinsics(&k).map_err(|e| format!("intrinsics{e}"))?;
        Ok(k)
    }
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

/// Writes a `foxglove.RawImage` of `data` into `out` (cleared first).
pub fn encode_raw_image(out: &mut Vec<u8>, header: RawImageHeader<'_>, data: &[u8]) {
    let RawImageHeader { stamp_ns, frame_id, width, height, encoding, step } = header;
    out.clear();
    let t = Time::from_ns(stamp_ns);
    // Writing into a Vec cannot fail.
    let _ = write!(
        out,
        r#"{{"timestamp":{{"sec":{},"nsec":{}}},"frame_id":"{frame_id}","width":{width},"height":{height},"encoding":"{encoding}","step":{step},"data":""#,
        t.sec, t.nsec
    );
    let start = out.len();
    out.resize(start + base64::encoded_len(data.len(), true).unwrap_or(0), 0);
    let written = STANDARD.encode_slice(data, &mut out[start..]).unwrap_or(0);
    out.truncate(start + written);
    out.extend_from_slice(b"\"}");
}

/// Writes a `foxglove.CompressedImage` (`format` `jpeg` or `png`, `data` the encoded file) into
/// `out` (cleared first).
pub fn encode_compressed_image(out: &mut Vec<u8>, stamp_ns: u64, frame_id: &str, format: &str, data: &[u8]) {
    out.clear();
    let t = Time::from_ns(stamp_ns);
    // Writing into a Vec cannot fail.
    let _ = write!(
        out,
        r#"{{"timestamp":{{"sec":{},"nsec":{}}},"frame_id":"{frame_id}","format":"{format}","data":""#,
        t.sec, t.nsec
    );
    let start = out.len();
    out.resize(start + base64::encoded_len(data.len(), true).unwrap_or(0), 0);
    let written = STANDARD.encode_slice(data, &mut out[start..]).unwrap_or(0);
    out.truncate(start + written);
    out.extend_from_slice(b"\"}");
}

/// A `foxglove.CompressedImage` as read, its data still base64.
#[derive(Debug, Deserialize)]
pub struct CompressedImageIn<'a> {
    /// Stamp.
    pub timestamp: Time,
    /// `jpeg` or `png`.
    pub format: String,
    /// Base64 of the encoded image.
    #[serde(borrow)]
    pub data: &'a str,
}

impl CompressedImageIn<'_> {
    /// Parses the JSON message.
    pub fn parse(bytes: &[u8]) -> Result<CompressedImageIn<'_>, String> {
        serde_json::from_slice(bytes).map_err(|e| format!("not a foxglove.CompressedImage: {e}"))
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
        scratch.clear();
        STANDARD.decode_vec(self.data.as_bytes(), scratch).map_err(|e| format!("data: bad base64 ({e})"))?;
        let decoded = image::load_from_memory_with_format(scratch, format)
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

/// A `foxglove.RawImage` as read, its data still base64.
#[derive(Debug, Deserialize)]
pub struct RawImageIn<'a> {
    /// Stamp.
    pub timestamp: Time,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixel encoding.
    pub encoding: String,
    /// Bytes per row.
    pub step: u32,
    /// Base64 pixels.
    #[serde(borrow)]
    pub data: &'a str,
}

impl RawImageIn<'_> {
    /// Parses the JSON message.
    pub fn parse(bytes: &[u8]) -> Result<RawImageIn<'_>, String> {
        serde_json::from_slice(bytes).map_err(|e| format!("not a foxglove.RawImage: {e}"))
    }

    /// Checks the encoding and size and decodes the pixels into `out` (exactly
    /// `width * height * bytes_per_pixel` bytes).
    pub fn decode_into(&self, encoding: &[&str], bytes_per_pixel: u32, out: &mut [u8]) -> Result<(), String> {
        if !encoding.contains(&self.encoding.as_str()) {
            return Err(format!("encoding \"{}\", expected {}", self.encoding, encoding.join(" or ")));
        }
        if self.step != self.width * bytes_per_pixel {
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
        let written =
            STANDARD.decode_slice(self.data.as_bytes(), out).map_err(|e| format!("data: bad base64 ({e})"))?;
        if written != expected {
            return Err(format!("data: {written} bytes, expected {expected}"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_image_round_trips() {
        let pixels: Vec<u8> = (0..=255).cycle().take(4 * 3 * 3).collect();
        let mut out = Vec::new();
        encode_raw_image(
            &mut out,
            RawImageHeader {
                stamp_ns: 1_500_000_001,
                frame_id: "camera",
                width: 4,
                height: 3,
                encoding: "rgb8",
                step: 12,
            },
            &pixels,
        );
        let value: serde_json::Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(value["timestamp"]["sec"], 1);
        assert_eq!(value["timestamp"]["nsec"], 500_000_001);
        let image = RawImageIn::parse(&out).unwrap();
        let mut back = vec![0u8; pixels.len()];
        image.decode_into(&["rgb8"], 3, &mut back).unwrap();
        assert_eq!(back, pixels);
        assert!(image.decode_into(&["16UC1"], 2, &mut back).unwrap_err().contains("encoding \"rgb8\""));
        let mut short = vec![0u8; 3];
        assert!(image.decode_into(&["rgb8"], 3, &mut short).unwrap_err().contains("4x3 image"));
    }

    #[test]
    fn calibration_and_pose_round_trip_exactly() {
        let k = Intrinsics { width: 848, height: 480, fx: 421.123_45, fy: 420.987_6, cx: 424.3, cy: 239.7 };
        let text = serde_json::to_string(&CameraCalibration::new(&k, 7)).unwrap();
        let back: CameraCalibration = serde_json::from_str(&text).unwrap();
        assert_eq!(back.intrinsics().unwrap(), k);
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
        encode_compressed_image(&mut msg, 1_500_000_000, "camera", "png", &png);
        let image = CompressedImageIn::parse(&msg).unwrap();
        assert_eq!(image.timestamp.to_ns(), 1_500_000_000);
        let (mut scratch, mut out) = (Vec::new(), vec![0u8; rgb.len()]);
        image.decode_rgb_into(w, h, &mut scratch, &mut out).unwrap();
        assert_eq!(out, rgb, "png is lossless");
        let e = image.decode_rgb_into(w + 1, h, &mut scratch, &mut vec![0u8; ((w + 1) * h * 3) as usize]).unwrap_err();
        assert!(e.contains("7x5 image, but the stream is 8x5"), "{e}");
        encode_compressed_image(&mut msg, 0, "camera", "webp", &png);
        let e = CompressedImageIn::parse(&msg).unwrap().decode_rgb_into(w, h, &mut scratch, &mut out).unwrap_err();
        assert!(e.contains("format \"webp\", expected jpeg or png"), "{e}");
        encode_compressed_image(&mut msg, 0, "camera", "jpeg", &png);
        let e = CompressedImageIn::parse(&msg).unwrap().decode_rgb_into(w, h, &mut scratch, &mut out).unwrap_err();
        assert!(e.starts_with("data: not a jpeg image"), "{e}");
    }
}
