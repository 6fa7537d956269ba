//! The SIMD blocks of the quarter turns on x86_64: colour in 4x4-pixel blocks with SSSE3
//! shuffles (where the CPU has it, checked at run time), 16-bit depth in 8x8 blocks with SSE2
//! (every x86_64 CPU). [`super`]'s tile loop does what they leave and runs alone elsewhere.
//!
//! With the librealsense FFI (`device/ffi.rs`) this is the only file of the crate that uses
//! `unsafe`: the entry into each kernel (compiled for its CPU feature, which a caller compiled
//! without it must vouch for), the prefetch hints, and the 16-byte loads and stores, each from or
//! into a checked slice or array of 16 bytes.

#![allow(unsafe_code)] // Kernel entries, prefetch hints, loads and stores, each argued where it is.

/// The quarter turns of colour in 4x4-pixel blocks with SSSE3 byte shuffles (x86_64 CPUs have
/// had them since 2006, the Stretch 3's NUC among them): four source rows of four pixels are
/// loaded, widened to one 32-bit lane per pixel (the channel order converted by the same
/// shuffle), transposed, and each column narrowed back to 12 bytes; a tile column's four
/// blocks, 16 consecutive destination pixels, go out as three 16-byte stores. The scalar tile
/// loop handles what is left (the last columns, a partial tile of rows, other CPUs).
///
/// `frame_handling` benchmark (848x480 RGB8, warm buffers, one core of the CI-kind VM): rotate
/// 90 0.245 ms against 0.608 ms for the tile loop alone.
pub(super) mod blocks {
    use crate::rotate::{ColourOrder, Rotation, TILE_ROWS};

    /// The shuffles for one channel order and turn, on a CPU that has SSSE3.
    #[derive(Debug, Clone, Copy)]
    pub(in crate::rotate) struct Blocks {
        /// Source bytes of pixel `j` into lane `j` (R, G, B, 0).
        widen: [u8; 16],
        /// The four lanes of a column into 12 bytes in destination order (the 90° turn writes
        /// the tile's rows bottom up).
        narrow: [u8; 16],
        cw90: bool,
    }

    impl Blocks {
        /// `None` unless the turn is 90° or 270° on a CPU with SSSE3.
        pub(in crate::rotate) fn new(order: ColourOrder, rotation: Rotation) -> Option<Self> {
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
        pub(in crate::rotate) fn turn_tile(
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
            // when `self` was made.
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

        /// See [`Blocks::turn_tile`]. Compiled for SSSE3: a caller that is not must know the CPU
        /// has it.
        #[target_feature(enable = "ssse3")]
        #[allow(clippy::too_many_arguments)]
        pub(super) fn turn_tile(
            blocks: &Blocks,
            rows: &[&[u8]; TILE_ROWS],
            bpp: usize,
            done: usize,
            width: usize,
            height: usize,
            v0: usize,
            dst: &mut [u8],
        ) {
            // SAFETY: 16-byte loads from arrays of 16 bytes (no alignment needed).
            let widen = unsafe { _mm_loadu_si128(blocks.widen.as_ptr().cast()) };
            // SAFETY: as above.
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
                        // SAFETY: a 16-byte load from a 16-byte array (no alignment needed).
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
                        // SAFETY: `chunk` holds 16 bytes (no alignment needed).
                        unsafe { _mm_storeu_si128(chunk.as_mut_ptr().cast(), x) };
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
pub(super) mod depth_blocks {
    use crate::rotate::TILE_ROWS;

    /// One whole tile: source rows `v0..v0 + TILE_ROWS` of a `width x height` image of 16-bit
    /// values, turned clockwise by 90° if `cw90`, else by 270°.
    #[derive(Clone, Copy)]
    pub(in crate::rotate) struct Tile<'a> {
        pub(in crate::rotate) rows: &'a [&'a [u8]; TILE_ROWS],
        pub(in crate::rotate) width: usize,
        pub(in crate::rotate) height: usize,
        pub(in crate::rotate) v0: usize,
        pub(in crate::rotate) cw90: bool,
    }

    /// Turns columns `0..done` of `tile` into `dst` (`height` wide); returns `done`, a multiple
    /// of 8 (0 on other CPUs).
    pub(in crate::rotate) fn turn_tile(tile: Tile, dst: &mut [u16]) -> usize {
        let Tile { rows, width, height, v0, .. } = tile;
        assert!(rows.iter().all(|r| r.len() >= width * 2) && dst.len() >= width * height);
        assert!(v0 + TILE_ROWS <= height);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the kernel is compiled for SSE2, which every x86_64 CPU has (the target's
        // baseline).
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
