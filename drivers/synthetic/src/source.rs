//! [`SyntheticSource`]: renders frame `k` of the camera path of a generated room.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::path::CameraPath;
use super::render::Renderer;
use super::scene::Scene;
use super::side_channel::{GroundTruth, InstanceIdChannel};
use super::{DepthNoiseConfig, SyntheticConfig};
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::source::{FrameSource, SourceError, SourceKind, SourceStatus, StampClock};

/// A [`FrameSource`] over a procedural room: RGB, noisy depth, instance ids and exact poses.
#[derive(Debug)]
pub struct SyntheticSource {
    config: SyntheticConfig,
    scene: Scene,
    path: CameraPath,
    renderer: Renderer,
    instance_ids: InstanceIdChannel,
    next: u64,
}

fn check_positive(field: &str, value: f64) -> Result<(), SourceError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SourceError::Config(format!("{field}: expected a positive finite number, found {value}")))
    }
}

fn check_probability(field: &str, value: f32) -> Result<(), SourceError> {
    if (0.0..=1.0).contains(&value) {
        Ok(())
    } else {
        Err(SourceError::Config(format!("{field}: expected a probability in [0, 1], found {value}")))
    }
}

fn check_intrinsics(k: &Intrinsics) -> Result<(), SourceError> {
    if k.width == 0 || k.height == 0 {
        return Err(SourceError::Config(format!("intrinsics: image size {}x{} is empty", k.width, k.height)));
    }
    check_positive("intrinsics.fx", f64::from(k.fx))?;
    check_positive("intrinsics.fy", f64::from(k.fy))?;
    for (field, v) in [("intrinsics.cx", k.cx), ("intrinsics.cy", k.cy)] {
        if !v.is_finite() {
            return Err(SourceError::Config(format!("{field}: expected a finite number, found {v}")));
        }
    }
    Ok(())
}

fn check_noise(n: &DepthNoiseConfig) -> Result<(), SourceError> {
    if !(n.sigma_at_1m_m.is_finite() && n.sigma_at_1m_m >= 0.0) {
        return Err(SourceError::Config(format!(
            "depth_noise.sigma_at_1m_m: expected a non-negative number, found {}",
            n.sigma_at_1m_m
        )));
    }
    if !(n.min_range_m.is_finite() && n.min_range_m >= 0.0) {
        return Err(SourceError::Config(format!(
            "depth_noise.min_range_m: expected a non-negative number, found {}",
            n.min_range_m
        )));
    }
    if !(n.max_range_m.is_finite() && n.max_range_m > n.min_range_m) {
        return Err(SourceError::Config(format!(
            "depth_noise.max_range_m: expected a number above min_range_m ({}), found {}",
            n.min_range_m, n.max_range_m
        )));
    }
    if !(n.edge_jump_ratio.is_finite() && n.edge_jump_ratio > 0.0) {
        return Err(SourceError::Config(format!(
            "depth_noise.edge_jump_ratio: expected a positive number, found {}",
            n.edge_jump_ratio
        )));
    }
    check_probability("depth_noise.edge_hole_probability", n.edge_hole_probability)?;
    check_probability("depth_noise.random_hole_probability", n.random_hole_probability)
}

impl SyntheticSource {
    /// Generates the room and plans the camera path; `Config` errors name the bad field.
    pub fn new(config: &SyntheticConfig) -> Result<Self, SourceError> {
        check_intrinsics(&config.intrinsics)?;
        check_positive("frame_rate_hz", config.frame_rate_hz)?;
        if let Some(noise) = &config.depth_noise {
            check_noise(noise)?;
        }
        let scene = Scene::generate(config.room, config.seed);
        let path = CameraPath::new(&scene, config.seed, config.frame_rate_hz);
        Ok(Self {
            config: config.clone(),
            scene,
            path,
            renderer: Renderer::new(),
            instance_ids: InstanceIdChannel::new(),
            next: 0,
        })
    }

    /// The generated room.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The camera path.
    pub fn path(&self) -> &CameraPath {
        &self.path
    }

    /// The ground truth of what this source renders: the scene and the channel that receives
    /// each delivered frame's instance ids.
    pub fn ground_truth(&self) -> GroundTruth {
        GroundTruth { scene: self.scene.clone(), instance_ids: self.instance_ids.clone() }
    }

    /// Camera pose of frame `k` (the path repeats when the source is endless).
    fn pose_of(&self, k: u64) -> op3dsg_drivers::pose::Isometry {
        let path_k = if self.config.frame_count.is_none() { k % self.path.period_frames() } else { k };
        self.path.pose_at(path_k)
    }

    /// Stamp of frame `k`, nanoseconds.
    fn stamp_of(&self, k: u64) -> u64 {
        (k as f64 * 1e9 / self.config.frame_rate_hz) as u64
    }

    /// Noise generator of frame `k`: depends only on the seed and `k`, so a frame is
    /// reproducible on its own.
    fn noise_rng(&self, k: u64) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(
            self.config.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ k.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ 0xA5A5,
        )
    }
}

impl FrameSource for SyntheticSource {
    fn kind(&self) -> SourceKind {
        SourceKind::Synthetic
    }

    fn intrinsics(&self) -> Intrinsics {
        self.config.intrinsics
    }

    fn has_poses(&self) -> bool {
        true
    }

    fn stamp_clock(&self) -> StampClock {
        StampClock::SceneTime
    }

    fn next_frame(&mut self, frame: &mut Frame) -> Result<SourceStatus, SourceError> {
        if self.config.frame_count.is_some_and(|n| self.next >= n) {
            return Ok(SourceStatus::EndOfStream);
        }
        let k = self.next;
        let pose = self.pose_of(k);
        let mut rng = self.noise_rng(k);
        let noise = self.config.depth_noise.as_ref().map(|n| (n, &mut rng));
        let stamp_ns = self.stamp_of(k);
        let (scene, renderer, intrinsics) = (&self.scene, &mut self.renderer, &self.config.intrinsics);
        self.instance_ids.write(frame, |frame, ids| {
            renderer.render(scene, &pose, intrinsics, noise, frame, Some(ids));
            frame.seq = k;
            frame.stamp_ns = stamp_ns;
        });
        self.next += 1;
        Ok(SourceStatus::Frame)
    }

    fn peek_pose(&mut self, frame: &mut Frame) -> Option<SourceStatus> {
        if self.config.frame_count.is_some_and(|n| self.next >= n) {
            return Some(SourceStatus::EndOfStream);
        }
        let k = self.next;
        frame.seq = k;
        frame.stamp_ns = self.stamp_of(k);
        frame.world_from_camera = Some(self.pose_of(k));
        Some(SourceStatus::Frame)
    }

    fn skip_frame(&mut self) {
        if self.config.frame_count.is_none_or(|n| self.next < n) {
            self.next += 1;
        }
    }

    fn len_hint(&self) -> Option<u64> {
        self.config.frame_count
    }

    fn describe(&self) -> String {
        self.scene.describe()
    }
}
