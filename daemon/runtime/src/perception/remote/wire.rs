//! The bytes of a remote detection: a keyframe request (robot → worker) and its reply (worker →
//! robot), little-endian, versioned, every field checked when read.
//!
//! ```text
//! request  "O3DQ" u16 version u16 0
//!          u64 request_id  u64 frame_seq  u64 stamp_ns
//!          str model  u16 n_prompts { str prompt }  u16 embedding_dim (0: none expected)
//!          u32 width  u32 height  f32 fx fy cx cy  f32 depth_units_per_m
//!          u8 colour_encoding u32 len bytes   u8 depth_encoding u32 len bytes
//! reply    "O3DR" u16 version u8 status u8 0  u64 request_id  u64 frame_seq  str worker
//!          status 0 (ok):  u32 detect_us  u16 embedding_dim  u16 n {
//!              str label  u8 kind (0 object, 1 part)  f32 score
//!              u32 x0 y0 width height  u32 n_runs { u32 run }   (runs alternate outside/inside,
//!              outside first, and cover width*height)
//!              u8 has_embedding { f32 × embedding_dim } }
//!          status 1 (refused) or 2 (failed): str reason
//! str      u16 length, UTF-8
//! ```
//!
//! Encodings: 0 raw (RGB8 rows; depth u16 LE rows), 1 PNG (RGB8; 16-bit grey), 2 lz4 of the raw
//! bytes (lz4 block with its size prepended), 3 zstd of the raw bytes (one zstd frame), 4 JPEG
//! (colour only; a request with `detector.remote.encoding = "jpeg"` sends its depth as 3). A
//! reader refuses what it does not know, naming the field, and never inflates past the size the
//! image's header gives.

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_ipc_types::NodeKind;

use crate::flow::{Detection, Mask};

/// The protocol version this build writes and reads.
pub const WIRE_VERSION: u16 = 1;
const REQUEST_MAGIC: &[u8; 4] = b"O3DQ";
const REPLY_MAGIC: &[u8; 4] = b"O3DR";
/// The largest image a request may carry (pixels), so a corrupt size cannot ask for gigabytes.
pub const MAX_PIXELS: u64 = 4096 * 4096;

/// Why bytes are not a request or reply of this version.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    /// The first four bytes are not the message's magic.
    #[error("not a {expected} (first bytes {found:?})")]
    Magic {
        /// `request` or `reply`.
        expected: &'static str,
        /// What came.
        found: Vec<u8>,
    },
    /// A version this build does not read.
    #[error("version {found}, this build reads {WIRE_VERSION}")]
    Version {
        /// What came.
        found: u16,
    },
    /// The bytes end inside a field.
    #[error("{field}: truncated ({needed} bytes needed, {left} left)")]
    Truncated {
        /// The field.
        field: String,
        /// Bytes the field needs.
        needed: usize,
        /// Bytes left.
        left: usize,
    },
    /// A field holds a value outside its range.
    #[error("{field}: {reason}")]
    Value {
        /// The field.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A mask's runs do not cover its box.
    #[error("detection {index}: mask runs cover {covered} pixels, its box {width}x{height} has {expected}")]
    MaskSize {
        /// The detection.
        index: usize,
        /// Pixels the runs cover.
        covered: u64,
        /// Box width.
        width: u32,
        /// Box height.
        height: u32,
        /// `width * height`.
        expected: u64,
    },
    /// Bytes after the last field.
    #[error("{0} bytes after the end of the message")]
    Trailing(usize),
}

/// How a keyframe's colour or depth travels (`detector.remote.encoding`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImageEncoding {
    /// The pixels as they are.
    Raw,
    /// Lossless PNG (8-bit RGB colour, 16-bit grey depth; fast compression, Sub filter): the
    /// default, the smallest lossless keyframe for about the robot's CPU of lz4
    /// (`op3dsg bench remote`, docs/benchmarks.md).
    #[default]
    Png,
    /// lz4 of the raw pixels: lossless, the fastest to decode, the largest compressed.
    Lz4,
    /// zstd (level 1) of the raw pixels: lossless, smaller than lz4, slower.
    Zstd,
    /// JPEG (quality [`JPEG_QUALITY`]) colour, lossy; the depth travels as [`Self::Zstd`]
    /// (depth is never sent lossy).
    Jpeg,
}

/// The JPEG quality of [`ImageEncoding::Jpeg`] colour.
pub const JPEG_QUALITY: u8 = 90;
/// The zstd level of [`ImageEncoding::Zstd`].
const ZSTD_LEVEL: i32 = 1;

