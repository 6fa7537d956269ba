//! Procedural room layouts: which furniture goes where, built from boxes and cylinders, with
//! their parts, materials and ground-truth relations.
//!
//! Furniture stands against the walls. Each wall has a local frame: `s` along the wall, `t`
//! into the room (0 at the wall), `z` up; fronts face the room. Placement refuses anything that
//! would overlap what is already placed ([`Builder::fits`]), so optional furniture is dropped
//! rather than overlapped in small rooms.

use glam::Vec3;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::scene::{Axis, CEILING_HEIGHT_M, GtEdge, Material, Primitive, Scene, Shape};
use super::{InstanceInfo, InstanceKind, RoomKind};

// Materials.
const WOOD_LIGHT: Material = Material::new("light wood", [0.72, 0.55, 0.36], 0.1, 8.0);
const WOOD_DARK: Material = Material::new("dark wood", [0.35, 0.22, 0.12], 0.15, 12.0);
const WHITE_LACQUER: Material = Material::new("white lacquer", [0.88, 0.88, 0.86], 0.3, 30.0);
const GREY_LAMINATE: Material = Material::new("grey laminate", [0.48, 0.5, 0.53], 0.1, 10.0);
const SAGE_PAINT: Material = Material::new("sage green paint", [0.42, 0.56, 0.42], 0.1, 10.0);
const NAVY_PAINT: Material = Material::new("navy paint", [0.16, 0.22, 0.4], 0.15, 12.0);
const STEEL: Material = Material::new("brushed steel", [0.7, 0.72, 0.75], 0.8, 40.0);
const BRASS: Material = Material::new("brass", [0.78, 0.58, 0.2], 0.9, 50.0);
const BLACK_METAL: Material = Material::new("black metal", [0.07, 0.07, 0.08], 0.6, 40.0);
const COPPER: Material = Material::new("copper", [0.72, 0.4, 0.24], 0.85, 45.0);
const CHROME: Material = Material::new("chrome", [0.85, 0.86, 0.9], 1.0, 80.0);
const WHITE_PLASTIC: Material = Material::new("white plastic", [0.94, 0.94, 0.91], 0.3, 20.0);
const BLACK_PLASTIC: Material = Material::new("black plastic", [0.09, 0.09, 0.1], 0.4, 25.0);
const RED_PLASTIC: Material = Material::new("red plastic", [0.8, 0.1, 0.08], 0.5, 30.0);
const CERAMIC: Material = Material::new("white ceramic", [0.95, 0.95, 0.97], 0.6, 60.0);
const DARK_GLASS: Material = Material::new("dark glass", [0.05, 0.06, 0.08], 0.9, 80.0);
const WINDOW_GLASS: Material = Material::new("window glass", [0.55, 0.72, 0.85], 0.7, 60.0);
const MIRROR: Material = Material::new("mirror", [0.72, 0.78, 0.84], 1.0, 100.0);
const BLUE_FABRIC: Material = Material::new("blue fabric", [0.2, 0.3, 0.55], 0.0, 1.0);
const GREY_FABRIC: Material = Material::new("grey fabric", [0.45, 0.45, 0.47], 0.0, 1.0);
const LINEN: Material = Material::new("white linen", [0.9, 0.87, 0.82], 0.0, 1.0);
const RED_ENAMEL: Material = Material::new("red enamel", [0.75, 0.12, 0.1], 0.6, 40.0);
const LIGHT_DIFFUSER: Material = Material::emissive("light diffuser", [1.0, 0.98, 0.92], 0.9);
const LAMP_SHADE: Material = Material::emissive("lamp shade", [0.95, 0.88, 0.7], 0.5);

const FRONTS: [Material; 5] = [WHITE_LACQUER, GREY_LAMINATE, WOOD_LIGHT, SAGE_PAINT, NAVY_PAINT];
const HANDLE_METALS: [Material; 4] = [STEEL, BRASS, BLACK_METAL, COPPER];
const FLOORS: [Material; 3] = [
    Material::new("oak floor", [0.6, 0.45, 0.3], 0.15, 10.0),
    Material::new("grey tile", [0.6, 0.6, 0.62], 0.3, 20.0),
    Material::new("terracotta tile", [0.66, 0.38, 0.26], 0.2, 15.0),
];
const WALLS: [Material; 3] = [
    Material::new("beige paint", [0.85, 0.8, 0.7], 0.0, 1.0),
    Material::new("pale blue paint", [0.72, 0.8, 0.86], 0.0, 1.0),
    Material::new("pale green paint", [0.76, 0.84, 0.74], 0.0, 1.0),
];
const CEILING: Material = Material::new("white ceiling", [0.95, 0.95, 0.95], 0.0, 1.0);

// Saturated, nearly matte plastics for the colour panel. Lit and shaded they keep HSV
// S > 0.5 and a channel maximum well below 229 (V < 0.9), so the colour feature sees them; the
// weak specular keeps the camera-light highlight small.
const PANEL_COLOURS: [Material; 6] = [
    Material::new("red plastic", [0.72, 0.08, 0.07], 0.15, 20.0),
    Material::new("blue plastic", [0.1, 0.22, 0.72], 0.15, 20.0),
    Material::new("green plastic", [0.1, 0.55, 0.16], 0.15, 20.0),
    Material::new("yellow plastic", [0.75, 0.64, 0.06], 0.15, 20.0),
    Material::new("orange plastic", [0.8, 0.38, 0.05], 0.15, 20.0),
    Material::new("purple plastic", [0.45, 0.12, 0.58], 0.15, 20.0),
];
const PANEL_BODY: Material = Material::new("dark grey metal", [0.22, 0.22, 0.24], 0.2, 20.0);

// Canonical functional relations.
const PULL: &str = "pull to open or close";
const WATER: &str = "control the water flow";
const ADJUST: &str = "rotate to adjust the setting or temperature";
const PRESS_START: &str = "press to start and operate";
const SWITCH: &str = "turn on or turn off";
const REMOTE: &str = "remote to control";
const FLUSH: &str = "press to flush";
const POWER: &str = "provide power";
const PUSH_OPEN: &str = "push or press to open";
const FLOW_SETTING: &str = "operate or adjust the flow or setting";
const ROTATE_OPEN: &str = "rotate to open or close";

/// The 11 canonical functional relation phrases.
pub const FUNCTIONAL_RELATIONS: [&str; 11] =
    [PULL, WATER, ADJUST, PRESS_START, SWITCH, REMOTE, FLUSH, POWER, PUSH_OPEN, FLOW_SETTING, ROTATE_OPEN];
/// Spatial relation phrases used in ground truth.
pub const SPATIAL_RELATIONS: [&str; 7] = ["part of", "on", "under", "above", "below", "next to", "inside"];

