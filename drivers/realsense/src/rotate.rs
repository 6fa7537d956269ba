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

use op3dsg_drivers::frame::Intrinsics;
use op3dsg_drivers::pose::Isometry;
use serde::{Deserialize, Serialize};

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
    copy_colour_with(src, layout, order, rotation, dst, blocks::Blocks::new(order, rotation))
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

/// The quarter turns of colour in 4x4-pixel blocks with SSSE3 byte shuffles (x86_64 CPUs have
/// had them since 2006, the Stretch 3's NUC among them): four source rows of four pixels are
/// loaded, widened to one 32-bit lane per pixel (the channel order converted by the same
/// shuffle), transposed, and each column narrowed back to 12 bytes; a tile column's four
/// blocks, 16 consecutive destination pixels, go out as three 16-byte stores. The scalar tile
/// loop handles what is left (the last columns, a partial tile of rows, other CPUs).
///
/// `frame_handling` benchmark (848x480 RGB8, warm buffers, one core of the CI-kind VM): rotate
/// 90 0.245 ms against 0.608 ms for the tile loop alone.
mod blocks {
    use super::{ColourOrder, Rotation, TILE_ROWS};

    /// The shuffles for one channel order and turn, on a CPU that has SSSE3.
    #[derive(Debug, Clone, Copy)]
    pub(super) struct Blocks {
        /// Source bytes of pixel `j` into lane `j` (R, G, B, 0).
        widen: [u8; 16],
        /// The four lanes of a column into 12 bytes in destination order (the 90° turn writes
        /// the tile's rows bottom up).
        narrow: [u8; 16],
        cw90: bool,
    }

    impl Blocks {
        /// `None` unless the turn is 90° or 270° on a CPU with SSSE3.
        pub(super) fn new(order: ColourOrder, rotation: Rotation) -> Option<Self> {
            if !rotation.swaps_axes() || !supported() {
                return None;
            }
            let bpp = order.bytes_per_pixel();
            let channel = |c: usize| if order.swaps_red_blue() { 2 - c } else { c };
            let mut widen = [0x80u8; 16];
            for j in 0..4 {
                for c in 0..3 {
                    widen[4 * j + c] = (bpp * j + channel(c)) as u8;
                }
            }
            let cw90 = rotation == Rotation::Cw90;
            let mut narrow = [0x80u8; 16];
            for k in 0..4 {
                let lane = if cw90 { 3 - k } else { k };
                for c in 0..3 {
                    narrow[3 * k + c] = (4 * lane + c) as u8;
                }
            }
            Some(Self { widen, narrow, cw90 })
        }

        /// Turns columns `0..done` of one whole tile (source rows `v0..v0 + TILE_ROWS` of a
        /// `width x height` image, `bpp` bytes per pixel) into `dst` (RGB8, `height` wide);
        /// returns `done`, a multiple of 4 whose last block's 16-byte loads stay in the rows.
        pub(super) fn turn_tile(
            &self,
            rows: &[&[u8]; TILE_ROWS],
            bpp: usize,
            width: usize,
            height: usize,
            v0: usize,
            dst: &mut [u8],
        ) -> usize {
            let done = if width * bpp < 16 { 0 } else { ((width * bpp - 16) / (4 * bpp) + 1) * 4 };
            assert!(rows.iter().all(|r| r.len() >= width * bpp) && dst.len() >= width * height * 3);
            assert!(v0 + TILE_ROWS <= height && done <= width);
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `supported()` held when `self` was made; the kernel indexes the slices
            // with checks.
            #[allow(unsafe_code)]
            unsafe {
                x86::turn_tile(self, rows, bpp, done, width, height, v0, dst);
            }
            done
        }
    }

    fn supported() -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            std::arch::is_x86_feature_detected!("ssse3")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[allow(unsafe_code)]
    mod x86 {
        use std::arch::x86_64::{
            _MM_HINT_T0, _mm_loadu_si128, _mm_or_si128, _mm_prefetch, _mm_setzero_si128, _mm_shuffle_epi8,
            _mm_slli_si128, _mm_srli_si128, _mm_storeu_si128, _mm_unpackhi_epi32, _mm_unpackhi_epi64,
            _mm_unpacklo_epi32, _mm_unpacklo_epi64,
        };

