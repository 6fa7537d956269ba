//! The living room: a TV stand with drawers, TV, game console and power strip, a sofa, a coffee
//! table with the remote, a floor lamp, a sideboard with a table lamp, a door with its switch, a
//! window.

use rand::Rng;

use super::builder::Builder;
use super::furniture::{Footprint, Grip, Metals, cabinet, ceiling_light, door_and_switches, outlet, window};
use super::materials::{
    BLACK_METAL, BLACK_PLASTIC, BLUE_FABRIC, BRASS, DARK_GLASS, GREY_FABRIC, GREY_LAMINATE, LAMP_SHADE, LINEN,
    WHITE_LACQUER, WHITE_PLASTIC, WOOD_DARK, WOOD_LIGHT,
};
use crate::truth::REMOTE_AWAY_FROM_TV;

pub(super) fn living_room(b: &mut Builder, base: usize) {
    let tv_wall = b.wall(base);
    let side_wall = b.wall(base + 1);
    let sofa_wall = b.wall(base + 2);
    let door_wall = b.wall(base + 3);
    let wood = b.pick(&[WOOD_LIGHT, WOOD_DARK, WHITE_LACQUER, GREY_LAMINATE]);
    let mut metals = Metals::new(b.two_metals());
    let light = ceiling_light(b, b.size.x * 0.5, b.size.y * 0.5);

    // TV stand with drawers, TV, game console, power strip.
    let sc = tv_wall.len * 0.5;
    let stand = b.object("tv stand", &["tv cabinet", "media console"], wood);
    let body = tv_wall.cuboid([sc - 0.7, sc + 0.7], [0.0, 0.45], [0.0, 0.5]);
    b.add(stand, body, wood);
    b.claim(&body);
    for s in [sc - 0.35, sc + 0.35] {
        let metal = metals.next();
        let bar = tv_wall.cuboid([s - 0.06, s + 0.06], [0.45, 0.475], [0.39, 0.41]);
        b.part(Some(stand), "drawer handle", metal, stand, &[bar]);
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
    b.part(Some(console), "power button", BLACK_PLASTIC, console, &[button]);

    let strip = b.object("power strip", &["extension cord", "multi plug"], WHITE_PLASTIC);
    let body = tv_wall.cuboid([sc + 0.8, sc + 1.2], [0.05, 0.12], [0.0, 0.04]);
    b.add(strip, body, WHITE_PLASTIC);
    b.claim(&body);
    for (k, target) in [tv, console].into_iter().enumerate() {
        let s = sc + 0.86 + 0.1 * k as f32;
        let socket = tv_wall.cuboid([s, s + 0.05], [0.06, 0.11], [0.04, 0.046]);
        b.part(Some(strip), "power outlet", BLACK_PLASTIC, target, &[socket]);
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
    b.acts_on(remote, tv);
    // Where the remote lies: on the coffee table, else on the sofa; the sideboard below may take
    // it away from the TV (a deviation).
    let (mut remote_box, mut remote_on) = if b.fits(&sofa_wall.cuboid([ss - 0.5, ss + 0.5], [1.35, 1.9], [0.0, 0.42])) {
        b.claim(&sofa_wall.cuboid([ss - 0.5, ss + 0.5], [1.35, 1.9], [0.0, 0.42]));
        let table = b.object("coffee table", &["table", "low table"], wood);
        b.add(table, top, wood);
        for (ls, lt) in [(-0.45, 1.4), (0.42, 1.4), (-0.45, 1.82), (0.42, 1.82)] {
            b.add(table, sofa_wall.cuboid([ss + ls, ss + ls + 0.03], [lt, lt + 0.03], [0.0, 0.38]), wood);
        }
        (sofa_wall.cuboid([ss - 0.12, ss + 0.05], [1.6, 1.65], [0.42, 0.44]), table)
    } else {
        (sofa_wall.cuboid([ss - 0.12, ss + 0.05], [0.5, 0.55], [0.42, 0.44]), sofa)
    };

    let ls = ss + 1.3;
    let lamp_zone = sofa_wall.cuboid([ls - 0.2, ls + 0.2], [0.1, 0.5], [0.0, 1.7]);
    let mut floor_lamp = None;
    if b.fits(&lamp_zone) {
        b.claim(&lamp_zone);
        let lamp = b.object("floor lamp", &["lamp", "standing lamp"], LAMP_SHADE);
        floor_lamp = Some(lamp);
        b.add(lamp, sofa_wall.post(ls, 0.3, [0.0, 0.03], 0.15), BLACK_METAL);
        b.add(lamp, sofa_wall.post(ls, 0.3, [0.03, 1.4], 0.015), BLACK_METAL);
        b.add(lamp, sofa_wall.post(ls, 0.3, [1.4, 1.7], 0.2), LAMP_SHADE);
        let switch = sofa_wall.post(ls, 0.3, [0.98, 1.03], 0.028);
        b.part(Some(lamp), "lamp switch", BLACK_PLASTIC, lamp, &[switch]);
        outlet(b, sofa_wall, ls + 0.3, 0.3, lamp);
    }

    // Sideboard (cabinet) with a table lamp on the side wall.
    let grip = if b.rng.random_bool(0.5) { Grip::Handle } else { Grip::Knob };
    let s0 = side_wall.len * 0.5 - 0.6;
    let sideboard_at = Footprint { wall: side_wall, s0, width: 1.2, depth: 0.45 };
    if let Some(cab) = cabinet(b, sideboard_at, [0.0, 0.8], wood, grip, &mut metals) {
        let lamp = b.object("lamp", &["table lamp"], LAMP_SHADE);
        let ls = s0 + 0.25;
        b.add(lamp, side_wall.post(ls, 0.2, [0.8, 0.84], 0.07), BRASS);
        b.add(lamp, side_wall.post(ls, 0.2, [0.84, 1.1], 0.01), BRASS);
        b.add(lamp, side_wall.post(ls, 0.2, [1.1, 1.3], 0.12), LAMP_SHADE);
        b.spatial(lamp, cab, "on");
        let switch = side_wall.post(ls + 0.04, 0.2, [0.84, 0.855], 0.012);
        b.part(Some(lamp), "lamp switch", WHITE_PLASTIC, lamp, &[switch]);
        outlet(b, side_wall, ls - 0.15, 0.95, lamp);
        if b.deviates(&REMOTE_AWAY_FROM_TV) {
            remote_box = side_wall.cuboid([s0 + 0.95, s0 + 1.12], [0.2, 0.25], [0.8, 0.82]);
            remote_on = cab;
            b.record(&REMOTE_AWAY_FROM_TV, remote);
        }
    }
    b.add(remote, remote_box, BLACK_PLASTIC);
    b.spatial(remote, remote_on, "on");

    door_and_switches(b, door_wall, 0.8, &[light], floor_lamp);
    window(b, door_wall, door_wall.len - 1.9, 1.0);
}
