//! Depth aligned to colour from the streams' calibration (`source.realsense.align = "op3dsg"`):
//! the same result as librealsense's align block, computed with rays made once at start.
//!
//! For each depth pixel `(x, y)` with a reading, the two corners of its footprint,
//! `(x - 0.5, y - 0.5)` and `(x + 0.5, y + 0.5)`, are deprojected with the depth stream's
//! intrinsics at the pixel's depth, moved into the colour camera by the depth → colour
//! extrinsics and projected with the colour intrinsics. Each corner lands on colour pixel
//! `round(p + 0.5)` (ties to even), as in librealsense's align. Every colour pixel of the
//! rectangle between the two corners gets the depth pixel's raw value, the nearest (smallest
//! non-zero) value winning where several land (a z-buffer: a near object hides what is behind
//! it). Colour pixels that no depth pixel reaches stay 0 (no depth), as do those whose depth
//! pixel had none. The value written is the depth sensor's own reading (its `z`, in depth
//! units), not the distance along the colour camera's axis: librealsense does the same.
//!
//! When the depth stream has at least as many pixels per degree as the colour stream (in both
//! directions, fields of view as `rs2_fov` computes them), only the top-left corner is mapped and
//! each depth pixel fills that one colour pixel, again as librealsense decides; the Stretch's
//! 848x480 depth to 1280x720 colour maps rectangles.
//!
//! **What is precomputed** ([`DepthToColour::new`], once per stream start): the ray through
//! each corner, undistorted and rotated into the colour camera (`R * (x_n, y_n, 1)`; for a
//! rectilinear depth lens as a table per corner column plus one per corner row, a few KiB), so
//! a frame costs per corner a few multiply-adds, the division and the projection, vectorised
//! over chunks of 128 depth pixels before the z-buffer writes. No buffer is allocated
//! per frame: [`DepthToColour::align`] writes into the pooled frame's depth buffer, rotating on the
//! way (align first, then rotate, in one pass: the z-buffer works on the rotated index of the
//! same colour pixel). The per-frame loop is compiled twice, for baseline x86-64 and for AVX2
//! (chosen once at run time from the CPU; no FMA, which would round differently from
//! librealsense). Where the colour stream has at least 1.25 times the depth's pixels per degree
//! (the D435i's 848x480 depth to 848x480 or 1280x720 colour) rectangles are written as fixed
//! blocks, without a branch on each rectangle's size: 3 or 4 lines of 4 values along colour y,
//! planned for 128 depth pixels at a time. Turned 90° or 270° (the Stretch's mount) colour y runs
//! along the output's rows; unturned and 180° frames are aligned turned 90° into a buffer kept
//! from frame to frame and turned the rest of the way. Below that ratio, with a loop sized per
//! pixel.
//!
//! **Lens models**, as librealsense's align block (its SSE build, what the PyPI library and
//! Intel's x86 packages run) applies them: depth rays through the inverse Brown-Conrady formula
//! when the depth stream has that model; projection through the modified Brown-Conrady formula
//! when the colour stream has that model (the tangential terms as `rs2_project_point_to_pixel`
//! writes them; librealsense's SSE align uses the x term for y, so the two differ where those
//! coefficients are not zero); the coefficients of other models are not applied (nor are they
//! by librealsense's align): [`DepthToColour::ignored_coefficients`] says which.
//!
//! ```
//! use op3dsg_realsense::align::{DepthToColour, Extrinsics, Lens};
//! use op3dsg_realsense::rotate::{Rotation, SourceLayout};
//!
//! let lens = Lens::pinhole(4, 2, 2.0, 2.0, 1.5, 0.5);
//! let mut align = DepthToColour::new(lens, lens, Extrinsics::IDENTITY, 0.001).unwrap();
//! let depth: Vec<u8> = [1000u16, 0, 1200, 1300, 900, 950, 0, 1000].iter().flat_map(|d| d.to_le_bytes()).collect();
//! let mut aligned = vec![0u16; 8];
//! align.align(&depth, SourceLayout { width: 4, height: 2, stride_bytes: 8 }, Rotation::None, &mut aligned).unwrap();
//! assert_eq!(aligned, [1000, 0, 1200, 1300, 900, 950, 0, 1000]); // same camera: unchanged
//! ```

