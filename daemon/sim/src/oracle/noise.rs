//! The oracle's random draws: the per-frame seed, scores, Poisson counts and the per-label
//! semantic vectors.

use op3dsg_runtime::embedding::normalise;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Hard cap on false positives in one frame (guards the Poisson sampler's tail).
const MAX_FALSE_POSITIVES_DRAWN: u32 = 1000;
/// Scores are clamped to `[MIN_SCORE, 1]`.
const MIN_SCORE: f64 = 0.05;

/// SplitMix64 finaliser.
fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Seed of a frame's noise stream.
pub(super) fn frame_seed(seed: u64, seq: u64) -> u64 {
    mix64(mix64(seed) ^ seq.wrapping_mul(0xD1B5_4A32_D192_ED03))
}

/// A standard normal draw (Box-Muller).
fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// The unit semantic vector of `label` (`dim` entries; empty for 0): Gaussian entries from a
/// stream seeded by the FNV-1a hash of the label's text.
pub fn label_vector(label: &str, dim: usize) -> Vec<f32> {
    if dim == 0 {
        return Vec::new();
    }
    let hash = label.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3));
    let mut rng = ChaCha8Rng::seed_from_u64(hash);
    let mut v: Vec<f32> = (0..dim).map(|_| rng.sample::<f32, _>(StandardNormal)).collect();
    normalise(&mut v);
    v
}

/// `clamp(N(mean, std), 0.05, 1)`.
pub(super) fn draw_score(mean: f64, std: f64, rng: &mut ChaCha8Rng) -> f32 {
    let value = if std > 0.0 { mean + std * standard_normal(rng) } else { mean };
    value.clamp(MIN_SCORE, 1.0) as f32
}

/// A Poisson draw of mean `lambda` (Knuth for small means, normal approximation beyond 30).
pub(super) fn draw_poisson(lambda: f64, rng: &mut ChaCha8Rng) -> u32 {
    if lambda.is_nan() || lambda <= 0.0 {
        return 0;
    }
    if lambda > 30.0 {
        let value = (lambda + lambda.sqrt() * standard_normal(rng)).round().max(0.0);
        return (value as u32).min(MAX_FALSE_POSITIVES_DRAWN);
    }
    let limit = (-lambda).exp();
    let mut product = rng.random::<f64>();
    let mut count = 0;
    while product > limit && count < MAX_FALSE_POSITIVES_DRAWN {
        count += 1;
        product *= rng.random::<f64>();
    }
    count
}