/// A wall's local frame.
#[derive(Debug, Clone, Copy)]
struct Wall {
    origin: Vec3,
    along: Vec3,
    inward: Vec3,
    len: f32,
}

impl Wall {
    fn point(&self, s: f32, t: f32, z: f32) -> Vec3 {
        self.origin + self.along * s + self.inward * t + Vec3::Z * z
    }

    /// World box of the local box `[s0, s1] x [t0, t1] x [z0, z1]`.
    fn cuboid(&self, s: [f32; 2], t: [f32; 2], z: [f32; 2]) -> Shape {
        let a = self.point(s[0], t[0], z[0]);
        let b = self.point(s[1], t[1], z[1]);
        Shape::Cuboid { min: a.min(b), max: a.max(b) }
    }

    /// A cylinder sticking out of a front face at `t_front` towards the room.
    fn knob(&self, s: f32, t_front: f32, z: f32, radius: f32, length: f32) -> Shape {
        let axis = if self.inward.x.abs() > 0.5 { Axis::X } else { Axis::Y };
        Shape::Cylinder { axis, centre: self.point(s, t_front + length * 0.5, z), radius, half_length: length * 0.5 }
    }

    /// A vertical cylinder.
    fn post(&self, s: f32, t: f32, z: [f32; 2], radius: f32) -> Shape {
        Shape::Cylinder {
            axis: Axis::Z,
            centre: self.point(s, t, (z[0] + z[1]) * 0.5),
            radius,
            half_length: (z[1] - z[0]) * 0.5,
        }
    }
}

/// Accumulates instances, primitives and edges.
struct Builder {
    rng: ChaCha8Rng,
    size: Vec3,
    instances: Vec<InstanceInfo>,
    affordances: Vec<Vec<&'static str>>,
    edges: Vec<GtEdge>,
    primitives: Vec<Primitive>,
    materials: Vec<Material>,
    /// Boxes of placed furniture (for overlap refusal).
    occupied: Vec<(Vec3, Vec3)>,
}

impl Builder {
    fn wall(&self, index: usize) -> Wall {
        let (w, d) = (self.size.x, self.size.y);
        match index % 4 {
            0 => Wall { origin: Vec3::ZERO, along: Vec3::X, inward: Vec3::Y, len: w },
            1 => Wall { origin: Vec3::new(w, 0.0, 0.0), along: Vec3::Y, inward: Vec3::NEG_X, len: d },
            2 => Wall { origin: Vec3::new(w, d, 0.0), along: Vec3::NEG_X, inward: Vec3::NEG_Y, len: w },
            _ => Wall { origin: Vec3::new(0.0, d, 0.0), along: Vec3::NEG_Y, inward: Vec3::X, len: d },
        }
    }

    fn material(&mut self, m: Material) -> u16 {
        if let Some(i) = self.materials.iter().position(|x| *x == m) {
            return i as u16;
        }
        self.materials.push(m);
        (self.materials.len() - 1) as u16
    }

    fn instance(
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

    fn object(&mut self, label: &str, synonyms: &[&str], material: Material) -> u16 {
        self.instance(label, InstanceKind::Object, None, synonyms, material, &[])
    }

    /// A part with its functional relation to `target`.
    #[allow(clippy::too_many_arguments)]
    fn part(
        &mut self,
        parent: Option<u16>,
        label: &str,
        material: Material,
        affordances: &[&'static str],
        target: u16,
        relation: &'static str,
        shapes: &[Shape],
    ) -> u16 {
        let id = self.instance(label, InstanceKind::Part, parent, &[], material, affordances);
        self.functional(id, target, relation);
        for shape in shapes {
            self.add(id, *shape, material);
        }
        id
    }

    fn add(&mut self, id: u16, shape: Shape, material: Material) {
        let material = self.material(material);
        self.primitives.push(Primitive { shape, instance: id, material });
    }

    fn spatial(&mut self, source: u16, target: u16, relation: &'static str) {
        self.edges.push(GtEdge { source, target, kind: "spatial", relation });
    }

    fn functional(&mut self, source: u16, target: u16, relation: &'static str) {
        self.edges.push(GtEdge { source, target, kind: "functional", relation });
    }

    /// Whether `shape`'s box is inside the room and overlaps no placed furniture.
    fn fits(&self, shape: &Shape) -> bool {
        let (min, max) = shape.aabb();
        let tol = 1e-3;
        if min.cmplt(Vec3::splat(-tol)).any() || max.cmpgt(self.size + tol).any() {
            return false;
        }
        !self.occupied.iter().any(|(a, b)| overlaps(min, max, *a, *b, tol))
    }

    /// Reserves a furniture volume.
    fn claim(&mut self, shape: &Shape) {
        self.occupied.push(shape.aabb());
    }

    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.rng.random_range(0..items.len())]
    }

    /// Two distinct handle metals.
    fn two_metals(&mut self) -> [Material; 2] {
        let mut metals = HANDLE_METALS;
        metals.shuffle(&mut self.rng);
        [metals[0], metals[1]]
    }
}

/// Whether two boxes overlap by more than `tol` along every axis.
pub(crate) fn overlaps(a_min: Vec3, a_max: Vec3, b_min: Vec3, b_max: Vec3, tol: f32) -> bool {
    (a_max.min(b_max) - a_min.max(b_min)).cmpgt(Vec3::splat(tol)).all()
}

/// Generates the room.
pub(crate) fn generate(room: RoomKind, seed: u64) -> Scene {
    let room_salt = (room as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ room_salt);
    let (w, d) = match room {
        RoomKind::Kitchen => (rng.random_range(3.6..6.0), rng.random_range(3.2..5.0)),
        RoomKind::Bathroom => (rng.random_range(3.5..4.5), rng.random_range(3.2..4.0)),
        RoomKind::Bedroom => (rng.random_range(3.8..5.5), rng.random_range(3.8..5.0)),
        RoomKind::LivingRoom => (rng.random_range(4.4..6.0), rng.random_range(4.2..5.0)),
        RoomKind::ColourPanel => (rng.random_range(3.0..3.6), rng.random_range(3.0..3.4)),
    };
    let round = |x: f32| (x * 20.0).round() / 20.0;
    let size = Vec3::new(round(w), round(d), CEILING_HEIGHT_M);
    let structure = [FLOORS[rng.random_range(0..3)], WALLS[rng.random_range(0..3)], CEILING];
    let mut b = Builder {
        rng,
        size,
        instances: Vec::new(),
        affordances: Vec::new(),
        edges: Vec::new(),
        primitives: Vec::new(),
        materials: Vec::new(),
        occupied: Vec::new(),
    };
    let base = b.rng.random_range(0..4usize);
    match room {
        RoomKind::Kitchen => kitchen(&mut b, base),
        RoomKind::Bathroom => bathroom(&mut b, base),
        RoomKind::Bedroom => bedroom(&mut b, base),
        RoomKind::LivingRoom => living_room(&mut b, base),
        RoomKind::ColourPanel => colour_panel(&mut b, base),
    }
    finish(b, room, seed, structure)
}

