//! The kitchen: a fridge, a run of sink, stove and drawers with wall cabinets, a second run of
//! cabinets with a trash can, countertop appliances (kettle, microwave, toaster) on outlets, a
//! door with its switch, a window.

use rand::Rng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::builder::{Builder, Wall};
use super::furniture::{
    Footprint, Grip, Metals, cabinet, ceiling_light, door_and_switches, drawer_stack, outlet, sink_with_faucet, window,
};
use super::materials::{BLACK_PLASTIC, CHROME, DARK_GLASS, FRONTS, RED_ENAMEL, STEEL, WHITE_LACQUER, WHITE_PLASTIC};
use crate::scene::Material;
use crate::truth::OVEN_DOOR_KNOB;

/// A base module of a kitchen run.
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

/// Depth of the base modules, metres.
const DEPTH: f32 = 0.6;
/// Height of the worktop, metres.
const TOP: f32 = 0.88;

pub(super) fn kitchen(b: &mut Builder, base: usize) {
    let run1 = b.wall(base);
    let run2 = b.wall(base + 1);
    let door_wall = b.wall(base + 2);
    let window_wall = b.wall(base + 3);
    let front = b.pick(&FRONTS);
    let mut metals = Metals::new(b.two_metals());
    let light = ceiling_light(b, b.size.x * 0.5, b.size.y * 0.5);
    fridge(b, run1);
    let mut plain = first_run(b, run1, front, &mut metals);
    plain.extend(second_run(b, run2, front, &mut metals));
    countertop_appliances(b, &plain);
    door_and_switches(b, door_wall, 0.8, &[light], None);
    let ww = 1.0f32.min(window_wall.len - 1.8);
    window(b, window_wall, (window_wall.len - ww) * 0.5, ww);
}

/// The fridge, in the corner where the first run starts.
fn fridge(b: &mut Builder, wall: Wall) {
    let fridge_mat = b.pick(&[STEEL, WHITE_LACQUER]);
    let fridge = b.object("fridge", &["refrigerator", "freezer"], fridge_mat);
    let body = wall.cuboid([0.05, 0.75], [0.0, 0.7], [0.0, 1.85]);
    b.add(fridge, body, fridge_mat);
    b.claim(&body);
    let fridge_handle_mat = b.pick(&[STEEL, BLACK_PLASTIC, CHROME]);
    for z in [[0.95, 1.45], [0.45, 0.75]] {
        let bar = wall.cuboid([0.66, 0.685], [0.7, 0.735], z);
        b.part(Some(fridge), "fridge handle", fridge_handle_mat, fridge, &[bar]);
    }
}

/// Run 1, past the fridge: sink, stove and drawers in a random order, then cabinets; wall
/// cabinets above most. The plain cabinets (neither sink nor stove nor drawers), with where
/// they stand.
fn first_run(b: &mut Builder, wall: Wall, front: Material, metals: &mut Metals) -> Vec<(Footprint, u16)> {
    let mut modules = [Module::Sink, Module::Stove, Module::Drawers];
    modules.shuffle(&mut b.rng);
    let mut plain = Vec::new();
    let mut s = 0.8;
    let mut k = 0;
    loop {
        let module = modules.get(k).copied().unwrap_or(Module::Cabinet);
        k += 1;
        let width = module.width(&mut b.rng);
        if s + width > wall.len - 0.05 {
            if width > 0.6 && s + 0.6 <= wall.len - 0.05 && module == Module::Cabinet {
                continue;
            }
            break;
        }
        let grip = if b.rng.random_bool(0.8) { Grip::Handle } else { Grip::Knob };
        let at = Footprint { wall, s0: s, width, depth: DEPTH };
        match module {
            Module::Sink => {
                if let Some(cab) = cabinet(b, at, [0.0, TOP], front, grip, metals) {
                    sink_with_faucet(b, at, TOP, cab);
                    upper_cabinet(b, at, front, metals, cab);
                }
            }
            Module::Stove => stove(b, wall, s),
            Module::Drawers => {
                let grip = if b.rng.random_bool(0.7) { Grip::Handle } else { Grip::Knob };
                drawer_stack(b, at, TOP, 3, front, grip, metals);
            }
            Module::Cabinet | Module::Trash => {
                if let Some(cab) = cabinet(b, at, [0.0, TOP], front, grip, metals) {
                    plain.push((at, cab));
                    if b.rng.random_bool(0.7) {
                        upper_cabinet(b, at, front, metals, cab);
                    }
                }
            }
        }
        s += width;
    }
    plain
}

/// Run 2 (starts past run 1's depth): cabinets, trash can, more cabinets. The cabinets, with
/// where they stand.
fn second_run(b: &mut Builder, wall: Wall, front: Material, metals: &mut Metals) -> Vec<(Footprint, u16)> {
    let mut s = 0.7;
    let mut plain = Vec::new();
    for module in [Module::Cabinet, Module::Cabinet, Module::Trash, Module::Cabinet, Module::Cabinet] {
        let width = module.width(&mut b.rng);
        if s + width > wall.len - 0.05 {
            continue;
        }
        match module {
            Module::Trash => trash_can(b, wall, s),
            _ => {
                let grip = if b.rng.random_bool(0.8) { Grip::Handle } else { Grip::Knob };
                let at = Footprint { wall, s0: s, width, depth: DEPTH };
                if let Some(cab) = cabinet(b, at, [0.0, TOP], front, grip, metals) {
                    plain.push((at, cab));
                }
            }
        }
        s += width;
    }
    plain
}

