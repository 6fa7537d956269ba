use glam::{DQuat, DVec3};
use op3dsg_drivers::frame::Intrinsics;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::OCCUPANCY_UNKNOWN;

use super::*;
use crate::world::UpAxis;

fn intrinsics() -> Intrinsics {
    Intrinsics { width: 64, height: 48, fx: 40.0, fy: 40.0, cx: 32.0, cy: 24.0 }
}

/// A camera 1 m above the floor at the origin looking along +x (z up): camera z = world x,
/// camera x = world -y, camera y = world -z.
fn looking_along_x() -> Isometry {
    let rotation = DQuat::from_mat3(&glam::DMat3::from_cols(DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X));
    Isometry::new(rotation, DVec3::new(0.0, 0.0, 1.0))
}

#[test]
fn bresenham_visits_every_cell_once_end_included() {
    let mut cells = Vec::new();
    bresenham(0, 0, 4, 2, |c, r| cells.push((c, r)));
    assert_eq!(cells.first(), Some(&(0, 0)));
    assert_eq!(cells.last(), Some(&(4, 2)));
    assert_eq!(cells.len(), 5);
    let mut back = Vec::new();
    bresenham(3, 3, 3, -1, |c, r| back.push((c, r)));
    assert_eq!(back, [(3, 3), (3, 2), (3, 1), (3, 0), (3, -1)]);
}

#[test]
fn a_wall_ahead_is_occupied_and_the_floor_before_it_free() {
    // Depth of a wall 2 m ahead (x = 2) for pixels looking above the floor, the floor for
    // those that meet it first.
    let k = intrinsics();
    let pose = looking_along_x();
    let mut depth = vec![0u16; (k.width * k.height) as usize];
    for v in 0..k.height {
        let b = (v as f64 - f64::from(k.cy)) / f64::from(k.fy);
        for u in 0..k.width {
            // Ray direction in world: (1, -a, -b); floor at z = 0 is met at t = 1 / b.
            let t_wall = 2.02;
            let t = if b > 0.0 { (1.0 / b).min(t_wall) } else { t_wall };
            depth[(v * k.width + u) as usize] = (t * 1000.0) as u16;
        }
    }
    let config = OccupancyConfig { size_m: 6.0, centre_m: Some([0.0, 0.0]), pixel_stride: 2, ..Default::default() };
    let mut grid = OccupancyGrid::new(&config, UpAxis::Z, 0.2, &k);
    let mut scan = DepthScan::with_capacity(&k, config.pixel_stride);
    scan.fill(&depth, &k, 1000.0, &pose, 1);
    let memory = grid.allocated_bytes();
    grid.integrate(&scan);
    grid.integrate(&scan);
    assert_eq!(grid.allocated_bytes(), memory, "integration grows no buffer");
    assert_eq!(grid.memory_bytes(), memory);
    let g = grid.geometry();
    let at = |x: f32, y: f32| {
        let (c, r) = g.cell_of([x, y]);
        grid.cell_percent(g.index(c, r).unwrap())
    };
    assert!(at(2.02, 0.0) >= 65, "wall cell {}", at(2.02, 0.0));
    assert!((0..=35).contains(&at(1.0, 0.0)), "floor before the wall {}", at(1.0, 0.0));
    assert!((0..=35).contains(&at(0.0, 0.0)), "under the robot {}", at(0.0, 0.0));
    assert_eq!(at(-2.0, 0.0), OCCUPANCY_UNKNOWN, "behind the camera");
    assert_eq!(at(2.6, 0.0), OCCUPANCY_UNKNOWN, "behind the wall");
    let robot = grid.robot().unwrap();
    assert!(robot.yaw_rad.abs() < 1e-5 && robot.xy == [0.0, 0.0], "{robot:?}");
}

#[test]
fn validation_names_the_field() {
    let bad = OccupancyConfig { cell_size_m: 0.0, ..Default::default() };
    assert!(bad.validate("occupancy").unwrap_err().starts_with("occupancy.cell_size_m"));
    let bad = OccupancyConfig { size_m: 500.0, ..Default::default() };
    assert!(bad.validate("occupancy").unwrap_err().starts_with("occupancy.size_m"));
    let bad = OccupancyConfig { obstacle_min_height_m: 2.0, ..Default::default() };
    assert!(bad.validate("occupancy").unwrap_err().contains("obstacle_min_height_m"));
    assert!(OccupancyConfig::default().validate("occupancy").is_ok());
}
