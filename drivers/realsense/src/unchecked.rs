//! What the compiler cannot check on the hot path, in one file: the entries into the quarter
//! turns' SIMD kernels and their prefetch hints ([`blocks`], [`depth_blocks`]), and the unchecked
//! writes of the alignment's z-buffer ([`zbuffer`]). With the librealsense FFI
//! (`device/ffi.rs`) this is the only file of the crate that uses `unsafe`; each use says why it
//! holds (`// SAFETY:`), and each function here keeps its own promise: none relies on its caller
//! for memory safety.
//!
//! Why they are not safe code: a kernel compiled for a CPU feature (SSSE3, SSE2) can only be
//! entered from code compiled without it by vouching for the CPU; a prefetch takes a raw pointer;
//! and the z-buffer's bounds checks, one per value or line written, cost the alignment a
//! measurable share: our align alone on the `frame_handling` benchmark's synthetic room (one
//! core, five runs alternating, p50 per frame) took 0.91-0.94 ms to 848x480 colour and
//! 1.00-1.06 ms to 1280x720 (rotate 90) with the checks turned into clamps the compiler could
//! drop, against 0.82-0.90 and 0.92-0.99 ms unchecked (plain checked indexing: 0.94-1.03 against
//! 0.80-0.82 ms, three runs). Here they are tested once per chunk of lines or per rectangle. The
//! kernels read and write through checked slices (16-byte loads and stores as `bytemuck` casts).

#![allow(unsafe_code)] // Kernel entries, prefetch hints and z-buffer writes, each argued where it is.

/// Source rows of one tile of the quarter turns: what `rotate`'s tile loop hands the kernels (the
/// argument types keep its `TILE_ROWS` equal to this).
const TILE_ROWS: usize = 16;

/// The quarter turns of colour in 4x4-pixel blocks with SSSE3 byte shuffles (x86_64 CPUs have
/// had them since 2006, the Stretch 3's NUC among them): four source rows of four pixels are
/// loaded, widened to one 32-bit lane per pixel (the channel order converted by the same
/// shuffle), transposed, and each column narrowed back to 12 bytes; a tile column's four
/// blocks, 16 consecutive destination pixels, go out as three 16-byte stores. The scalar tile
/// loop handles what is left (the last columns, a partial tile of rows, other CPUs).
///
/// `frame_handling` benchmark (848x480 RGB8, warm buffers, one core of the CI-kind VM): rotate
/// 90 0.245 ms against 0.608 ms for the tile loop alone.
pub(crate) mod blocks {
    use super::TILE_ROWS;

    /// The shuffles for one channel order and turn, on a CPU that has SSSE3.
    #[derive(Debug, Clone, Copy)]
    pub(crate) struct Blocks {
        /// Source bytes of pixel `j` into lane `j` (R, G, B, 0).
        widen: [u8; 16],
        /// The four lanes of a column into 12 bytes in destination order (the 90° turn writes
        /// the tile's rows bottom up).
        narrow: [u8; 16],
        cw90: bool,
    }