fn finish(mut b: Builder, room: RoomKind, seed: u64, structure: [Material; 3]) -> Scene {
    for prim in &b.primitives {
        let (min, max) = prim.shape.aabb();
        let info = &mut b.instances[prim.instance as usize - 1];
        info.box_min_m = info.box_min_m.min(min);
        info.box_max_m = info.box_max_m.max(max);
    }
    // `next to` between floor-standing objects whose footprints (almost) touch.
    let objects: Vec<&InstanceInfo> = b
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
        b.spatial(a, c, "next to");
    }
    let light_m = Vec3::new(b.size.x * 0.5, b.size.y * 0.5, CEILING_HEIGHT_M - 0.15);
    Scene {
        room,
        seed,
        size: b.size,
        instances: b.instances,
        affordances: b.affordances,
        edges: b.edges,
        primitives: b.primitives,
        materials: b.materials,
        structure,
        light_m,
    }
}

// ---------------------------------------------------------------------------------------------
// Shared furniture.

fn ceiling_light(b: &mut Builder, x: f32, y: f32) -> u16 {
    let id = b.object("ceiling light", &["light", "lamp", "light fixture"], LIGHT_DIFFUSER);
    let shape = Shape::Cylinder {
        axis: Axis::Z,
        centre: Vec3::new(x, y, CEILING_HEIGHT_M - 0.04),
        radius: 0.2,
        half_length: 0.04,
    };
    b.add(id, shape, LIGHT_DIFFUSER);
    id
}

/// A door at `[s0, s0 + 0.9]` on `wall` and light switches to its side (one per light).
fn door_and_switches(b: &mut Builder, wall: Wall, s0: f32, lights: &[u16]) {
    let door_mat = b.pick(&[WOOD_LIGHT, WHITE_LACQUER, WOOD_DARK]);
    let door = b.object("door", &[], door_mat);
    let slab = wall.cuboid([s0, s0 + 0.9], [0.0, 0.04], [0.0, 2.05]);
    b.add(door, slab, door_mat);
    b.claim(&slab);
    let handle_mat = b.pick(&HANDLE_METALS);
    let lever = wall.cuboid([s0 + 0.7, s0 + 0.82], [0.045, 0.075], [1.0, 1.025]);
    let rose = wall.knob(s0 + 0.8, 0.04, 1.0125, 0.025, 0.005);
    b.part(Some(door), "door handle", handle_mat, &["hook_turn"], door, ROTATE_OPEN, &[lever, rose]);
    for (k, light) in lights.iter().enumerate() {
        let s = s0 + 1.05 + 0.1 * k as f32;
        let plate = wall.cuboid([s, s + 0.08], [0.0, 0.012], [1.06, 1.14]);
        b.part(None, "light switch", WHITE_PLASTIC, &["tip_push"], *light, SWITCH, &[plate]);
    }
}

/// A wall outlet centred at `(s, z)` powering `target`.
fn outlet(b: &mut Builder, wall: Wall, s: f32, z: f32, target: u16) -> u16 {
    let plate = wall.cuboid([s - 0.04, s + 0.04], [0.0, 0.012], [z - 0.04, z + 0.04]);
    b.part(None, "power outlet", WHITE_PLASTIC, &["plug_in", "unplug"], target, POWER, &[plate])
}

fn window(b: &mut Builder, wall: Wall, s0: f32, width: f32) {
    let frame_mat = b.pick(&[WHITE_PLASTIC, WOOD_DARK]);
    let win = b.object("window", &[], WINDOW_GLASS);
    let frame = wall.cuboid([s0, s0 + width], [0.0, 0.02], [0.9, 2.0]);
    b.add(win, frame, frame_mat);
    let glass = wall.cuboid([s0 + 0.06, s0 + width - 0.06], [0.02, 0.03], [0.96, 1.94]);
    b.add(win, glass, WINDOW_GLASS);
    let handle = wall.cuboid([s0 + width - 0.05, s0 + width - 0.025], [0.03, 0.06], [1.35, 1.47]);
    let metal = b.pick(&HANDLE_METALS);
    b.part(Some(win), "window handle", metal, &["hook_turn"], win, ROTATE_OPEN, &[handle]);
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Grip {
    Handle,
    Knob,
}

/// A cabinet body with one or two doors and a handle or knob on each.
#[allow(clippy::too_many_arguments)]
fn cabinet(
    b: &mut Builder,
    wall: Wall,
    s0: f32,
    width: f32,
    depth: f32,
    z: [f32; 2],
    front: Material,
    grip: Grip,
    metals: [Material; 2],
    metal_counter: &mut usize,
) -> Option<u16> {
    let body = wall.cuboid([s0, s0 + width], [0.0, depth], z);
    if !b.fits(&body) {
        return None;
    }
    b.claim(&body);
    let id = b.object("cabinet", &["cupboard", "cupboard door"], front);
    b.add(id, body, front);
    let doors = if width >= 0.7 { 2 } else { 1 };
    // Handles sit near the top of low cabinets and near the bottom of wall cabinets.
    let zc = if z[0] > 1.0 { z[0] + 0.11 } else { z[1] - 0.12 };
    for door in 0..doors {
        let s = match (doors, door) {
            (1, _) => s0 + width - 0.06,
            (_, 0) => s0 + width * 0.5 - 0.05,
            _ => s0 + width * 0.5 + 0.05,
        };
        let metal = metals[*metal_counter % 2];
        *metal_counter += 1;
        match grip {
            Grip::Handle => {
                let bar = wall.cuboid([s - 0.01, s + 0.01], [depth, depth + 0.025], [zc - 0.06, zc + 0.06]);
                b.part(Some(id), "cabinet handle", metal, &["hook_pull"], id, PULL, &[bar]);
            }
            Grip::Knob => {
                let knob = wall.knob(s, depth, zc, 0.015, 0.025);
                b.part(Some(id), "cabinet knob", metal, &["rotate", "pinch_pull"], id, ROTATE_OPEN, &[knob]);
            }
        }
    }
    Some(id)
}

/// A stack of drawers (each its own object) with a handle or knob on each.
#[allow(clippy::too_many_arguments)]
fn drawer_stack(
    b: &mut Builder,
    wall: Wall,
    s0: f32,
    width: f32,
    depth: f32,
    height: f32,
    count: usize,
    front: Material,
    grip: Grip,
    metals: [Material; 2],
    metal_counter: &mut usize,
) -> Vec<u16> {
    let whole = wall.cuboid([s0, s0 + width], [0.0, depth], [0.0, height]);
    if !b.fits(&whole) {
        return Vec::new();
    }
    b.claim(&whole);
    let mut ids = Vec::new();
    let step = height / count as f32;
    for k in 0..count {
        let (z0, z1) = (step * k as f32, step * (k + 1) as f32);
        let id = b.object("drawer", &["drawers", "chest of drawers"], front);
        b.add(id, wall.cuboid([s0, s0 + width], [0.0, depth], [z0, z1]), front);
        let sc = s0 + width * 0.5;
        let zc = z1 - step.min(0.3) * 0.35;
        let metal = metals[*metal_counter % 2];
        *metal_counter += 1;
        match grip {
            Grip::Handle => {
                let bar = wall.cuboid([sc - 0.06, sc + 0.06], [depth, depth + 0.025], [zc - 0.01, zc + 0.01]);
                b.part(Some(id), "drawer handle", metal, &["hook_pull"], id, PULL, &[bar]);
            }
            Grip::Knob => {
                let knob = wall.knob(sc, depth, zc, 0.015, 0.025);
                b.part(Some(id), "drawer knob", metal, &["pinch_pull"], id, PULL, &[knob]);
            }
        }
        ids.push(id);
    }
    ids
}

/// A sink slab with a faucet on top of a cabinet.
fn sink_with_faucet(b: &mut Builder, wall: Wall, s0: f32, width: f32, depth: f32, top: f32, under: u16) -> u16 {
    let sink = b.object("sink", &["basin", "washbasin"], STEEL);
    let slab = wall.cuboid([s0 + 0.05, s0 + width - 0.05], [0.04, depth - 0.04], [top, top + 0.04]);
    b.add(sink, slab, STEEL);
    let bowl = wall.cuboid([s0 + 0.12, s0 + width - 0.12], [0.14, depth - 0.1], [top + 0.04, top + 0.045]);
    b.add(sink, bowl, GREY_LAMINATE);
    b.spatial(sink, under, "on");
    let sc = s0 + width * 0.5;
    let faucet_metal = b.pick(&[CHROME, BRASS, BLACK_METAL]);
    let post = wall.post(sc, 0.09, [top + 0.04, top + 0.3], 0.015);
    let spout = wall.cuboid([sc - 0.015, sc + 0.015], [0.09, 0.26], [top + 0.27, top + 0.3]);
    b.part(Some(sink), "faucet", faucet_metal, &["rotate", "hook_turn"], sink, WATER, &[post, spout]);
    sink
}

// ---------------------------------------------------------------------------------------------
// Kitchen.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Module {
    Sink,
    Stove,
    Drawers,
    Cabinet,
    Trash,
}