        use super::{Blocks, TILE_ROWS};

        /// How far ahead along its source rows the turn asks for memory (bytes). The source is
        /// the frame librealsense has just decoded, mostly outside this core's caches, read as
        /// 16 row streams at once; left to the hardware prefetcher, the turn of a recorded
        /// 848x480 frame inside `next_frame` took about twice as long. (Timed on the
        /// `frame_handling` benchmark's recordings, one core: 128 to 256 bytes ahead the
        /// fastest, 1024 and more slower. Depth's quarter turns, which mostly read the
        /// aligner's own buffer while it is still cached, were slower with such hints.)
        const PREFETCH_AHEAD: usize = 256;

        /// Asks for the cache line `PREFETCH_AHEAD` bytes past byte `at` of each of a tile's
        /// rows.
        #[inline(always)]
        fn prefetch_rows(rows: &[&[u8]; TILE_ROWS], at: usize) {
            for row in rows {
                // SAFETY: a prefetch (SSE, every x86_64 CPU) is a hint: it changes no memory
                // the program can observe and cannot fault, past a row's end too; the pointer
                // is made with `wrapping_add` and never dereferenced.
                unsafe { _mm_prefetch::<_MM_HINT_T0>(row.as_ptr().wrapping_add(at + PREFETCH_AHEAD).cast()) };
            }
        }