impl ImageEncoding {
    fn code(self) -> u8 {
        match self {
            Self::Raw => 0,
            Self::Png => 1,
            Self::Lz4 => 2,
            Self::Zstd => 3,
            Self::Jpeg => 4,
        }
    }

    /// The encoding of the depth image when the keyframe is sent with `self`.
    pub fn for_depth(self) -> Self {
        match self {
            Self::Jpeg => Self::Zstd,
            other => other,
        }
    }

    /// Every encoding, in code order.
    pub const ALL: [Self; 5] = [Self::Raw, Self::Png, Self::Lz4, Self::Zstd, Self::Jpeg];

    /// Its name in profiles (`raw`, `png`, `lz4`, `zstd`, `jpeg`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Raw => "raw",
            Self::Png => "png",
            Self::Lz4 => "lz4",
            Self::Zstd => "zstd",
            Self::Jpeg => "jpeg",
        }
    }

    fn from_code(code: u8, field: &str) -> Result<Self, WireError> {
        match code {
            0 => Ok(Self::Raw),
            1 => Ok(Self::Png),
            2 => Ok(Self::Lz4),
            3 => Ok(Self::Zstd),
            4 => Ok(Self::Jpeg),
            other => Err(value(field, format!("unknown encoding {other} (0 raw, 1 png, 2 lz4, 3 zstd, 4 jpeg)"))),
        }
    }
}

/// What a request asks of the worker besides the image: its model contract.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Contract {
    /// The detector kind the worker must run (`yolox`, `open_vocab`).
    pub model: String,
    /// Labels the robot wants found; empty: whatever the worker's model finds.
    pub prompts: Vec<String>,
    /// The dimension of the region embeddings the robot expects; 0: none.
    pub embedding_dim: u16,
}

/// A decoded request.
#[derive(Debug, Clone)]
pub struct Request {
    /// The robot's id of this request (unique per robot process).
    pub request_id: u64,
    /// The keyframe.
    pub frame: Frame,
    /// The model contract.
    pub contract: Contract,
}

/// Writes a request for `frame` into `out` (cleared first).
pub fn encode_request(
    out: &mut Vec<u8>,
    request_id: u64,
    frame: &Frame,
    contract: &Contract,
    encoding: ImageEncoding,
) -> Result<(), WireError> {
    out.clear();
    out.extend_from_slice(REQUEST_MAGIC);
    put_u16(out, WIRE_VERSION);
    put_u16(out, 0);
    put_u64(out, request_id);
    put_u64(out, frame.seq);
    put_u64(out, frame.stamp_ns);
    put_str(out, &contract.model, "model")?;
    put_u16(out, u16::try_from(contract.prompts.len()).map_err(|_| value("prompts", "more than 65535".into()))?);
    for prompt in &contract.prompts {
        put_str(out, prompt, "prompts")?;
    }
    put_u16(out, contract.embedding_dim);
    let k = &frame.intrinsics;
    put_u32(out, k.width);
    put_u32(out, k.height);
    for v in [k.fx, k.fy, k.cx, k.cy, frame.depth_units_per_m] {
        put_f32(out, v);
    }
    let (w, h) = (k.width, k.height);
    out.push(encoding.code());
    let at = reserve_len(out);
    encode_colour(out, &frame.rgb, w, h, encoding)?;
    finish_len(out, at);
    let depth_encoding = encoding.for_depth();
    out.push(depth_encoding.code());
    let at = reserve_len(out);
    encode_depth(out, &frame.depth, w, h, depth_encoding)?;
    finish_len(out, at);
    Ok(())
}

