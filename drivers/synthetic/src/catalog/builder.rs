//! The layout tools: a wall's local frame ([`Wall`]: `s` along the wall, `t` into the room, `z`
//! up) and the [`Builder`] that accumulates instances, primitives and edges, refuses overlapping
//! furniture, and finishes into a [`Scene`].

use glam::Vec3;
use rand::Rng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::materials::HANDLE_METALS;
use crate::scene::{Axis, CEILING_HEIGHT_M, GtEdge, Material, Primitive, Scene, Shape};
use crate::truth::{self, Deviation, PartTruth, SceneDeviation};
use crate::{InstanceInfo, InstanceKind, RoomKind};

/// A wall's local frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct Wall {
    origin: Vec3,
    along: Vec3,
    inward: Vec3,
    /// Length along the wall, metres.
    pub(super) len: f32,
}

impl Wall {
    /// World point of the local `(s, t, z)`.
    pub(super) fn point(&self, s: f32, t: f32, z: f32) -> Vec3 {
        self.origin + self.along * s + self.inward * t + Vec3::Z * z
    }

    /// World box of the local box `[s0, s1] x [t0, t1] x [z0, z1]`.
    pub(super) fn cuboid(&self, s: [f32; 2], t: [f32; 2], z: [f32; 2]) -> Shape {
        let a = self.point(s[0], t[0], z[0]);
        let b = self.point(s[1], t[1], z[1]);
        Shape::Cuboid { min: a.min(b), max: a.max(b) }
    }

    /// A cylinder sticking out of a front face at `t_front` towards the room.
    pub(super) fn knob(&self, s: f32, t_front: f32, z: f32, radius: f32, length: f32) -> Shape {
        let axis = if self.inward.x.abs() > 0.5 { Axis::X } else { Axis::Y };
        Shape::Cylinder { axis, centre: self.point(s, t_front + length * 0.5, z), radius, half_length: length * 0.5 }
    }

    /// A vertical cylinder.
    pub(super) fn post(&self, s: f32, t: f32, z: [f32; 2], radius: f32) -> Shape {
        Shape::Cylinder {
            axis: Axis::Z,
            centre: self.point(s, t, (z[0] + z[1]) * 0.5),
            radius,
            half_length: (z[1] - z[0]) * 0.5,
        }
    }
}

/// Accumulates instances, primitives and edges.
pub(super) struct Builder {
    pub(super) rng: ChaCha8Rng,
    /// The stream the [`truth::DEVIATIONS`] are drawn from (its own, so that drawing one does
    /// not change the rest of the layout).
    deviation_rng: ChaCha8Rng,
    deviations: Vec<SceneDeviation>,
    /// Room box size (width, depth, ceiling height), metres.
    pub(super) size: Vec3,
    instances: Vec<InstanceInfo>,
    /// Affordances per instance (index = id - 1).
    pub(super) affordances: Vec<Vec<&'static str>>,
    edges: Vec<GtEdge>,
    primitives: Vec<Primitive>,
    materials: Vec<Material>,
    /// Boxes of placed furniture (for overlap refusal).
    occupied: Vec<(Vec3, Vec3)>,
}

impl Builder {
    /// An empty room of `size` whose layout draws from `rng` and whose deviations from the
    /// usual ground truth from `deviation_rng`.
    pub(super) fn new(rng: ChaCha8Rng, deviation_rng: ChaCha8Rng, size: Vec3) -> Self {
        Self {
            rng,
            deviation_rng,
            deviations: Vec::new(),
            size,
            instances: Vec::new(),
            affordances: Vec::new(),
            edges: Vec::new(),
            primitives: Vec::new(),
            materials: Vec::new(),
            occupied: Vec::new(),
        }
    }

