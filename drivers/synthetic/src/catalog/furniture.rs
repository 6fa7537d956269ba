//! Furniture every room uses: the ceiling light, a door with its light switches, wall outlets,
//! windows, cabinets and drawer stacks with handles or knobs, and a sink with its faucet.

use glam::Vec3;

use super::builder::{Builder, Wall};
use super::materials::{
    BLACK_METAL, BRASS, CHROME, GREY_LAMINATE, HANDLE_METALS, LIGHT_DIFFUSER, STEEL, WHITE_LACQUER, WHITE_PLASTIC,
    WINDOW_GLASS, WOOD_DARK, WOOD_LIGHT,
};
use crate::scene::{Axis, CEILING_HEIGHT_M, Material, Shape};
use crate::truth::{EMPTY_OUTLET, SWITCH_FOR_FAR_LAMP, SWITCH_FOR_NEXT_ROOM, TURN_LATCH_KNOB};

pub(super) fn ceiling_light(b: &mut Builder, x: f32, y: f32) -> u16 {
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
///
/// Deviations drawn here: a further switch for the next room's light
/// ([`SWITCH_FOR_NEXT_ROOM`]); with `far_lamp`, a further switch for that lamp across the room
/// ([`SWITCH_FOR_FAR_LAMP`]); an outlet low on the wall past the switches with nothing plugged
/// in ([`EMPTY_OUTLET`]).
pub(super) fn door_and_switches(b: &mut Builder, wall: Wall, s0: f32, lights: &[u16], far_lamp: Option<u16>) {
    let door_mat = b.pick(&[WOOD_LIGHT, WHITE_LACQUER, WOOD_DARK]);
    let door = b.object("door", &[], door_mat);
    let slab = wall.cuboid([s0, s0 + 0.9], [0.0, 0.04], [0.0, 2.05]);
    b.add(door, slab, door_mat);
    b.claim(&slab);
    let handle_mat = b.pick(&HANDLE_METALS);
    let lever = wall.cuboid([s0 + 0.7, s0 + 0.82], [0.045, 0.075], [1.0, 1.025]);
    let rose = wall.knob(s0 + 0.8, 0.04, 1.0125, 0.025, 0.005);
    b.part(Some(door), "door handle", handle_mat, door, &[lever, rose]);
    let plate = |k: usize| {
        let s = s0 + 1.05 + 0.1 * k as f32;
        wall.cuboid([s, s + 0.08], [0.0, 0.012], [1.06, 1.14])
    };
    for (k, light) in lights.iter().enumerate() {
        b.part(None, "light switch", WHITE_PLASTIC, *light, &[plate(k)]);
    }
    let mut k = lights.len();
    if let Some(lamp) = far_lamp
        && b.deviates(&SWITCH_FOR_FAR_LAMP)
    {
        let id = b.part(None, "light switch", WHITE_PLASTIC, lamp, &[plate(k)]);
        b.record(&SWITCH_FOR_FAR_LAMP, id);
        k += 1;
    }
    if b.deviates(&SWITCH_FOR_NEXT_ROOM)
        && let Some(truth) = SWITCH_FOR_NEXT_ROOM.truth.as_ref()
    {
        let id = b.part_as(None, truth, WHITE_PLASTIC, None, &[plate(k)]);
        b.record(&SWITCH_FOR_NEXT_ROOM, id);
    }
    if b.deviates(&EMPTY_OUTLET)
        && let Some(truth) = EMPTY_OUTLET.truth.as_ref()
    {
        let s = s0 + 1.6;
        let plate = wall.cuboid([s - 0.04, s + 0.04], [0.0, 0.012], [0.26, 0.34]);
        let id = b.part_as(None, truth, WHITE_PLASTIC, None, &[plate]);
        b.record(&EMPTY_OUTLET, id);
    }
}

/// A wall outlet centred at `(s, z)` powering `target`.
pub(super) fn outlet(b: &mut Builder, wall: Wall, s: f32, z: f32, target: u16) -> u16 {
    let plate = wall.cuboid([s - 0.04, s + 0.04], [0.0, 0.012], [z - 0.04, z + 0.04]);
    b.part(None, "power outlet", WHITE_PLASTIC, target, &[plate])
}

pub(super) fn window(b: &mut Builder, wall: Wall, s0: f32, width: f32) {
    let frame_mat = b.pick(&[WHITE_PLASTIC, WOOD_DARK]);
    let win = b.object("window", &[], WINDOW_GLASS);
    let frame = wall.cuboid([s0, s0 + width], [0.0, 0.02], [0.9, 2.0]);
    b.add(win, frame, frame_mat);
    let glass = wall.cuboid([s0 + 0.06, s0 + width - 0.06], [0.02, 0.03], [0.96, 1.94]);
    b.add(win, glass, WINDOW_GLASS);
    let handle = wall.cuboid([s0 + width - 0.05, s0 + width - 0.025], [0.03, 0.06], [1.35, 1.47]);
    let metal = b.pick(&HANDLE_METALS);
    b.part(Some(win), "window handle", metal, win, &[handle]);
}

/// What a cabinet door or drawer is opened by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Grip {
    /// A bar handle.
    Handle,
    /// A round knob.
    Knob,
}