/// Reads a request; every error names the field.
pub fn decode_request(bytes: &[u8]) -> Result<Request, WireError> {
    let mut r = Reader { bytes, at: 0 };
    r.magic(REQUEST_MAGIC, "request")?;
    r.u16("reserved")?;
    let request_id = r.u64("request_id")?;
    let seq = r.u64("frame_seq")?;
    let stamp_ns = r.u64("stamp_ns")?;
    let model = r.str("model")?;
    let n_prompts = r.u16("prompts")?;
    let prompts = (0..n_prompts).map(|_| r.str("prompts")).collect::<Result<Vec<_>, _>>()?;
    let embedding_dim = r.u16("embedding_dim")?;
    let width = r.u32("width")?;
    let height = r.u32("height")?;
    let pixels = u64::from(width) * u64::from(height);
    if width < 16 || height < 16 || pixels > MAX_PIXELS {
        return Err(value("width", format!("image {width}x{height} outside 16x16 .. {MAX_PIXELS} pixels")));
    }
    let (fx, fy, cx, cy) = (r.f32("fx")?, r.f32("fy")?, r.f32("cx")?, r.f32("cy")?);
    let depth_units_per_m = r.f32("depth_units_per_m")?;
    for (field, v) in [("fx", fx), ("fy", fy), ("depth_units_per_m", depth_units_per_m)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(value(field, format!("must be a positive number, got {v}")));
        }
    }
    if !(cx.is_finite() && cy.is_finite()) {
        return Err(value("cx", format!("principal point ({cx}, {cy}) is not finite")));
    }
    let intrinsics = Intrinsics { width, height, fx, fy, cx, cy };
    let mut frame = Frame::new(intrinsics);
    frame.seq = seq;
    frame.stamp_ns = stamp_ns;
    frame.depth_units_per_m = depth_units_per_m;
    let colour_encoding = ImageEncoding::from_code(r.u8("colour_encoding")?, "colour_encoding")?;
    let colour = r.blob("colour")?;
    decode_colour(colour, colour_encoding, width, height, &mut frame.rgb)?;
    let depth_encoding = ImageEncoding::from_code(r.u8("depth_encoding")?, "depth_encoding")?;
    let depth = r.blob("depth")?;
    decode_depth(depth, depth_encoding, width, height, &mut frame.depth)?;
    r.end()?;
    Ok(Request { request_id, frame, contract: Contract { model, prompts, embedding_dim } })
}

/// What a worker answered.
#[derive(Debug, Clone, PartialEq)]
pub enum ReplyBody {
    /// The detections.
    Detections {
        /// Time the worker spent detecting, µs.
        detect_us: u32,
        /// The dimension of every embedding in `detections` (0: none carried).
        embedding_dim: u16,
        /// The detections, masks in image pixels.
        detections: Vec<Detection>,
    },
    /// The worker cannot serve this contract (model, prompts, image size).
    Refused(String),
    /// The worker's detector failed on this keyframe.
    Failed(String),
}

/// A decoded reply.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    /// The request it answers.
    pub request_id: u64,
    /// The keyframe it answers.
    pub frame_seq: u64,
    /// The worker's id.
    pub worker: String,
    /// What it answered.
    pub body: ReplyBody,
}

/// Writes `reply` into `out` (cleared first).
pub fn encode_reply(out: &mut Vec<u8>, reply: &Reply) -> Result<(), WireError> {
    out.clear();
    out.extend_from_slice(REPLY_MAGIC);
    put_u16(out, WIRE_VERSION);
    out.push(match reply.body {
        ReplyBody::Detections { .. } => 0,
        ReplyBody::Refused(_) => 1,
        ReplyBody::Failed(_) => 2,
    });
    out.push(0);
    put_u64(out, reply.request_id);
    put_u64(out, reply.frame_seq);
    put_str(out, &reply.worker, "worker")?;
    match &reply.body {
        ReplyBody::Refused(reason) | ReplyBody::Failed(reason) => put_str(out, reason, "reason")?,
        ReplyBody::Detections { detect_us, embedding_dim, detections } => {
            put_u32(out, *detect_us);
            put_u16(out, *embedding_dim);
            put_u16(out, u16::try_from(detections.len()).map_err(|_| value("detections", "more than 65535".into()))?);
            for d in detections {
                put_str(out, &d.label, "label")?;
                out.push(d.kind as u8);
                put_f32(out, d.score);
                let m = &d.mask;
                for v in [m.x0, m.y0, m.width, m.height] {
                    put_u32(out, v);
                }
                let at = out.len();
                put_u32(out, 0);
                let mut runs = 0u32;
                let mut inside = false;
                let mut run = 0u32;
                for &v in &m.data {
                    if (v != 0) != inside {
                        put_u32(out, run);
                        runs += 1;
                        inside = !inside;
                        run = 0;
                    }
                    run += 1;
                }
                put_u32(out, run);
                runs += 1;
                out[at..at + 4].copy_from_slice(&runs.to_le_bytes());
                match &d.semantic_feature {
                    Some(feature) => {
                        if feature.len() != usize::from(*embedding_dim) {
                            return Err(value(
                                "embedding",
                                format!("{} values, the reply says {embedding_dim}", feature.len()),
                            ));
                        }
                        out.push(1);
                        feature.iter().for_each(|v| put_f32(out, *v));
                    }
                    None => out.push(0),
                }
            }
        }
    }
    Ok(())
}

