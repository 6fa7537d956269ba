//! The paper's colour-distribution feature for parts ("Feature Extraction", "Part
//! Association" and "Feature Update" of OP3DSG).
//!
//! A part's feature `f^c = [H^cn, H^ab, H^opp]` is three L1-normalised histograms over the
//! *valid* pixels `Ω` of its mask:
//!
//! * **White balance** (gray-world). Per channel gain `g_c = m / m_c`, where `m_c` is the mean
//!   of channel `c` over a pixel set and `m = (m_R + m_G + m_B) / 3`; a balanced channel is
//!   `clamp(g_c · c, 0, 255)`. If any channel mean is 0 (or there are no pixels) all gains
//!   stay 1. It is applied before everything else. [`white_balance_gains`] works on any pixel set;
//!   [`extract`] takes the gains explicitly. **Choose the set with care:** gray-world over the
//!   part mask alone turns every single-coloured part grey (its channel means become equal, so
//!   `S = 0` and `Ω` is empty — see the test `mask_only_gray_world_erases_uniform_part`), and
//!   parts are single-material by the paper's own premise. Compute the gains over the whole
//!   frame (`white_balance_gains(rgb, 0..width * height)`) and reuse them for every mask of
//!   that frame.
//! * **Valid pixels** `Ω = mask ∧ S > τ_S ∧ V < τ_V`, with HSV `V = max / 255` and
//!   `S = (max − min) / max` (`S = 0` when `max = 0`) on the balanced pixel. Specular
//!   highlights (near white: low `S`, high `V`) and dark or grey pixels (`S = 0`) leave `Ω`.
//!   Note that `V < τ_V` also drops fully saturated 8-bit colours such as `(255, 0, 0)`
//!   (`V = 1`): with `τ_V = 0.9` a channel maximum above 229 is out.
//! * **`H^cn`** (11 bins): the sum of the Color Names (w2c, van de Weijer et al. 2009) rows of
//!   the valid pixels, L1-normalised. Row index `(r >> 3) + 32 (g >> 3) + 1024 (b >> 3)`;
//!   columns black, blue, brown, gray, green, orange, pink, purple, red, white, yellow. The
//!   table (`daemon/data/color_names/`) is embedded in the binary.
//! * **`H^ab`** (8 × 8 = 64 bins): CIELAB `a*`, `b*` (sRGB → linear → XYZ, D65 white
//!   `(0.95047, 1, 1.08883)` → Lab), each clamped to `[−128, 127]` and cut into 8 bins of width
//!   32 starting at −128 (`bin = floor((v + 128) / 32)`, at most 7); index `8 · bin_a + bin_b`.
//! * **`H^opp`** (8 × 8 = 64 bins): opponent colours on `[0, 1]` channels,
//!   `O1 = (R − G) / √2 ∈ [−1/√2, 1/√2]` and `O2 = (R + G − 2B) / √6 ∈ [−2/√6, 2/√6]`, each
//!   range cut into 8 equal bins; index `8 · bin_O1 + bin_O2`. The intensity channel
//!   `O3 = (R + G + B) / √3` is left out on purpose: the feature should be robust to
//!   illumination strength, and `O3` carries only that.
//!
//! **Similarity.** `χ²(h, k) = ½ Σ (h_i − k_i)² / (h_i + k_i)` over bins with `h_i + k_i > 0`;
//! with the ½ it lies in `[0, 1]` for L1-normalised histograms (0 identical, 1 disjoint).
//! `d^c = w1 d^cn + w2 d^ab + w3 d^opp` (default weights `(0.2, 0.4, 0.4)`, summing to 1, so
//! `d^c ∈ [0, 1]`) and `s^c = 1 / (1 + d^c) ∈ [0.5, 1]`.
//!
//! **Empty `Ω`.** A feature with no valid pixel (`valid_pixels == 0`, all histograms 0) is
//! invalid ([`ColourFeature::is_valid`]); [`colour_distance`] and [`colour_similarity`] return
//! `None` when either side is invalid, and the caller then leaves colour out of `S^p` (i.e. uses
//! `w^p = 1`) instead of inventing a neutral value.
//!
//! **Update.** [`ColourFeature::ema_update`] applies the paper's EMA per histogram,
//! `H̃ = (1 − α) H_prev + α Ĥ_new`, `H = H̃ / (‖H̃‖₁ + ε)`. The paper leaves `α` and `ε` open;
//! the defaults here are `α = 0.3`, `ε = 1e-6`.
//!
//! Everything after the one-time decoding of the embedded table is allocation-free.

