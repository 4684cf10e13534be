//! An image while it is rendered, and how a webcam develops it: defocus, exposure gain,
//! sensor noise drawn from a counter-based hash (deterministic in parallel), 8 bits.

use rayon::prelude::*;

const BLUR_SIGMA_PX: f64 = 0.7;
const READ_NOISE_DN: f32 = 0.4;
const SHOT_NOISE_DN: f32 = 0.004;

/// A pixel rectangle, corners inclusive: (x0, y0, x1, y1).
pub type Rect = (usize, usize, usize, usize);

/// An RGB image of floating-point intensities (0-255) while rendering.
#[derive(Clone, Debug, PartialEq)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<f32>,
    /// Where anything but the smooth backdrop was drawn (what the defocus blur must touch).
    pub detail: Option<Rect>,
}

impl Canvas {
    /// Blurs where detail was drawn (in place: what was drawn stays marked as `detail`),
    /// applies `gain`, adds noise keyed by (`seed`, `image`) and rounds to 8-bit RGB.
    ///
    /// Blurring only the detail is exact where the rest is the smooth backdrop (a 5-pixel
    /// Gaussian changes it by under 0.01 DN).
    pub fn develop(&mut self, gain: f64, seed: u64, image: u64) -> Vec<u8> {
        let w = self.width;
        if let Some(rect) = self.detail {
            self.blur(rect, BLUR_SIGMA_PX);
        }
        let key = splitmix(seed ^ splitmix(image));
        let gain = gain as f32;
        let normals = &*NORMALS;
        let mut out = vec![0u8; self.rgb.len()];
        out.par_chunks_mut(3 * w)
            .zip(self.rgb.par_chunks(3 * w))
            .enumerate()
            .for_each(|(row, (out, values))| {
                // The row's noise: a window of the table at an offset keyed by the image and
                // the row.
                let start =
                    splitmix(key ^ splitmix(row as u64)) % (NORMALS_LEN - values.len()) as u64;
                let noise = &normals[start as usize..][..values.len()];
                // One pass the compiler vectorises.
                for ((o, &v), &n) in out.iter_mut().zip(values).zip(noise) {
                    let signal = v * gain;
                    let variance =
                        READ_NOISE_DN * READ_NOISE_DN + SHOT_NOISE_DN * signal.clamp(0.0, 255.0);
                    let developed = (signal + variance.sqrt() * n).clamp(0.0, 255.0);
                    // Rounded to the nearest level through the float's mantissa: adding
                    // 1.5 · 2²³ leaves the integer in the low bits (`as u8` would not vectorise).
                    *o = (developed + 12_582_912.0).to_bits() as u8;
                }
            });
        out
    }

    /// Separable Gaussian blur (σ = `sigma` px, out to the nearest whole pixel to 3σ) of a
    /// rectangle, reading that far beyond it (clamped at the image's edges).
    pub(super) fn blur(&mut self, (x0, y0, x1, y1): Rect, sigma: f64) {
        let r = (3.0 * sigma).round() as usize;
        let weights: Vec<f32> = {
            let w: Vec<f64> = (0..=2 * r)
                .map(|k| {
                    let d = k as f64 - r as f64;
                    (-(d * d) / (2.0 * sigma * sigma)).exp()
                })
                .collect();
            let sum: f64 = w.iter().sum();
            w.iter().map(|v| (v / sum) as f32).collect()
        };
        let (w, h) = (self.width, self.height);
        let (ya, yb) = (y0.saturating_sub(r), (y1 + r).min(h - 1));
        let span = 3 * (x1 - x0 + 1);
        // Horizontal pass over the rows the vertical pass will read: each row padded with r
        // pixels each side (the edge pixel repeated), so that each weight adds one shifted run.
        let src = &self.rgb;
        let weights = &weights;
        let mut horizontal = vec![0f32; (yb - ya + 1) * span];
        horizontal
            .par_chunks_mut(span)
            .enumerate()
            .for_each_init(Vec::new, |padded, (dy, out)| {
                let row = &src[3 * w * (ya + dy)..][..3 * w];
                padded.clear();
                for x in x0 as isize - r as isize..=(x1 + r) as isize {
                    let x = x.clamp(0, w as isize - 1) as usize;
                    padded.extend_from_slice(&row[3 * x..3 * x + 3]);
                }
                for (k, weight) in weights.iter().enumerate() {
                    for (o, p) in out.iter_mut().zip(&padded[3 * k..]) {
                        *o += weight * p;
                    }
                }
            });
        self.rgb[3 * w * y0..3 * w * (y1 + 1)]
            .par_chunks_mut(3 * w)
            .enumerate()
            .for_each(|(dy, row)| {
                let out = &mut row[3 * x0..][..span];
                out.fill(0.0);
                for (t, weight) in weights.iter().enumerate() {
                    // Row y0 + dy + t − r, the edge row repeated.
                    let y = (y0 + dy + t).saturating_sub(r).clamp(ya, yb);
                    let from = &horizontal[(y - ya) * span..][..span];
                    for (o, p) in out.iter_mut().zip(from) {
                        *o += weight * p;
                    }
                }
            });
    }
}