    impl Blocks {
        /// The shuffles for a 90° (`cw90`) or 270° turn of pixels of `bpp` bytes (3 or 4), red
        /// and blue swapped on the way if `swap_red_blue`; `None` on a CPU without SSSE3.
        pub(crate) fn new(bpp: usize, swap_red_blue: bool, cw90: bool) -> Option<Self> {
            if !supported() {
                return None;
            }
            let channel = |c: usize| if swap_red_blue { 2 - c } else { c };
            let mut widen = [0x80u8; 16];
            for j in 0..4 {
                for c in 0..3 {
                    widen[4 * j + c] = (bpp * j + channel(c)) as u8;
                }
            }
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
        pub(crate) fn turn_tile(
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
            // SAFETY: the kernel is compiled for SSSE3, and `supported()` (the CPU has it) held
            // when `self` was made; it reads and writes through checked slices only.
            unsafe {
                x86::turn_tile(self, rows, bpp, done, (width, height, v0), dst);
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
    mod x86 {
        use std::arch::x86_64::{
            __m128i, _MM_HINT_T0, _mm_or_si128, _mm_prefetch, _mm_setzero_si128, _mm_shuffle_epi8, _mm_slli_si128,
            _mm_srli_si128, _mm_unpackhi_epi32, _mm_unpackhi_epi64, _mm_unpacklo_epi32, _mm_unpacklo_epi64,
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

        /// See [`Blocks::turn_tile`]. Compiled for SSSE3: a caller that is not must know the CPU
        /// has it.
        /// `(width, height, v0)`: the source image's size and the tile's first row.
        #[target_feature(enable = "ssse3")]
        pub(super) fn turn_tile(
            blocks: &Blocks,
            rows: &[&[u8]; TILE_ROWS],
            bpp: usize,
            done: usize,
            (width, height, v0): (usize, usize, usize),
            dst: &mut [u8],
        ) {
            // Loads and stores as casts of 16-byte arrays, from and into checked slices.
            let widen: __m128i = bytemuck::cast(blocks.widen);
            let narrow: __m128i = bytemuck::cast(blocks.narrow);
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
                        _mm_shuffle_epi8(bytemuck::cast(*bytes), widen)
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
                        chunk.copy_from_slice(&bytemuck::cast::<__m128i, [u8; 16]>(x));
                    }
                }
            }
        }
    }
}

/// The quarter turns of 16-bit values in 8x8 blocks with SSE2 (every x86_64 CPU): eight source
/// rows of eight values are loaded and transposed with three rounds of unpacks; a tile's 16
/// rows make each of eight columns one run of 16 consecutive destination values, two 16-byte
/// stores. The tile loop handles the rest (the last columns, a partial tile of rows, other
/// CPUs).
///
/// `frame_handling` benchmark (848x480 Z16, warm buffers, one core, three runs alternating with
/// the value-by-value loop): rotate 90 and 270 0.04-0.06 ms against 0.16-0.18 ms.
pub(crate) mod depth_blocks {
    use super::TILE_ROWS;

    /// One whole tile: source rows `v0..v0 + TILE_ROWS` of a `width x height` image of 16-bit
    /// values, turned clockwise by 90° if `cw90`, else by 270°.
    #[derive(Clone, Copy)]
    pub(crate) struct Tile<'a> {
        pub(crate) rows: &'a [&'a [u8]; TILE_ROWS],
        pub(crate) width: usize,
        pub(crate) height: usize,
        pub(crate) v0: usize,
        pub(crate) cw90: bool,
    }

    /// Turns columns `0..done` of `tile` into `dst` (`height` wide); returns `done`, a multiple
    /// of 8 (0 on other CPUs).
    pub(crate) fn turn_tile(tile: Tile, dst: &mut [u16]) -> usize {
        let Tile { rows, width, height, v0, .. } = tile;
        assert!(rows.iter().all(|r| r.len() >= width * 2) && dst.len() >= width * height);
        assert!(v0 + TILE_ROWS <= height);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the kernel is compiled for SSE2, which every x86_64 CPU has (the target's
        // baseline); it reads and writes through checked slices only.
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
    mod x86 {
        use std::arch::x86_64::{
            __m128i, _mm_unpackhi_epi16, _mm_unpackhi_epi32, _mm_unpackhi_epi64, _mm_unpacklo_epi16,
            _mm_unpacklo_epi32, _mm_unpacklo_epi64,
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
                    bytemuck::cast::<[u8; 16], __m128i>(*bytes)
                };
                let top = transpose(std::array::from_fn(load));
                let bottom = transpose(std::array::from_fn(|k| load(8 + k)));
                for j in 0..8 {
                    let u = u0 + j;
                    // (u, v) -> (h-1-v, u) for 90°, (v, w-1-u) for 270°.
                    let line = if cw90 { u } else { width - 1 - u };
                    let start = line * height + first;
                    let (a, b) = dst[start..start + TILE_ROWS].split_at_mut(8);
                    a.copy_from_slice(&bytemuck::cast::<__m128i, [u16; 8]>(top[j]));
                    b.copy_from_slice(&bytemuck::cast::<__m128i, [u16; 8]>(bottom[j]));
                }
            }
            done
        }
    }
}

