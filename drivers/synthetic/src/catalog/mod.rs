//! The room catalog: procedural layouts of the synthetic rooms, which furniture goes where,
//! built from boxes and cylinders, with their parts, materials and ground-truth relations;
//! [`Scene::generate`] picks a room's size and structure and runs its layout.
//!
//! Furniture stands against the walls. Each wall has a local frame: `s` along the wall, `t`
//! into the room (0 at the wall), `z` up; fronts face the room. Placement refuses anything that
//! would overlap what is already placed ([`Builder::fits`]), so optional furniture is dropped
//! rather than overlapped in small rooms.
//!
//! | module | what |
//! |---|---|
//! | [`builder`] | wall frames and the builder that accumulates instances, primitives and edges, then finishes the scene |
//! | [`materials`] | the shared material palette |
//! | [`relations`] | the canonical relation phrases |
//! | [`furniture`] | furniture every room uses: lights, doors and switches, outlets, windows, cabinets, drawers, sinks |
//! | [`kitchen`], [`bathroom`], [`bedroom`], [`living_room`] | the benchmark rooms |
//! | [`colour_panel`] | the colour-panel test scene |
//!
//! What each part does and its affordances come from [`crate::truth`] (the ground-truth table
//! and the rooms that differ from it), never from the runtime's knowledge base.

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::RoomKind;
use super::scene::{CEILING_HEIGHT_M, Scene};

mod bathroom;
mod bedroom;
mod builder;
mod colour_panel;
mod furniture;
mod kitchen;
mod living_room;
mod materials;
mod relations;

use builder::Builder;
use materials::{CEILING, FLOORS, WALLS};
pub use relations::{FUNCTIONAL_RELATIONS, SPATIAL_RELATIONS};

impl Scene {
    /// Generates the room `room` from `seed` (deterministic).
    pub fn generate(room: RoomKind, seed: u64) -> Scene {
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
        // Deviations from the usual ground truth draw from a stream of their own.
        let deviation_rng = ChaCha8Rng::seed_from_u64(seed ^ room_salt ^ 0x5EED_D3F1_A7E0_0001);
        let mut b = Builder::new(rng, deviation_rng, size);
        let base = b.rng.random_range(0..4usize);
        match room {
            RoomKind::Kitchen => kitchen::kitchen(&mut b, base),
            RoomKind::Bathroom => bathroom::bathroom(&mut b, base),
            RoomKind::Bedroom => bedroom::bedroom(&mut b, base),
            RoomKind::LivingRoom => living_room::living_room(&mut b, base),
            RoomKind::ColourPanel => colour_panel::colour_panel(&mut b, base),
        }
        b.finish(room, seed, structure)
    }
}