/// Reads a reply; every error names the field. Masks are checked against their boxes here;
/// against the image and the request by the caller.
pub fn decode_reply(bytes: &[u8]) -> Result<Reply, WireError> {
    let mut r = Reader { bytes, at: 0 };
    r.magic(REPLY_MAGIC, "reply")?;
    let status = r.u8("status")?;
    r.u8("reserved")?;
    let request_id = r.u64("request_id")?;
    let frame_seq = r.u64("frame_seq")?;
    let worker = r.str("worker")?;
    let body = match status {
        0 => {
            let detect_us = r.u32("detect_us")?;
            let embedding_dim = r.u16("embedding_dim")?;
            let n = r.u16("detections")?;
            let mut detections = Vec::with_capacity(usize::from(n));
            for index in 0..usize::from(n) {
                detections.push(read_detection(&mut r, index, embedding_dim)?);
            }
            ReplyBody::Detections { detect_us, embedding_dim, detections }
        }
        1 => ReplyBody::Refused(r.str("reason")?),
        2 => ReplyBody::Failed(r.str("reason")?),
        other => return Err(value("status", format!("unknown status {other} (0 ok, 1 refused, 2 failed)"))),
    };
    r.end()?;
    Ok(Reply { request_id, frame_seq, worker, body })
}

fn read_detection(r: &mut Reader, index: usize, embedding_dim: u16) -> Result<Detection, WireError> {
    let field = |name: &str| format!("detections[{index}].{name}");
    let label = r.str(&field("label"))?;
    let kind = r.u8(&field("kind"))?;
    let kind = NodeKind::from_u8(kind).ok_or_else(|| value(&field("kind"), format!("{kind} (0 object, 1 part)")))?;
    let score = r.f32(&field("score"))?;
    if !(0.0..=1.0).contains(&score) {
        return Err(value(&field("score"), format!("must be within [0, 1], got {score}")));
    }
    let (x0, y0, width, height) =
        (r.u32(&field("x0"))?, r.u32(&field("y0"))?, r.u32(&field("width"))?, r.u32(&field("height"))?);
    let expected = u64::from(width) * u64::from(height);
    if expected > MAX_PIXELS {
        return Err(value(&field("width"), format!("box {width}x{height} larger than any image")));
    }
    let n_runs = r.u32(&field("runs"))?;
    if u64::from(n_runs) > expected + 1 {
        return Err(WireError::MaskSize { index, covered: u64::from(n_runs), width, height, expected });
    }
    let mut data = Vec::with_capacity(expected as usize);
    let mut inside = false;
    let mut covered = 0u64;
    for _ in 0..n_runs {
        let run = r.u32(&field("runs"))?;
        covered += u64::from(run);
        if covered > expected {
            return Err(WireError::MaskSize { index, covered, width, height, expected });
        }
        data.extend(std::iter::repeat_n(u8::from(inside), run as usize));
        inside = !inside;
    }
    if covered != expected {
        return Err(WireError::MaskSize { index, covered, width, height, expected });
    }
    let semantic_feature = match r.u8(&field("has_embedding"))? {
        0 => None,
        1 => {
            let values = (0..embedding_dim).map(|_| r.f32(&field("embedding"))).collect::<Result<Vec<_>, _>>()?;
            if values.iter().any(|v| !v.is_finite()) {
                return Err(value(&field("embedding"), "holds a value that is not finite".into()));
            }
            Some(values)
        }
        other => return Err(value(&field("has_embedding"), format!("{other} (0 or 1)"))),
    };
    Ok(Detection { label, kind, score, mask: Mask { x0, y0, width, height, data }, semantic_feature })
}

fn value(field: &str, reason: String) -> WireError {
    WireError::Value { field: field.to_owned(), reason }
}

fn put_u16(out: &mut Vec<u8>, v: u16) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_u64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_str(out: &mut Vec<u8>, s: &str, field: &str) -> Result<(), WireError> {
    put_u16(out, u16::try_from(s.len()).map_err(|_| value(field, format!("{} bytes, at most 65535", s.len())))?);
    out.extend_from_slice(s.as_bytes());
    Ok(())
}
fn reserve_len(out: &mut Vec<u8>) -> usize {
    put_u32(out, 0);
    out.len()
}
fn finish_len(out: &mut [u8], at: usize) {
    let len = (out.len() - at) as u32;
    out[at - 4..at].copy_from_slice(&len.to_le_bytes());
}