mod calibration;
mod chunks;
mod projection;
#[cfg(test)]
mod tests;
mod write;

use self::calibration::check_extrinsics;
pub use self::calibration::{AlignError, Distortion, Extrinsics, Lens};
use self::chunks::align_rows;
use self::projection::{Projection, Rays};
use self::write::{LANES, Placement};
use crate::rotate::{CopyError, Rotation, SourceLayout};

/// Depth pixels handled per pass (projection into stack arrays, then the z-buffer writes).
/// (Timed on the `frame_handling` benchmark's synthetic room, one core, runs alternating: turned
/// 90° about 8 % faster than 64, as fast as 256; unturned the same as 64.)
const CHUNK: usize = 128;
/// Colour pixels per depth pixel (in both directions) from which rectangles are written as
/// fixed blocks ([`LinePlan`](write::LinePlan)). A rectangle spans the projections of a depth
/// pixel's corners, rounded: at 1.25 or more it is 2 or 3 pixels a side, and the fixed block (no
/// branch on its size) wins; nearer 1 most rectangles are 1 or 2 a side and a block would write
/// most cells several times. Measured by the `frame_handling` benchmark (synthetic room, one core), with
/// 3x3 blocks written cell by cell: 848x480 depth to 848x480 colour (1.3 and 1.4 colour pixels
/// per depth pixel) 2.03-2.15 ms with blocks against 2.26-2.36 ms with the sized loop; to
/// 1280x720 colour (1.9 and 2.1) blocks were already the faster.
const BLOCK_RATIO: f32 = 1.25;
/// How each depth pixel is written: one colour pixel ...
const PIXELS: u8 = 0;
/// ... the rectangle between its corners, loop sized per pixel ...
const RECTANGLES: u8 = 1;
/// ... or, with colour y along the output's rows (turned 90° or 270°), as up to 3 or 4 lines of
/// [`LANES`] values, planned for a whole chunk at once ([`LinePlan`](write::LinePlan)). Unturned
/// and 180° frames are aligned turned 90° and turned the rest of the way
/// ([`DepthToColour::align`]).
const LINES_3: u8 = 3;
const LINES_4: u8 = 4;

/// Depth → colour alignment for one pair of streams (made at stream start, used per frame).
#[derive(Debug, Clone)]
pub struct DepthToColour {
    depth: Lens,
    colour: Lens,
    extrinsics: Extrinsics,
    rays: Rays,
    /// Whether each depth pixel fills the rectangle between its corners (else one pixel).
    rectangles: bool,
    /// Whether rectangles are written as fixed blocks, lines of [`LANES`] values (colour pixels
    /// per depth pixel at least [`BLOCK_RATIO`] in both directions) rather than loops sized per
    /// pixel.
    blocks: bool,
    /// Whether rectangles are up to 4 colour pixels wide (at least 2 colour pixels per depth
    /// pixel along x), else 3: turned, blocks are written as that many lines.
    wide: bool,
    projection: Projection,
    distort: bool,
    /// Whether chunks of depth whose corners cannot land on the colour image are passed over
    /// before the projection (always, but for the tests that compare with the full projection).
    skips: bool,
    /// Unturned and 180° frames written as blocks: the aligned depth turned 90°, before it is
    /// turned the rest of the way into the frame (made at the first such frame).
    turned: Scratch,
}

/// A buffer reused from frame to frame (its values are not worth a `Debug` line).
#[derive(Clone, Default)]
struct Scratch(Vec<u16>);

impl std::fmt::Debug for Scratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Scratch({} values)", self.0.len())
    }
}

