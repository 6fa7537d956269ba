//! The colour-panel test scene: one control panel whose rows of knobs and push buttons share a
//! label within the row and differ in colour, so telling neighbours apart needs colour features.

use rand::seq::SliceRandom;

use super::builder::Builder;
use super::furniture::ceiling_light;
use crate::scene::Material;

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

pub(crate) const PANEL_KNOB_SPACING_M: f32 = 0.04;
/// Centre spacing of the push buttons in a row, metres (2.5 cm buttons: 5 mm gaps).
pub(crate) const PANEL_BUTTON_SPACING_M: f32 = 0.03;

/// A floor-standing control panel in the middle of a wall: a row of six knobs, a row of six
/// push buttons and another row of six knobs, each row in six different colours (shuffled per
/// seed), so every part's neighbours in its row share its label and differ in colour.
pub(super) fn colour_panel(b: &mut Builder, base: usize) {
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
                b.part(Some(panel), "knob", colour, panel, &[knob]);
            } else {
                let s = sc + offset * PANEL_BUTTON_SPACING_M;
                let button = wall.cuboid([s - 0.0125, s + 0.0125], [DEPTH, DEPTH + 0.012], [z - 0.0125, z + 0.0125]);
                b.part(Some(panel), "push button", colour, panel, &[button]);
            }
        }
    }
}