/// Where a piece of furniture stands against a wall, in the wall's frame: from `s0` along the
/// wall, `width` wide, `depth` into the room (metres).
#[derive(Debug, Clone, Copy)]
pub(super) struct Footprint {
    pub(super) wall: Wall,
    pub(super) s0: f32,
    pub(super) width: f32,
    pub(super) depth: f32,
}

impl Footprint {
    /// The box over the footprint between the heights `z` (metres above the floor).
    fn cuboid(&self, z: [f32; 2]) -> Shape {
        self.wall.cuboid([self.s0, self.s0 + self.width], [0.0, self.depth], z)
    }
}

/// The two handle metals of a room, handed out in turn to the handles and knobs of its
/// cabinets and drawers.
#[derive(Debug, Clone, Copy)]
pub(super) struct Metals {
    pub(super) pair: [Material; 2],
    /// Handles and knobs made so far.
    handed_out: usize,
}

impl Metals {
    pub(super) fn new(pair: [Material; 2]) -> Self {
        Self { pair, handed_out: 0 }
    }

    /// The metal of the next handle or knob.
    pub(super) fn next(&mut self) -> Material {
        let metal = self.pair[self.handed_out % 2];
        self.handed_out += 1;
        metal
    }
}

/// A cabinet body between the heights `z` with one or two doors and a handle or knob on each.
pub(super) fn cabinet(
    b: &mut Builder,
    at: Footprint,
    z: [f32; 2],
    front: Material,
    grip: Grip,
    metals: &mut Metals,
) -> Option<u16> {
    let Footprint { wall, s0, width, depth } = at;
    let body = at.cuboid(z);
    if !b.fits(&body) {
        return None;
    }
    b.claim(&body);
    let id = b.object("cabinet", &["cupboard", "cupboard door"], front);
    b.add(id, body, front);
    let doors = if width >= 0.7 { 2 } else { 1 };
    // A cabinet with knobs may close with turn-knob latches.
    let latch = (grip == Grip::Knob && b.deviates(&TURN_LATCH_KNOB)).then_some(TURN_LATCH_KNOB.truth).flatten();
    // Handles sit near the top of low cabinets and near the bottom of wall cabinets.
    let zc = if z[0] > 1.0 { z[0] + 0.11 } else { z[1] - 0.12 };
    for door in 0..doors {
        let s = match (doors, door) {
            (1, _) => s0 + width - 0.06,
            (_, 0) => s0 + width * 0.5 - 0.05,
            _ => s0 + width * 0.5 + 0.05,
        };
        let metal = metals.next();
        match grip {
            Grip::Handle => {
                let bar = wall.cuboid([s - 0.01, s + 0.01], [depth, depth + 0.025], [zc - 0.06, zc + 0.06]);
                b.part(Some(id), "cabinet handle", metal, id, &[bar]);
            }
            Grip::Knob => {
                let knob = wall.knob(s, depth, zc, 0.015, 0.025);
                match latch.as_ref() {
                    Some(truth) => {
                        let knob = b.part_as(Some(id), truth, metal, Some(id), &[knob]);
                        b.record(&TURN_LATCH_KNOB, knob);
                    }
                    None => {
                        b.part(Some(id), "cabinet knob", metal, id, &[knob]);
                    }
                }
            }
        }
    }
    Some(id)
}

/// A stack of `count` drawers (each its own object), `height` tall, with a handle or knob on
/// each.
pub(super) fn drawer_stack(
    b: &mut Builder,
    at: Footprint,
    height: f32,
    count: usize,
    front: Material,
    grip: Grip,
    metals: &mut Metals,
) -> Vec<u16> {
    let Footprint { wall, s0, width, depth } = at;
    let whole = at.cuboid([0.0, height]);
    if !b.fits(&whole) {
        return Vec::new();
    }
    b.claim(&whole);
    let mut ids = Vec::new();
    let step = height / count as f32;
    for k in 0..count {
        let (z0, z1) = (step * k as f32, step * (k + 1) as f32);
        let id = b.object("drawer", &["drawers", "chest of drawers"], front);
        b.add(id, at.cuboid([z0, z1]), front);
        let sc = s0 + width * 0.5;
        let zc = z1 - step.min(0.3) * 0.35;
        let metal = metals.next();
        match grip {
            Grip::Handle => {
                let bar = wall.cuboid([sc - 0.06, sc + 0.06], [depth, depth + 0.025], [zc - 0.01, zc + 0.01]);
                b.part(Some(id), "drawer handle", metal, id, &[bar]);
            }
            Grip::Knob => {
                let knob = wall.knob(sc, depth, zc, 0.015, 0.025);
                b.part(Some(id), "drawer knob", metal, id, &[knob]);
            }
        }
        ids.push(id);
    }
    ids
}

/// A sink slab with a faucet on top (at height `top`) of the cabinet `under` standing at `at`.
pub(super) fn sink_with_faucet(b: &mut Builder, at: Footprint, top: f32, under: u16) -> u16 {
    let Footprint { wall, s0, width, depth } = at;
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
    b.part(Some(sink), "faucet", faucet_metal, sink, &[post, spout]);
    sink
}
