//! The keyframe gate's hand-over to the live view (`crate::live_view`): the newest keyframe's
//! pose, and the newest frame's colour and depth downscaled, at most at the view's image rate
//! and only while a viewer subscribes to an image. Nothing here waits: the pose is a
//! latest-wins slot, the images a slot the gate fills with `try_lock` (a busy slot is a counted
//! drop), into buffers allocated once.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, TryLockError};
use std::time::{Duration, Instant};

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;

use crate::queue::Latest;

/// A frame's colour (rgb8) and depth (u16, the frame's depth units) at `1/scale` of its size:
/// every `scale`-th pixel of every `scale`-th row (nearest, so depths are never mixed).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LiveImages {
    /// Increases with every fill (0: never filled).
    pub version: u64,
    /// The frame's stamp, nanoseconds.
    pub stamp_ns: u64,
    /// Width and height after downscaling, pixels.
    pub width: u32,
    /// Height after downscaling, pixels.
    pub height: u32,
    /// Depth units per metre (the frame's).
    pub depth_units_per_m: f32,
    /// Row-major rgb8, `width * height * 3` bytes.
    pub rgb: Vec<u8>,
    /// Row-major depth, `width * height` values.
    pub depth: Vec<u16>,
}

impl LiveImages {
    /// Buffers for frames of `width × height` downscaled by `scale`, allocated now.
    pub fn with_capacity(width: u32, height: u32, scale: u32) -> Self {
        let pixels = (width.div_ceil(scale) * height.div_ceil(scale)) as usize;
        Self { rgb: Vec::with_capacity(pixels * 3), depth: Vec::with_capacity(pixels), ..Self::default() }
    }

    /// Fills from `frame`, downscaled by `scale` (≥ 1); no allocation when the buffers were
    /// made for this frame size.
    pub fn fill(&mut self, frame: &Frame, scale: u32) {
        let k = frame.intrinsics;
        let scale = scale.max(1) as usize;
        let (w, h) = (k.width as usize, k.height as usize);
        let (out_w, out_h) = (w.div_ceil(scale), h.div_ceil(scale));
        self.version += 1;
        self.stamp_ns = frame.stamp_ns;
        self.width = out_w as u32;
        self.height = out_h as u32;
        self.depth_units_per_m = frame.depth_units_per_m;
        self.rgb.clear();
        self.depth.clear();
        let has_rgb = frame.rgb.len() >= w * h * 3;
        let has_depth = frame.depth.len() >= w * h;
        for row in (0..h).step_by(scale) {
            for col in (0..w).step_by(scale) {
                let i = row * w + col;
                if has_rgb {
                    self.rgb.extend_from_slice(&frame.rgb[i * 3..i * 3 + 3]);
                }
                if has_depth {
                    self.depth.push(frame.depth[i]);
                }
            }
        }
    }
}

/// The slot both ends share.
#[derive(Debug)]
struct Shared {
    images: Mutex<LiveImages>,
    /// Set by the live view while a viewer subscribes to the colour or depth image.
    wanted: AtomicBool,
    /// Images handed over.
    offered: AtomicU64,
    /// Images not handed over because the view was copying the slot at that moment.
    dropped: AtomicU64,
}

/// The gate's end ([`LiveFeed::offer_keyframe`], [`LiveFeed::offer_frame`]).
#[derive(Debug)]
pub struct LiveFeed {
    camera: Arc<Latest<(u64, Isometry)>>,
    shared: Arc<Shared>,
    scale: u32,
    period: Option<Duration>,
    next: Option<Instant>,
}

/// The live view's end.
#[derive(Debug, Clone)]
pub struct LiveIntake {
    /// The newest keyframe's stamp and `world_from_camera`.
    pub camera: Arc<Latest<(u64, Isometry)>>,
    shared: Arc<Shared>,
}

/// The two ends of the hand-over: images downscaled by `scale`, at most `rate_hz` a second
/// (`None`: no images at all), for frames of `width × height`.
pub fn live_feed(width: u32, height: u32, scale: u32, rate_hz: Option<f64>) -> (LiveFeed, LiveIntake) {
    let camera = Arc::new(Latest::new());
    let images = match rate_hz {
        Some(_) => LiveImages::with_capacity(width, height, scale),
        None => LiveImages::default(),
    };
    let shared = Arc::new(Shared {
        images: Mutex::new(images),
        wanted: AtomicBool::new(false),
        offered: AtomicU64::new(0),
        dropped: AtomicU64::new(0),
    });
    let period = rate_hz.filter(|r| *r > 0.0).map(|r| Duration::from_secs_f64(1.0 / r));
    let feed = LiveFeed { camera: camera.clone(), shared: shared.clone(), scale, period, next: None };
    (feed, LiveIntake { camera, shared })
}