use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

/// Bins of `H^cn` (the 11 basic colour terms).
pub const CN_BINS: usize = 11;
/// Bins of `H^ab` (8 × 8).
pub const AB_BINS: usize = 64;
/// Bins of `H^opp` (8 × 8).
pub const OPP_BINS: usize = 64;

/// Bins per axis of the 2D histograms.
const AXIS_BINS: usize = 8;
/// Rows of the w2c table.
const W2C_ROWS: usize = 32_768;

/// Names of the `H^cn` bins, in column order.
pub const COLOUR_NAMES: [&str; CN_BINS] =
    ["black", "blue", "brown", "gray", "green", "orange", "pink", "purple", "red", "white", "yellow"];

static W2C_BYTES: &[u8] = include_bytes!("../../data/color_names/w2c_32768x11_f32le.bin");

/// Parameters of the colour-distribution feature.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourParams {
    /// Saturation threshold `τ_S`: valid pixels have `S > tau_s`.
    pub tau_s: f32,
    /// Value threshold `τ_V`: valid pixels have `V < tau_v`.
    pub tau_v: f32,
    /// `(w1, w2, w3)` for `d^cn`, `d^ab`, `d^opp`.
    pub weights: [f32; 3],
    /// EMA smoothing factor `α ∈ (0, 1)`.
    pub ema_alpha: f32,
    /// EMA renormalisation constant `ε > 0`.
    pub ema_epsilon: f32,
}

impl Default for ColourParams {
    fn default() -> Self {
        Self { tau_s: 0.1, tau_v: 0.9, weights: [0.2, 0.4, 0.4], ema_alpha: 0.3, ema_epsilon: 1e-6 }
    }
}

impl ColourParams {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        for (name, v) in [("tau_s", self.tau_s), ("tau_v", self.tau_v)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("{path}.{name}: must be within [0, 1], got {v}"));
            }
        }
        for (i, w) in self.weights.iter().enumerate() {
            if !(w.is_finite() && *w >= 0.0) {
                return Err(format!("{path}.weights[{i}]: must be finite and >= 0, got {w}"));
            }
        }
        let sum: f32 = self.weights.iter().sum();
        if sum <= 0.0 {
            return Err(format!("{path}.weights: must not all be 0, got {:?}", self.weights));
        }
        if !(self.ema_alpha > 0.0 && self.ema_alpha < 1.0) {
            return Err(format!("{path}.ema_alpha: must be within (0, 1), got {}", self.ema_alpha));
        }
        if !(self.ema_epsilon > 0.0 && self.ema_epsilon < 1.0) {
            return Err(format!("{path}.ema_epsilon: must be within (0, 1), got {}", self.ema_epsilon));
        }
        Ok(())
    }
}

/// The colour-distribution feature `f^c` of one part.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourFeature {
    /// `H^cn`, L1-normalised (all 0 when invalid).
    pub cn: [f32; CN_BINS],
    /// `H^ab`, L1-normalised (all 0 when invalid).
    pub ab: [f32; AB_BINS],
    /// `H^opp`, L1-normalised (all 0 when invalid).
    pub opp: [f32; OPP_BINS],
    /// `|Ω|` of the observation; after EMA updates, the sum over the fused observations
    /// (saturating). 0 means invalid.
    pub valid_pixels: u32,
}

impl Default for ColourFeature {
    fn default() -> Self {
        Self { cn: [0.0; CN_BINS], ab: [0.0; AB_BINS], opp: [0.0; OPP_BINS], valid_pixels: 0 }
    }
}

impl ColourFeature {
    /// Whether the feature saw at least one valid pixel.
    pub fn is_valid(&self) -> bool {
        self.valid_pixels > 0
    }

