//! CPU ray caster: one ray per pixel through the pixel centre `(col, row)`.
//!
//! Acceleration: each frame, every primitive's world box is projected into the image and the
//! primitive is binned into the 16x16 tiles its screen rectangle covers, in order of nearest
//! camera depth. A pixel tests only its tile's candidates whose rectangle contains it, and stops
//! as soon as the next candidate cannot be nearer than the current hit. The room (floor, walls,
//! ceiling; instance 0) is intersected analytically as the inside of a box.
//!
//! Shading: ambient + Lambert from a ceiling point light + a weak camera-mounted light, with
//! Blinn-Phong highlights from both, so shiny parts facing the camera go near white.

use glam::{Mat3, Vec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::DepthNoiseConfig;
use super::noise;
use super::scene::{Material, Scene};
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;

const TILE: usize = 16;
const NEAR_M: f32 = 0.01;

/// Reusable scratch for rendering; keeps per-frame work free of image-sized allocations.
#[derive(Debug, Default)]
pub struct Renderer {
    tiles_x: usize,
    tiles_y: usize,
    tile_lists: Vec<Vec<u32>>,
    rects: Vec<[i32; 4]>,
    near: Vec<f32>,
    order: Vec<(f32, u32)>,
    clean_depth: Vec<f32>,
    /// Pixels of the scene's depthless instances ([`Scene::depthless`]).
    hidden: Vec<bool>,
}

impl Renderer {
    /// An empty renderer; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    /// Renders one view into `frame` (RGB, depth in millimetres, pose and intrinsics) and,
    /// when given, the per-pixel instance ids (ground truth, kept out of the frame) into
    /// `instance_ids`; exact depth when `noise` is `None`. The scene's depth controls apply
    /// last: no depth on [`Scene::depthless`] instances' pixels, garbage beyond
    /// [`Scene::unreliable_beyond_m`] (drawn from `noise`'s generator after the noise; without
    /// noise from a generator seeded by the scene's seed).
    pub fn render(
        &mut self,
        scene: &Scene,
        world_from_camera: &Isometry,
        intrinsics: &Intrinsics,
        noise: Option<(&DepthNoiseConfig, &mut ChaCha8Rng)>,
        frame: &mut Frame,
        instance_ids: Option<&mut Vec<u16>>,
    ) {
        self.trace(scene, world_from_camera, intrinsics, frame, instance_ids);
        match noise {
            Some((config, rng)) => self.write_depth(scene, Some(config), rng, frame),
            None => {
                let mut rng = ChaCha8Rng::seed_from_u64(scene.seed ^ 0xFA2D_E97B_0000_0001);
                self.write_depth(scene, None, &mut rng, frame);
            }
        }
    }

    /// Casts every pixel's ray: colour, pose and intrinsics into `frame`, ids into
    /// `instance_ids`, exact depth kept for [`Renderer::write_depth`].
    pub(crate) fn trace(
        &mut self,
        scene: &Scene,
        world_from_camera: &Isometry,
        intrinsics: &Intrinsics,
        frame: &mut Frame,
        mut instance_ids: Option<&mut Vec<u16>>,
    ) {
        let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
        let n = w * h;
        frame.intrinsics = *intrinsics;
        frame.depth_units_per_m = 1000.0;
        frame.world_from_camera = Some(*world_from_camera);
        // Only a frame of another size is resized; the normal path reuses its buffers.
        frame.rgb.resize(n * 3, 0);
        frame.depth.resize(n, 0);
        if let Some(ids) = instance_ids.as_deref_mut() {
            ids.resize(n, 0);
        }
        self.clean_depth.resize(n, 0.0);
        let hide = !scene.depthless.is_empty();
        if hide {
            self.hidden.resize(n, false);
        }
        self.bin(scene, world_from_camera, intrinsics);

        let rot = Mat3::from_quat(world_from_camera.rotation.as_quat());
        let origin = world_from_camera.translation.as_vec3();
        let light = scene.light_m;
        let (fx, fy, cx, cy) = (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy);

        for row in 0..h {
            let b = (row as f32 - cy) / fy;
            let row_dir = rot.y_axis * b + rot.z_axis;
            for col in 0..w {
                let i = row * w + col;
                let a = (col as f32 - cx) / fx;
                let dir = rot.x_axis * a + row_dir;
                let hit = self.cast(scene, origin, dir, col, row);
                if let Some(ids) = instance_ids.as_deref_mut() {
                    ids[i] = hit.instance;
                }
                if hide {
                    self.hidden[i] = scene.depthless.contains(&hit.instance);
                }
                if hit.t.is_finite() {
                    self.clean_depth[i] = hit.t;
                    let colour = shade(hit.material, origin + dir * hit.t, hit.normal, -dir.normalize(), light);
                    frame.rgb[i * 3] = colour[0];
                    frame.rgb[i * 3 + 1] = colour[1];
                    frame.rgb[i * 3 + 2] = colour[2];
                } else {
                    self.clean_depth[i] = 0.0;
                    frame.rgb[i * 3..i * 3 + 3].fill(0);
                }
            }
        }
    }

    /// Writes the depth of the view [`Renderer::trace`] cast into `frame`: exact, or with
    /// `noise` drawn from `rng`; then the change script's depth controls: garbage beyond
    /// [`Scene::unreliable_beyond_m`] (drawn from `rng` after the noise), no depth on the pixels
    /// of [`Scene::depthless`] instances.
    pub(crate) fn write_depth(
        &self,
        scene: &Scene,
        noise: Option<&DepthNoiseConfig>,
        rng: &mut ChaCha8Rng,
        frame: &mut Frame,
    ) {
        let (w, h) = (frame.intrinsics.width as usize, frame.intrinsics.height as usize);
        let depth = &mut frame.depth;
        match noise {
            Some(config) => noise::apply(config, rng, &self.clean_depth, w, h, 1000.0, depth),
            None => {
                for (d, &z) in depth.iter_mut().zip(&self.clean_depth) {
                    *d = if z > 0.0 { noise::quantise(z, 1000.0) } else { 0 };
                }
            }
        }
        if let Some(range_m) = scene.unreliable_beyond_m {
            noise::degrade_beyond(range_m, rng, &self.clean_depth, 1000.0, depth);
        }
        if !scene.depthless.is_empty() {
            for (d, &hidden) in depth.iter_mut().zip(&self.hidden) {
                if hidden {
                    *d = 0;
                }
            }
        }
    }

    /// Casts the ray of pixel `(col, row)` from `origin` along `dir` (world frame): the nearest
    /// of its tile's candidate primitives, else the face of the room it leaves through.
    #[inline]
    fn cast<'s>(&self, scene: &'s Scene, origin: Vec3, dir: Vec3, col: usize, row: usize) -> Hit<'s> {
        let room = scene.size;
        let prims = &scene.primitives;
        let inv = dir.recip();
        // Room box from the inside: the nearest exit face.
        let mut best_t = f32::INFINITY;
        let mut best_axis = 0usize;
        for k in 0..3 {
            let t = if dir[k] > 0.0 {
                (room[k] - origin[k]) * inv[k]
            } else if dir[k] < 0.0 {
                -origin[k] * inv[k]
            } else {
                f32::INFINITY
            };
            if t < best_t {
                best_t = t;
                best_axis = k;
            }
        }
        if !(best_t > 0.0 && best_t.is_finite()) {
            best_t = f32::INFINITY;
        }
        let mut hit: Option<(u32, Vec3)> = None;
        let list = &self.tile_lists[(row / TILE) * self.tiles_x + col / TILE];
        let (ci, ri) = (col as i32, row as i32);
        for &p in list {
            let p = p as usize;
            if self.near[p] >= best_t {
                break;
            }
            let r = self.rects[p];
            if ci < r[0] || ci > r[2] || ri < r[1] || ri > r[3] {
                continue;
            }
            if let Some((t, normal)) = prims[p].shape.intersect(origin, dir, inv, best_t) {
                best_t = t;
                hit = Some((p as u32, normal));
            }
        }
        match hit {
            Some((p, normal)) => {
                let prim = &prims[p as usize];
                Hit { t: best_t, instance: prim.instance, material: &scene.materials[prim.material as usize], normal }
            }
            None => {
                let mut normal = Vec3::ZERO;
                normal[best_axis] = -dir[best_axis].signum();
                let material = match (best_axis, dir[best_axis] > 0.0) {
                    (2, false) => &scene.structure[0],
                    (2, true) => &scene.structure[2],
                    _ => &scene.structure[1],
                };
                Hit { t: best_t, instance: 0, material, normal }
            }
        }
    }

    /// Projects every primitive's box and bins it into the tiles it may cover.
    fn bin(&mut self, scene: &Scene, world_from_camera: &Isometry, intrinsics: &Intrinsics) {
        let (w, h) = (intrinsics.width as i32, intrinsics.height as i32);
        self.tiles_x = (w as usize).div_ceil(TILE);
        self.tiles_y = (h as usize).div_ceil(TILE);
        self.tile_lists.resize_with(self.tiles_x * self.tiles_y, Vec::new);
        for list in &mut self.tile_lists {
            list.clear();
        }
        let prims = &scene.primitives;
        self.rects.resize(prims.len(), [0; 4]);
        self.near.resize(prims.len(), f32::INFINITY);
        self.order.clear();
        let camera_from_world = world_from_camera.inverse().to_mat4();
        for (p, prim) in prims.iter().enumerate() {
            let (min, max) = prim.shape.aabb();
            let mut zmin = f32::INFINITY;
            let mut zmax = f32::NEG_INFINITY;
            let (mut u0, mut v0, mut u1, mut v1) = (f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY);
            let mut behind = false;
            for c in 0..8 {
                let corner = Vec3::new(
                    if c & 1 == 0 { min.x } else { max.x },
                    if c & 2 == 0 { min.y } else { max.y },
                    if c & 4 == 0 { min.z } else { max.z },
                );
                let q = camera_from_world.transform_point3(corner);
                zmin = zmin.min(q.z);
                zmax = zmax.max(q.z);
                if q.z <= NEAR_M {
                    behind = true;
                    continue;
                }
                let u = intrinsics.fx * q.x / q.z + intrinsics.cx;
                let v = intrinsics.fy * q.y / q.z + intrinsics.cy;
                u0 = u0.min(u);
                u1 = u1.max(u);
                v0 = v0.min(v);
                v1 = v1.max(v);
            }
            if zmax <= NEAR_M {
                continue;
            }
            let rect = if behind {
                [0, 0, w - 1, h - 1]
            } else {
                [
                    (u0.floor() as i32 - 1).max(0),
                    (v0.floor() as i32 - 1).max(0),
                    (u1.ceil() as i32 + 1).min(w - 1),
                    (v1.ceil() as i32 + 1).min(h - 1),
                ]
            };
            if rect[0] > rect[2] || rect[1] > rect[3] {
                continue;
            }
            self.rects[p] = rect;
            // The box's nearest camera depth bounds any hit's z-depth from below.
            self.near[p] = zmin.max(0.0);
            self.order.push((self.near[p], p as u32));
        }
        self.order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for &(_, p) in &self.order {
            let r = self.rects[p as usize];
            for ty in (r[1] as usize / TILE)..=(r[3] as usize / TILE) {
                for tx in (r[0] as usize / TILE)..=(r[2] as usize / TILE) {
                    self.tile_lists[ty * self.tiles_x + tx].push(p);
                }
            }
        }
    }
}