impl LiveFeed {
    /// A keyframe's pose.
    pub fn offer_keyframe(&self, stamp_ns: u64, world_from_camera: &Isometry) {
        self.camera.set((stamp_ns, *world_from_camera));
    }

    /// A frame the gate received: downscaled into the slot when images are on, a viewer wants
    /// them and the rate allows; never waits.
    pub fn offer_frame(&mut self, frame: &Frame) {
        let Some(period) = self.period else { return };
        if !self.shared.wanted.load(Ordering::Relaxed) {
            return;
        }
        let now = Instant::now();
        if self.next.is_some_and(|next| now < next) {
            return;
        }
        self.next = Some(now + period);
        match self.shared.images.try_lock() {
            Ok(mut images) => {
                images.fill(frame, self.scale);
                self.shared.offered.fetch_add(1, Ordering::Relaxed);
            }
            Err(TryLockError::WouldBlock) => {
                self.shared.dropped.fetch_add(1, Ordering::Relaxed);
            }
            Err(TryLockError::Poisoned(poisoned)) => poisoned.into_inner().fill(frame, self.scale),
        }
    }
}

impl LiveIntake {
    /// Says whether a viewer wants images (the gate copies none otherwise).
    pub fn set_images_wanted(&self, wanted: bool) {
        self.shared.wanted.store(wanted, Ordering::Relaxed);
    }

    /// Swaps the slot's images into `out` when they are newer than `out`'s (the buffers trade
    /// places: nothing is allocated); whether they were.
    pub fn take_images(&self, out: &mut LiveImages) -> bool {
        let mut images = self.shared.images.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if images.version <= out.version {
            return false;
        }
        std::mem::swap(&mut *images, out);
        // The slot keeps counting from the newest version.
        images.version = out.version;
        true
    }

    /// Images handed over, and images dropped because the slot was busy.
    pub fn image_counts(&self) -> (u64, u64) {
        (self.shared.offered.load(Ordering::Relaxed), self.shared.dropped.load(Ordering::Relaxed))
    }
}

#[cfg(test)]
mod tests {
    use op3dsg_drivers::frame::Intrinsics;

    use super::*;

    fn frame(width: u32, height: u32) -> Frame {
        let intrinsics = Intrinsics { width, height, fx: 1.0, fy: 1.0, cx: 0.0, cy: 0.0 };
        let mut frame = Frame::new(intrinsics);
        let n = (width * height) as usize;
        frame.rgb = (0..n * 3).map(|i| (i % 251) as u8).collect();
        frame.depth = (0..n).map(|i| i as u16).collect();
        frame.stamp_ns = 42;
        frame
    }

    #[test]
    fn images_are_every_scale_th_pixel_and_swap_without_allocating() {
        let (mut feed, intake) = live_feed(5, 4, 2, Some(1000.0));
        let f = frame(5, 4);
        feed.offer_frame(&f);
        let mut out = LiveImages::with_capacity(5, 4, 2);
        assert!(!intake.take_images(&mut out), "nothing copied while no viewer wants images");
        intake.set_images_wanted(true);
        feed.offer_frame(&f);
        assert!(intake.take_images(&mut out));
        assert_eq!((out.width, out.height, out.stamp_ns), (3, 2, 42));
        assert_eq!(out.depth, [0, 2, 4, 10, 12, 14]);
        assert_eq!(&out.rgb[3..6], &f.rgb[6..9]);
        assert!(!intake.take_images(&mut out), "no newer images");
        std::thread::sleep(Duration::from_millis(2));
        let before = (out.rgb.capacity(), out.depth.capacity());
        feed.offer_frame(&f);
        assert!(intake.take_images(&mut out));
        assert_eq!((out.rgb.capacity(), out.depth.capacity()), before, "buffers trade places");
        assert_eq!(intake.image_counts(), (2, 0));
    }

    #[test]
    fn without_images_only_the_pose_goes() {
        let (mut feed, intake) = live_feed(4, 4, 1, None);
        intake.set_images_wanted(true);
        feed.offer_frame(&frame(4, 4));
        assert!(!intake.take_images(&mut LiveImages::default()));
        feed.offer_keyframe(7, &Isometry::default());
        assert_eq!(intake.camera.get().map(|(stamp, _)| stamp), Some(7));
    }
}
