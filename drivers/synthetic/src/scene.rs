//! The scene: instances (ground-truth nodes), the primitives that render them, materials, and
//! the ground-truth graph. The room catalog builds scenes ([`Scene::generate`], in `catalog`).
//!
//! Geometry is deliberately simple: axis-aligned boxes and axis-aligned cylinders. Furniture
//! stands against the (axis-aligned) walls, so every face is axis-aligned and the tight world
//! box of an instance is the union of its primitives' boxes.

use glam::Vec3;

use super::{InstanceInfo, InstanceKind, RoomKind};
use op3dsg_drivers::graph_json::{EdgeJson, GraphJson, NodeJson};

/// Ceiling height of every room, metres.
pub const CEILING_HEIGHT_M: f32 = 2.5;

/// A coordinate axis (cylinder axes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    /// World x.
    X,
    /// World y.
    Y,
    /// World z (up).
    Z,
}

impl Axis {
    /// Component index.
    #[inline]
    pub fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }
}

/// The shape of one primitive, world frame, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// An axis-aligned box.
    Cuboid {
        /// Minimum corner.
        min: Vec3,
        /// Maximum corner.
        max: Vec3,
    },
    /// A closed cylinder whose axis is parallel to a world axis.
    Cylinder {
        /// Axis direction.
        axis: Axis,
        /// Centre (midpoint of the axis segment).
        centre: Vec3,
        /// Radius.
        radius: f32,
        /// Half the length along the axis.
        half_length: f32,
    },
}

const RAY_EPS: f32 = 1e-5;

impl Shape {
    /// Tight axis-aligned box.
    pub fn aabb(&self) -> (Vec3, Vec3) {
        match *self {
            Shape::Cuboid { min, max } => (min, max),
            Shape::Cylinder { axis, centre, radius, half_length } => {
                let mut half = Vec3::splat(radius);
                half[axis.index()] = half_length;
                (centre - half, centre + half)
            }
        }
    }

    /// Nearest intersection of the ray `origin + t * dir` with `t` in `(0, t_max)`: the
    /// parameter `t` and the outward unit normal. `inv_dir` is `1 / dir` per component. `dir`
    /// need not be normalised.
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3, inv_dir: Vec3, t_max: f32) -> Option<(f32, Vec3)> {
        match *self {
            Shape::Cuboid { min, max } => {
                let t1 = (min - origin) * inv_dir;
                let t2 = (max - origin) * inv_dir;
                let tmin = t1.min(t2);
                let tmax = t1.max(t2);
                let t_near = tmin.x.max(tmin.y).max(tmin.z);
                let t_far = tmax.x.min(tmax.y).min(tmax.z);
                if t_near > t_far || t_near <= RAY_EPS || t_near >= t_max {
                    return None;
                }
                let normal = if t_near == tmin.x {
                    Vec3::new(-dir.x.signum(), 0.0, 0.0)
                } else if t_near == tmin.y {
                    Vec3::new(0.0, -dir.y.signum(), 0.0)
                } else {
                    Vec3::new(0.0, 0.0, -dir.z.signum())
                };
                Some((t_near, normal))
            }
            Shape::Cylinder { axis, centre, radius, half_length } => {
                let a = axis.index();
                let (i, j) = ((a + 1) % 3, (a + 2) % 3);
                let oi = origin[i] - centre[i];
                let oj = origin[j] - centre[j];
                let (di, dj) = (dir[i], dir[j]);
                let mut best: Option<(f32, Vec3)> = None;
                // Side.
                let qa = di * di + dj * dj;
                if qa > 1e-12 {
                    let qb = oi * di + oj * dj;
                    let qc = oi * oi + oj * oj - radius * radius;
                    let disc = qb * qb - qa * qc;
                    if disc >= 0.0 {
                        let t = (-qb - disc.sqrt()) / qa;
                        if t > RAY_EPS && t < t_max {
                            let along = origin[a] + t * dir[a] - centre[a];
                            if along.abs() <= half_length {
                                let mut n = Vec3::ZERO;
                                n[i] = (oi + t * di) / radius;
                                n[j] = (oj + t * dj) / radius;
                                best = Some((t, n));
                            }
                        }
                    }
                }
                // The cap facing the ray.
                if dir[a].abs() > 1e-12 {
                    let side = -dir[a].signum();
                    let t = (centre[a] + side * half_length - origin[a]) * inv_dir[a];
                    if t > RAY_EPS && t < best.map_or(t_max, |b| b.0) {
                        let pi = oi + t * di;
                        let pj = oj + t * dj;
                        if pi * pi + pj * pj <= radius * radius {
                            let mut n = Vec3::ZERO;
                            n[a] = side;
                            best = Some((t, n));
                        }
                    }
                }
                best
            }
        }
    }

    /// Distance from `p` to the surface of the shape (0 on it), metres.
    pub fn distance_to_surface(&self, p: Vec3) -> f32 {
        match *self {
            Shape::Cuboid { min, max } => {
                let outside = (min - p).max(p - max).max(Vec3::ZERO);
                if outside.length_squared() > 0.0 { outside.length() } else { (p - min).min(max - p).min_element() }
            }
            Shape::Cylinder { axis, centre, radius, half_length } => {
                let a = axis.index();
                let mut radial = p - centre;
                let along = radial[a];
                radial[a] = 0.0;
                let r = radial.length() - radius;
                let h = along.abs() - half_length;
                if r > 0.0 || h > 0.0 { (r.max(0.0).powi(2) + h.max(0.0).powi(2)).sqrt() } else { (-r).min(-h) }
            }
        }
    }
}