pub(super) fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A uniform number in [0, 1) from a key and a counter.
pub(super) fn uniform(key: u64, k: u64) -> f64 {
    (splitmix(key ^ splitmix(k)) >> 11) as f64 / (1u64 << 53) as f64
}

/// The sensor noise's table: 2²⁰ approximately standard normal numbers, made once (from
/// [`pixel_noise`] with a fixed key). A row of an image takes a window of it at an offset keyed
/// by the image and the row: one hash a row instead of one a pixel, and the rows of an image,
/// and the images, still independent to any test of a bead's place (a window overlaps another
/// row's only at a shifted offset).
const NORMALS_LEN: usize = 1 << 20;
static NORMALS: std::sync::LazyLock<Vec<f32>> = std::sync::LazyLock::new(|| {
    (0..NORMALS_LEN as u64 / 3 + 1)
        .flat_map(|k| pixel_noise(0x004e_4f49_5345, k))
        .take(NORMALS_LEN)
        .collect()
});

/// Three approximately standard normal numbers (one per colour channel) for pixel `k`: from
/// one SplitMix64 output, each the sum of four 5-bit uniforms, centred and scaled (Irwin-Hall;
/// 125 levels, tails cut at ±3.4σ — finer than the 8-bit output it perturbs).
fn pixel_noise(key: u64, k: u64) -> [f32; 3] {
    /// The 125 levels: a sum s of four uniforms on 0..=31 (mean 62, variance
    /// 4 · (32² − 1)/12 = 341) is (s − 62) / √341, looked up rather than divided per pixel.
    static LEVELS: std::sync::LazyLock<[f32; 125]> =
        std::sync::LazyLock::new(|| std::array::from_fn(|s| (s as f32 - 62.0) / 341f32.sqrt()));
    let bits = splitmix(key.wrapping_add(k.wrapping_mul(0x9e37_79b9_7f4a_7c15)));
    // The 5-bit fields (four per channel, from bit 20 c) added in pairs in one word: each
    // pair's sum (at most 62) in its own 10 bits.
    const FIELDS: u64 = 0x007C_1F07_C1F0_7C1F;
    let pairs = (bits & FIELDS) + ((bits >> 5) & FIELDS);
    let levels = &*LEVELS;
    std::array::from_fn(|c| {
        let sum = ((pairs >> (20 * c)) & 0x3FF) + ((pairs >> (20 * c + 10)) & 0x3FF);
        levels[sum as usize]
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_the_stated_spread_and_is_keyed() {
        for c in 0..3 {
            let n: Vec<f64> = (0..20000)
                .map(|k| f64::from(pixel_noise(42, k)[c]))
                .collect();
            let (mean, sd) = crate::stats::mean_sd(&n).unwrap();
            assert!(mean.abs() < 0.03 && (sd - 1.0).abs() < 0.03, "{mean} {sd}");
        }
        // Channels are independent of each other.
        let corr: f64 = (0..20000)
            .map(|k| {
                let n = pixel_noise(9, k);
                f64::from(n[0]) * f64::from(n[1])
            })
            .sum::<f64>()
            / 20000.0;
        assert!(corr.abs() < 0.03, "{corr}");
        assert_eq!(pixel_noise(42, 7), pixel_noise(42, 7));
        assert_ne!(pixel_noise(42, 7), pixel_noise(43, 7));
    }
}