impl DepthToColour {
    /// Precomputes the rays for `depth` → `colour` with the device's extrinsics and depth scale
    /// (metres per depth unit, librealsense's `depth_units`).
    pub fn new(
        depth: Lens,
        colour: Lens,
        depth_to_colour: Extrinsics,
        metres_per_unit: f32,
    ) -> Result<Self, AlignError> {
        depth.check("depth")?;
        colour.check("colour")?;
        if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
            return Err(AlignError::DepthScale(metres_per_unit));
        }
        check_extrinsics(&depth_to_colour)?;
        let [depth_fov, colour_fov] = [depth.fov_deg(), colour.fov_deg()];
        let depth_per_deg = [depth.width as f32 / depth_fov[0], depth.height as f32 / depth_fov[1]];
        let colour_per_deg = [colour.width as f32 / colour_fov[0], colour.height as f32 / colour_fov[1]];
        // librealsense also maps rectangles for two resolution pairs it names.
        let special = matches!(
            ((depth.width, depth.height), (colour.width, colour.height)),
            ((640, 240), (320, 180)) | ((640, 480), (640, 360))
        );
        let rectangles = depth_per_deg[0] < colour_per_deg[0] || depth_per_deg[1] < colour_per_deg[1] || special;
        let blocks = rectangles
            && colour_per_deg[0] >= BLOCK_RATIO * depth_per_deg[0]
            && colour_per_deg[1] >= BLOCK_RATIO * depth_per_deg[1];
        // Colour pixels per depth pixel along x, where the images meet: the focal lengths' ratio.
        let wide = colour.fx >= 2.0 * depth.fx;
        let distort = colour.model == Distortion::ModifiedBrownConrady && colour.has_coefficients();
        Ok(Self {
            depth,
            colour,
            extrinsics: depth_to_colour,
            rays: Rays::new(&depth, &depth_to_colour),
            rectangles,
            blocks,
            wide,
            projection: Projection {
                metres_per_unit,
                t: depth_to_colour.translation_m,
                fx: colour.fx,
                fy: colour.fy,
                ppx: colour.ppx,
                ppy: colour.ppy,
                coeffs: colour.coeffs,
            },
            distort,
            skips: true,
            turned: Scratch::default(),
        })
    }

    /// The depth stream's lens.
    pub fn depth(&self) -> &Lens {
        &self.depth
    }

    /// The colour stream's lens (the aligned depth has its size).
    pub fn colour(&self) -> &Lens {
        &self.colour
    }

    /// The extrinsics it was made with.
    pub fn extrinsics(&self) -> &Extrinsics {
        &self.extrinsics
    }

    /// Whether each depth pixel fills the rectangle between its corners (`false`: one pixel).
    pub fn maps_rectangles(&self) -> bool {
        self.rectangles
    }

    /// Metres per depth unit.
    pub fn metres_per_unit(&self) -> f32 {
        self.projection.metres_per_unit
    }

    /// Replaces the depth scale (the first frame's own depth units, when the sensor's option
    /// disagreed); ignored unless finite and above 0.
    pub fn set_metres_per_unit(&mut self, metres_per_unit: f32) {
        if metres_per_unit.is_finite() && metres_per_unit > 0.0 {
            self.projection.metres_per_unit = metres_per_unit;
        }
    }

    /// The streams whose lens coefficients are not applied (non-zero, of a model the align does
    /// not use for that stream), for a warning at start.
    pub fn ignored_coefficients(&self) -> Vec<(&'static str, Distortion)> {
        let mut ignored = Vec::new();
        if self.depth.has_coefficients() && self.depth.model != Distortion::InverseBrownConrady {
            ignored.push(("depth", self.depth.model));
        }
        if self.colour.has_coefficients() && self.colour.model != Distortion::ModifiedBrownConrady {
            ignored.push(("colour", self.colour.model));
        }
        ignored
    }

    /// Aligns one Z16 depth image (little-endian `u16` per pixel, rows `layout.stride_bytes`
    /// apart) to the colour stream and writes it, turned by `rotation`, into `out` (the pooled
    /// frame's depth: colour width x height values). Every value of `out` is written (0 where
    /// no depth lands).
    ///
    /// Where rectangles are written as blocks, an unturned or 180° frame is aligned turned 90°
    /// into a buffer kept for the next frame (allocated at the first), then turned into `out`:
    /// the blocks' lines run along colour y ([`LinePlan`](write::LinePlan)).
    pub fn align(
        &mut self,
        depth: &[u8],
        layout: SourceLayout,
        rotation: Rotation,
        out: &mut [u16],
    ) -> Result<(), CopyError> {
        let (dw, dh) = (self.depth.width as usize, self.depth.height as usize);
        let (cw, ch) = (self.colour.width as usize, self.colour.height as usize);
        let SourceLayout { width, height, stride_bytes } = layout;
        let needed = if dh == 0 { 0 } else { stride_bytes * (dh - 1) + dw * 2 };
        if (width, height) != (dw, dh) || stride_bytes < dw * 2 || depth.len() < needed {
            return Err(CopyError::ShortSource {
                stream: "depth",
                got: depth.len(),
                needed: needed.max(dw * dh * 2),
                width: dw,
                height: dh,
                stride: stride_bytes,
            });
        }
        if out.len() != cw * ch {
            return Err(CopyError::Destination {
                stream: "aligned depth",
                got: out.len(),
                needed: cw * ch,
                width: cw,
                height: ch,
            });
        }
        let mode = match (self.rectangles, self.blocks) {
            (false, _) => PIXELS,
            // (A line needs LANES values of the output.)
            (true, true) if out.len() >= LANES => {
                if self.wide {
                    LINES_4
                } else {
                    LINES_3
                }
            }
            (true, _) => RECTANGLES,
        };
        let place = Placement::new(rotation, cw, ch);
        if place.along_x && (mode == LINES_3 || mode == LINES_4) {
            // Lines along colour y: aligned turned 90° (ch wide, cw tall), then turned back 90°
            // (unturned) or on by 90° (180°).
            let mut turned = std::mem::take(&mut self.turned.0);
            turned.clear();
            turned.resize(out.len(), 0);
            self.align_rows(mode, depth, stride_bytes, Placement::new(Rotation::Cw90, cw, ch), &mut turned);
            let rest = if rotation == Rotation::None { Rotation::Cw270 } else { Rotation::Cw90 };
            crate::rotate::turn_u16(&turned, ch, cw, rest, out);
            self.turned.0 = turned;
        } else {
            out.fill(0);
            self.align_rows(mode, depth, stride_bytes, place, out);
        }
        Ok(())
    }

    /// The per-frame loop for `mode`, written into `out` (zeroed) as `place` turns it.
    fn align_rows(&self, mode: u8, depth: &[u8], stride_bytes: usize, place: Placement, out: &mut [u16]) {
        match (self.distort, mode) {
            (false, PIXELS) => align_rows::<false, PIXELS>(self, depth, stride_bytes, place, out),
            (false, RECTANGLES) => align_rows::<false, RECTANGLES>(self, depth, stride_bytes, place, out),
            (false, LINES_3) => align_rows::<false, LINES_3>(self, depth, stride_bytes, place, out),
            (false, _) => align_rows::<false, LINES_4>(self, depth, stride_bytes, place, out),
            (true, PIXELS) => align_rows::<true, PIXELS>(self, depth, stride_bytes, place, out),
            (true, RECTANGLES) => align_rows::<true, RECTANGLES>(self, depth, stride_bytes, place, out),
            (true, LINES_3) => align_rows::<true, LINES_3>(self, depth, stride_bytes, place, out),
            (true, _) => align_rows::<true, LINES_4>(self, depth, stride_bytes, place, out),
        }
    }
}