impl Module {
    fn width(self, rng: &mut ChaCha8Rng) -> f32 {
        match self {
            Module::Sink => 0.8,
            Module::Stove => 0.6,
            Module::Drawers => 0.5,
            Module::Cabinet => {
                if rng.random_bool(0.5) {
                    0.6
                } else {
                    0.8
                }
            }
            Module::Trash => 0.4,
        }
    }
}

fn kitchen(b: &mut Builder, base: usize) {
    let run1 = b.wall(base);
    let run2 = b.wall(base + 1);
    let door_wall = b.wall(base + 2);
    let window_wall = b.wall(base + 3);
    let front = b.pick(&FRONTS);
    let metals = b.two_metals();
    let mut metal_counter = 0usize;
    let light = ceiling_light(b, b.size.x * 0.5, b.size.y * 0.5);
    const DEPTH: f32 = 0.6;
    const TOP: f32 = 0.88;

    // Fridge in the corner.
    let fridge_mat = b.pick(&[STEEL, WHITE_LACQUER]);
    let fridge = b.object("fridge", &["refrigerator", "freezer"], fridge_mat);
    let body = run1.cuboid([0.05, 0.75], [0.0, 0.7], [0.0, 1.85]);
    b.add(fridge, body, fridge_mat);
    b.claim(&body);
    let fridge_handle_mat = b.pick(&[STEEL, BLACK_PLASTIC, CHROME]);
    for z in [[0.95, 1.45], [0.45, 0.75]] {
        let bar = run1.cuboid([0.66, 0.685], [0.7, 0.735], z);
        b.part(Some(fridge), "fridge handle", fridge_handle_mat, &["hook_pull"], fridge, PULL, &[bar]);
    }

    // Run 1: sink, stove and drawers, then cabinets; wall cabinets above most.
    let mut modules = [Module::Sink, Module::Stove, Module::Drawers];
    modules.shuffle(&mut b.rng);
    let mut plain = Vec::new();
    let mut s = 0.8;
    let mut k = 0;
    loop {
        let module = modules.get(k).copied().unwrap_or(Module::Cabinet);
        k += 1;
        let width = module.width(&mut b.rng);
        if s + width > run1.len - 0.05 {
            if width > 0.6 && s + 0.6 <= run1.len - 0.05 && module == Module::Cabinet {
                continue;
            }
            break;
        }
        let grip = if b.rng.random_bool(0.8) { Grip::Handle } else { Grip::Knob };
        match module {
            Module::Sink => {
                if let Some(cab) =
                    cabinet(b, run1, s, width, DEPTH, [0.0, TOP], front, grip, metals, &mut metal_counter)
                {
                    sink_with_faucet(b, run1, s, width, DEPTH, TOP, cab);
                    upper_cabinet(b, run1, s, width, front, metals, &mut metal_counter, cab);
                }
            }
            Module::Stove => stove(b, run1, s),
            Module::Drawers => {
                let grip = if b.rng.random_bool(0.7) { Grip::Handle } else { Grip::Knob };
                drawer_stack(b, run1, s, width, DEPTH, TOP, 3, front, grip, metals, &mut metal_counter);
            }
            Module::Cabinet | Module::Trash => {
                if let Some(cab) =
                    cabinet(b, run1, s, width, DEPTH, [0.0, TOP], front, grip, metals, &mut metal_counter)
                {
                    plain.push((run1, s, width, cab));
                    if b.rng.random_bool(0.7) {
                        upper_cabinet(b, run1, s, width, front, metals, &mut metal_counter, cab);
                    }
                }
            }
        }
        s += width;
    }

    // Run 2 (starts past run 1's depth): cabinets, trash can, more cabinets.
    let mut s = 0.7;
    let mut plain2 = Vec::new();
    for module in [Module::Cabinet, Module::Cabinet, Module::Trash, Module::Cabinet, Module::Cabinet] {
        let width = module.width(&mut b.rng);
        if s + width > run2.len - 0.05 {
            continue;
        }
        match module {
            Module::Trash => trash_can(b, run2, s),
            _ => {
                let grip = if b.rng.random_bool(0.8) { Grip::Handle } else { Grip::Knob };
                if let Some(cab) =
                    cabinet(b, run2, s, width, DEPTH, [0.0, TOP], front, grip, metals, &mut metal_counter)
                {
                    plain2.push((run2, s, width, cab));
                }
            }
        }
        s += width;
    }

    // Countertop appliances on plain cabinets, each with a wall outlet.
    let mut tops: Vec<_> = plain.iter().chain(plain2.iter()).copied().collect();
    tops.reverse();
    if let Some((wall, s0, width, cab)) = tops.pop() {
        let sc = s0 + width * 0.5;
        let kettle_mat = b.pick(&[RED_ENAMEL, STEEL, WHITE_PLASTIC]);
        let kettle = b.object("kettle", &["electric kettle"], kettle_mat);
        b.add(kettle, wall.post(sc - 0.05, 0.3, [TOP, TOP + 0.22], 0.09), kettle_mat);
        b.add(kettle, wall.cuboid([sc - 0.07, sc - 0.03], [0.28, 0.32], [TOP + 0.22, TOP + 0.25]), BLACK_PLASTIC);
        b.spatial(kettle, cab, "on");
        outlet(b, wall, sc + 0.17, 1.08, kettle);
    }
    if let Some((wall, s0, width, cab)) = tops.pop() {
        let sc = s0 + width * 0.5;
        let shell = b.pick(&[WHITE_LACQUER, STEEL, BLACK_PLASTIC]);
        let microwave = b.object("microwave", &["microwave oven"], shell);
        let body = wall.cuboid([sc - 0.24, sc + 0.24], [0.1, 0.45], [TOP, TOP + 0.3]);
        b.add(microwave, body, shell);
        b.add(microwave, wall.cuboid([sc - 0.22, sc + 0.08], [0.45, 0.455], [TOP + 0.04, TOP + 0.26]), DARK_GLASS);
        let button = wall.cuboid([sc + 0.12, sc + 0.19], [0.45, 0.462], [TOP + 0.06, TOP + 0.1]);
        b.part(Some(microwave), "microwave button", BLACK_PLASTIC, &["tip_push"], microwave, PRESS_START, &[button]);
        b.spatial(microwave, cab, "on");
        outlet(b, wall, sc + 0.33, 1.08, microwave);
    }
    if let Some((wall, s0, width, cab)) = tops.pop() {
        let sc = s0 + width * 0.5;
        let toaster_mat = b.pick(&[STEEL, RED_ENAMEL, BLACK_PLASTIC]);
        let toaster = b.object("toaster", &[], toaster_mat);
        b.add(toaster, wall.cuboid([sc - 0.14, sc + 0.14], [0.15, 0.33], [TOP, TOP + 0.2]), toaster_mat);
        let lever = wall.cuboid([sc + 0.14, sc + 0.16], [0.22, 0.26], [TOP + 0.12, TOP + 0.14]);
        b.part(Some(toaster), "toaster lever", BLACK_PLASTIC, &["tip_push"], toaster, PRESS_START, &[lever]);
        b.spatial(toaster, cab, "on");
        outlet(b, wall, sc + 0.24, 1.08, toaster);
    }

    door_and_switches(b, door_wall, 0.8, &[light]);
    let ww = 1.0f32.min(window_wall.len - 1.8);
    window(b, window_wall, (window_wall.len - ww) * 0.5, ww);
}