fn encode_colour(out: &mut Vec<u8>, rgb: &[u8], w: u32, h: u32, encoding: ImageEncoding) -> Result<(), WireError> {
    match encoding {
        ImageEncoding::Raw => out.extend_from_slice(rgb),
        ImageEncoding::Lz4 => out.extend_from_slice(&lz4_flex::compress_prepend_size(rgb)),
        ImageEncoding::Zstd => zstd_into(out, rgb, "colour")?,
        ImageEncoding::Png => {
            use image::ImageEncoder as _;
            image::codecs::png::PngEncoder::new_with_quality(
                &mut *out,
                image::codecs::png::CompressionType::Fast,
                image::codecs::png::FilterType::Sub,
            )
            .write_image(rgb, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| value("colour", format!("PNG: {e}")))?;
        }
        ImageEncoding::Jpeg => {
            use image::ImageEncoder as _;
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut *out, JPEG_QUALITY)
                .write_image(rgb, w, h, image::ExtendedColorType::Rgb8)
                .map_err(|e| value("colour", format!("JPEG: {e}")))?;
        }
    }
    Ok(())
}

fn zstd_into(out: &mut Vec<u8>, raw: &[u8], field: &str) -> Result<(), WireError> {
    let compressed = zstd::bulk::compress(raw, ZSTD_LEVEL).map_err(|e| value(field, format!("zstd: {e}")))?;
    out.extend_from_slice(&compressed);
    Ok(())
}

/// zstd-decompresses at most `expected` bytes (a larger frame is an error, not an allocation).
fn unzstd(bytes: &[u8], expected: usize, field: &str) -> Result<Vec<u8>, WireError> {
    let raw = zstd::bulk::decompress(bytes, expected).map_err(|e| value(field, format!("zstd: {e}")))?;
    expect_len(field, raw.len(), expected)?;
    Ok(raw)
}

fn encode_depth(out: &mut Vec<u8>, depth: &[u16], w: u32, h: u32, encoding: ImageEncoding) -> Result<(), WireError> {
    match encoding {
        ImageEncoding::Raw => depth.iter().for_each(|v| put_u16(out, *v)),
        ImageEncoding::Lz4 => {
            let raw: Vec<u8> = depth.iter().flat_map(|v| v.to_le_bytes()).collect();
            out.extend_from_slice(&lz4_flex::compress_prepend_size(&raw));
        }
        ImageEncoding::Zstd => {
            let raw: Vec<u8> = depth.iter().flat_map(|v| v.to_le_bytes()).collect();
            zstd_into(out, &raw, "depth")?;
        }
        ImageEncoding::Jpeg => return Err(value("depth", "depth is never sent as JPEG (lossy)".into())),
        ImageEncoding::Png => {
            use image::ImageEncoder as _;
            // The encoder takes 16-bit samples in native order (it writes PNG's big-endian).
            let be: Vec<u8> = depth.iter().flat_map(|v| v.to_ne_bytes()).collect();
            image::codecs::png::PngEncoder::new_with_quality(
                &mut *out,
                image::codecs::png::CompressionType::Fast,
                image::codecs::png::FilterType::Sub,
            )
            .write_image(&be, w, h, image::ExtendedColorType::L16)
            .map_err(|e| value("depth", format!("PNG: {e}")))?;
        }
    }
    Ok(())
}

fn expect_len(field: &str, got: usize, expected: usize) -> Result<(), WireError> {
    if got != expected {
        return Err(value(field, format!("{got} bytes of pixels, the image size needs {expected}")));
    }
    Ok(())
}

fn decode_colour(bytes: &[u8], encoding: ImageEncoding, w: u32, h: u32, rgb: &mut [u8]) -> Result<(), WireError> {
    let expected = rgb.len();
    match encoding {
        ImageEncoding::Raw => {
            expect_len("colour", bytes.len(), expected)?;
            rgb.copy_from_slice(bytes);
        }
        ImageEncoding::Lz4 => {
            let raw = lz4_flex::decompress_size_prepended(bytes).map_err(|e| value("colour", format!("lz4: {e}")))?;
            expect_len("colour", raw.len(), expected)?;
            rgb.copy_from_slice(&raw);
        }
        ImageEncoding::Zstd => rgb.copy_from_slice(&unzstd(bytes, expected, "colour")?),
        ImageEncoding::Jpeg => {
            let decoded = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
                .map_err(|e| value("colour", format!("JPEG: {e}")))?;
            if (decoded.width(), decoded.height()) != (w, h) {
                return Err(value(
                    "colour",
                    format!("JPEG is {}x{}, the request says {w}x{h}", decoded.width(), decoded.height()),
                ));
            }
            rgb.copy_from_slice(decoded.into_rgb8().as_raw());
        }
        ImageEncoding::Png => {
            let decoded = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
                .map_err(|e| value("colour", format!("PNG: {e}")))?;
            if (decoded.width(), decoded.height()) != (w, h) {
                return Err(value(
                    "colour",
                    format!("PNG is {}x{}, the request says {w}x{h}", decoded.width(), decoded.height()),
                ));
            }
            let decoded = decoded.into_rgb8();
            rgb.copy_from_slice(decoded.as_raw());
        }
    }
    Ok(())
}