        /// See [`Blocks::turn_tile`].
        ///
        /// # Safety
        ///
        /// The CPU has SSSE3.
        #[target_feature(enable = "ssse3")]
        #[allow(clippy::too_many_arguments)]
        pub(super) unsafe fn turn_tile(
            blocks: &Blocks,
            rows: &[&[u8]; TILE_ROWS],
            bpp: usize,
            done: usize,
            width: usize,
            height: usize,
            v0: usize,
            dst: &mut [u8],
        ) {
            // SAFETY (every block below): loads and stores go through slices indexed with checks.
            let widen = unsafe { _mm_loadu_si128(blocks.widen.as_ptr().cast()) };
            let narrow = unsafe { _mm_loadu_si128(blocks.narrow.as_ptr().cast()) };
            for u0 in (0..done).step_by(4) {
                let at = u0 * bpp;
                // Every 4 blocks, 48 or 64 bytes of each row: one line ahead for each.
                if u0 % 16 == 0 {
                    prefetch_rows(rows, at);
                }
                // pieces[j][k]: source column u0 + j of the tile's rows 4k .. 4k + 4, narrowed to
                // 12 bytes in destination order (the top 4 bytes zero).
                let mut pieces = [[_mm_setzero_si128(); 4]; 4];
                for k in 0..TILE_ROWS / 4 {
                    let load = |r: usize| {
                        let bytes: &[u8; 16] = rows[4 * k + r][at..at + 16].try_into().expect("16 bytes");
                        _mm_shuffle_epi8(unsafe { _mm_loadu_si128(bytes.as_ptr().cast()) }, widen)
                    };
                    let (r0, r1, r2, r3) = (load(0), load(1), load(2), load(3));
                    let (t0, t1) = (_mm_unpacklo_epi32(r0, r1), _mm_unpacklo_epi32(r2, r3));
                    let (t2, t3) = (_mm_unpackhi_epi32(r0, r1), _mm_unpackhi_epi32(r2, r3));
                    pieces[0][k] = _mm_shuffle_epi8(_mm_unpacklo_epi64(t0, t1), narrow);
                    pieces[1][k] = _mm_shuffle_epi8(_mm_unpackhi_epi64(t0, t1), narrow);
                    pieces[2][k] = _mm_shuffle_epi8(_mm_unpacklo_epi64(t2, t3), narrow);
                    pieces[3][k] = _mm_shuffle_epi8(_mm_unpackhi_epi64(t2, t3), narrow);
                }
                for (j, p) in pieces.into_iter().enumerate() {
                    let u = u0 + j;
                    // (u, v) -> (h-1-v, u) for 90°, (v, w-1-u) for 270°: one run of the
                    // tile's 16 pixels, from its lowest destination column; the 90° turn puts
                    // the tile's rows there bottom up.
                    let (row, first, [a, b, c, d]) = if blocks.cw90 {
                        (u, height - TILE_ROWS - v0, [p[3], p[2], p[1], p[0]])
                    } else {
                        (width - 1 - u, v0, p)
                    };
                    let start = (row * height + first) * 3;
                    let out = &mut dst[start..start + 48];
                    // Four 12-byte pieces as three 16-byte stores.
                    let x = [
                        _mm_or_si128(a, _mm_slli_si128::<12>(b)),
                        _mm_or_si128(_mm_srli_si128::<4>(b), _mm_slli_si128::<8>(c)),
                        _mm_or_si128(_mm_srli_si128::<8>(c), _mm_slli_si128::<4>(d)),
                    ];
                    for (chunk, x) in out.chunks_exact_mut(16).zip(x) {
                        // SAFETY: `chunk` holds 16 bytes.
                        unsafe { _mm_storeu_si128(chunk.as_mut_ptr().cast(), x) };
                    }
                }
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

/// The quarter turns of 16-bit values in 8x8 blocks with SSE2 (every x86_64 CPU): eight source
/// rows of eight values are loaded and transposed with three rounds of unpacks; a tile's 16
/// rows make each of eight columns one run of 16 consecutive destination values, two 16-byte
/// stores. The tile loop handles the rest (the last columns, a partial tile of rows, other
/// CPUs).
///
/// `frame_handling` benchmark (848x480 Z16, warm buffers, one core, three runs alternating with
/// the value-by-value loop): rotate 90 and 270 0.04-0.06 ms against 0.16-0.18 ms.
mod depth_blocks {
    use super::TILE_ROWS;

    /// One whole tile: source rows `v0..v0 + TILE_ROWS` of a `width x height` image of 16-bit
    /// values, turned clockwise by 90° if `cw90`, else by 270°.
    #[derive(Clone, Copy)]
    pub(super) struct Tile<'a> {
        pub(super) rows: &'a [&'a [u8]; TILE_ROWS],
        pub(super) width: usize,
        pub(super) height: usize,
        pub(super) v0: usize,
        pub(super) cw90: bool,
    }

    /// Turns columns `0..done` of `tile` into `dst` (`height` wide); returns `done`, a multiple
    /// of 8 (0 on other CPUs).
    pub(super) fn turn_tile(tile: Tile, dst: &mut [u16]) -> usize {
        let Tile { rows, width, height, v0, .. } = tile;
        assert!(rows.iter().all(|r| r.len() >= width * 2) && dst.len() >= width * height);
        assert!(v0 + TILE_ROWS <= height);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE2 is part of every x86_64 CPU (the target's baseline); the kernel indexes
        // the slices with checks.
        #[allow(unsafe_code)]
        unsafe {
            x86::turn_tile(tile, dst)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = dst;
            0
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[allow(unsafe_code)]
    mod x86 {
        use std::arch::x86_64::{
            __m128i, _mm_loadu_si128, _mm_storeu_si128, _mm_unpackhi_epi16, _mm_unpackhi_epi32, _mm_unpackhi_epi64,
            _mm_unpacklo_epi16, _mm_unpacklo_epi32, _mm_unpacklo_epi64,
        };

        use super::{TILE_ROWS, Tile};

        /// Columns `j` of eight rows of eight values: `out[j]` holds `r[0][j] .. r[7][j]`.
        #[target_feature(enable = "sse2")]
        fn transpose(r: [__m128i; 8]) -> [__m128i; 8] {
            // Rows 2h, 2h + 1 interleaved: columns 0-3 (t[2h]) and 4-7 (t[2h + 1]).
            let t: [__m128i; 8] = std::array::from_fn(|i| {
                let (a, b) = (r[i / 2 * 2], r[i / 2 * 2 + 1]);
                if i % 2 == 0 { _mm_unpacklo_epi16(a, b) } else { _mm_unpackhi_epi16(a, b) }
            });
            // Columns 2k, 2k + 1 of rows 0-3 (s[k]) and of rows 4-7 (s[4 + k]).
            let s: [__m128i; 8] = std::array::from_fn(|i| {
                let (h, k) = (i / 4 * 4, i % 4);
                let (a, b) = (t[h + k / 2], t[h + k / 2 + 2]);
                if k % 2 == 0 { _mm_unpacklo_epi32(a, b) } else { _mm_unpackhi_epi32(a, b) }
            });
            std::array::from_fn(|j| {
                let (a, b) = (s[j / 2], s[4 + j / 2]);
                if j % 2 == 0 { _mm_unpacklo_epi64(a, b) } else { _mm_unpackhi_epi64(a, b) }
            })
        }

        /// See [`super::turn_tile`].
        #[target_feature(enable = "sse2")]
        pub(super) fn turn_tile(Tile { rows, width, height, v0, cw90 }: Tile, dst: &mut [u16]) -> usize {
            let done = width / 8 * 8;
            // Destination run order: the 90° turn puts the tile's rows there bottom up.
            let row = |k: usize| if cw90 { rows[TILE_ROWS - 1 - k] } else { rows[k] };
            let first = if cw90 { height - TILE_ROWS - v0 } else { v0 };
            for u0 in (0..done).step_by(8) {
                let load = |k: usize| {
                    let bytes: &[u8; 16] = row(k)[u0 * 2..u0 * 2 + 16].try_into().expect("16 bytes");
                    // SAFETY: a 16-byte load from a 16-byte array (no alignment needed).
                    unsafe { _mm_loadu_si128(bytes.as_ptr().cast()) }
                };
                let top = transpose(std::array::from_fn(load));
                let bottom = transpose(std::array::from_fn(|k| load(8 + k)));
                for j in 0..8 {
                    let u = u0 + j;
                    // (u, v) -> (h-1-v, u) for 90°, (v, w-1-u) for 270°.
                    let line = if cw90 { u } else { width - 1 - u };
                    let start = line * height + first;
                    let (a, b) = dst[start..start + TILE_ROWS].split_at_mut(8);
                    // SAFETY: 16-byte stores into slices of eight u16 (no alignment needed).
                    unsafe {
                        _mm_storeu_si128(a.as_mut_ptr().cast(), top[j]);
                        _mm_storeu_si128(b.as_mut_ptr().cast(), bottom[j]);
                    }
                }
            }
            done
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [Rotation; 4] = [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270];

    fn k() -> Intrinsics {
        Intrinsics { width: 848, height: 480, fx: 421.5, fy: 420.25, cx: 425.75, cy: 238.5 }
    }

    #[test]
    fn ninety_degrees_maps_the_corners_and_a_known_pixel() {
        let r = Rotation::Cw90;
        // The top-left corner goes to the top-right, the bottom-left to the top-left.
        assert_eq!(r.map_pixel(0, 0, 848, 480), (479, 0));
        assert_eq!(r.map_pixel(0, 479, 848, 480), (0, 0));
        assert_eq!(r.map_pixel(847, 479, 848, 480), (0, 847));
        assert_eq!(r.map_pixel(100, 30, 848, 480), (449, 100));
        assert_eq!(Rotation::Cw270.map_pixel(100, 30, 848, 480), (30, 747));
        assert_eq!(Rotation::Cw180.map_pixel(100, 30, 848, 480), (747, 449));
    }

    #[test]
    fn rotated_intrinsics_are_exact_for_ninety_degrees() {
        let r = Rotation::Cw90.intrinsics(&k());
        assert_eq!(r, Intrinsics { width: 480, height: 848, fx: 420.25, fy: 421.5, cx: 479.0 - 238.5, cy: 425.75 });
        let r = Rotation::Cw270.intrinsics(&k());
        assert_eq!(r, Intrinsics { width: 480, height: 848, fx: 420.25, fy: 421.5, cx: 238.5, cy: 847.0 - 425.75 });
        let r = Rotation::Cw180.intrinsics(&k());
        assert_eq!(r, Intrinsics { cx: 847.0 - 425.75, cy: 479.0 - 238.5, ..k() });
        assert_eq!(Rotation::None.intrinsics(&k()), k());
    }

    #[test]
    fn rotation_keeps_back_projection_consistent() {
        // A pixel and its rotated twin back-project to the same point once the upright camera
        // frame is turned back into the physical one.
        let k = k();
        for r in ALL {
            let kr = r.intrinsics(&k);
            let camera_from_upright = r.camera_from_upright();
            for (u, v) in [(0u32, 0u32), (100, 30), (847, 479), (424, 240), (5, 470)] {
                let depth_m = 1.7;
                let p = k.point_in_camera(u as f32, v as f32, depth_m).as_dvec3();
                let (ur, vr) = r.map_pixel(u, v, k.width, k.height);
                let q =
                    camera_from_upright.transform_point(kr.point_in_camera(ur as f32, vr as f32, depth_m).as_dvec3());
                assert!((p - q).length() < 1e-5, "{r:?} pixel ({u}, {v}): {p} vs {q}");
            }
        }
    }

    #[test]
    fn parses_degrees_and_refuses_others() {
        assert_eq!(Rotation::try_from(270), Ok(Rotation::Cw270));
        assert!(Rotation::try_from(45).unwrap_err().contains("got 45"));
    }

    fn test_image(w: usize, h: usize, stride: usize) -> (Vec<u8>, Vec<u8>) {
        let mut rgb = vec![0xEEu8; stride * h];
        let mut z16 = vec![0xEEu8; (stride * 2 / 3).max(w * 2) * h];
        let zstride = z16.len() / h;
        for v in 0..h {
            for u in 0..w {
                let i = v * stride + u * 3;
                rgb[i..i + 3].copy_from_slice(&[u as u8, v as u8, (u * 7 + v) as u8]);
                let d = (1000 + u * 10 + v) as u16;
                z16[v * zstride + u * 2..v * zstride + u * 2 + 2].copy_from_slice(&d.to_le_bytes());
            }
        }
        (rgb, z16)
    }

    #[test]
    fn copies_land_every_pixel_where_map_pixel_says() {
        // One partial tile of rows, and two whole tiles plus a partial one; widths with none,
        // one and three of depth's 8-value blocks, the last with columns past them.
        for (w, h) in [(7usize, 5usize), (11, 2 * TILE_ROWS + 5), (8, TILE_ROWS), (27, TILE_ROWS + 1)] {
            copies_land_where_map_pixel_says(w, h);
        }
    }

    fn copies_land_where_map_pixel_says(w: usize, h: usize) {
        let stride = w * 3 + 9;
        let (rgb, z16) = test_image(w, h, stride);
        let zstride = z16.len() / h;
        for r in ALL {
            let mut out_rgb = vec![0u8; w * h * 3];
            let mut out_depth = vec![0u16; w * h];
            copy_colour(
                &rgb,
                SourceLayout { width: w, height: h, stride_bytes: stride },
                ColourOrder::Rgb8,
                r,
                &mut out_rgb,
            )
            .unwrap();
            copy_depth(&z16, SourceLayout { width: w, height: h, stride_bytes: zstride }, r, &mut out_depth).unwrap();
            let out_w = if r.swaps_axes() { h } else { w };
            for v in 0..h {
                for u in 0..w {
                    let (ur, vr) = r.map_pixel(u as u32, v as u32, w as u32, h as u32);
                    let i = vr as usize * out_w + ur as usize;
                    assert_eq!(&out_rgb[i * 3..i * 3 + 3], &[u as u8, v as u8, (u * 7 + v) as u8], "{r:?} ({u},{v})");
                    assert_eq!(out_depth[i], (1000 + u * 10 + v) as u16, "{r:?} ({u},{v})");
                }
            }
        }
    }

    #[test]
    fn quarter_turns_put_every_pixel_of_every_channel_order_where_map_pixel_says() {
        // Whole tiles and a partial one; widths leaving 0 to 3 columns past the 4x4 blocks, and
        // one too narrow for any block.
        for (w, h) in [(37usize, 2 * TILE_ROWS + 3), (40, TILE_ROWS), (42, TILE_ROWS), (5, TILE_ROWS)] {
            for order in [ColourOrder::Rgb8, ColourOrder::Bgr8, ColourOrder::Rgba8, ColourOrder::Bgra8] {
                let bpp = order.bytes_per_pixel();
                let stride = w * bpp + 5;
                let src: Vec<u8> = (0..stride * h).map(|i| (i * 131 % 251) as u8).collect();
                for r in [Rotation::Cw90, Rotation::Cw270] {
                    let mut out = vec![0u8; w * h * 3];
                    let layout = SourceLayout { width: w, height: h, stride_bytes: stride };
                    copy_colour(&src, layout, order, r, &mut out).unwrap();
                    let mut portable = vec![0u8; w * h * 3];
                    copy_colour_portable(&src, layout, order, r, &mut portable).unwrap();
                    assert!(out == portable, "{w}x{h} {order:?} {r:?}: SIMD blocks and portable loop differ");
                    for v in 0..h {
                        for u in 0..w {
                            let i = v * stride + u * bpp;
                            let px = &src[i..i + 3];
                            let want =
                                if order.swaps_red_blue() { [px[2], px[1], px[0]] } else { [px[0], px[1], px[2]] };
                            let (ur, vr) = r.map_pixel(u as u32, v as u32, w as u32, h as u32);
                            let at = (vr as usize * h + ur as usize) * 3;
                            assert_eq!(out[at..at + 3], want, "{w}x{h} {order:?} {r:?} ({u},{v})");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn channel_orders_convert_to_rgb() {
        let layout = SourceLayout { width: 2, height: 1, stride_bytes: 8 };
        let mut out = vec![0u8; 6];
        copy_colour(&[3, 2, 1, 255, 6, 5, 4, 255], layout, ColourOrder::Bgra8, Rotation::None, &mut out).unwrap();
        assert_eq!(out, [1, 2, 3, 4, 5, 6]);
        // Turned a quarter (the tiled path): the row becomes a column, top to bottom.
        copy_colour(&[3, 2, 1, 255, 6, 5, 4, 255], layout, ColourOrder::Bgra8, Rotation::Cw90, &mut out).unwrap();
        assert_eq!(out, [1, 2, 3, 4, 5, 6]);
        copy_colour(&[3, 2, 1, 255, 6, 5, 4, 255], layout, ColourOrder::Bgra8, Rotation::Cw270, &mut out).unwrap();
        assert_eq!(out, [4, 5, 6, 1, 2, 3]);
        let layout = SourceLayout { width: 2, height: 1, stride_bytes: 6 };
        copy_colour(&[3, 2, 1, 6, 5, 4], layout, ColourOrder::Bgr8, Rotation::Cw180, &mut out).unwrap();
        assert_eq!(out, [4, 5, 6, 1, 2, 3]);
    }

    #[test]
    fn values_turned_in_memory_land_where_map_pixel_says() {
        for (w, h) in [(5usize, 3usize), (24, TILE_ROWS), (19, 2 * TILE_ROWS + 7)] {
            let src: Vec<u16> = (0..w * h).map(|i| (i * 40_503 % 65_521) as u16).collect();
            for r in ALL {
                let mut out = vec![0u16; w * h];
                turn_u16(&src, w, h, r, &mut out);
                let out_w = if r.swaps_axes() { h } else { w };
                for v in 0..h {
                    for u in 0..w {
                        let (ur, vr) = r.map_pixel(u as u32, v as u32, w as u32, h as u32);
                        assert_eq!(out[vr as usize * out_w + ur as usize], src[v * w + u], "{w}x{h} {r:?} ({u},{v})");
                    }
                }
            }
        }
    }

    #[test]
    fn short_buffers_are_refused_naming_the_stream() {
        let layout = SourceLayout { width: 4, height: 4, stride_bytes: 8 };
        let mut out = vec![0u16; 16];
        let e = copy_depth(&[0; 30], layout, Rotation::Cw90, &mut out).unwrap_err();
        assert!(e.to_string().starts_with("depth: driver buffer holds 30 bytes"), "{e}");
        let mut out = vec![0u16; 15];
        let e = copy_depth(&[0; 32], layout, Rotation::None, &mut out).unwrap_err();
        assert!(e.to_string().contains("frame buffer holds 15 values"), "{e}");
    }
}