#[allow(clippy::too_many_arguments)]
fn upper_cabinet(
    b: &mut Builder,
    wall: Wall,
    s0: f32,
    width: f32,
    front: Material,
    metals: [Material; 2],
    metal_counter: &mut usize,
    below: u16,
) {
    let grip = Grip::Handle;
    if let Some(upper) = cabinet(b, wall, s0, width, 0.35, [1.45, 2.15], front, grip, metals, metal_counter) {
        b.spatial(upper, below, "above");
    }
}

fn stove(b: &mut Builder, wall: Wall, s0: f32) {
    let body = wall.cuboid([s0, s0 + 0.6], [0.0, 0.6], [0.0, 0.88]);
    if !b.fits(&body) {
        return;
    }
    b.claim(&body);
    let stove = b.object("stove", &["oven", "cooker", "range"], STEEL);
    b.add(stove, body, STEEL);
    b.add(stove, wall.cuboid([s0 + 0.02, s0 + 0.58], [0.02, 0.58], [0.88, 0.9]), DARK_GLASS);
    b.add(stove, wall.cuboid([s0 + 0.08, s0 + 0.52], [0.6, 0.603], [0.15, 0.6]), DARK_GLASS);
    let knob_mat = b.pick(&[BLACK_PLASTIC, CHROME, WHITE_PLASTIC]);
    for k in 0..4 {
        let knob = wall.knob(s0 + 0.12 + 0.12 * k as f32, 0.6, 0.8, 0.018, 0.025);
        b.part(Some(stove), "stove knob", knob_mat, &["rotate"], stove, ADJUST, &[knob]);
    }
    let bar = wall.cuboid([s0 + 0.1, s0 + 0.5], [0.615, 0.64], [0.68, 0.7]);
    b.part(Some(stove), "oven handle", STEEL, &["hook_pull"], stove, PULL, &[bar]);
}

fn trash_can(b: &mut Builder, wall: Wall, s0: f32) {
    let body = wall.cuboid([s0 + 0.05, s0 + 0.35], [0.05, 0.4], [0.0, 0.6]);
    if !b.fits(&body) {
        return;
    }
    b.claim(&body);
    let mat = b.pick(&[STEEL, WHITE_PLASTIC, BLACK_PLASTIC]);
    let can = b.object("trash can", &["bin", "garbage can", "dustbin"], mat);
    b.add(can, body, mat);
    let pedal = wall.cuboid([s0 + 0.13, s0 + 0.27], [0.4, 0.46], [0.02, 0.05]);
    b.part(Some(can), "pedal", BLACK_PLASTIC, &["foot_push"], can, PUSH_OPEN, &[pedal]);
}

// ---------------------------------------------------------------------------------------------
// Bathroom.

