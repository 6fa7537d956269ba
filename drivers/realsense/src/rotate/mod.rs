//! Rotating frames upright: the Stretch 3's head camera is mounted rotated by 90°, detectors
//! expect upright images, so colour, depth and the intrinsics are turned before anything else
//! sees them.
//!
//! `rotate` is the **clockwise** turn applied to the image as the camera delivers it, in
//! degrees (0, 90, 180, 270). Pixel indices follow librealsense and
//! [`Intrinsics::point_in_camera`]: pixel `(u, v)` is at `(u, v)` (no half-pixel offset). For
//! 90° a `w x h` image becomes `h x w` and pixel `(u, v)` lands at `(h - 1 - v, u)`.
//!
//! The camera frame turns with the image (x right, y down, z forward in the *upright* image):
//! [`Rotation::camera_from_upright`] is the rotation about the optical axis that takes a point
//! in the upright camera frame to the physical camera's optical frame, so
//! `world_from_upright = world_from_camera * camera_from_upright` and back-projection with the
//! rotated intrinsics lands every pixel where the unrotated image would have put it.
//!
//! The copy kernels read the driver's buffer (any row stride) and write the pooled frame's
//! buffers in place: nothing is allocated per frame.

#[cfg(test)]
mod tests;

use op3dsg_drivers::frame::Intrinsics;
use op3dsg_drivers::pose::Isometry;
use serde::{Deserialize, Serialize};

use crate::unchecked::{blocks, depth_blocks};

/// A clockwise image rotation by a multiple of 90°.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(try_from = "u32", into = "u32")]
pub enum Rotation {
    /// As delivered.
    #[default]
    None,
    /// 90° clockwise.
    Cw90,
    /// 180°.
    Cw180,
    /// 270° clockwise (90° counter-clockwise).
    Cw270,
}

impl TryFrom<u32> for Rotation {
    type Error = String;
    fn try_from(degrees: u32) -> Result<Self, String> {
        match degrees {
            0 => Ok(Self::None),
            90 => Ok(Self::Cw90),
            180 => Ok(Self::Cw180),
            270 => Ok(Self::Cw270),
            other => Err(format!("must be 0, 90, 180 or 270 (degrees clockwise), got {other}")),
        }
    }
}

impl From<Rotation> for u32 {
    fn from(rotation: Rotation) -> u32 {
        rotation.degrees()
    }
}

impl Rotation {
    /// Clockwise degrees.
    pub fn degrees(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Cw90 => 90,
            Self::Cw180 => 180,
            Self::Cw270 => 270,
        }
    }

    /// Whether width and height swap.
    pub fn swaps_axes(self) -> bool {
        matches!(self, Self::Cw90 | Self::Cw270)
    }

    /// Where pixel `(u, v)` of a `width x height` source image lands in the rotated image.
    #[inline]
    pub fn map_pixel(self, u: u32, v: u32, width: u32, height: u32) -> (u32, u32) {
        match self {
            Self::None => (u, v),
            Self::Cw90 => (height - 1 - v, u),
            Self::Cw180 => (width - 1 - u, height - 1 - v),
            Self::Cw270 => (v, width - 1 - u),
        }
    }

    /// The intrinsics of the rotated image.
    pub fn intrinsics(self, k: &Intrinsics) -> Intrinsics {
        let (w, h) = (k.width as f32, k.height as f32);
        match self {
            Self::None => *k,
            Self::Cw90 => {
                Intrinsics { width: k.height, height: k.width, fx: k.fy, fy: k.fx, cx: h - 1.0 - k.cy, cy: k.cx }
            }
            Self::Cw180 => Intrinsics { cx: w - 1.0 - k.cx, cy: h - 1.0 - k.cy, ..*k },
            Self::Cw270 => {
                Intrinsics { width: k.height, height: k.width, fx: k.fy, fy: k.fx, cx: k.cy, cy: w - 1.0 - k.cx }
            }
        }
    }

    /// `camera_from_upright`: the physical camera's optical frame from the upright image's
    /// camera frame (a rotation about the optical axis z).
    pub fn camera_from_upright(self) -> Isometry {
        // Upright x' = -y (90° cw) etc.: the upright axes expressed in the camera frame.
        let angle = -(self.degrees() as f64).to_radians();
        Isometry::new(glam::DQuat::from_rotation_z(angle), glam::DVec3::ZERO)
    }
}