fn decode_depth(bytes: &[u8], encoding: ImageEncoding, w: u32, h: u32, depth: &mut [u16]) -> Result<(), WireError> {
    let expected = depth.len() * 2;
    let from_le = |raw: &[u8], depth: &mut [u16]| {
        for (d, b) in depth.iter_mut().zip(raw.chunks_exact(2)) {
            *d = u16::from_le_bytes([b[0], b[1]]);
        }
    };
    match encoding {
        ImageEncoding::Raw => {
            expect_len("depth", bytes.len(), expected)?;
            from_le(bytes, depth);
        }
        ImageEncoding::Lz4 => {
            let raw = lz4_flex::decompress_size_prepended(bytes).map_err(|e| value("depth", format!("lz4: {e}")))?;
            expect_len("depth", raw.len(), expected)?;
            from_le(&raw, depth);
        }
        ImageEncoding::Zstd => from_le(&unzstd(bytes, expected, "depth")?, depth),
        ImageEncoding::Jpeg => return Err(value("depth", "depth is never sent as JPEG (lossy)".into())),
        ImageEncoding::Png => {
            let decoded = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
                .map_err(|e| value("depth", format!("PNG: {e}")))?;
            if (decoded.width(), decoded.height()) != (w, h) {
                return Err(value(
                    "depth",
                    format!("PNG is {}x{}, the request says {w}x{h}", decoded.width(), decoded.height()),
                ));
            }
            let image::DynamicImage::ImageLuma16(grey) = decoded else {
                return Err(value("depth", "PNG is not 16-bit grey".into()));
            };
            depth.copy_from_slice(grey.as_raw());
        }
    }
    Ok(())
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, field: &str) -> Result<&'a [u8], WireError> {
        let left = self.bytes.len() - self.at;
        if n > left {
            return Err(WireError::Truncated { field: field.to_owned(), needed: n, left });
        }
        let slice = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(slice)
    }
    fn magic(&mut self, magic: &[u8; 4], expected: &'static str) -> Result<(), WireError> {
        let found = self
            .take(4, "magic")
            .map_err(|_| WireError::Magic { expected, found: self.bytes.iter().take(4).copied().collect() })?;
        if found != magic {
            return Err(WireError::Magic { expected, found: found.to_vec() });
        }
        let version = self.u16("version")?;
        if version != WIRE_VERSION {
            return Err(WireError::Version { found: version });
        }
        Ok(())
    }
    fn u8(&mut self, field: &str) -> Result<u8, WireError> {
        Ok(self.take(1, field)?[0])
    }
    fn u16(&mut self, field: &str) -> Result<u16, WireError> {
        let b = self.take(2, field)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self, field: &str) -> Result<u32, WireError> {
        let b = self.take(4, field)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self, field: &str) -> Result<u64, WireError> {
        let b = self.take(8, field)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
    fn f32(&mut self, field: &str) -> Result<f32, WireError> {
        Ok(f32::from_bits(self.u32(field)?))
    }
    fn str(&mut self, field: &str) -> Result<String, WireError> {
        let n = self.u16(field)?;
        let b = self.take(usize::from(n), field)?;
        String::from_utf8(b.to_vec()).map_err(|_| value(field, "not UTF-8".into()))
    }
    fn blob(&mut self, field: &str) -> Result<&'a [u8], WireError> {
        let n = self.u32(field)?;
        self.take(n as usize, field)
    }
    fn end(&self) -> Result<(), WireError> {
        match self.bytes.len() - self.at {
            0 => Ok(()),
            n => Err(WireError::Trailing(n)),
        }
    }
}

#[cfg(test)]
#[path = "wire_tests.rs"]
mod tests;