fn bathroom(b: &mut Builder, base: usize) {
    let tub_wall = b.wall(base);
    let vanity_wall = b.wall(base + 1);
    let door_wall = b.wall(base + 2);
    let radiator_wall = b.wall(base + 3);
    let front = b.pick(&FRONTS);
    let metals = b.two_metals();
    let mut metal_counter = 0usize;
    let light = ceiling_light(b, b.size.x * 0.5, b.size.y * 0.5);

    // Bathtub along the first wall, faucet on the wall above it.
    let tub_len = 1.7f32.min(tub_wall.len - 0.9);
    let tub = b.object("bathtub", &["bath", "tub"], CERAMIC);
    let shell = tub_wall.cuboid([0.05, 0.05 + tub_len], [0.0, 0.75], [0.0, 0.55]);
    b.add(tub, shell, CERAMIC);
    b.claim(&shell);
    let sm = 0.05 + tub_len * 0.5;
    let faucet_metal = b.pick(&[CHROME, BRASS]);
    let mixer = tub_wall.knob(sm, 0.0, 0.85, 0.03, 0.05);
    let spout = tub_wall.cuboid([sm - 0.02, sm + 0.02], [0.0, 0.15], [0.72, 0.76]);
    b.part(Some(tub), "faucet", faucet_metal, &["rotate", "hook_turn"], tub, WATER, &[mixer, spout]);

    // Toilet, vanity with sink, drawers, mirror and its light along the second wall.
    let toilet = b.object("toilet", &["wc", "toilet bowl"], CERAMIC);
    let t0 = 0.9;
    let tank = vanity_wall.cuboid([t0, t0 + 0.4], [0.0, 0.2], [0.4, 0.8]);
    let bowl = vanity_wall.post(t0 + 0.2, 0.45, [0.0, 0.42], 0.2);
    b.add(toilet, tank, CERAMIC);
    b.add(toilet, bowl, CERAMIC);
    b.claim(&vanity_wall.cuboid([t0, t0 + 0.4], [0.0, 0.65], [0.0, 0.8]));
    let button = Shape::Cylinder {
        axis: Axis::Z,
        centre: vanity_wall.point(t0 + 0.2, 0.1, 0.806),
        radius: 0.025,
        half_length: 0.006,
    };
    b.part(Some(toilet), "flush button", CHROME, &["tip_push"], toilet, FLUSH, &[button]);

    let v0 = t0 + 0.7;
    let vanity = cabinet(b, vanity_wall, v0, 0.8, 0.5, [0.0, 0.8], front, Grip::Handle, metals, &mut metal_counter);
    if let Some(vanity) = vanity {
        sink_with_faucet(b, vanity_wall, v0, 0.8, 0.5, 0.8, vanity);
        let mirror = b.object("mirror", &[], MIRROR);
        b.add(mirror, vanity_wall.cuboid([v0 + 0.1, v0 + 0.7], [0.0, 0.02], [1.2, 1.85]), MIRROR);
        b.spatial(mirror, vanity, "above");
    }
    let wall_light = b.object("wall light", &["light", "lamp", "sconce"], LIGHT_DIFFUSER);
    b.add(wall_light, vanity_wall.cuboid([v0 + 0.25, v0 + 0.55], [0.0, 0.08], [1.92, 1.99]), LIGHT_DIFFUSER);
    let d0 = v0 + 0.8;
    let grip = if b.rng.random_bool(0.5) { Grip::Handle } else { Grip::Knob };
    let drawers = drawer_stack(b, vanity_wall, d0, 0.4, 0.5, 0.8, 2, front, grip, metals, &mut metal_counter);
    if let Some(&top) = drawers.last() {
        let dryer_mat = b.pick(&[BLACK_PLASTIC, WHITE_PLASTIC, RED_PLASTIC]);
        let dryer = b.object("hair dryer", &["blow dryer"], dryer_mat);
        b.add(dryer, vanity_wall.cuboid([d0 + 0.1, d0 + 0.3], [0.15, 0.23], [0.8, 0.88]), dryer_mat);
        b.add(dryer, vanity_wall.cuboid([d0 + 0.17, d0 + 0.21], [0.23, 0.33], [0.8, 0.84]), dryer_mat);
        b.spatial(dryer, top, "on");
        outlet(b, vanity_wall, d0 + 0.2, 1.05, dryer);
    }

    door_and_switches(b, door_wall, 0.7, &[light, wall_light]);

    // Radiator with its valve; a wall cabinet with knobs above it.
    let rs = radiator_wall.len * 0.5;
    let radiator = b.object("radiator", &["heater"], WHITE_LACQUER);
    let panel = radiator_wall.cuboid([rs - 0.4, rs + 0.4], [0.03, 0.13], [0.15, 0.75]);
    b.add(radiator, panel, WHITE_LACQUER);
    b.claim(&panel);
    let valve = radiator_wall.post(rs + 0.45, 0.08, [0.12, 0.2], 0.022);
    b.part(Some(radiator), "radiator valve", WHITE_PLASTIC, &["rotate"], radiator, FLOW_SETTING, &[valve]);
    let knobs = [metals[1], metals[0]];
    let mut counter = 0;
    cabinet(b, radiator_wall, rs - 0.3, 0.7, 0.25, [1.4, 2.0], front, Grip::Knob, knobs, &mut counter);
}

// ---------------------------------------------------------------------------------------------
// Bedroom.

