//! The bathroom: a bathtub and its faucet, a toilet with its flush button, a vanity with sink,
//! mirror and wall light, drawers with a hair dryer, a door with its switches, a radiator with
//! its valve under a wall cabinet.

use rand::Rng;

use super::builder::Builder;
use super::furniture::{
    Footprint, Grip, Metals, cabinet, ceiling_light, door_and_switches, drawer_stack, outlet, sink_with_faucet,
};
use super::materials::{
    BLACK_PLASTIC, BRASS, CERAMIC, CHROME, FRONTS, LIGHT_DIFFUSER, MIRROR, RED_PLASTIC, WHITE_LACQUER, WHITE_PLASTIC,
};
use crate::scene::{Axis, Shape};

pub(super) fn bathroom(b: &mut Builder, base: usize) {
    let tub_wall = b.wall(base);
    let vanity_wall = b.wall(base + 1);
    let door_wall = b.wall(base + 2);
    let radiator_wall = b.wall(base + 3);
    let front = b.pick(&FRONTS);
    let mut metals = Metals::new(b.two_metals());
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
    b.part(Some(tub), "faucet", faucet_metal, tub, &[mixer, spout]);

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
    b.part(Some(toilet), "flush button", CHROME, toilet, &[button]);

    let v0 = t0 + 0.7;
    let vanity_at = Footprint { wall: vanity_wall, s0: v0, width: 0.8, depth: 0.5 };
    let vanity = cabinet(b, vanity_at, [0.0, 0.8], front, Grip::Handle, &mut metals);
    if let Some(vanity) = vanity {
        sink_with_faucet(b, vanity_at, 0.8, vanity);
        let mirror = b.object("mirror", &[], MIRROR);
        b.add(mirror, vanity_wall.cuboid([v0 + 0.1, v0 + 0.7], [0.0, 0.02], [1.2, 1.85]), MIRROR);
        b.spatial(mirror, vanity, "above");
    }
    let wall_light = b.object("wall light", &["light", "lamp", "sconce"], LIGHT_DIFFUSER);
    b.add(wall_light, vanity_wall.cuboid([v0 + 0.25, v0 + 0.55], [0.0, 0.08], [1.92, 1.99]), LIGHT_DIFFUSER);
    let d0 = v0 + 0.8;
    let grip = if b.rng.random_bool(0.5) { Grip::Handle } else { Grip::Knob };
    let drawers_at = Footprint { wall: vanity_wall, s0: d0, width: 0.4, depth: 0.5 };
    let drawers = drawer_stack(b, drawers_at, 0.8, 2, front, grip, &mut metals);
    if let Some(&top) = drawers.last() {
        let dryer_mat = b.pick(&[BLACK_PLASTIC, WHITE_PLASTIC, RED_PLASTIC]);
        let dryer = b.object("hair dryer", &["blow dryer"], dryer_mat);
        b.add(dryer, vanity_wall.cuboid([d0 + 0.1, d0 + 0.3], [0.15, 0.23], [0.8, 0.88]), dryer_mat);
        b.add(dryer, vanity_wall.cuboid([d0 + 0.17, d0 + 0.21], [0.23, 0.33], [0.8, 0.84]), dryer_mat);
        b.spatial(dryer, top, "on");
        outlet(b, vanity_wall, d0 + 0.2, 1.05, dryer);
    }

    door_and_switches(b, door_wall, 0.7, &[light, wall_light], None);

    // Radiator with its valve; a wall cabinet with knobs above it.
    let rs = radiator_wall.len * 0.5;
    let radiator = b.object("radiator", &["heater"], WHITE_LACQUER);
    let panel = radiator_wall.cuboid([rs - 0.4, rs + 0.4], [0.03, 0.13], [0.15, 0.75]);
    b.add(radiator, panel, WHITE_LACQUER);
    b.claim(&panel);
    let valve = radiator_wall.post(rs + 0.45, 0.08, [0.12, 0.2], 0.022);
    b.part(Some(radiator), "radiator valve", WHITE_PLASTIC, radiator, &[valve]);
    let mut knobs = Metals::new([metals.pair[1], metals.pair[0]]);
    let cabinet_at = Footprint { wall: radiator_wall, s0: rs - 0.3, width: 0.7, depth: 0.25 };
    cabinet(b, cabinet_at, [1.4, 2.0], front, Grip::Knob, &mut knobs);
}
