//! # The 2D occupancy map: depth and poses → free and occupied floor cells
//!
//! A fixed-size square grid on the floor plane (`[occupancy]`: `size_m` side, `cell_size_m`
//! cells, centred on `centre_m` or, unset, on the first keyframe's camera position), allocated
//! once when the daemon starts; nothing grows afterwards ([`OccupancyGrid::memory_bytes`]).
//! Every keyframe is integrated on a thread of its own ([`service`]), never on the fusion
//! thread; the planner on top of it is [`nav`].
//!
//! ## Integration of one keyframe ([`OccupancyGrid::integrate`])
//!
//! 1. Every `pixel_stride`-th pixel in both directions (8: 80 × 60 rays for 640 × 480) with a
//!    depth is back-projected (`point_in_camera = ((u - cx) / fx · d, (v - cy) / fy · d, d)`) and
//!    moved into the world (`world_from_camera`). Its height above the floor is
//!    `h = up · point_in_world - floor_height_m`.
//! 2. A point within the obstacle band `[obstacle_min_height_m, obstacle_max_height_m]` is a
//!    **hit**: its cell gets evidence of occupancy. A point below the band is floor: its cell is
//!    free evidence. A point above the band (ceiling, top of a wardrobe) is left out altogether
//!    (it says nothing about the band below it). A ray longer than `max_range_m` is cut there
//!    and its end is not a hit.
//! 3. **Free space by ray casting**: the cells of the 2D Bresenham line from the camera's floor
//!    projection to the end cell (the end excluded when it is a hit) get evidence of freedom.
//! 4. Each cell changes at most once per keyframe (a hit wins over free), so the many rays near
//!    the camera do not count as many observations.
//! 5. The robot stands where the camera is: the cells within `navigation.robot_radius_m` of the
//!    camera's floor projection are made free (the camera does not see the floor under itself).
//!
//! Evidence is **log-odds**: `l += hit_log_odds` for a hit (0.85: p = 0.70), `l -= miss_log_odds`
//! for free (0.7: p = 0.33), clamped to `±max_log_odds`. Published cells are the probability
//! `p = 1 - 1 / (1 + e^l)` in percent, `-1` for a cell never updated
//! ([`op3dsg_ipc_types::occupancy_types`]); free ≤ 35 %, occupied ≥ 65 %, so one clear
//! observation makes a cell free and one hit makes it occupied, and a hit seen once, then seen
//! through twice (a person who walked away) is free again.
//!
//! Known limits: a 2D map of a 3D band: a ray that passes over a low obstacle (below the camera)
//! to the floor behind it counts the obstacle's cell as free at that keyframe; hits are stronger
//! than misses so an obstacle seen from several keyframes stays occupied, but a low, thin one
//! seen once may not. Overhangs above `obstacle_max_height_m` are ignored by design (set it to
//! the robot's height).
//!
//! ## Cost and memory
//!
//! Per keyframe: `(width / stride) · (height / stride)` rays of at most `max_range_m /
//! cell_size_m` cells (`op3dsg bench nav` prints p50/p99 per keyframe). Memory: 4 bytes of
//! log-odds and 4 of per-keyframe marks per cell (20 m at 5 cm: 400 × 400 cells, 1.22 MiB), plus
//! a fixed buffer of ray ends (1.29 MiB in all at 640 × 480, as `op3dsg bench nav` prints).
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[occupancy]` ([`OccupancyConfig`]); `[navigation]` is `nav.rs`'s |
//! | `scan.rs` | [`DepthScan`], the floor plane, the robot's pose |
//! | `grid.rs` | [`OccupancyGrid`] and its [`GridGeometry`] |
//! | `nav.rs` | approach poses and A* on the grid ([`Planner`]) |
//! | `persist.rs` | the map's file beside the map snapshot ([`persist::OccupancyStore`]) |
//! | `publisher.rs` | `<prefix>/occupancy` ([`OccupancyPublisher`]) |
//! | `thread.rs` | [`OccupancyThread`], its scan queue and the query worker's copy of the map |

mod config;
mod grid;
pub mod nav;
pub mod persist;
mod publisher;
mod scan;
mod thread;

#[cfg(test)]
mod tests;

pub use config::OccupancyConfig;
pub use grid::{GridGeometry, OccupancyGrid, bresenham};
pub use nav::{Approach, NavigationConfig, Planner, Target};
pub use publisher::OccupancyPublisher;
pub use scan::{DepthScan, PlanePoint, RobotPose, to_plane};
pub use thread::{
    LatestOccupancy, MapCopy, OccupancyFeed, OccupancyIntake, OccupancyThread, copy_if_newer, scan_queue,
};
