//! The red tip marker in one frame: red against grey, the paper's way, with thresholds that
//! adapt to the frame.
//!
//! 1. Redness of a pixel: r = 2R − G − B (three times R minus the grey mean), 0 on grey, about
//!    +250 on the matte red bead, +20 on the pale silicone.
//! 2. Marker pixels: r at least `noise_factor` robust standard deviations above the frame's
//!    median redness (median and MAD of a 1-in-64 sample) and at least `3 · min_redness`, and
//!    r at least `min_chroma` × (R + G + B) — redness relative to brightness, which does not
//!    change with the exposure: about 1.4 on the bead, 0.06 on the silicone, 0 on grey.
//! 3. 8-connected marker pixels form regions.
//! 4. Per region: its peak; its core, the pixels above half the peak; the centroid of the core
//!    weighted by r − peak/2 (sub-pixel, continuous as a pixel crosses the threshold, so noise
//!    moves it little); the core's area and elongation (square root of the ratio of its second
//!    moments' eigenvalues).
//! 5. A region is a marker candidate when its area is within `[min_area_px, max_area_px]`, its
//!    elongation at most `max_elongation`, and it does not touch the border. Several candidates
//!    are left to the epipolar constraint; none means the marker is missing from the frame.

use super::subpixel;
use crate::image::RgbImage;
use crate::stats::upper_median_by;

use serde::Serialize;

impl RgbImage {
    /// The redness 2R − G − B of pixel `i` (row-major index).
    #[inline]
    fn redness(&self, i: usize) -> i32 {
        redness(&self.data[3 * i..3 * i + 3])
    }
}

/// 2R − G − B of an RGB pixel.
#[inline]
fn redness(p: &[u8]) -> i32 {
    2 * i32::from(p[0]) - i32::from(p[1]) - i32::from(p[2])
}

/// The largest 2R − G − B of a row of RGB pixels: over 16-bit lanes, which the compiler
/// vectorises (2 · 255 fits).
fn max_redness(row: &[u8]) -> i16 {
    let (pixels, _) = row.as_chunks::<3>();
    pixels
        .iter()
        .map(|&[r, g, b]| 2 * i16::from(r) - i16::from(g) - i16::from(b))
        .fold(i16::MIN, i16::max)
}

/// Whether a pixel is red enough to be part of a marker.
#[derive(Clone, Copy, Debug)]
struct MarkerPixel {
    /// Least 2R − G − B.
    floor: i32,
    /// Least (2R − G − B) / (R + G + B), in 1/1024.
    chroma_1024: i32,
}

impl MarkerPixel {
    #[inline]
    fn test(self, p: &[u8]) -> bool {
        let r = redness(p);
        let sum = i32::from(p[0]) + i32::from(p[1]) + i32::from(p[2]);
        r >= self.floor && 1024 * r >= self.chroma_1024 * sum
    }
}

/// Limits of a marker.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MarkerOptions {
    /// Core area (pixels above half the peak), smallest and largest.
    pub min_area_px: usize,
    pub max_area_px: usize,
    /// Largest elongation (1 for a disc).
    pub max_elongation: f64,
    /// Least redness R − grey of a marker's seed (8-bit levels).
    pub min_redness: f64,
    /// Marker pixels are this many robust standard deviations above the frame's median redness.
    pub noise_factor: f64,
    /// Least redness relative to brightness, (2R − G − B) / (R + G + B).
    pub min_chroma: f64,
}

impl Default for MarkerOptions {
    fn default() -> Self {
        MarkerOptions {
            min_area_px: 4,
            max_area_px: 2000,
            max_elongation: 2.5,
            min_redness: 15.0,
            noise_factor: 10.0,
            min_chroma: 0.25,
        }
    }
}

/// A red region that passed the limits.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Blob {
    /// Centre (x, y) in pixels, OpenCV's convention (pixel centres at integers): fitted
    /// ([`subpixel::refine`]), or the core's centroid when the fit did not settle.
    pub centre_px: [f64; 2],
    /// Whether `centre_px` is the fitted centre.
    pub fitted: bool,
    pub area_px: usize,
    /// Peak redness R − grey (8-bit levels).
    pub peak: f64,
    pub elongation: f64,
}

/// What one frame holds.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Markers {
    /// Candidates, most red first.
    pub blobs: Vec<Blob>,
    /// Red regions that failed a limit (too small or large, elongated, at the border).
    pub discarded: usize,
}