/// Surface appearance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Name (`brass`, `brushed steel`, ...).
    pub name: &'static str,
    /// Base colour, linear 0..1.
    pub albedo: [f32; 3],
    /// Specular strength 0..1 (0 = matte).
    pub specular: f32,
    /// Blinn-Phong exponent.
    pub shininess: f32,
    /// Self-illumination 0..1 (light fixtures).
    pub emission: f32,
}

impl Material {
    /// A material.
    pub const fn new(name: &'static str, albedo: [f32; 3], specular: f32, shininess: f32) -> Self {
        Self { name, albedo, specular, shininess, emission: 0.0 }
    }

    /// A self-lit material (lamp shades, ceiling lights).
    pub const fn emissive(name: &'static str, albedo: [f32; 3], emission: f32) -> Self {
        Self { name, albedo, specular: 0.0, shininess: 1.0, emission }
    }
}

/// One renderable primitive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    /// Geometry.
    pub shape: Shape,
    /// Instance it belongs to (never 0: structure is rendered analytically).
    pub instance: u16,
    /// Index into [`Scene::materials`].
    pub material: u16,
}

/// A ground-truth edge.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GtEdge {
    /// Actor / subject instance id.
    pub source: u16,
    /// Acted-on / reference instance id.
    pub target: u16,
    /// `spatial` or `functional`.
    pub kind: &'static str,
    /// Canonical phrase.
    pub relation: &'static str,
}

/// A procedurally generated room with exact ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub(crate) room: RoomKind,
    pub(crate) seed: u64,
    pub(crate) size: Vec3,
    pub(crate) instances: Vec<InstanceInfo>,
    pub(crate) affordances: Vec<Vec<&'static str>>,
    pub(crate) edges: Vec<GtEdge>,
    pub(crate) primitives: Vec<Primitive>,
    pub(crate) materials: Vec<Material>,
    /// Floor, wall, ceiling materials.
    pub(crate) structure: [Material; 3],
    pub(crate) light_m: Vec3,
    pub(crate) deviations: Vec<crate::truth::SceneDeviation>,
    /// Instances removed by the change script (they keep their entry in `instances`, without
    /// primitives).
    pub(crate) removed: Vec<u16>,
    /// Instances whose pixels read no depth (the change script's `hide_depth`).
    pub(crate) depthless: Vec<u16>,
    /// Depth beyond this range is unreliable (the change script's `degrade_depth_beyond_m`).
    pub(crate) unreliable_beyond_m: Option<f32>,
}

impl Scene {
    /// Room type.
    pub fn room(&self) -> RoomKind {
        self.room
    }

    /// Layout seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Objects and parts; `instances()[k - 1].id == k`. Every instance that ever existed in
    /// this scene, including those a change script removed (they keep their last box and have
    /// no primitives: [`Scene::is_present`]) and those it added (new ids after the catalog's).
    pub fn instances(&self) -> &[InstanceInfo] {
        &self.instances
    }

    /// Whether instance `id` exists and has not been removed by a change script.
    pub fn is_present(&self, id: u16) -> bool {
        self.instance(id).is_some() && !self.removed.contains(&id)
    }

    /// The instances that are in the room (not removed), in id order: the ground truth's nodes.
    pub fn present_instances(&self) -> impl Iterator<Item = &InstanceInfo> {
        self.instances.iter().filter(|i| !self.removed.contains(&i.id))
    }

    /// Instances whose pixels read no depth (colour and instance ids unchanged): the change
    /// script's `hide_depth`.
    pub fn depthless(&self) -> &[u16] {
        &self.depthless
    }

    /// Range beyond which the rendered depth is garbage (the change script's
    /// `degrade_depth_beyond_m`); `None`: the normal noise model everywhere.
    pub fn unreliable_beyond_m(&self) -> Option<f32> {
        self.unreliable_beyond_m
    }