/// What a pixel's ray meets first.
struct Hit<'s> {
    /// Distance along the ray, metres (infinite: the ray leaves the room through no face).
    t: f32,
    /// Instance id (0: the room itself).
    instance: u16,
    material: &'s Material,
    /// Surface normal, world frame.
    normal: Vec3,
}

/// Colour of a surface point seen along `to_eye` (unit), lit by `light` and a camera light.
#[inline]
fn shade(m: &Material, point: Vec3, normal: Vec3, to_eye: Vec3, light: Vec3) -> [u8; 3] {
    let to_light = light - point;
    let dist2 = to_light.length_squared();
    let l = to_light * dist2.sqrt().recip();
    let atten = 1.0 / (1.0 + 0.06 * dist2);
    let n_l = normal.dot(l).max(0.0);
    let n_e = normal.dot(to_eye).max(0.0);
    let diffuse = 0.3 + 0.7 * n_l * atten + 0.25 * n_e;
    let mut spec = 0.0;
    if m.specular > 0.0 {
        let half = (l + to_eye).normalize_or_zero();
        let n_h = normal.dot(half).max(0.0);
        if n_l > 0.0 && n_h > 0.5 {
            spec += 0.8 * atten.sqrt() * n_h.powf(m.shininess);
        }
        // Camera light: its half vector is the view direction.
        if n_e > 0.7 {
            spec += 0.9 * n_e.powf(m.shininess);
        }
        spec *= m.specular;
    }
    let lit = diffuse * (1.0 - m.emission) + m.emission;
    let mut out = [0u8; 3];
    for (o, a) in out.iter_mut().zip(m.albedo) {
        *o = ((a * lit + spec) * 255.0).clamp(0.0, 255.0) as u8;
    }
    out
}

/// Renders one view into `frame` (RGB, depth in millimetres with `depth_units_per_m` = 1000)
/// and, when given, `instance_ids`; exact depth when `noise` is `None`. Allocates its scratch;
/// a [`Renderer`] reuses it across frames.
pub fn render(
    scene: &Scene,
    world_from_camera: &Isometry,
    intrinsics: &Intrinsics,
    noise: Option<(&DepthNoiseConfig, &mut ChaCha8Rng)>,
    frame: &mut Frame,
    instance_ids: Option<&mut Vec<u16>>,
) {
    Renderer::new().render(scene, world_from_camera, intrinsics, noise, frame, instance_ids);
}