/// Finds the marker candidates in `image`.
pub fn find_markers(image: &RgbImage, options: &MarkerOptions) -> Markers {
    let (w, h) = (image.width, image.height);
    let n = w * h;
    if n == 0 {
        return Markers::default();
    }
    let is_marker = MarkerPixel {
        floor: seed_threshold(image, options),
        chroma_1024: (1024.0 * options.min_chroma).round() as i32,
    };
    let pixel = |i: usize| &image.data[3 * i..3 * i + 3];
    // One bit per pixel: a red cable's thousands of pixels cost a hash set more than a whole
    // frame's bits (14 400 words at 720p).
    let mut visited = vec![0u64; n.div_ceil(64)];
    let mut visit = |i: usize| {
        let (word, bit) = (i / 64, 1u64 << (i % 64));
        let new = visited[word] & bit == 0;
        visited[word] |= bit;
        new
    };
    let mut out = Markers::default();
    let mut region = Vec::new();
    let mut stack = Vec::new();
    let cap = 4 * options.max_area_px.max(1) + 64;
    let rows = image.data.chunks_exact(3 * w).enumerate();
    // Most rows hold no red at all: a branch-free maximum rules them out quickly.
    let candidates = rows
        .filter(|(_, row)| i32::from(max_redness(row)) >= is_marker.floor)
        .flat_map(|(y, row)| {
            row.chunks_exact(3)
                .enumerate()
                .map(move |(x, p)| (y * w + x, p))
        });
    for (start, p) in candidates {
        if !is_marker.test(p) || !visit(start) {
            continue;
        }
        // Flood fill over the 8-neighbours.
        region.clear();
        stack.push(start);
        let mut at_border = false;
        while let Some(i) = stack.pop() {
            region.push(i);
            let (x, y) = (i % w, i / w);
            at_border |= x == 0 || y == 0 || x + 1 == w || y + 1 == h;
            for ny in y.saturating_sub(1)..(y + 2).min(h) {
                for nx in x.saturating_sub(1)..(x + 2).min(w) {
                    let j = ny * w + nx;
                    if is_marker.test(pixel(j)) && visit(j) {
                        stack.push(j);
                    }
                }
            }
        }
        // A region larger than any marker (a red object) is discarded like one at the border.
        match measure(image, &region) {
            Some(b)
                if !at_border
                    && region.len() <= cap
                    && (options.min_area_px..=options.max_area_px).contains(&b.area_px)
                    && b.elongation <= options.max_elongation =>
            {
                out.blobs.push(b)
            }
            _ => out.discarded += 1,
        }
    }
    out.blobs.sort_by(|a, b| b.peak.total_cmp(&a.peak));
    for b in out.blobs.iter_mut().take(MAX_CANDIDATES) {
        // The core is the bead's image above half its peak: the disc, where its edge is sharp.
        let radius = (b.area_px as f64 / std::f64::consts::PI).sqrt();
        if let Some(c) = subpixel::refine(w, h, &image.data, &image.chroma, b.centre_px, radius) {
            (b.centre_px, b.fitted) = (c, true);
        }
    }
    out
}

/// Candidates per image that are placed to a fraction of a pixel and tried against each
/// other's epipolar lines (the reddest first).
pub const MAX_CANDIDATES: usize = 4;

/// The least 2R − G − B of a marker pixel: far above the frame's own redness noise.
fn seed_threshold(image: &RgbImage, options: &MarkerOptions) -> i32 {
    let (w, h) = (image.width, image.height);
    let mut sample: Vec<i32> = (0..h)
        .step_by(8)
        .flat_map(|y| (0..w).step_by(8).map(move |x| y * w + x))
        .map(|i| image.redness(i))
        .collect();
    let median = upper_median_by(&mut sample, i32::cmp).unwrap_or(0);
    let mut dev: Vec<i32> = sample.iter().map(|v| (v - median).abs()).collect();
    let mad = upper_median_by(&mut dev, i32::cmp).unwrap_or(0);
    // MAD of integers can be 0 on a very clean frame; one level is the floor.
    let sigma = 1.4826 * f64::from(mad.max(1));
    let noise = f64::from(median) + options.noise_factor * sigma;
    noise.max(3.0 * options.min_redness).ceil() as i32
}