    /// The instance with id `id` (1-based).
    pub fn instance(&self, id: u16) -> Option<&InstanceInfo> {
        id.checked_sub(1).and_then(|i| self.instances.get(i as usize))
    }

    /// Canonical affordance names of instance `id` (empty for unknown ids).
    pub fn affordances(&self, id: u16) -> &[&'static str] {
        id.checked_sub(1).and_then(|i| self.affordances.get(i as usize)).map_or(&[], |a| a.as_slice())
    }

    /// Ground-truth edges (instance ids).
    pub fn edges(&self) -> &[GtEdge] {
        &self.edges
    }

    /// Where this room differs from the usual ground truth ([`crate::truth::DEVIATIONS`]), in
    /// the order the catalog drew them.
    pub fn deviations(&self) -> &[crate::truth::SceneDeviation] {
        &self.deviations
    }

    /// Render primitives with their instance ids.
    pub fn primitives(&self) -> &[Primitive] {
        &self.primitives
    }

    /// Materials referenced by [`Primitive::material`].
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Room box, world metres: `(0, 0, 0)` to `(width, depth, ceiling height)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (Vec3::ZERO, self.size)
    }

    /// Position of the ceiling light used for shading.
    pub fn light_position(&self) -> Vec3 {
        self.light_m
    }

    /// Text used as the graph's `source`: `synthetic kitchen seed 1`.
    pub fn describe(&self) -> String {
        format!("synthetic {} seed {}", self.room.as_str(), self.seed)
    }

    /// The ground-truth scene graph: every present instance as a node (id = instance id),
    /// `part of` edges, true object–object spatial relations, and functional relations. Removed
    /// instances and every edge touching them are left out.
    pub fn ground_truth(&self) -> GraphJson {
        let mut graph = GraphJson::new(self.describe());
        for info in self.present_instances() {
            let centre = (info.box_min_m + info.box_max_m) * 0.5;
            graph.nodes.push(NodeJson {
                id: u32::from(info.id),
                label: info.label.clone(),
                kind: match info.kind {
                    InstanceKind::Object => "object".to_owned(),
                    InstanceKind::Part => "part".to_owned(),
                },
                parent: info.parent.map(u32::from),
                centre_m: centre.to_array(),
                box_min_m: info.box_min_m.to_array(),
                box_max_m: info.box_max_m.to_array(),
                obb: None,
                affordances: self.affordances(info.id).iter().map(|a| (*a).to_owned()).collect(),
                affordance_origins: Default::default(),
                confidence: 1.0,
                observation_count: 0,
                seen_keyframes: None,
            });
        }
        for edge in self.edges.iter().filter(|e| self.is_present(e.source) && self.is_present(e.target)) {
            graph.edges.push(EdgeJson {
                source: u32::from(edge.source),
                target: u32::from(edge.target),
                kind: edge.kind.to_owned(),
                relation: edge.relation.to_owned(),
                confidence: 1.0,
                origin: "ground_truth".to_owned(),
            });
        }
        graph
    }

    /// Distance from a world point to the surface of instance `id` (minimum over its
    /// primitives); infinity when it has none.
    pub fn distance_to_instance(&self, id: u16, p: Vec3) -> f32 {
        self.primitives
            .iter()
            .filter(|prim| prim.instance == id)
            .map(|prim| prim.shape.distance_to_surface(p))
            .fold(f32::INFINITY, f32::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_and_cylinder_hits() {
        let b = Shape::Cuboid { min: Vec3::new(1.0, -1.0, -1.0), max: Vec3::new(2.0, 1.0, 1.0) };
        let d = Vec3::new(1.0, 0.0, 0.0);
        let (t, n) = b.intersect(Vec3::ZERO, d, d.recip(), 10.0).unwrap();
        assert!((t - 1.0).abs() < 1e-6 && n == Vec3::NEG_X);
        assert!(b.intersect(Vec3::ZERO, d, d.recip(), 0.5).is_none());
        let c = Shape::Cylinder { axis: Axis::Z, centre: Vec3::new(3.0, 0.0, 0.0), radius: 0.5, half_length: 1.0 };
        let (t, n) = c.intersect(Vec3::ZERO, d, d.recip(), 10.0).unwrap();
        assert!((t - 2.5).abs() < 1e-5 && (n - Vec3::NEG_X).length() < 1e-5);
        let down = Vec3::new(0.0, 0.0, -2.0);
        let (t, n) = c.intersect(Vec3::new(3.1, 0.0, 3.0), down, down.recip(), 10.0).unwrap();
        assert!((t - 1.0).abs() < 1e-5 && n == Vec3::Z);
        assert!(c.distance_to_surface(Vec3::new(3.0, 0.0, 1.0)) < 1e-6);
        assert!((c.distance_to_surface(Vec3::new(4.0, 0.0, 0.0)) - 0.5).abs() < 1e-6);
    }
}
