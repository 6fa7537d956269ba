//! The shared material palette: furniture fronts, handle metals, plastics, glass, fabrics, and
//! the floors, walls and ceiling the rooms draw from.

use crate::scene::Material;

pub(super) const WOOD_LIGHT: Material = Material::new("light wood", [0.72, 0.55, 0.36], 0.1, 8.0);
pub(super) const WOOD_DARK: Material = Material::new("dark wood", [0.35, 0.22, 0.12], 0.15, 12.0);
pub(super) const WHITE_LACQUER: Material = Material::new("white lacquer", [0.88, 0.88, 0.86], 0.3, 30.0);
pub(super) const GREY_LAMINATE: Material = Material::new("grey laminate", [0.48, 0.5, 0.53], 0.1, 10.0);
pub(super) const SAGE_PAINT: Material = Material::new("sage green paint", [0.42, 0.56, 0.42], 0.1, 10.0);
pub(super) const NAVY_PAINT: Material = Material::new("navy paint", [0.16, 0.22, 0.4], 0.15, 12.0);
pub(super) const STEEL: Material = Material::new("brushed steel", [0.7, 0.72, 0.75], 0.8, 40.0);
pub(super) const BRASS: Material = Material::new("brass", [0.78, 0.58, 0.2], 0.9, 50.0);
pub(super) const BLACK_METAL: Material = Material::new("black metal", [0.07, 0.07, 0.08], 0.6, 40.0);
pub(super) const COPPER: Material = Material::new("copper", [0.72, 0.4, 0.24], 0.85, 45.0);
pub(super) const CHROME: Material = Material::new("chrome", [0.85, 0.86, 0.9], 1.0, 80.0);
pub(super) const WHITE_PLASTIC: Material = Material::new("white plastic", [0.94, 0.94, 0.91], 0.3, 20.0);
pub(super) const BLACK_PLASTIC: Material = Material::new("black plastic", [0.09, 0.09, 0.1], 0.4, 25.0);
pub(super) const RED_PLASTIC: Material = Material::new("red plastic", [0.8, 0.1, 0.08], 0.5, 30.0);
pub(super) const CERAMIC: Material = Material::new("white ceramic", [0.95, 0.95, 0.97], 0.6, 60.0);
pub(super) const DARK_GLASS: Material = Material::new("dark glass", [0.05, 0.06, 0.08], 0.9, 80.0);
pub(super) const WINDOW_GLASS: Material = Material::new("window glass", [0.55, 0.72, 0.85], 0.7, 60.0);
pub(super) const MIRROR: Material = Material::new("mirror", [0.72, 0.78, 0.84], 1.0, 100.0);
pub(super) const BLUE_FABRIC: Material = Material::new("blue fabric", [0.2, 0.3, 0.55], 0.0, 1.0);
pub(super) const GREY_FABRIC: Material = Material::new("grey fabric", [0.45, 0.45, 0.47], 0.0, 1.0);
pub(super) const LINEN: Material = Material::new("white linen", [0.9, 0.87, 0.82], 0.0, 1.0);
pub(super) const RED_ENAMEL: Material = Material::new("red enamel", [0.75, 0.12, 0.1], 0.6, 40.0);
pub(super) const LIGHT_DIFFUSER: Material = Material::emissive("light diffuser", [1.0, 0.98, 0.92], 0.9);
pub(super) const LAMP_SHADE: Material = Material::emissive("lamp shade", [0.95, 0.88, 0.7], 0.5);

pub(super) const FRONTS: [Material; 5] = [WHITE_LACQUER, GREY_LAMINATE, WOOD_LIGHT, SAGE_PAINT, NAVY_PAINT];
pub(super) const HANDLE_METALS: [Material; 4] = [STEEL, BRASS, BLACK_METAL, COPPER];
pub(super) const FLOORS: [Material; 3] = [
    Material::new("oak floor", [0.6, 0.45, 0.3], 0.15, 10.0),
    Material::new("grey tile", [0.6, 0.6, 0.62], 0.3, 20.0),
    Material::new("terracotta tile", [0.66, 0.38, 0.26], 0.2, 15.0),
];
pub(super) const WALLS: [Material; 3] = [
    Material::new("beige paint", [0.85, 0.8, 0.7], 0.0, 1.0),
    Material::new("pale blue paint", [0.72, 0.8, 0.86], 0.0, 1.0),
    Material::new("pale green paint", [0.76, 0.84, 0.74], 0.0, 1.0),
];
pub(super) const CEILING: Material = Material::new("white ceiling", [0.95, 0.95, 0.95], 0.0, 1.0);