/// Layout of a driver buffer: size in pixels and the byte stride of one row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SourceLayout {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Bytes from one row to the next (at least `width * bytes_per_pixel`).
    pub stride_bytes: usize,
}

/// Colour channel order of a driver buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColourOrder {
    /// R, G, B (3 bytes).
    Rgb8,
    /// B, G, R (3 bytes).
    Bgr8,
    /// R, G, B, A (4 bytes).
    Rgba8,
    /// B, G, R, A (4 bytes).
    Bgra8,
}

impl ColourOrder {
    /// Bytes per pixel.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Self::Rgb8 | Self::Bgr8 => 3,
            Self::Rgba8 | Self::Bgra8 => 4,
        }
    }

    fn swaps_red_blue(self) -> bool {
        matches!(self, Self::Bgr8 | Self::Bgra8)
    }
}

/// A buffer or layout that does not fit: what was expected and what came.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CopyError {
    /// The source slice is shorter than its layout says.
    #[error("{stream}: driver buffer holds {got} bytes, {width}x{height} with stride {stride} needs {needed}")]
    ShortSource {
        /// `colour` or `depth`.
        stream: &'static str,
        /// Bytes present.
        got: usize,
        /// Bytes needed.
        needed: usize,
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
        /// Row stride, bytes.
        stride: usize,
    },
    /// The destination does not have exactly one element per pixel (per channel).
    #[error("{stream}: frame buffer holds {got} values, the {width}x{height} stream needs {needed}")]
    Destination {
        /// `colour` or `depth`.
        stream: &'static str,
        /// Values present.
        got: usize,
        /// Values needed.
        needed: usize,
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
    },
}

fn check(
    stream: &'static str,
    src: &[u8],
    layout: SourceLayout,
    bpp: usize,
    dst_len: usize,
    channels: usize,
) -> Result<(), CopyError> {
    let SourceLayout { width, height, stride_bytes } = layout;
    let needed = if height == 0 { 0 } else { stride_bytes * (height - 1) + width * bpp };
    if src.len() < needed || stride_bytes < width * bpp {
        return Err(CopyError::ShortSource { stream, got: src.len(), needed, width, height, stride: stride_bytes });
    }
    let want = width * height * channels;
    if dst_len != want {
        return Err(CopyError::Destination { stream, got: dst_len, needed: want, width, height });
    }
    Ok(())
}

/// Destination index and per-step increments for walking the source row by row: the rotated
/// position of source pixel `(0, v)` and how it moves per `u`.
#[inline]
fn walk(rotation: Rotation, v: usize, w: usize, h: usize) -> (isize, isize) {
    // Destination width: h when axes swap, else w.
    let (w, h, v) = (w as isize, h as isize, v as isize);
    match rotation {
        Rotation::None => (v * w, 1),
        // (u, v) -> (h-1-v, u), dst width h: index = u*h + (h-1-v).
        Rotation::Cw90 => (h - 1 - v, h),
        // (u, v) -> (w-1-u, h-1-v), dst width w.
        Rotation::Cw180 => ((h - 1 - v) * w + (w - 1), -1),
        // (u, v) -> (v, w-1-u), dst width h: index = (w-1-u)*h + v.
        Rotation::Cw270 => ((w - 1) * h + v, -h),
    }
}

/// Copies a colour buffer into `dst` (row-major RGB8 of the rotated image), converting the
/// channel order.
pub fn copy_colour(
    src: &[u8],
    layout: SourceLayout,
    order: ColourOrder,
    rotation: Rotation,
    dst: &mut [u8],
) -> Result<(), CopyError> {
    let blocks = rotation
        .swaps_axes()
        .then(|| blocks::Blocks::new(order.bytes_per_pixel(), order.swaps_red_blue(), rotation == Rotation::Cw90))
        .flatten();
    copy_colour_with(src, layout, order, rotation, dst, blocks)
}