/// Peak, weighted centroid, area and elongation of a region's core.
fn measure(image: &RgbImage, region: &[usize]) -> Option<Blob> {
    let w = image.width;
    let peak = region.iter().map(|&i| image.redness(i)).max()?;
    let half = f64::from(peak) / 2.0;
    let (mut s, mut sx, mut sy, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut area = 0;
    for &i in region {
        let weight = f64::from(image.redness(i)) - half;
        if weight < 0.0 {
            continue;
        }
        area += 1;
        let (x, y) = ((i % w) as f64, (i / w) as f64);
        s += weight;
        sx += weight * x;
        sy += weight * y;
        sxx += weight * x * x;
        syy += weight * y * y;
        sxy += weight * x * y;
    }
    if s <= 0.0 {
        return None;
    }
    let (cx, cy) = (sx / s, sy / s);
    let (vxx, vyy, vxy) = (sxx / s - cx * cx, syy / s - cy * cy, sxy / s - cx * cy);
    let tr = vxx + vyy;
    let disc = ((vxx - vyy).powi(2) / 4.0 + vxy * vxy).sqrt();
    let (big, small) = (tr / 2.0 + disc, tr / 2.0 - disc);
    let elongation = if small > 1e-9 {
        (big / small).sqrt()
    } else if big > 1e-9 {
        f64::INFINITY
    } else {
        1.0
    };
    Some(Blob {
        centre_px: [cx, cy],
        fitted: false,
        area_px: area,
        peak: f64::from(peak) / 3.0,
        elongation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::ChromaSampling;

    /// A grey frame with red discs (centre, radius) drawn with 8 × 8 supersampled edges.
    fn frame(discs: &[([f64; 2], f64)], w: usize, h: usize) -> RgbImage {
        let mut data = vec![0u8; 3 * w * h];
        for y in 0..h {
            for x in 0..w {
                let mut cover = 0.0;
                for s in 0..64 {
                    let (px, py) = (
                        x as f64 - 0.5 + ((s % 8) as f64 + 0.5) / 8.0,
                        y as f64 - 0.5 + ((s / 8) as f64 + 0.5) / 8.0,
                    );
                    if discs
                        .iter()
                        .any(|(c, r)| (px - c[0]).hypot(py - c[1]) <= *r)
                    {
                        cover += 1.0 / 64.0;
                    }
                }
                let grey = 120.0 + ((x * 7 + y * 13) % 5) as f64; // a little texture
                let rgb = [
                    grey + cover * (200.0 - grey),
                    grey + cover * (25.0 - grey),
                    grey + cover * (22.0 - grey),
                ];
                for k in 0..3 {
                    data[3 * (y * w + x) + k] = rgb[k].round() as u8;
                }
            }
        }
        RgbImage {
            width: w,
            height: h,
            data,
            chroma: ChromaSampling::FULL,
        }
    }

    #[test]
    fn a_red_disc_is_found_at_its_centre() {
        for (k, centre) in [[40.3, 31.7], [20.5, 20.5], [55.12, 12.9]]
            .iter()
            .enumerate()
        {
            let r = 2.0 + k as f64 * 2.0;
            let m = find_markers(&frame(&[(*centre, r)], 80, 50), &MarkerOptions::default());
            assert_eq!(m.blobs.len(), 1, "{centre:?}");
            let b = &m.blobs[0];
            let err = (b.centre_px[0] - centre[0]).hypot(b.centre_px[1] - centre[1]);
            assert!(err < 0.08, "disc r {r} at {centre:?}: {err:.3} px off");
            assert!(b.elongation < 1.3, "{}", b.elongation);
            assert!((b.peak - 150.0).abs() < 40.0, "peak {}", b.peak);
        }
    }

    #[test]
    fn grey_frames_have_no_marker_and_limits_discard_the_wrong_shapes() {
        let opts = MarkerOptions::default();
        assert_eq!(find_markers(&frame(&[], 60, 40), &opts), Markers::default());
        // Two discs → two candidates, the limits do not choose between them.
        let two = find_markers(
            &frame(&[([15.0, 15.0], 3.0), ([45.0, 20.0], 3.0)], 60, 40),
            &opts,
        );
        assert_eq!(two.blobs.len(), 2);
        // A line of touching discs is elongated; a disc on the border is cut.
        let line: Vec<([f64; 2], f64)> = (0..12)
            .map(|i| ([10.0 + 2.0 * i as f64, 20.0], 1.5))
            .collect();
        let m = find_markers(&frame(&line, 60, 40), &opts);
        assert!(m.blobs.is_empty() && m.discarded == 1, "{m:?}");
        let m = find_markers(&frame(&[([0.5, 20.0], 3.0)], 60, 40), &opts);
        assert!(m.blobs.is_empty() && m.discarded == 1, "{m:?}");
        // Too small.
        let tiny = MarkerOptions {
            min_area_px: 40,
            ..opts
        };
        let m = find_markers(&frame(&[([30.0, 20.0], 2.0)], 60, 40), &tiny);
        assert!(m.blobs.is_empty() && m.discarded == 1, "{m:?}");
    }

    #[test]
    fn the_threshold_follows_the_exposure() {
        // At a third of the exposure the bead is still found, at the same place.
        let bright = frame(&[([30.4, 20.6], 3.5)], 60, 40);
        let dim = RgbImage {
            data: bright
                .data
                .iter()
                .map(|&v| (f64::from(v) / 3.0).round() as u8)
                .collect(),
            ..bright.clone()
        };
        let opts = MarkerOptions::default();
        let (a, b) = (find_markers(&bright, &opts), find_markers(&dim, &opts));
        assert_eq!((a.blobs.len(), b.blobs.len()), (1, 1));
        let d = (a.blobs[0].centre_px[0] - b.blobs[0].centre_px[0])
            .hypot(a.blobs[0].centre_px[1] - b.blobs[0].centre_px[1]);
        assert!(d < 0.05, "{d}");
    }
}
