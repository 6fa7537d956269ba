//! D435i-like depth noise.
//!
//! Applied to exact z-depth (metres) from the ray caster, per pixel, in this order:
//! 1. **Range**: depth outside `[min_range_m, max_range_m]` reads 0 (no depth).
//! 2. **Edge holes**: a pixel is a depth edge when one of its 4 neighbours differs from it by
//!    more than `edge_jump_ratio * z` (or has no depth); an edge pixel reads 0 with probability
//!    `edge_hole_probability` (stereo matching fails at occlusion boundaries).
//! 3. **Random holes**: any other valid pixel reads 0 with probability
//!    `random_hole_probability`.
//! 4. **Gaussian error**: surviving pixels get `z + sigma(z) * n`, `n ~ N(0, 1)`, with
//!    `sigma(z) = sigma_at_1m_m * z^2` (stereo depth error grows with the square of distance).
//!
//! The result is quantised to `units_per_m` (millimetres). Instance ids are never touched. The
//! noise is a pure function of the clean depth and the random generator's state: every pixel
//! consumes exactly one uniform and one normal sample, in row-major order.
//!
//! A change script's `degrade_depth_beyond_m` ([`degrade_beyond`]) then makes depth beyond a
//! range garbage: every pixel with depth whose exact depth is beyond it gets an error of sigma
//! [`FAR_SIGMA_M`], and [`FAR_OUTLIER_SHARE`] of them read [`FAR_OUTLIER_M`] too far besides (a
//! revisit from beyond the trusted range), drawing from the same generator after the noise.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::DepthNoiseConfig;

/// Standard deviation of the depth error at depth `z_m`, metres.
#[inline]
pub fn sigma_at(config: &DepthNoiseConfig, z_m: f32) -> f32 {
    config.sigma_at_1m_m * z_m * z_m
}

/// Writes noisy quantised depth into `out` from exact depth `clean` (metres, 0 = none).
pub fn apply(
    config: &DepthNoiseConfig,
    rng: &mut ChaCha8Rng,
    clean: &[f32],
    width: usize,
    height: usize,
    units_per_m: f32,
    out: &mut [u16],
) {
    debug_assert_eq!(clean.len(), width * height);
    debug_assert_eq!(out.len(), width * height);
    for row in 0..height {
        for col in 0..width {
            let i = row * width + col;
            let u: f32 = rng.random();
            let n: f32 = rng.sample(StandardNormal);
            let z = clean[i];
            if z <= 0.0 || z < config.min_range_m || z > config.max_range_m {
                out[i] = 0;
                continue;
            }
            let limit = config.edge_jump_ratio * z;
            let jump = |j: usize| {
                let zn = clean[j];
                zn <= 0.0 || (zn - z).abs() > limit
            };
            let edge = (col > 0 && jump(i - 1))
                || (col + 1 < width && jump(i + 1))
                || (row > 0 && jump(i - width))
                || (row + 1 < height && jump(i + width));
            let hole_probability = if edge { config.edge_hole_probability } else { config.random_hole_probability };
            if u < hole_probability {
                out[i] = 0;
                continue;
            }
            let noisy = z + sigma_at(config, z) * n;
            out[i] = quantise(noisy, units_per_m);
        }
    }
}

/// Standard deviation of the error of depth beyond a change script's
/// `degrade_depth_beyond_m`, metres.
pub const FAR_SIGMA_M: f32 = 0.25;
/// Share of the pixels beyond `degrade_depth_beyond_m` that read much too far.
pub const FAR_OUTLIER_SHARE: f32 = 0.3;
/// How much too far those pixels read, metres (uniform in the range).
pub const FAR_OUTLIER_M: (f32, f32) = (0.3, 1.0);

/// Replaces the depth of every pixel whose exact depth `clean` (metres) is beyond `range_m` and
/// that has depth in `out` by garbage: `z + FAR_SIGMA_M * n`, plus `FAR_OUTLIER_M` for a share
/// `FAR_OUTLIER_SHARE` of them (0 where that is not in front of the camera). Each such pixel
/// consumes one normal and two uniform samples, in row-major order.
pub fn degrade_beyond(range_m: f32, rng: &mut ChaCha8Rng, clean: &[f32], units_per_m: f32, out: &mut [u16]) {
    debug_assert_eq!(clean.len(), out.len());
    for (d, &z) in out.iter_mut().zip(clean) {
        if *d == 0 || z <= range_m {
            continue;
        }
        let n: f32 = rng.sample(StandardNormal);
        let u: f32 = rng.random();
        let v: f32 = rng.random();
        let outlier =
            if u < FAR_OUTLIER_SHARE { FAR_OUTLIER_M.0 + (FAR_OUTLIER_M.1 - FAR_OUTLIER_M.0) * v } else { 0.0 };
        let garbage = z + FAR_SIGMA_M * n + outlier;
        *d = if garbage > 0.05 { quantise(garbage, units_per_m) } else { 0 };
    }
}

/// Metres to sensor units, clamped to the valid non-zero range.
#[inline]
pub fn quantise(z_m: f32, units_per_m: f32) -> u16 {
    (z_m * units_per_m).round().clamp(1.0, 65535.0) as u16
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn flat(z: f32, n: usize) -> Vec<f32> {
        vec![z; n]
    }

    /// The empirical spread on a flat wall follows sigma_at_1m * z^2 (ratio 9 between 3 m and 1 m).
    #[test]
    fn spread_grows_with_depth_squared() {
        let config = DepthNoiseConfig { random_hole_probability: 0.0, ..DepthNoiseConfig::default() };
        let (w, h) = (200, 200);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut stds = Vec::new();
        for z in [1.0f32, 3.0] {
            let clean = flat(z, w * h);
            let mut out = vec![0u16; w * h];
            // Use a finer unit than mm so quantisation does not swamp the 2 mm spread at 1 m.
            apply(&config, &mut rng, &clean, w, h, 10_000.0, &mut out);
            let errs: Vec<f64> = out.iter().map(|&d| d as f64 / 10_000.0 - z as f64).collect();
            let mean = errs.iter().sum::<f64>() / errs.len() as f64;
            let var = errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errs.len() as f64;
            let std = var.sqrt();
            let expected = sigma_at(&config, z) as f64;
            assert!((std / expected - 1.0).abs() < 0.1, "z {z}: std {std} expected {expected}");
            stds.push(std);
        }
        let ratio = stds[1] / stds[0];
        assert!((ratio - 9.0).abs() < 0.9, "ratio {ratio}");
    }

    #[test]
    fn holes_at_edges_and_out_of_range() {
        let config = DepthNoiseConfig {
            edge_hole_probability: 1.0,
            random_hole_probability: 0.0,
            ..DepthNoiseConfig::default()
        };
        let (w, h) = (10, 4);
        // Left half at 1 m, right half at 2 m; one pixel too close, one too far.
        let mut clean: Vec<f32> = (0..w * h).map(|i| if i % w < 5 { 1.0 } else { 2.0 }).collect();
        clean[0] = 0.1;
        clean[w * h - 1] = 9.0;
        let mut out = vec![0u16; w * h];
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        apply(&config, &mut rng, &clean, w, h, 1000.0, &mut out);
        for row in 0..h {
            assert_eq!(out[row * w + 4], 0, "edge pixel left of the jump");
            assert_eq!(out[row * w + 5], 0, "edge pixel right of the jump");
            assert!(out[row * w + 2] > 0);
        }
        assert_eq!(out[0], 0, "closer than min range");
        assert_eq!(out[w * h - 1], 0, "farther than max range");
    }
}
