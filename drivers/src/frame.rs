//! Camera frames, intrinsics and the frame pool.

use crossbeam_channel::{Receiver, Sender, bounded};
use serde::{Deserialize, Serialize};

use crate::pose::Isometry;

/// Pinhole intrinsics of the colour camera (depth is aligned to colour).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
}

impl Intrinsics {
    /// Intel RealSense D435i colour stream at 640x480 (typical factory calibration; the depth
    /// stream is aligned to it).
    pub const fn d435i_640x480() -> Self {
        Self { width: 640, height: 480, fx: 615.0, fy: 615.0, cx: 320.0, cy: 240.0 }
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The camera-frame point (x right, y down, z forward, metres) seen at pixel centre
    /// `(u, v)` at depth `depth_m`.
    #[inline]
    pub fn point_in_camera(&self, u: f32, v: f32, depth_m: f32) -> glam::Vec3 {
        glam::Vec3::new((u - self.cx) / self.fx * depth_m, (v - self.cy) / self.fy * depth_m, depth_m)
    }

    /// Projects a camera-frame point to pixel coordinates; `None` behind the camera.
    #[inline]
    pub fn project(&self, point_in_camera: glam::Vec3) -> Option<(f32, f32)> {
        if point_in_camera.z <= 1e-6 {
            return None;
        }
        Some((
            self.fx * point_in_camera.x / point_in_camera.z + self.cx,
            self.fy * point_in_camera.y / point_in_camera.z + self.cy,
        ))
    }
}

/// One RGB-D frame: colour, aligned depth, and what the source knows besides.
///
/// Buffers are sized once (from the intrinsics) and reused through a [`FramePool`].
#[derive(Debug, Clone)]
pub struct Frame {
    /// Sequence number assigned by the source, increasing by one per delivered frame.
    pub seq: u64,
    /// Sensor timestamp, nanoseconds.
    pub stamp_ns: u64,
    /// Intrinsics of colour (and aligned depth).
    pub intrinsics: Intrinsics,
    /// Row-major RGB8, `width * height * 3` bytes.
    pub rgb: Vec<u8>,
    /// Row-major depth in sensor units, `width * height` values; 0 = no depth.
    pub depth: Vec<u16>,
    /// Depth units per metre (1000 = millimetres).
    pub depth_units_per_m: f32,
    /// `world_from_camera` when the source carries its own pose (synthetic, replay).
    pub world_from_camera: Option<Isometry>,
}

impl Frame {
    /// A zeroed frame with buffers sized for `intrinsics`.
    pub fn new(intrinsics: Intrinsics) -> Self {
        let n = intrinsics.pixel_count();
        Self {
            seq: 0,
            stamp_ns: 0,
            intrinsics,
            rgb: vec![0; n * 3],
            depth: vec![0; n],
            depth_units_per_m: 1000.0,
            world_from_camera: None,
        }
    }

    /// Depth at pixel index `i` in metres (0 = invalid).
    #[inline]
    pub fn depth_m(&self, i: usize) -> f32 {
        self.depth[i] as f32 / self.depth_units_per_m
    }
}

/// A fixed set of frames allocated at start-up and recycled: taking from an empty pool fails
/// instead of allocating, so memory stays flat however the pipeline behaves.
#[derive(Debug, Clone)]
pub struct FramePool {
    free_tx: Sender<Box<Frame>>,
    free_rx: Receiver<Box<Frame>>,
    capacity: usize,
}

impl FramePool {
    /// Allocates `capacity` frames for `intrinsics`.
    pub fn new(capacity: usize, intrinsics: Intrinsics) -> Self {
        let (free_tx, free_rx) = bounded(capacity);
        for _ in 0..capacity {
            // Cannot fail: the channel has exactly `capacity` slots.
            let _ = free_tx.try_send(Box::new(Frame::new(intrinsics)));
        }
        Self { free_tx, free_rx, capacity }
    }

    /// Takes a free frame, or `None` when all are in flight.
    pub fn try_take(&self) -> Option<PooledFrame> {
        self.free_rx.try_recv().ok().map(|frame| PooledFrame { frame: Some(frame), home: self.free_tx.clone() })
    }

    /// Waits up to `timeout` for a free frame.
    pub fn take_timeout(&self, timeout: std::time::Duration) -> Option<PooledFrame> {
        self.free_rx
            .recv_timeout(timeout)
            .ok()
            .map(|frame| PooledFrame { frame: Some(frame), home: self.free_tx.clone() })
    }

    /// Frames currently free.
    pub fn available(&self) -> usize {
        self.free_rx.len()
    }

    /// Frames owned by the pool.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
}

/// A frame on loan from a [`FramePool`]; it returns to the pool when dropped.
#[derive(Debug)]
pub struct PooledFrame {
    frame: Option<Box<Frame>>,
    home: Sender<Box<Frame>>,
}

impl std::ops::Deref for PooledFrame {
    type Target = Frame;
    fn deref(&self) -> &Frame {
        // Invariant: `frame` is `Some` until drop.
        self.frame.as_deref().expect("pooled frame present until drop")
    }
}

impl std::ops::DerefMut for PooledFrame {
    fn deref_mut(&mut self) -> &mut Frame {
        self.frame.as_deref_mut().expect("pooled frame present until drop")
    }
}

impl Drop for PooledFrame {
    fn drop(&mut self) {
        if let Some(frame) = self.frame.take() {
            // The pool may be gone at shutdown; then the frame is simply freed.
            let _ = self.home.try_send(frame);
        }
    }
}

/// `Ok` or `".field: message"` (to be prefixed with the intrinsics' own path).
pub(crate) fn check_intrinsics(k: &Intrinsics) -> Result<(), String> {
    if k.width < 16 || k.height < 16 {
        return Err(format!(": image must be at least 16x16, got {}x{}", k.width, k.height));
    }
    for (name, v) in [("fx", k.fx), ("fy", k.fy)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(format!(".{name}: must be > 0, got {v}"));
        }
    }
    for (name, v) in [("cx", k.cx), ("cy", k.cy)] {
        if !v.is_finite() {
            return Err(format!(".{name}: must be a finite number, got {v}"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pool_recycles_and_refuses_when_empty() {
        let pool = FramePool::new(2, Intrinsics::d435i_640x480());
        let a = pool.try_take().unwrap();
        let _b = pool.try_take().unwrap();
        assert!(pool.try_take().is_none());
        drop(a);
        assert_eq!(pool.available(), 1);
        assert!(pool.try_take().is_some());
    }

    #[test]
    fn back_projection_inverts_projection() {
        let k = Intrinsics::d435i_640x480();
        let p = k.point_in_camera(100.5, 300.5, 2.0);
        let (u, v) = k.project(p).unwrap();
        assert!((u - 100.5).abs() < 1e-4 && (v - 300.5).abs() < 1e-4);
    }
}