/// The alignment's z-buffer writes (`align`'s line plans and rectangles): the nearest depth wins
/// in every value, 0 (nothing yet) counting as farthest: `min(out - 1, z1) + 1` in wrapping
/// `u16` arithmetic. Each function tests its indices against `out` once, for a whole chunk of
/// lines or a whole rectangle, then writes without a test per value; indices outside (which
/// `align` never makes) write nothing, and a debug build stops on them.
pub(crate) mod zbuffer {
    /// Values per line: up to 4 colour pixels along colour y, one 8-byte load and store.
    pub(crate) const LANES: usize = 4;

    /// Writes the lines of `n` depth pixels: for pixel `i` with depths `lanes(i)`, the [`LANES`]
    /// values from `line[i]` of every line of `lines` keep the nearer of theirs and those (a lane
    /// of `u16::MAX` keeps its value: `min(out - 1, MAX) + 1 = out`). Vectorised by the compiler.
    ///
    /// Every line start in `lines` (the `n` used and the rest) must lie in
    /// `0..=out.len() - LANES`, as `align` plans them for one output; it is tested once for all of
    /// them, one vectorised pass over the whole table, and if one does not, nothing is written.
    #[inline(always)]
    pub(crate) fn nearest_lines<const L: usize, const N: usize>(
        out: &mut [u16],
        lines: &[[i32; N]; L],
        n: usize,
        lanes: impl Fn(usize) -> Option<[u16; LANES]>,
    ) {
        let n = n.min(N);
        let Some(last_low) = out.len().checked_sub(LANES) else { return };
        // The greatest start (a negative one beyond any, as u32): one maximum over the table,
        // cheaper than a test per line.
        let greatest = lines.as_flattened().iter().fold(0u32, |m, &low| m.max(low as u32));
        let outside = greatest as usize > last_low;
        debug_assert!(!outside, "a planned line outside the {} aligned depth values", out.len());
        if outside {
            return;
        }
        for i in 0..n {
            let Some(z) = lanes(i) else { continue };
            for line in lines {
                let low = line[i] as usize;
                // SAFETY: `0 <= low <= out.len() - LANES`, tested above for every start in
                // `lines`.
                let cells = unsafe { out.get_unchecked_mut(low..low + LANES) };
                for (cell, z) in cells.iter_mut().zip(z) {
                    *cell = cell.wrapping_sub(1).min(z).wrapping_add(1);
                }
            }
        }
    }

    /// Writes depth `z1 + 1` into the values `origin + x * step_x + y * step_y` of `out` for `x`
    /// in `xa..=xb` and `y` in `ya..=yb`, the nearest winning, with a loop sized to the rectangle.
    ///
    /// Every value must lie in `out`, as `align` places them; it is tested once, at the
    /// rectangle's four corners (the index is linear in `x` and `y`, so the corners hold its
    /// least and greatest values), and if one does not, nothing is written.
    #[inline(always)]
    pub(crate) fn nearest_rectangle(
        out: &mut [u16],
        [origin, step_x, step_y]: [isize; 3],
        z1: u16,
        [xa, ya, xb, yb]: [i32; 4],
    ) {
        if xa > xb || ya > yb {
            return;
        }
        let at = |x: i32, y: i32| origin + x as isize * step_x + y as isize * step_y;
        let corners = [at(xa, ya), at(xb, ya), at(xa, yb), at(xb, yb)];
        let inside = corners.iter().all(|&c| c >= 0 && (c as usize) < out.len());
        debug_assert!(inside, "aligned depth indices {corners:?} outside {} values", out.len());
        if !inside {
            return;
        }
        let mut row_at = corners[0];
        for _ in ya..=yb {
            let mut at = row_at;
            for _ in xa..=xb {
                // SAFETY: `0 <= at < out.len()`: a value of the rectangle, whose corners were
                // tested above.
                let cell = unsafe { out.get_unchecked_mut(at as usize) };
                *cell = cell.wrapping_sub(1).min(z1) + 1;
                at += step_x;
            }
            row_at += step_y;
        }
    }
}
