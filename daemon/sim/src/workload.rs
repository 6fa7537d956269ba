//! Reproducible fusion workloads for benchmarks and allocation tests: real keyframes of the
//! synthetic kitchen (renderer with depth noise, oracle detector) and maps of a chosen size.
//!
//! Large maps are built from copies of the kitchen placed side by side on a grid 20 m apart (the
//! same keyframes integrated with the pose shifted), so a 20,000-node map has the density of a
//! real building and the measured step still looks at the original kitchen.

use glam::DVec3;
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::NodeKind;
use op3dsg_synthetic::{CameraPath, DepthNoiseConfig, InstanceIdChannel, Renderer, RoomKind, Scene, look_rotation};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::oracle::{OracleConfig, OracleDetector};
use op3dsg_runtime::fusion::Fusion;
use op3dsg_runtime::perception::{Detection, Detector};

/// One keyframe with its detections.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// The rendered frame.
    pub frame: Frame,
    /// Its `world_from_camera`.
    pub pose: Isometry,
    /// What the oracle detected in it.
    pub detections: Vec<Detection>,
}

/// Keyframes along the kitchen's camera path.
#[derive(Debug, Clone)]
pub struct Workload {
    /// The keyframes, in path order.
    pub keyframes: Vec<Keyframe>,
}

impl Workload {
    /// `count` keyframes of kitchen `seed`, every `spacing` frames of the 30 Hz path, detected
    /// with `oracle`.
    pub fn kitchen(seed: u64, count: usize, spacing: u64, oracle: OracleConfig) -> Self {
        let mut camera = Camera::new(seed, oracle);
        let path = CameraPath::new(&camera.scene, seed, 30.0);
        let keyframes = (0..count as u64).map(|i| camera.shoot(path.pose_at(i * spacing), i * spacing)).collect();
        Self { keyframes }
    }

    /// The benchmarks' fusion step: the busiest wide view of kitchen `seed` ([`Workload::overview`])
    /// detected with the realistic preset's mask, label and score noise but no misses or false
    /// positives (so that `detections` of them fit in one 640x480 view).
    pub fn busy_step(seed: u64, detections: usize) -> Keyframe {
        let dense = OracleConfig {
            object_miss_rate: 0.0,
            part_miss_rate: 0.0,
            small_miss_boost: 0.0,
            far_miss_boost: 0.0,
            false_positives_per_frame: 0.0,
            ..OracleConfig::realistic()
        };
        Workload { keyframes: vec![Workload::overview(seed, dense)] }.step(detections)
    }

    /// A wide view of kitchen `seed`: from whichever upper corner of the room (1.8 m high, looking
    /// at the room's centre, 25° down) the `oracle` detects most instances. A busy keyframe for
    /// the benchmark's step.
    pub fn overview(seed: u64, oracle: OracleConfig) -> Keyframe {
        let mut camera = Camera::new(seed, oracle);
        let (lo, hi) = camera
            .scene
            .instances()
            .iter()
            .fold((glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), i| {
                (lo.min(i.box_min_m), hi.max(i.box_max_m))
            });
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        let centre = (lo + hi) * 0.5;
        let corners = [(lo.x, lo.y), (lo.x, hi.y), (hi.x, lo.y), (hi.x, hi.y)];
        let views = corners.iter().flat_map(|&c| [(c, 1.8, -25.0), (c, 2.3, -35.0), (c, 1.5, -15.0)]);
        views
            .map(|((x, y), height, tilt_deg): ((f64, f64), f64, f64)| {
                let inset = (centre - DVec3::new(x, y, centre.z)).normalize() * 0.3;
                let position = DVec3::new(x, y, height) + DVec3::new(inset.x, inset.y, 0.0);
                let yaw = (centre.y - position.y).atan2(centre.x - position.x);
                camera.shoot(Isometry::new(look_rotation(yaw, tilt_deg.to_radians()), position), 0)
            })
            .max_by_key(|k| k.detections.len())
            .expect("four corners")
    }