/// [`copy_colour`] without the SIMD blocks of the quarter turns: what CPUs without SSSE3 run,
/// for the benchmark's comparison and the tests.
#[doc(hidden)]
pub fn copy_colour_portable(
    src: &[u8],
    layout: SourceLayout,
    order: ColourOrder,
    rotation: Rotation,
    dst: &mut [u8],
) -> Result<(), CopyError> {
    copy_colour_with(src, layout, order, rotation, dst, None)
}

fn copy_colour_with(
    src: &[u8],
    layout: SourceLayout,
    order: ColourOrder,
    rotation: Rotation,
    dst: &mut [u8],
    blocks: Option<blocks::Blocks>,
) -> Result<(), CopyError> {
    let bpp = order.bytes_per_pixel();
    check("colour", src, layout, bpp, dst.len(), 3)?;
    let SourceLayout { width, height, stride_bytes } = layout;
    let swap = order.swaps_red_blue();
    if rotation == Rotation::None && bpp == 3 && !swap {
        for v in 0..height {
            dst[v * width * 3..(v + 1) * width * 3]
                .copy_from_slice(&src[v * stride_bytes..v * stride_bytes + width * 3]);
        }
        return Ok(());
    }
    let rgb = |px: &[u8]| if swap { [px[2], px[1], px[0]] } else { [px[0], px[1], px[2]] };
    if rotation.swaps_axes() {
        let fast = |rows: &[&[u8]; TILE_ROWS], v0: usize, dst: &mut [u8]| {
            blocks.map_or(0, |b| b.turn_tile(rows, bpp, width, height, v0, dst))
        };
        match bpp {
            3 => turn_in_tiles::<u8, 3, 3>(src, layout, rotation, dst, fast, |px| rgb(px)),
            _ => turn_in_tiles::<u8, 4, 3>(src, layout, rotation, dst, fast, |px| rgb(px)),
        }
        return Ok(());
    }
    let mut put = |v: usize, u: usize, at: usize| {
        let i = v * stride_bytes + u * bpp;
        dst[at * 3..at * 3 + 3].copy_from_slice(&rgb(&src[i..i + bpp]));
    };
    for v in 0..height {
        let (mut at, step) = walk(rotation, v, width, height);
        for u in 0..width {
            put(v, u, at as usize);
            at += step;
        }
    }
    Ok(())
}

/// Source rows per tile when the axes swap: a source column of this many pixels becomes one
/// run of consecutive destination pixels, and the tile's source rows stay in cache while its
/// columns are walked.
const TILE_ROWS: usize = 16;

/// The 90° and 270° turns, tile by tile: `TILE_ROWS` source rows at a time, each source column
/// of the tile written as one run of consecutive destination pixels. Row-by-row order would
/// write every pixel to a new destination row (a new cache line per pixel). `convert` turns one
/// source pixel (`BPP` bytes) into its `OUT` destination values.
///
/// `fast` turns a whole tile's first columns first (colour through [`blocks`]) and returns how
/// many it did; the loop here does the rest.
#[inline(always)]
fn turn_in_tiles<T: Copy, const BPP: usize, const OUT: usize>(
    src: &[u8],
    layout: SourceLayout,
    rotation: Rotation,
    dst: &mut [T],
    mut fast: impl FnMut(&[&[u8]; TILE_ROWS], usize, &mut [T]) -> usize,
    convert: impl Fn(&[u8]) -> [T; OUT],
) {
    let SourceLayout { width, height, stride_bytes } = layout;
    for v0 in (0..height).step_by(TILE_ROWS) {
        let v1 = (v0 + TILE_ROWS).min(height);
        let n = v1 - v0;
        let rows: [&[u8]; TILE_ROWS] = std::array::from_fn(|r| {
            let v = v0 + r;
            if v < v1 { &src[v * stride_bytes..v * stride_bytes + width * BPP] } else { &[] }
        });
        let done = if n == TILE_ROWS { fast(&rows, v0, dst) } else { 0 };
        for u in done..width {
            // The destination row this source column becomes, and where the tile's run starts.
            let (row, first) = match rotation {
                // (u, v) -> (h-1-v, u): row u, columns h-v1 ..= h-1-v0, v0 last.
                Rotation::Cw90 => (u, height - v1),
                // (u, v) -> (v, w-1-u): row w-1-u, columns v0 .. v1.
                _ => (width - 1 - u, v0),
            };
            let start = (row * height + first) * OUT;
            let run = &mut dst[start..start + n * OUT];
            for (r, source_row) in rows[..n].iter().enumerate() {
                let k = if rotation == Rotation::Cw90 { n - 1 - r } else { r };
                let value = convert(&source_row[u * BPP..u * BPP + BPP]);
                run[k * OUT..k * OUT + OUT].copy_from_slice(&value);
            }
        }
    }
}