    /// The paper's EMA update with `new`, per histogram. An invalid `new` leaves `self`
    /// unchanged; an invalid `self` takes `new` as it is.
    pub fn ema_update(&mut self, new: &ColourFeature, params: &ColourParams) {
        if !new.is_valid() {
            return;
        }
        if !self.is_valid() {
            self.clone_from(new);
            return;
        }
        let (alpha, eps) = (params.ema_alpha, params.ema_epsilon);
        ema(&mut self.cn, &new.cn, alpha, eps);
        ema(&mut self.ab, &new.ab, alpha, eps);
        ema(&mut self.opp, &new.opp, alpha, eps);
        self.valid_pixels = self.valid_pixels.saturating_add(new.valid_pixels);
    }
}

fn ema(prev: &mut [f32], new: &[f32], alpha: f32, eps: f32) {
    let mut l1 = 0.0;
    for (p, n) in prev.iter_mut().zip(new) {
        *p = (1.0 - alpha) * *p + alpha * n;
        l1 += p.abs();
    }
    let scale = 1.0 / (l1 + eps);
    for p in prev.iter_mut() {
        *p *= scale;
    }
}

/// The Color Names (w2c) lookup table.
#[derive(Debug)]
pub struct ColourNames {
    rows: Vec<[f32; CN_BINS]>,
}

impl ColourNames {
    /// The table embedded in the binary, decoded on first use.
    pub fn embedded() -> &'static ColourNames {
        static TABLE: OnceLock<ColourNames> = OnceLock::new();
        TABLE.get_or_init(|| ColourNames::decode(W2C_BYTES))
    }

    /// Decodes a row-major little-endian f32 table (missing rows read as all 0).
    fn decode(bytes: &[u8]) -> ColourNames {
        let mut rows = vec![[0.0f32; CN_BINS]; W2C_ROWS];
        for (i, chunk) in bytes.chunks_exact(4).take(W2C_ROWS * CN_BINS).enumerate() {
            let v = f32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
            rows[i / CN_BINS][i % CN_BINS] = v;
        }
        ColourNames { rows }
    }

    /// Number of rows (32768).
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether the table has no rows (never for the embedded one).
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Probabilities of the 11 colour terms for an 8-bit RGB colour.
    pub fn probabilities(&self, rgb: [u8; 3]) -> &[f32; CN_BINS] {
        let index = usize::from(rgb[0] >> 3) + 32 * usize::from(rgb[1] >> 3) + 1024 * usize::from(rgb[2] >> 3);
        &self.rows[index]
    }
}

/// Reads pixel `index` of a row-major RGB8 image; `None` when out of range.
fn pixel(rgb_image: &[u8], index: usize) -> Option<[u8; 3]> {
    let start = index.checked_mul(3)?;
    let p = rgb_image.get(start..start.checked_add(3)?)?;
    Some([p[0], p[1], p[2]])
}

/// Gray-world gains over the given pixels of a row-major RGB8 image (out-of-range indices are
/// skipped). All 1 when there is no pixel or a channel mean is 0.
pub fn white_balance_gains(rgb_image: &[u8], pixels: impl Iterator<Item = usize>) -> [f32; 3] {
    let mut sum = [0u64; 3];
    let mut n = 0u64;
    for p in pixels.filter_map(|i| pixel(rgb_image, i)) {
        for c in 0..3 {
            sum[c] += u64::from(p[c]);
        }
        n += 1;
    }
    if n == 0 || sum.contains(&0) {
        return [1.0; 3];
    }
    let means = sum.map(|s| s as f64 / n as f64);
    let grey = (means[0] + means[1] + means[2]) / 3.0;
    means.map(|m| (grey / m) as f32)
}

/// Applies white-balance gains to one pixel, rounding and clamping to `[0, 255]`.
pub fn apply_gains(rgb: [u8; 3], gains: [f32; 3]) -> [u8; 3] {
    let mut out = [0u8; 3];
    for c in 0..3 {
        // Clamped to [0, 255] first, so the cast cannot truncate.
        // `+ 0.5` then truncation rounds half up for these non-negative values (and avoids the
        // libm call `round` becomes on baseline x86-64).
        out[c] = (f32::from(rgb[c]) * gains[c] + 0.5).clamp(0.0, 255.0) as u8;
    }
    out
}