    /// The keyframe with the most detections, cut to at most `n` of them (objects and parts
    /// interleaved so both kinds stay when cutting): the benchmark's step.
    pub fn step(&self, n: usize) -> Keyframe {
        let best = self.keyframes.iter().max_by_key(|k| k.detections.len()).expect("at least one keyframe");
        let (objects, parts): (Vec<_>, Vec<_>) =
            best.detections.iter().cloned().partition(|d| d.kind == NodeKind::Object);
        let mut detections = Vec::with_capacity(n);
        let (mut o, mut p) = (objects.into_iter(), parts.into_iter());
        while detections.len() < n {
            match (o.next(), p.next()) {
                (None, None) => break,
                (a, b) => detections.extend(a.into_iter().chain(b)),
            }
        }
        detections.truncate(n);
        Keyframe { frame: best.frame.clone(), pose: best.pose, detections }
    }

    /// Integrates every keyframe at the original place, then copies of the kitchen 20 m apart
    /// until `fusion` holds at least `target_nodes` nodes (or `max_copies` copies exist).
    pub fn fill_map(&self, fusion: &mut dyn Fusion, target_nodes: usize, max_copies: usize) -> usize {
        self.grow_map(fusion, 0, target_nodes, max_copies)
    }

    /// Like [`Self::fill_map`], but starts at kitchen copy `first_copy` of a map already filled
    /// with the copies before it (the value the previous call returned), so one map can be grown
    /// through several sizes. Returns the next copy to integrate.
    pub fn grow_map(
        &self,
        fusion: &mut dyn Fusion,
        first_copy: usize,
        target_nodes: usize,
        max_copies: usize,
    ) -> usize {
        let mut copy = first_copy;
        loop {
            let offset = copy_offset(copy);
            for kf in &self.keyframes {
                let pose = Isometry::new(glam::DQuat::IDENTITY, offset).compose(&kf.pose);
                fusion.integrate(&kf.frame, &pose, &kf.detections);
                if copy > 0 && fusion.node_count() >= target_nodes {
                    return copy + 1;
                }
            }
            copy += 1;
            if fusion.node_count() >= target_nodes || copy >= max_copies {
                return copy;
            }
        }
    }
}

/// Renders and detects views of one kitchen.
struct Camera {
    scene: Scene,
    intrinsics: Intrinsics,
    noise: DepthNoiseConfig,
    renderer: Renderer,
    rng: ChaCha8Rng,
    instance_ids: InstanceIdChannel,
    detector: OracleDetector,
}

impl Camera {
    fn new(seed: u64, oracle: OracleConfig) -> Self {
        let scene = Scene::generate(RoomKind::Kitchen, seed);
        let instance_ids = InstanceIdChannel::new();
        let detector =
            OracleDetector::new(oracle, scene.instances().to_vec(), 0).with_instance_ids(instance_ids.clone());
        Self {
            scene,
            intrinsics: Intrinsics::d435i_640x480(),
            noise: DepthNoiseConfig::default(),
            renderer: Renderer::new(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            instance_ids,
            detector,
        }
    }

    /// Frame `seq` (30 Hz stamps) rendered at `pose`, with the oracle's detections.
    fn shoot(&mut self, pose: Isometry, seq: u64) -> Keyframe {
        let mut frame = Frame::new(self.intrinsics);
        let (scene, renderer, intrinsics) = (&self.scene, &mut self.renderer, &self.intrinsics);
        let noise = Some((&self.noise, &mut self.rng));
        self.instance_ids.write(&mut frame, |frame, ids| {
            renderer.render(scene, &pose, intrinsics, noise, frame, Some(ids));
            frame.seq = seq;
            frame.stamp_ns = seq * 33_333_333;
        });
        let mut detections = Vec::new();
        // The oracle only fails on frames the channel has no instance ids for; these have them.
        let _ = self.detector.detect(&frame, &mut detections);
        Keyframe { frame, pose, detections }
    }
}

/// Offset of kitchen copy `i`: 0 for the original, then a spiral-free 64-wide grid at 20 m.
fn copy_offset(i: usize) -> DVec3 {
    if i == 0 {
        return DVec3::ZERO;
    }
    let (x, y) = (i % 64, i / 64 + 1);
    DVec3::new(20.0 * x as f64, 20.0 * y as f64, 0.0)
}