    pub(super) fn wall(&self, index: usize) -> Wall {
        let (w, d) = (self.size.x, self.size.y);
        match index % 4 {
            0 => Wall { origin: Vec3::ZERO, along: Vec3::X, inward: Vec3::Y, len: w },
            1 => Wall { origin: Vec3::new(w, 0.0, 0.0), along: Vec3::Y, inward: Vec3::NEG_X, len: d },
            2 => Wall { origin: Vec3::new(w, d, 0.0), along: Vec3::NEG_X, inward: Vec3::NEG_Y, len: w },
            _ => Wall { origin: Vec3::new(0.0, d, 0.0), along: Vec3::NEG_Y, inward: Vec3::X, len: d },
        }
    }

    pub(super) fn material(&mut self, m: Material) -> u16 {
        if let Some(i) = self.materials.iter().position(|x| *x == m) {
            return i as u16;
        }
        self.materials.push(m);
        (self.materials.len() - 1) as u16
    }

    pub(super) fn instance(
        &mut self,
        label: &str,
        kind: InstanceKind,
        parent: Option<u16>,
        synonyms: &[&str],
        material: Material,
        affordances: &[&'static str],
    ) -> u16 {
        let id = (self.instances.len() + 1) as u16;
        self.instances.push(InstanceInfo {
            id,
            label: label.to_owned(),
            kind,
            parent,
            box_min_m: Vec3::splat(f32::INFINITY),
            box_max_m: Vec3::splat(f32::NEG_INFINITY),
            synonyms: synonyms.iter().map(|s| (*s).to_owned()).collect(),
            material: material.name.to_owned(),
        });
        self.affordances.push(affordances.to_vec());
        if let Some(parent) = parent {
            self.spatial(id, parent, "part of");
        }
        id
    }

    pub(super) fn object(&mut self, label: &str, synonyms: &[&str], material: Material) -> u16 {
        self.instance(label, InstanceKind::Object, None, synonyms, material, &[])
    }

    /// A part with the ground truth of its label on its parent ([`truth::PARTS`]; wall plates
    /// without a parent look up `on = ""`) and its functional relation to `target`.
    ///
    /// Panics when the table has no entry for the pair: every part the catalog builds must have
    /// its documented truth (the catalog tests generate every room).
    pub(super) fn part(
        &mut self,
        parent: Option<u16>,
        label: &str,
        material: Material,
        target: u16,
        shapes: &[Shape],
    ) -> u16 {
        let on = parent.map_or(String::new(), |p| self.instances[p as usize - 1].label.clone());
        let truth = truth::part_truth(label, &on)
            .unwrap_or_else(|| panic!("ground truth: no entry for part \"{label}\" on \"{on}\" in truth::PARTS"));
        self.part_as(parent, truth, material, Some(target), shapes)
    }

    /// A part with the given truth (a deviation's); the functional edge goes to `target` when the
    /// truth has a relation and a target is given.
    pub(super) fn part_as(
        &mut self,
        parent: Option<u16>,
        truth: &PartTruth,
        material: Material,
        target: Option<u16>,
        shapes: &[Shape],
    ) -> u16 {
        let id = self.instance(truth.part, InstanceKind::Part, parent, &[], material, truth.affordances);
        if let (Some(relation), Some(target)) = (truth.relation, target) {
            self.functional(id, target, relation);
        }
        for shape in shapes {
            self.add(id, *shape, material);
        }
        id
    }

    /// Gives object `id` the truth of an object that acts on another ([`truth::OBJECTS`]) and
    /// its functional relation to `target`.
    pub(super) fn acts_on(&mut self, id: u16, target: u16) {
        let label = self.instances[id as usize - 1].label.clone();
        let truth = truth::object_truth(&label)
            .unwrap_or_else(|| panic!("ground truth: no entry for object \"{label}\" in truth::OBJECTS"));
        self.affordances[id as usize - 1] = truth.affordances.to_vec();
        self.functional(id, target, truth.relation);
    }

    /// Whether this occasion of `deviation` happens (drawn from the deviation stream).
    pub(super) fn deviates(&mut self, deviation: &Deviation) -> bool {
        self.deviation_rng.random_bool(deviation.probability)
    }

    /// Records that `deviation` concerns instance `id`.
    pub(super) fn record(&mut self, deviation: &Deviation, id: u16) {
        self.deviations.push(SceneDeviation { name: deviation.name, instance: id });
    }

    pub(super) fn add(&mut self, id: u16, shape: Shape, material: Material) {
        let material = self.material(material);
        self.primitives.push(Primitive { shape, instance: id, material });
    }

    pub(super) fn spatial(&mut self, source: u16, target: u16, relation: &'static str) {
        self.edges.push(GtEdge { source, target, kind: "spatial", relation });
    }

    pub(super) fn functional(&mut self, source: u16, target: u16, relation: &'static str) {
        self.edges.push(GtEdge { source, target, kind: "functional", relation });
    }

    /// Whether `shape`'s box is inside the room and overlaps no placed furniture.
    pub(super) fn fits(&self, shape: &Shape) -> bool {
        let (min, max) = shape.aabb();
        let tol = 1e-3;
        if min.cmplt(Vec3::splat(-tol)).any() || max.cmpgt(self.size + tol).any() {
            return false;
        }
        !self.occupied.iter().any(|(a, b)| overlaps(min, max, *a, *b, tol))
    }

    /// Reserves a furniture volume.
    pub(super) fn claim(&mut self, shape: &Shape) {
        self.occupied.push(shape.aabb());
    }

    pub(super) fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.rng.random_range(0..items.len())]
    }

    /// Two distinct handle metals.
    pub(super) fn two_metals(&mut self) -> [Material; 2] {
        let mut metals = HANDLE_METALS;
        metals.shuffle(&mut self.rng);
        [metals[0], metals[1]]
    }

    /// The scene: each instance's box from its primitives, and `next to` between floor-standing
    /// objects whose footprints (almost) touch.
    pub(super) fn finish(mut self, room: RoomKind, seed: u64, structure: [Material; 3]) -> Scene {
        for prim in &self.primitives {
            let (min, max) = prim.shape.aabb();
            let info = &mut self.instances[prim.instance as usize - 1];
            info.box_min_m = info.box_min_m.min(min);
            info.box_max_m = info.box_max_m.max(max);
        }
        // `next to` between floor-standing objects whose footprints (almost) touch.
        let objects: Vec<&InstanceInfo> = self
            .instances
            .iter()
            .filter(|i| i.kind == InstanceKind::Object && i.box_min_m.z < 0.02 && i.box_max_m.z > 0.3)
            .collect();
        let mut next_to = Vec::new();
        for (k, a) in objects.iter().enumerate() {
            for c in &objects[k + 1..] {
                let gap = (a.box_min_m.max(c.box_min_m) - a.box_max_m.min(c.box_max_m)).truncate();
                let overlap = (a.box_max_m.min(c.box_max_m) - a.box_min_m.max(c.box_min_m)).truncate();
                // Touching or within 10 cm along one axis, overlapping along the other.
                let adjacent = (gap.x <= 0.1 && overlap.y > 0.1) || (gap.y <= 0.1 && overlap.x > 0.1);
                if adjacent {
                    next_to.push((a.id, c.id));
                }
            }
        }
        for (a, c) in next_to {
            self.spatial(a, c, "next to");
        }
        let light_m = Vec3::new(self.size.x * 0.5, self.size.y * 0.5, CEILING_HEIGHT_M - 0.15);
        Scene {
            room,
            seed,
            size: self.size,
            instances: self.instances,
            affordances: self.affordances,
            edges: self.edges,
            primitives: self.primitives,
            materials: self.materials,
            structure,
            light_m,
            deviations: self.deviations,
            removed: Vec::new(),
            depthless: Vec::new(),
            unreliable_beyond_m: None,
        }
    }
}

/// Whether two boxes overlap by more than `tol` along every axis.
fn overlaps(a_min: Vec3, a_max: Vec3, b_min: Vec3, b_max: Vec3, tol: f32) -> bool {
    (a_max.min(b_max) - a_min.max(b_min)).cmpgt(Vec3::splat(tol)).all()
}