/// HSV saturation and value, both in `[0, 1]`.
pub fn saturation_value(rgb: [u8; 3]) -> (f32, f32) {
    let max = rgb[0].max(rgb[1]).max(rgb[2]);
    let min = rgb[0].min(rgb[1]).min(rgb[2]);
    let v = f32::from(max) / 255.0;
    let s = if max == 0 { 0.0 } else { f32::from(max - min) / f32::from(max) };
    (s, v)
}

/// Whether a (balanced) pixel belongs to `Ω`.
pub fn is_valid_pixel(rgb: [u8; 3], params: &ColourParams) -> bool {
    let (s, v) = saturation_value(rgb);
    s > params.tau_s && v < params.tau_v
}

fn srgb_to_linear(c: u8) -> f32 {
    let c = f32::from(c) / 255.0;
    if c <= 0.040_45 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

fn lab_f(t: f32) -> f32 {
    const DELTA: f32 = 6.0 / 29.0;
    if t > DELTA * DELTA * DELTA { t.cbrt() } else { t / (3.0 * DELTA * DELTA) + 4.0 / 29.0 }
}

/// CIELAB `(a*, b*)` of an sRGB colour (D65).
pub fn lab_ab(rgb: [u8; 3]) -> (f32, f32) {
    let [r, g, b] = rgb.map(srgb_to_linear);
    let x = 0.412_456_4 * r + 0.357_576_1 * g + 0.180_437_5 * b;
    let y = 0.212_672_9 * r + 0.715_152_2 * g + 0.072_175 * b;
    let z = 0.019_333_9 * r + 0.119_192 * g + 0.950_304_1 * b;
    let (fx, fy, fz) = (lab_f(x / 0.950_47), lab_f(y), lab_f(z / 1.088_83));
    (500.0 * (fx - fy), 200.0 * (fy - fz))
}

/// Bin of `v` in `[lo, hi]` cut into [`AXIS_BINS`] equal bins (clamped).
fn axis_bin(v: f32, lo: f32, hi: f32) -> usize {
    let t = ((v - lo) / (hi - lo) * AXIS_BINS as f32).floor();
    // Clamped to [0, AXIS_BINS - 1] first, so the cast cannot truncate.
    t.clamp(0.0, (AXIS_BINS - 1) as f32) as usize
}

/// `H^ab` bin of a colour.
pub fn ab_bin(rgb: [u8; 3]) -> usize {
    let (a, b) = lab_ab(rgb);
    let (a, b) = (a.clamp(-128.0, 127.0), b.clamp(-128.0, 127.0));
    axis_bin(a, -128.0, 128.0) * AXIS_BINS + axis_bin(b, -128.0, 128.0)
}

/// `H^opp` bin of a colour.
pub fn opp_bin(rgb: [u8; 3]) -> usize {
    let [r, g, b] = rgb.map(|c| f32::from(c) / 255.0);
    let o1 = (r - g) / std::f32::consts::SQRT_2;
    let o2 = (r + g - 2.0 * b) / 6.0f32.sqrt();
    let h1 = std::f32::consts::FRAC_1_SQRT_2;
    let h2 = 2.0 / 6.0f32.sqrt();
    axis_bin(o1, -h1, h1) * AXIS_BINS + axis_bin(o2, -h2, h2)
}

fn l1_normalise(h: &mut [f32]) {
    let sum: f32 = h.iter().sum();
    if sum > 0.0 {
        for v in h.iter_mut() {
            *v /= sum;
        }
    }
}

/// Computes `f^c` of the pixels `pixel_indices` (a part mask) of a row-major RGB8 image into
/// `out`, balancing each pixel with `gains` first (see [`white_balance_gains`]; pass
/// `[1.0; 3]` for none). Out-of-range indices are skipped. With no valid pixel `out` is the
/// invalid all-zero feature.
pub fn extract(
    rgb_image: &[u8],
    pixel_indices: impl Iterator<Item = usize>,
    gains: [f32; 3],
    params: &ColourParams,
    out: &mut ColourFeature,
) {
    let names = ColourNames::embedded();
    out.cn = [0.0; CN_BINS];
    out.ab = [0.0; AB_BINS];
    out.opp = [0.0; OPP_BINS];
    let mut count = 0u32;
    for raw in pixel_indices.filter_map(|i| pixel(rgb_image, i)) {
        let p = apply_gains(raw, gains);
        if !is_valid_pixel(p, params) {
            continue;
        }
        count = count.saturating_add(1);
        for (h, v) in out.cn.iter_mut().zip(names.probabilities(p)) {
            *h += v;
        }
        out.ab[ab_bin(p)] += 1.0;
        out.opp[opp_bin(p)] += 1.0;
    }
    out.valid_pixels = count;
    l1_normalise(&mut out.cn);
    l1_normalise(&mut out.ab);
    l1_normalise(&mut out.opp);
}

/// `χ² = ½ Σ (a_i − b_i)² / (a_i + b_i)` over bins with `a_i + b_i > 0` (over the shorter
/// length if they differ). In `[0, 1]` for L1-normalised histograms.
pub fn chi_square(a: &[f32], b: &[f32]) -> f32 {
    debug_assert_eq!(a.len(), b.len());
    let mut d = 0.0;
    for (x, y) in a.iter().zip(b) {
        let s = x + y;
        if s > 0.0 {
            d += (x - y) * (x - y) / s;
        }
    }
    0.5 * d
}

/// `d^c = w1 χ²(cn) + w2 χ²(ab) + w3 χ²(opp)`; `None` if either feature is invalid.
pub fn colour_distance(a: &ColourFeature, b: &ColourFeature, params: &ColourParams) -> Option<f32> {
    if !(a.is_valid() && b.is_valid()) {
        return None;
    }
    let [w1, w2, w3] = params.weights;
    Some(w1 * chi_square(&a.cn, &b.cn) + w2 * chi_square(&a.ab, &b.ab) + w3 * chi_square(&a.opp, &b.opp))
}

/// `s^c = 1 / (1 + d^c)`; `None` if either feature is invalid (leave colour out of `S^p`).
pub fn colour_similarity(a: &ColourFeature, b: &ColourFeature, params: &ColourParams) -> Option<f32> {
    colour_distance(a, b, params).map(|d| 1.0 / (1.0 + d))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(pixels: &[[u8; 3]]) -> Vec<u8> {
        pixels.iter().flatten().copied().collect()
    }

    fn feature(pixels: &[[u8; 3]], gains: [f32; 3]) -> ColourFeature {
        let img = image(pixels);
        let mut f = ColourFeature::default();
        extract(&img, 0..pixels.len(), gains, &ColourParams::default(), &mut f);
        f
    }

    fn argmax(v: &[f32]) -> usize {
        let mut best = 0;
        for (i, x) in v.iter().enumerate() {
            if *x > v[best] {
                best = i;
            }
        }
        best
    }

    fn name_of(rgb: [u8; 3]) -> &'static str {
        COLOUR_NAMES[argmax(ColourNames::embedded().probabilities(rgb))]
    }

    fn close(a: f32, b: f32, tol: f32) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn embedded_table_rows_sum_to_one() {
        let t = ColourNames::embedded();
        assert_eq!(W2C_BYTES.len(), W2C_ROWS * CN_BINS * 4);
        assert_eq!(t.len(), 32_768);
        for (i, row) in t.rows.iter().enumerate() {
            let s: f32 = row.iter().sum();
            assert!(close(s, 1.0, 1e-4), "row {i} sums to {s}");
        }
    }

    #[test]
    fn readme_checked_colours() {
        assert_eq!(name_of([255, 0, 0]), "red");
        assert_eq!(name_of([0, 0, 255]), "blue");
        assert_eq!(name_of([0, 255, 0]), "green");
        assert_eq!(name_of([255, 255, 255]), "white");
        assert_eq!(name_of([255, 255, 0]), "yellow");
        assert_eq!(name_of([128, 0, 128]), "purple");
        assert_eq!(name_of([255, 182, 193]), "pink");
        // White has S = 0 and V = 1: never valid.
        assert!(!is_valid_pixel([255, 255, 255], &ColourParams::default()));
        // Fully saturated 8-bit colours have V = 1 > τ_V: not valid either.
        assert!(!is_valid_pixel([255, 0, 0], &ColourParams::default()));
        assert!(is_valid_pixel([200, 0, 0], &ColourParams::default()));
    }

    #[test]
    fn red_patch_cn_is_the_red_row() {
        // (200, 0, 0): V = 0.78 < 0.9, S = 1. G and B means are 0, so gray-world keeps gains 1.
        let px = [[200, 0, 0]; 10];
        let gains = white_balance_gains(&image(&px), 0..px.len());
        assert_eq!(gains, [1.0; 3]);
        let f = feature(&px, gains);
        assert_eq!(f.valid_pixels, 10);
        let row = ColourNames::embedded().probabilities([200, 0, 0]);
        assert_eq!(COLOUR_NAMES[argmax(&f.cn)], "red");
        let sum: f32 = row.iter().sum();
        for (h, r) in f.cn.iter().zip(row) {
            assert!(close(*h, r / sum, 1e-6));
        }
        // One colour → one bin in each 2D histogram.
        assert_eq!(f.ab[ab_bin([200, 0, 0])], 1.0);
        assert_eq!(f.opp[opp_bin([200, 0, 0])], 1.0);
    }

    #[test]
    fn half_red_half_blue_cn_is_the_mean_row() {
        let mut px = vec![[200, 0, 0]; 6];
        px.extend([[0, 0, 200]; 6]);
        let gains = white_balance_gains(&image(&px), 0..px.len());
        assert_eq!(gains, [1.0; 3], "G mean is 0, gains stay 1");
        let f = feature(&px, gains);
        assert_eq!(f.valid_pixels, 12);
        let t = ColourNames::embedded();
        let (r, b) = (t.probabilities([200, 0, 0]), t.probabilities([0, 0, 200]));
        for i in 0..CN_BINS {
            assert!(close(f.cn[i], 0.5 * (r[i] + b[i]), 1e-5), "bin {i}");
        }
        // Red and blue land in different a*b* and opponent bins, half each.
        assert_ne!(ab_bin([200, 0, 0]), ab_bin([0, 0, 200]));
        assert_eq!(f.ab[ab_bin([200, 0, 0])], 0.5);
        assert_eq!(f.opp[opp_bin([0, 0, 200])], 0.5);
    }

    #[test]
    fn balanced_thirds_keep_their_colours() {
        // Equal channel means (200/3 each): gray-world gains are 1 and nothing changes.
        let px = [[200, 0, 0], [0, 200, 0], [0, 0, 200]];
        let gains = white_balance_gains(&image(&px), 0..3);
        for g in gains {
            assert!(close(g, 1.0, 1e-6));
        }
        let f = feature(&px, gains);
        let t = ColourNames::embedded();
        for i in 0..CN_BINS {
            let mean = (t.probabilities(px[0])[i] + t.probabilities(px[1])[i] + t.probabilities(px[2])[i]) / 3.0;
            assert!(close(f.cn[i], mean, 1e-5));
        }
    }

    #[test]
    fn gray_world_gains_equalise_channel_means() {
        // Means (150, 75, 75), gray mean 100 → gains (2/3, 4/3, 4/3).
        let px = [[200, 100, 100], [100, 50, 50]];
        let img = image(&px);
        let g = white_balance_gains(&img, 0..2);
        assert!(close(g[0], 2.0 / 3.0, 1e-6) && close(g[1], 4.0 / 3.0, 1e-6) && close(g[2], 4.0 / 3.0, 1e-6));
        assert_eq!(apply_gains(px[0], g), [133, 133, 133]);
        assert_eq!(apply_gains(px[1], g), [67, 67, 67]);
        // Output is clamped to 255.
        assert_eq!(apply_gains([250, 0, 0], [2.0, 1.0, 1.0]), [255, 0, 0]);
        // Out-of-range indices are skipped; no pixels → neutral.
        assert_eq!(white_balance_gains(&img, 5..9), [1.0; 3]);
    }

    #[test]
    fn frame_gray_world_removes_a_colour_cast() {
        // A warm cast (×1.2 R, ×0.8 B) over a scene with a neutral average: the frame gains undo
        // it and the part feature matches the uncast one.
        let scene = [[150, 60, 60], [60, 150, 60], [60, 60, 150], [120, 120, 120]];
        let cast: Vec<[u8; 3]> = scene.iter().map(|p| apply_gains(*p, [1.2, 1.0, 0.8])).collect();
        let gains = white_balance_gains(&image(&cast), 0..cast.len());
        let part = [cast[0]; 5];
        let f_cast = feature(&part, gains);
        let f_ref = feature(&[scene[0]; 5], [1.0; 3]);
        let f_raw = feature(&part, [1.0; 3]);
        let p = ColourParams::default();
        let s_bal = colour_similarity(&f_cast, &f_ref, &p).unwrap_or(0.0);
        let s_raw = colour_similarity(&f_raw, &f_ref, &p).unwrap_or(0.0);
        assert!(s_bal >= s_raw, "balanced {s_bal} vs raw {s_raw}");
        assert!(s_bal > 0.95, "balanced {s_bal}");
    }

    #[test]
    fn mask_only_gray_world_erases_uniform_part() {
        // Why the gains should come from the frame: gray-world over a single-colour mask makes it
        // grey (S = 0), so Ω is empty.
        let px = [[180, 140, 60]; 8];
        let gains = white_balance_gains(&image(&px), 0..px.len());
        let f = feature(&px, gains);
        assert!(!f.is_valid());
    }

    #[test]
    fn specular_dark_and_bright_pixels_leave_omega() {
        let mut px = vec![[200, 0, 0]; 8];
        px.extend([[250, 250, 250]; 2]); // 20 % specular: S = 0
        let f = feature(&px, [1.0; 3]);
        assert_eq!(f.valid_pixels, 8);
        let row = ColourNames::embedded().probabilities([200, 0, 0]);
        for (h, r) in f.cn.iter().zip(row) {
            assert!(close(*h, *r, 1e-5), "specular pixels do not contribute");
        }
        assert_eq!(feature(&[[30, 30, 30]; 4], [1.0; 3]).valid_pixels, 0); // S = 0
        assert_eq!(feature(&[[255, 0, 0]; 4], [1.0; 3]).valid_pixels, 0); // V = 1
        assert_eq!(feature(&[[0, 0, 0]; 4], [1.0; 3]).valid_pixels, 0); // max = 0 → S = 0
        // (200, 190, 190): S = 0.05 < 0.1, weakly chromatic.
        assert_eq!(feature(&[[200, 190, 190]; 4], [1.0; 3]).valid_pixels, 0);
        let (s, v) = saturation_value([200, 100, 50]);
        assert!(close(s, 0.75, 1e-6) && close(v, 200.0 / 255.0, 1e-6));
    }

    #[test]
    fn chi_square_hand_values() {
        // ½ [0.25²/0.75 + 0.25²/0.75 + 0.5²/0.5] = ½ [1/12 + 1/12 + 1/2] = 1/3.
        let d = chi_square(&[0.5, 0.5, 0.0], &[0.25, 0.25, 0.5]);
        assert!(close(d, 1.0 / 3.0, 1e-6), "{d}");
        assert_eq!(chi_square(&[0.2, 0.3, 0.5], &[0.2, 0.3, 0.5]), 0.0);
        assert!(close(chi_square(&[0.5, 0.5, 0.0, 0.0], &[0.0, 0.0, 0.3, 0.7]), 1.0, 1e-6));
        assert_eq!(chi_square(&[0.0; 4], &[0.0; 4]), 0.0);
    }

    fn one_hot(cn: usize, ab: usize, opp: usize) -> ColourFeature {
        let mut f = ColourFeature { valid_pixels: 1, ..ColourFeature::default() };
        f.cn[cn] = 1.0;
        f.ab[ab] = 1.0;
        f.opp[opp] = 1.0;
        f
    }

    #[test]
    fn distance_and_similarity_hand_values() {
        let p = ColourParams::default();
        let a = one_hot(0, 0, 0);
        assert_eq!(colour_distance(&a, &a, &p), Some(0.0));
        assert_eq!(colour_similarity(&a, &a, &p), Some(1.0));
        let b = one_hot(1, 1, 1);
        assert!(close(colour_distance(&a, &b, &p).unwrap_or(0.0), 1.0, 1e-6));
        assert!(close(colour_similarity(&a, &b, &p).unwrap_or(0.0), 0.5, 1e-6));
        // Only the cn histogram differs: d^c = w1 = 0.2, s^c = 1 / 1.2.
        let c = one_hot(1, 0, 0);
        assert!(close(colour_distance(&a, &c, &p).unwrap_or(0.0), 0.2, 1e-6));
        assert!(close(colour_similarity(&a, &c, &p).unwrap_or(0.0), 1.0 / 1.2, 1e-6));
        // Invalid on either side → None.
        let empty = ColourFeature::default();
        assert_eq!(colour_similarity(&a, &empty, &p), None);
        assert_eq!(colour_distance(&empty, &a, &p), None);
    }

    #[test]
    fn ema_renormalises() {
        let p = ColourParams { ema_alpha: 0.25, ..ColourParams::default() };
        let eps = p.ema_epsilon;
        let mut prev = one_hot(0, 0, 0);
        let new = one_hot(1, 1, 1);
        prev.ema_update(&new, &p);
        for h in [&prev.cn[..], &prev.ab[..], &prev.opp[..]] {
            assert!(close(h[0], 0.75 / (1.0 + eps), 1e-7));
            assert!(close(h[1], 0.25 / (1.0 + eps), 1e-7));
            let s: f32 = h.iter().sum();
            assert!(close(s, 1.0, 2.0 * eps));
        }
        assert_eq!(prev.valid_pixels, 2);
        for _ in 0..50 {
            prev.ema_update(&new, &p);
            let s: f32 = prev.cn.iter().sum();
            assert!(close(s, 1.0, 1e-5));
        }
        // Invalid new: unchanged. Invalid self: takes new.
        let before = prev.clone();
        prev.ema_update(&ColourFeature::default(), &p);
        assert_eq!(prev, before);
        let mut empty = ColourFeature::default();
        empty.ema_update(&new, &p);
        assert_eq!(empty, new);
    }

    #[test]
    fn same_material_across_brightness_beats_other_materials() {
        let p = ColourParams::default();
        let materials = [("brass", [180u8, 140, 60]), ("black steel", [60, 60, 70]), ("red plastic", [180, 30, 30])];
        // Each material as a shaded patch (a gradient of 0.85..1.0 of its colour) at two
        // brightness levels, 1.0 and 0.7.
        let shade = |rgb: [u8; 3], level: f32| -> ColourFeature {
            let px: Vec<[u8; 3]> = (0..16)
                .map(|i| {
                    let k = level * (0.85 + 0.01 * i as f32);
                    rgb.map(|c| (f32::from(c) * k).round() as u8)
                })
                .collect();
            feature(&px, [1.0; 3])
        };
        let bright: Vec<ColourFeature> = materials.iter().map(|(_, c)| shade(*c, 1.0)).collect();
        let dark: Vec<ColourFeature> = materials.iter().map(|(_, c)| shade(*c, 0.7)).collect();
        for f in bright.iter().chain(&dark) {
            assert!(f.is_valid());
        }
        for i in 0..3 {
            let same = colour_similarity(&bright[i], &dark[i], &p).unwrap_or(0.0);
            for j in 0..3 {
                if i == j {
                    continue;
                }
                for other in [&bright[j], &dark[j]] {
                    let cross = colour_similarity(&bright[i], other, &p).unwrap_or(1.0);
                    assert!(same > cross, "{} across brightness {same} vs {} {cross}", materials[i].0, materials[j].0);
                }
            }
        }
    }

    #[test]
    fn params_validate() {
        assert_eq!(ColourParams::default().validate("fusion.colour"), Ok(()));
        let bad = ColourParams { tau_s: 2.0, ..ColourParams::default() };
        assert_eq!(bad.validate("fusion.colour"), Err("fusion.colour.tau_s: must be within [0, 1], got 2".into()));
        assert!(ColourParams { ema_alpha: 1.0, ..ColourParams::default() }.validate("c").is_err());
        assert!(ColourParams { ema_epsilon: 0.0, ..ColourParams::default() }.validate("c").is_err());
        assert!(ColourParams { weights: [0.0; 3], ..ColourParams::default() }.validate("c").is_err());
        assert!(ColourParams { weights: [-0.1, 0.5, 0.6], ..ColourParams::default() }.validate("c").is_err());
        let json = r#"{"tau_s":0.1,"tau_v":0.9,"weights":[0.2,0.4,0.4],"ema_alpha":0.3,"ema_epsilon":1e-6}"#;
        let parsed: ColourParams = serde_json::from_str(json).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(parsed, ColourParams::default());
        assert!(serde_json::from_str::<ColourParams>(r#"{"tau_s":0.1,"extra":1}"#).is_err());
    }
}