/// Turns a `width x height` image of `u16` (row-major, no padding) by `rotation` into `dst`
/// (`width * height` values): the aligned depth of an unturned frame, made turned 90° and turned
/// back ([`crate::align::DepthToColour::align`]).
pub(crate) fn turn_u16(src: &[u16], width: usize, height: usize, rotation: Rotation, dst: &mut [u16]) {
    assert!(
        src.len() == width * height && dst.len() == width * height,
        "{width}x{height} turn of {} values into {}",
        src.len(),
        dst.len()
    );
    let layout = SourceLayout { width, height, stride_bytes: width * 2 };
    copy_u16(bytemuck::cast_slice(src), layout, rotation, dst, u16::from_ne_bytes);
}

/// The quarter turns of 16-bit values (`value` reads one from its two bytes): whole tiles'
/// columns in 8x8 blocks where the CPU has them ([`depth_blocks`]), the rest value by value.
#[inline(always)]
fn turn_depth(src: &[u8], layout: SourceLayout, rotation: Rotation, dst: &mut [u16], value: fn([u8; 2]) -> u16) {
    let SourceLayout { width, height, .. } = layout;
    // The blocks copy the bytes as they are: little-endian values on x86_64, as both callers'.
    let fast = |rows: &[&[u8]; TILE_ROWS], v0: usize, dst: &mut [u16]| {
        depth_blocks::turn_tile(depth_blocks::Tile { rows, width, height, v0, cw90: rotation == Rotation::Cw90 }, dst)
    };
    turn_in_tiles::<u16, 2, 1>(src, layout, rotation, dst, fast, |px| [value([px[0], px[1]])]);
}

/// Copies a Z16 depth buffer (little-endian `u16` per pixel, any stride and alignment) into
/// `dst` (row-major depth of the rotated image).
pub fn copy_depth(src: &[u8], layout: SourceLayout, rotation: Rotation, dst: &mut [u16]) -> Result<(), CopyError> {
    check("depth", src, layout, 2, dst.len(), 1)?;
    copy_u16(src, layout, rotation, dst, u16::from_le_bytes);
    Ok(())
}

/// Copies 16-bit values (`value` reads one from its two bytes) turned by `rotation` into `dst`,
/// the layout checked by the caller: [`copy_depth`] (Z16, little-endian) and [`turn_u16`] (the
/// aligner's own buffer, native order).
#[inline(always)]
fn copy_u16(src: &[u8], layout: SourceLayout, rotation: Rotation, dst: &mut [u16], value: fn([u8; 2]) -> u16) {
    let SourceLayout { width, height, stride_bytes } = layout;
    if rotation.swaps_axes() {
        turn_depth(src, layout, rotation, dst, value);
        return;
    }
    for v in 0..height {
        let row = &src[v * stride_bytes..v * stride_bytes + width * 2];
        let (mut at, step) = walk(rotation, v, width, height);
        if rotation == Rotation::None {
            for (d, px) in dst[v * width..(v + 1) * width].iter_mut().zip(row.chunks_exact(2)) {
                *d = value([px[0], px[1]]);
            }
            continue;
        }
        for px in row.chunks_exact(2) {
            dst[at as usize] = value([px[0], px[1]]);
            at += step;
        }
    }
}
