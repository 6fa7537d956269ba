//! `[occupancy]`: the 2D occupancy map's size, resolution, heights and rates.

use op3dsg_ipc_types::OCCUPANCY_MAX_SIDE_CELLS;
use serde::{Deserialize, Serialize};

/// `[occupancy]`: the 2D occupancy map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OccupancyConfig {
    /// Build the map and publish it on `<prefix>/occupancy`.
    pub enabled: bool,
    /// Side of a square cell, metres.
    pub cell_size_m: f32,
    /// Side of the square grid, metres (fixed at start; `size_m / cell_size_m` cells a side).
    pub size_m: f32,
    /// Centre of the grid on the floor plane (`[x, y]` with z up, `[x, z]` with y up), metres;
    /// unset: the first keyframe's camera position.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub centre_m: Option<[f32; 2]>,
    /// World coordinate of the floor along the up axis, metres.
    pub floor_height_m: f32,
    /// Lowest height above the floor that is an obstacle, metres (below: floor).
    pub obstacle_min_height_m: f32,
    /// Highest height above the floor that is an obstacle, metres (the robot's height; above:
    /// ignored).
    pub obstacle_max_height_m: f32,
    /// Rays are cut at this range, metres (depth beyond is too noisy to mark obstacles).
    pub max_range_m: f32,
    /// Every `pixel_stride`-th pixel in both directions is a ray.
    pub pixel_stride: u32,
    /// Log-odds added to a cell a ray ends in (a hit).
    pub hit_log_odds: f32,
    /// Log-odds taken from a cell a ray passes through.
    pub miss_log_odds: f32,
    /// Log-odds are clamped to `±max_log_odds` (how fast the map can change its mind).
    pub max_log_odds: f32,
    /// Keyframes waiting for the occupancy thread at most; more are dropped (counted in the
    /// published header), never waited for.
    pub queue_capacity: usize,
    /// How often the map is published on `<prefix>/occupancy` and handed to the query service,
    /// milliseconds.
    pub publish_period_ms: u64,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            cell_size_m: 0.05,
            size_m: 20.0,
            centre_m: None,
            floor_height_m: 0.0,
            obstacle_min_height_m: 0.05,
            obstacle_max_height_m: 1.5,
            max_range_m: 4.0,
            pixel_stride: 8,
            hit_log_odds: 0.85,
            miss_log_odds: 0.7,
            max_log_odds: 3.5,
            queue_capacity: 2,
            publish_period_ms: 1000,
        }
    }
}

impl OccupancyConfig {
    /// Cells along one side.
    pub fn side_cells(&self) -> u32 {
        (self.size_m / self.cell_size_m).round() as u32
    }

    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let positive = |value: f32, field: &str| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(format!("{path}.{field}: must be a positive number of metres, got {value}"))
            }
        };
        positive(self.cell_size_m, "cell_size_m")?;
        positive(self.size_m, "size_m")?;
        positive(self.max_range_m, "max_range_m")?;
        if !(0.01..=1.0).contains(&self.cell_size_m) {
            return Err(format!("{path}.cell_size_m: must be within [0.01, 1] m, got {}", self.cell_size_m));
        }
        let side = self.side_cells();
        if !(8..=OCCUPANCY_MAX_SIDE_CELLS).contains(&side) {
            return Err(format!(
                "{path}.size_m: {} m / cell_size_m {} m = {side} cells a side; must be within [8, \
                 {OCCUPANCY_MAX_SIDE_CELLS}]",
                self.size_m, self.cell_size_m
            ));
        }
        if let Some(centre) = self.centre_m
            && !centre.iter().all(|c| c.is_finite())
        {
            return Err(format!("{path}.centre_m: must be finite, got {centre:?}"));
        }
        if !self.floor_height_m.is_finite() {
            return Err(format!("{path}.floor_height_m: must be finite, got {}", self.floor_height_m));
        }
        if !(self.obstacle_min_height_m.is_finite()
            && self.obstacle_max_height_m.is_finite()
            && self.obstacle_min_height_m >= 0.0
            && self.obstacle_min_height_m < self.obstacle_max_height_m)
        {
            return Err(format!(
                "{path}.obstacle_min_height_m: must be >= 0 and below obstacle_max_height_m, got {} and {}",
                self.obstacle_min_height_m, self.obstacle_max_height_m
            ));
        }
        if !(1..=64).contains(&self.pixel_stride) {
            return Err(format!("{path}.pixel_stride: must be within [1, 64], got {}", self.pixel_stride));
        }
        for (value, field) in [
            (self.hit_log_odds, "hit_log_odds"),
            (self.miss_log_odds, "miss_log_odds"),
            (self.max_log_odds, "max_log_odds"),
        ] {
            if !(value.is_finite() && value > 0.0 && value <= 20.0) {
                return Err(format!("{path}.{field}: must be within (0, 20], got {value}"));
            }
        }
        if !(1..=64).contains(&self.queue_capacity) {
            return Err(format!("{path}.queue_capacity: must be within [1, 64], got {}", self.queue_capacity));
        }
        if !(50..=60_000).contains(&self.publish_period_ms) {
            return Err(format!(
                "{path}.publish_period_ms: must be within [50, 60000], got {}",
                self.publish_period_ms
            ));
        }
        Ok(())
    }
}