fn bedroom(b: &mut Builder, base: usize) {
    let bed_wall = b.wall(base);
    let dresser_wall = b.wall(base + 1);
    let door_wall = b.wall(base + 2);
    let wardrobe_wall = b.wall(base + 3);
    let wood = b.pick(&[WOOD_LIGHT, WOOD_DARK, WHITE_LACQUER]);
    let metals = b.two_metals();
    let mut metal_counter = 0usize;
    let light = ceiling_light(b, b.size.x * 0.5, b.size.y * 0.5);

    let bw = if b.rng.random_bool(0.5) { 1.4 } else { 1.6 };
    let sc = bed_wall.len * 0.5;
    let mattress_mat = b.pick(&[LINEN, BLUE_FABRIC, GREY_FABRIC]);
    let bed = b.object("bed", &["double bed"], mattress_mat);
    let frame = bed_wall.cuboid([sc - bw * 0.5, sc + bw * 0.5], [0.0, 2.0], [0.0, 0.3]);
    b.add(bed, frame, wood);
    b.add(bed, bed_wall.cuboid([sc - bw * 0.5, sc + bw * 0.5], [0.06, 2.0], [0.3, 0.5]), mattress_mat);
    b.add(bed, bed_wall.cuboid([sc - bw * 0.5, sc + bw * 0.5], [0.0, 0.06], [0.3, 1.0]), wood);
    b.claim(&bed_wall.cuboid([sc - bw * 0.5, sc + bw * 0.5], [0.0, 2.0], [0.0, 1.0]));

    for side in [-1.0f32, 1.0] {
        let inner = sc + side * (bw * 0.5 + 0.05);
        let outer = inner + side * 0.45;
        let (s0, s1) = (inner.min(outer), inner.max(outer));
        let body = bed_wall.cuboid([s0, s1], [0.0, 0.4], [0.0, 0.55]);
        if !b.fits(&body) {
            continue;
        }
        b.claim(&body);
        let stand = b.object("nightstand", &["bedside table", "night table"], wood);
        b.add(stand, body, wood);
        let ns = (s0 + s1) * 0.5;
        let metal = metals[metal_counter % 2];
        metal_counter += 1;
        let knob = bed_wall.knob(ns, 0.4, 0.44, 0.015, 0.025);
        b.part(Some(stand), "drawer knob", metal, &["pinch_pull"], stand, PULL, &[knob]);
        let lamp = b.object("lamp", &["table lamp", "bedside lamp"], LAMP_SHADE);
        b.add(lamp, bed_wall.post(ns, 0.2, [0.55, 0.6], 0.07), BLACK_METAL);
        b.add(lamp, bed_wall.post(ns, 0.2, [0.6, 0.85], 0.01), BLACK_METAL);
        b.add(lamp, bed_wall.post(ns, 0.2, [0.85, 1.05], 0.12), LAMP_SHADE);
        b.spatial(lamp, stand, "on");
        let switch = bed_wall.post(ns + side * 0.04, 0.2, [0.6, 0.615], 0.012);
        b.part(Some(lamp), "lamp switch", WHITE_PLASTIC, &["tip_push"], lamp, SWITCH, &[switch]);
        outlet(b, bed_wall, ns + side * 0.14, 0.7, lamp);
    }

    // Dresser near the door wall, window in the same wall above head height of the dresser.
    let dw = if b.rng.random_bool(0.5) { 1.0 } else { 1.2 };
    let d0 = dresser_wall.len - 0.3 - dw;
    let body = dresser_wall.cuboid([d0, d0 + dw], [0.0, 0.5], [0.0, 0.85]);
    if b.fits(&body) {
        b.claim(&body);
        let dresser = b.object("dresser", &["chest of drawers", "drawers"], wood);
        b.add(dresser, body, wood);
        let grip = if b.rng.random_bool(0.5) { Grip::Handle } else { Grip::Knob };
        for row in 0..3 {
            let zc = 0.2 + 0.27 * row as f32;
            for col in 0..2 {
                let s = d0 + dw * (0.25 + 0.5 * col as f32);
                let metal = metals[metal_counter % 2];
                metal_counter += 1;
                match grip {
                    Grip::Handle => {
                        let bar = dresser_wall.cuboid([s - 0.06, s + 0.06], [0.5, 0.525], [zc - 0.01, zc + 0.01]);
                        b.part(Some(dresser), "drawer handle", metal, &["hook_pull"], dresser, PULL, &[bar]);
                    }
                    Grip::Knob => {
                        let knob = dresser_wall.knob(s, 0.5, zc, 0.015, 0.025);
                        b.part(Some(dresser), "drawer knob", metal, &["pinch_pull"], dresser, PULL, &[knob]);
                    }
                }
            }
        }
    }
    window(b, dresser_wall, (dresser_wall.len - 1.0) * 0.5, 1.0);

    door_and_switches(b, door_wall, door_wall.len * 0.5 - 0.45, &[light]);

    let body = wardrobe_wall.cuboid([0.3, 1.3], [0.0, 0.6], [0.0, 2.0]);
    if b.fits(&body) {
        b.claim(&body);
        let wardrobe = b.object("wardrobe", &["closet", "armoire"], wood);
        b.add(wardrobe, body, wood);
        let metal = b.pick(&HANDLE_METALS);
        for s in [0.76, 0.84] {
            let bar = wardrobe_wall.cuboid([s - 0.01, s + 0.01], [0.6, 0.625], [0.95, 1.25]);
            b.part(Some(wardrobe), "wardrobe handle", metal, &["hook_pull"], wardrobe, PULL, &[bar]);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Living room.

fn living_room(b: &mut Builder, base: usize) {
    let tv_wall = b.wall(base);
    let side_wall = b.wall(base + 1);
    let sofa_wall = b.wall(base + 2);
    let door_wall = b.wall(base + 3);
    let wood = b.pick(&[WOOD_LIGHT, WOOD_DARK, WHITE_LACQUER, GREY_LAMINATE]);
    let metals = b.two_metals();
    let mut metal_counter = 0usize;
    let light = ceiling_light(b, b.size.x * 0.5, b.size.y * 0.5);

    // TV stand with drawers, TV, game console, power strip.
    let sc = tv_wall.len * 0.5;
    let stand = b.object("tv stand", &["tv cabinet", "media console"], wood);
    let body = tv_wall.cuboid([sc - 0.7, sc + 0.7], [0.0, 0.45], [0.0, 0.5]);
    b.add(stand, body, wood);
    b.claim(&body);
    for s in [sc - 0.35, sc + 0.35] {
        let metal = metals[metal_counter % 2];
        metal_counter += 1;
        let bar = tv_wall.cuboid([s - 0.06, s + 0.06], [0.45, 0.475], [0.39, 0.41]);
        b.part(Some(stand), "drawer handle", metal, &["hook_pull"], stand, PULL, &[bar]);
    }
    let tv = b.object("tv", &["television", "monitor", "tv screen"], BLACK_PLASTIC);
    b.add(tv, tv_wall.cuboid([sc - 0.15, sc + 0.15], [0.1, 0.3], [0.5, 0.52]), BLACK_METAL);
    b.add(tv, tv_wall.cuboid([sc - 0.03, sc + 0.03], [0.18, 0.22], [0.52, 0.62]), BLACK_METAL);
    b.add(tv, tv_wall.cuboid([sc - 0.55, sc + 0.55], [0.17, 0.23], [0.62, 1.27]), DARK_GLASS);
    b.spatial(tv, stand, "on");
    let console = b.object("game console", &["console"], WHITE_PLASTIC);
    b.add(console, tv_wall.cuboid([sc + 0.3, sc + 0.6], [0.31, 0.44], [0.5, 0.56]), WHITE_PLASTIC);
    b.spatial(console, stand, "on");
    let button = tv_wall.cuboid([sc + 0.33, sc + 0.36], [0.44, 0.446], [0.52, 0.54]);
    b.part(Some(console), "power button", BLACK_PLASTIC, &["tip_push"], console, PRESS_START, &[button]);

    let strip = b.object("power strip", &["extension cord", "multi plug"], WHITE_PLASTIC);
    let body = tv_wall.cuboid([sc + 0.8, sc + 1.2], [0.05, 0.12], [0.0, 0.04]);
    b.add(strip, body, WHITE_PLASTIC);
    b.claim(&body);
    for (k, target) in [tv, console].into_iter().enumerate() {
        let s = sc + 0.86 + 0.1 * k as f32;
        let socket = tv_wall.cuboid([s, s + 0.05], [0.06, 0.11], [0.04, 0.046]);
        b.part(Some(strip), "power outlet", BLACK_PLASTIC, &["plug_in", "unplug"], target, POWER, &[socket]);
    }
    outlet(b, tv_wall, sc + 1.35, 0.3, strip);

    // Sofa, coffee table with the remote, floor lamp.
    let ss = sofa_wall.len * 0.5;
    let fabric = b.pick(&[BLUE_FABRIC, GREY_FABRIC, LINEN]);
    let sofa = b.object("sofa", &["couch", "settee"], fabric);
    b.add(sofa, sofa_wall.cuboid([ss - 1.0, ss + 1.0], [0.0, 0.9], [0.0, 0.42]), fabric);
    b.add(sofa, sofa_wall.cuboid([ss - 1.0, ss + 1.0], [0.0, 0.2], [0.42, 0.85]), fabric);
    b.add(sofa, sofa_wall.cuboid([ss - 1.0, ss - 0.85], [0.2, 0.9], [0.42, 0.6]), fabric);
    b.add(sofa, sofa_wall.cuboid([ss + 0.85, ss + 1.0], [0.2, 0.9], [0.42, 0.6]), fabric);
    b.claim(&sofa_wall.cuboid([ss - 1.0, ss + 1.0], [0.0, 0.9], [0.0, 0.85]));
    let top = sofa_wall.cuboid([ss - 0.5, ss + 0.5], [1.35, 1.9], [0.38, 0.42]);
    let remote = b.object("remote control", &["remote", "tv remote"], BLACK_PLASTIC);
    b.affordances[remote as usize - 1] = vec!["key_press"];
    b.functional(remote, tv, REMOTE);
    let remote_box = if b.fits(&sofa_wall.cuboid([ss - 0.5, ss + 0.5], [1.35, 1.9], [0.0, 0.42])) {
        b.claim(&sofa_wall.cuboid([ss - 0.5, ss + 0.5], [1.35, 1.9], [0.0, 0.42]));
        let table = b.object("coffee table", &["table", "low table"], wood);
        b.add(table, top, wood);
        for (ls, lt) in [(-0.45, 1.4), (0.42, 1.4), (-0.45, 1.82), (0.42, 1.82)] {
            b.add(table, sofa_wall.cuboid([ss + ls, ss + ls + 0.03], [lt, lt + 0.03], [0.0, 0.38]), wood);
        }
        b.spatial(remote, table, "on");
        sofa_wall.cuboid([ss - 0.12, ss + 0.05], [1.6, 1.65], [0.42, 0.44])
    } else {
        b.spatial(remote, sofa, "on");
        sofa_wall.cuboid([ss - 0.12, ss + 0.05], [0.5, 0.55], [0.42, 0.44])
    };
    b.add(remote, remote_box, BLACK_PLASTIC);

    let ls = ss + 1.3;
    let lamp_zone = sofa_wall.cuboid([ls - 0.2, ls + 0.2], [0.1, 0.5], [0.0, 1.7]);
    if b.fits(&lamp_zone) {
        b.claim(&lamp_zone);
        let lamp = b.object("floor lamp", &["lamp", "standing lamp"], LAMP_SHADE);
        b.add(lamp, sofa_wall.post(ls, 0.3, [0.0, 0.03], 0.15), BLACK_METAL);
        b.add(lamp, sofa_wall.post(ls, 0.3, [0.03, 1.4], 0.015), BLACK_METAL);
        b.add(lamp, sofa_wall.post(ls, 0.3, [1.4, 1.7], 0.2), LAMP_SHADE);
        let switch = sofa_wall.post(ls, 0.3, [0.98, 1.03], 0.028);
        b.part(Some(lamp), "lamp switch", BLACK_PLASTIC, &["tip_push"], lamp, SWITCH, &[switch]);
        outlet(b, sofa_wall, ls + 0.3, 0.3, lamp);
    }

    // Sideboard (cabinet) with a table lamp on the side wall.
    let grip = if b.rng.random_bool(0.5) { Grip::Handle } else { Grip::Knob };
    let s0 = side_wall.len * 0.5 - 0.6;
    if let Some(cab) = cabinet(b, side_wall, s0, 1.2, 0.45, [0.0, 0.8], wood, grip, metals, &mut metal_counter) {
        let lamp = b.object("lamp", &["table lamp"], LAMP_SHADE);
        let ls = s0 + 0.25;
        b.add(lamp, side_wall.post(ls, 0.2, [0.8, 0.84], 0.07), BRASS);
        b.add(lamp, side_wall.post(ls, 0.2, [0.84, 1.1], 0.01), BRASS);
        b.add(lamp, side_wall.post(ls, 0.2, [1.1, 1.3], 0.12), LAMP_SHADE);
        b.spatial(lamp, cab, "on");
        let switch = side_wall.post(ls + 0.04, 0.2, [0.84, 0.855], 0.012);
        b.part(Some(lamp), "lamp switch", WHITE_PLASTIC, &["tip_push"], lamp, SWITCH, &[switch]);
        outlet(b, side_wall, ls - 0.15, 0.95, lamp);
    }

    door_and_switches(b, door_wall, 0.8, &[light]);
    window(b, door_wall, door_wall.len - 1.9, 1.0);
}

// ---------------------------------------------------------------------------------------------
// Colour panel (test scene).

/// Centre spacing of the knobs in a row, metres (3 cm knobs: 1 cm gaps).
pub(crate) const PANEL_KNOB_SPACING_M: f32 = 0.04;
/// Centre spacing of the push buttons in a row, metres (2.5 cm buttons: 5 mm gaps).
pub(crate) const PANEL_BUTTON_SPACING_M: f32 = 0.03;

/// A floor-standing control panel in the middle of a wall: a row of six knobs, a row of six
/// push buttons and another row of six knobs, each row in six different colours (shuffled per
/// seed), so every part's neighbours in its row share its label and differ in colour.
fn colour_panel(b: &mut Builder, base: usize) {
    let wall = b.wall(base);
    ceiling_light(b, b.size.x * 0.5, b.size.y * 0.5);
    const DEPTH: f32 = 0.35;
    let sc = wall.len * 0.5;
    let panel = b.object("control panel", &["panel", "control board"], PANEL_BODY);
    let body = wall.cuboid([sc - 0.35, sc + 0.35], [0.0, DEPTH], [0.0, 1.35]);
    b.add(panel, body, PANEL_BODY);
    b.claim(&body);
    let row = |b: &mut Builder| {
        let mut colours = PANEL_COLOURS;
        colours.shuffle(&mut b.rng);
        colours
    };
    for (z, knobs) in [(1.22f32, true), (1.1, false), (0.98, true)] {
        let colours = row(b);
        for (k, colour) in colours.into_iter().enumerate() {
            let offset = k as f32 - 2.5;
            if knobs {
                let knob = wall.knob(sc + offset * PANEL_KNOB_SPACING_M, DEPTH, z, 0.015, 0.025);
                b.part(Some(panel), "knob", colour, &["rotate"], panel, ADJUST, &[knob]);
            } else {
                let s = sc + offset * PANEL_BUTTON_SPACING_M;
                let button = wall.cuboid([s - 0.0125, s + 0.0125], [DEPTH, DEPTH + 0.012], [z - 0.0125, z + 0.0125]);
                b.part(Some(panel), "push button", colour, &["tip_push"], panel, PRESS_START, &[button]);
            }
        }
    }
}
