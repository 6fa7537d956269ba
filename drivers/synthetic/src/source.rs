//! [`SyntheticSource`]: renders frame `k` of the camera path of a generated room, as the
//! change script ([`crate::change`]) left it by frame `k`.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::change::{self, AppliedChange};
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
    /// `(first frame, scene)` in frame order; the first is the generated room from frame 0.
    epochs: Vec<(u64, Scene)>,
    /// What the change script did.
    applied: Vec<AppliedChange>,
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
    /// Generates the room, plans the camera path (on the generated room) and applies the
    /// change script; `Config` errors name the bad field (`changes[i].<key>: ...` for the
    /// script).
    pub fn new(config: &SyntheticConfig) -> Result<Self, SourceError> {
        check_intrinsics(&config.intrinsics)?;
        check_positive("frame_rate_hz", config.frame_rate_hz)?;
        if let Some(noise) = &config.depth_noise {
            check_noise(noise)?;
        }
        let scene = Scene::generate(config.room, config.seed);
        let path = CameraPath::new(&scene, config.seed, config.frame_rate_hz);
        let script = change::apply(&scene, &config.changes, &path, config.frame_count)?;
        Ok(Self {
            config: config.clone(),
            epochs: script.epochs,
            applied: script.applied,
            path,
            renderer: Renderer::new(),
            instance_ids: InstanceIdChannel::new(),
            next: 0,
        })
    }

    /// The generated room (before any change).
    pub fn scene(&self) -> &Scene {
        &self.epochs[0].1
    }

    /// The room as frame `k` shows it (absolute frame number).
    pub fn scene_at(&self, k: u64) -> &Scene {
        epoch_at(&self.epochs, k)
    }

    /// The room after every change.
    pub fn final_scene(&self) -> &Scene {
        self.epochs.last().map_or(&self.epochs[0].1, |(_, scene)| scene)
    }

    /// The scenes of the change script: `(first frame, scene)` in frame order, the first being
    /// the generated room from frame 0.
    pub fn epochs(&self) -> &[(u64, Scene)] {
        &self.epochs
    }

    /// The camera path.
    pub fn path(&self) -> &CameraPath {
        &self.path
    }

    /// The ground truth of what this source renders: the final scene (after every change),
    /// the channel that receives each delivered frame's instance ids, and with a change script
    /// the scene before it and what each change did.
    pub fn ground_truth(&self) -> GroundTruth {
        let changed = self.epochs.len() > 1;
        GroundTruth {
            scene: self.final_scene().clone(),
            instance_ids: self.instance_ids.clone(),
            initial: changed.then(|| self.scene().clone()),
            changes: self.applied.clone(),
        }
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
        let noise = self.config.depth_noise.as_ref();
        let stamp_ns = self.stamp_of(k);
        let scene = epoch_at(&self.epochs, k);
        let (renderer, intrinsics) = (&mut self.renderer, &self.config.intrinsics);
        self.instance_ids.write(frame, |frame, ids| {
            renderer.trace(scene, &pose, intrinsics, frame, Some(ids));
            // The frame's generator also draws the change script's far-depth garbage without noise.
            renderer.write_depth(scene, noise, &mut rng, frame);
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
        self.scene().describe()
    }
}

/// The scene of the last epoch starting at or before frame `k`.
fn epoch_at(epochs: &[(u64, Scene)], k: u64) -> &Scene {
    let index = epochs.partition_point(|(start, _)| *start <= k).saturating_sub(1);
    &epochs[index].1
}
