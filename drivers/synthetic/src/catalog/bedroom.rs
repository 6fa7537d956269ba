//! The bedroom: a bed between nightstands with lamps, a dresser under a window, a door with its
//! switch, a wardrobe.

use rand::Rng;

use super::builder::Builder;
use super::furniture::{Grip, Metals, ceiling_light, door_and_switches, outlet, window};
use super::materials::{
    BLACK_METAL, BLUE_FABRIC, GREY_FABRIC, HANDLE_METALS, LAMP_SHADE, LINEN, WHITE_LACQUER, WHITE_PLASTIC, WOOD_DARK,
    WOOD_LIGHT,
};

pub(super) fn bedroom(b: &mut Builder, base: usize) {
    let bed_wall = b.wall(base);
    let dresser_wall = b.wall(base + 1);
    let door_wall = b.wall(base + 2);
    let wardrobe_wall = b.wall(base + 3);
    let wood = b.pick(&[WOOD_LIGHT, WOOD_DARK, WHITE_LACQUER]);
    let mut metals = Metals::new(b.two_metals());
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
        let metal = metals.next();
        let knob = bed_wall.knob(ns, 0.4, 0.44, 0.015, 0.025);
        b.part(Some(stand), "drawer knob", metal, stand, &[knob]);
        let lamp = b.object("lamp", &["table lamp", "bedside lamp"], LAMP_SHADE);
        b.add(lamp, bed_wall.post(ns, 0.2, [0.55, 0.6], 0.07), BLACK_METAL);
        b.add(lamp, bed_wall.post(ns, 0.2, [0.6, 0.85], 0.01), BLACK_METAL);
        b.add(lamp, bed_wall.post(ns, 0.2, [0.85, 1.05], 0.12), LAMP_SHADE);
        b.spatial(lamp, stand, "on");
        let switch = bed_wall.post(ns + side * 0.04, 0.2, [0.6, 0.615], 0.012);
        b.part(Some(lamp), "lamp switch", WHITE_PLASTIC, lamp, &[switch]);
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
                let metal = metals.next();
                match grip {
                    Grip::Handle => {
                        let bar = dresser_wall.cuboid([s - 0.06, s + 0.06], [0.5, 0.525], [zc - 0.01, zc + 0.01]);
                        b.part(Some(dresser), "drawer handle", metal, dresser, &[bar]);
                    }
                    Grip::Knob => {
                        let knob = dresser_wall.knob(s, 0.5, zc, 0.015, 0.025);
                        b.part(Some(dresser), "drawer knob", metal, dresser, &[knob]);
                    }
                }
            }
        }
    }
    window(b, dresser_wall, (dresser_wall.len - 1.0) * 0.5, 1.0);

    door_and_switches(b, door_wall, door_wall.len * 0.5 - 0.45, &[light], None);

    let body = wardrobe_wall.cuboid([0.3, 1.3], [0.0, 0.6], [0.0, 2.0]);
    if b.fits(&body) {
        b.claim(&body);
        let wardrobe = b.object("wardrobe", &["closet", "armoire"], wood);
        b.add(wardrobe, body, wood);
        let metal = b.pick(&HANDLE_METALS);
        for s in [0.76, 0.84] {
            let bar = wardrobe_wall.cuboid([s - 0.01, s + 0.01], [0.6, 0.625], [0.95, 1.25]);
            b.part(Some(wardrobe), "wardrobe handle", metal, wardrobe, &[bar]);
        }
    }
}