/// Countertop appliances on the first plain cabinets, in order a kettle, a microwave and a
/// toaster, each with a wall outlet.
fn countertop_appliances(b: &mut Builder, plain: &[(Footprint, u16)]) {
    let mut tops = plain.iter().copied();
    if let Some((at, cab)) = tops.next() {
        kettle(b, at, cab);
    }
    if let Some((at, cab)) = tops.next() {
        microwave(b, at, cab);
    }
    if let Some((at, cab)) = tops.next() {
        toaster(b, at, cab);
    }
}

fn kettle(b: &mut Builder, at: Footprint, cab: u16) {
    let Footprint { wall, s0, width, .. } = at;
    let sc = s0 + width * 0.5;
    let kettle_mat = b.pick(&[RED_ENAMEL, STEEL, WHITE_PLASTIC]);
    let kettle = b.object("kettle", &["electric kettle"], kettle_mat);
    b.add(kettle, wall.post(sc - 0.05, 0.3, [TOP, TOP + 0.22], 0.09), kettle_mat);
    b.add(kettle, wall.cuboid([sc - 0.07, sc - 0.03], [0.28, 0.32], [TOP + 0.22, TOP + 0.25]), BLACK_PLASTIC);
    b.spatial(kettle, cab, "on");
    outlet(b, wall, sc + 0.17, 1.08, kettle);
}

fn microwave(b: &mut Builder, at: Footprint, cab: u16) {
    let Footprint { wall, s0, width, .. } = at;
    let sc = s0 + width * 0.5;
    let shell = b.pick(&[WHITE_LACQUER, STEEL, BLACK_PLASTIC]);
    let microwave = b.object("microwave", &["microwave oven"], shell);
    let body = wall.cuboid([sc - 0.24, sc + 0.24], [0.1, 0.45], [TOP, TOP + 0.3]);
    b.add(microwave, body, shell);
    b.add(microwave, wall.cuboid([sc - 0.22, sc + 0.08], [0.45, 0.455], [TOP + 0.04, TOP + 0.26]), DARK_GLASS);
    let button = wall.cuboid([sc + 0.12, sc + 0.19], [0.45, 0.462], [TOP + 0.06, TOP + 0.1]);
    b.part(Some(microwave), "microwave button", BLACK_PLASTIC, microwave, &[button]);
    b.spatial(microwave, cab, "on");
    outlet(b, wall, sc + 0.33, 1.08, microwave);
}

fn toaster(b: &mut Builder, at: Footprint, cab: u16) {
    let Footprint { wall, s0, width, .. } = at;
    let sc = s0 + width * 0.5;
    let toaster_mat = b.pick(&[STEEL, RED_ENAMEL, BLACK_PLASTIC]);
    let toaster = b.object("toaster", &[], toaster_mat);
    b.add(toaster, wall.cuboid([sc - 0.14, sc + 0.14], [0.15, 0.33], [TOP, TOP + 0.2]), toaster_mat);
    let lever = wall.cuboid([sc + 0.14, sc + 0.16], [0.22, 0.26], [TOP + 0.12, TOP + 0.14]);
    b.part(Some(toaster), "toaster lever", BLACK_PLASTIC, toaster, &[lever]);
    b.spatial(toaster, cab, "on");
    outlet(b, wall, sc + 0.24, 1.08, toaster);
}

/// A wall cabinet with handles above the base module at `below_at` (the cabinet `below`).
fn upper_cabinet(b: &mut Builder, below_at: Footprint, front: Material, metals: &mut Metals, below: u16) {
    let at = Footprint { depth: 0.35, ..below_at };
    if let Some(upper) = cabinet(b, at, [1.45, 2.15], front, Grip::Handle, metals) {
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
        b.part(Some(stove), "stove knob", knob_mat, stove, &[knob]);
    }
    // The oven door opens by a bar handle, or in some cookers by a knob.
    match OVEN_DOOR_KNOB.truth.as_ref().filter(|_| b.deviates(&OVEN_DOOR_KNOB)) {
        Some(truth) => {
            let knob = wall.knob(s0 + 0.3, 0.6, 0.69, 0.02, 0.03);
            let id = b.part_as(Some(stove), truth, STEEL, Some(stove), &[knob]);
            b.record(&OVEN_DOOR_KNOB, id);
        }
        None => {
            let bar = wall.cuboid([s0 + 0.1, s0 + 0.5], [0.615, 0.64], [0.68, 0.7]);
            b.part(Some(stove), "oven handle", STEEL, stove, &[bar]);
        }
    }
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
    b.part(Some(can), "pedal", BLACK_PLASTIC, can, &[pedal]);
}
