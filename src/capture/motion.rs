//! How much later one camera sees a motion than the other, from the frames alone: each frame's
//! motion is the mean absolute change of its grey image, in 8 × 8 blocks, from the camera's
//! previous frame, and the right camera's delay behind the left is the lag that best correlates the two
//! motion series. A calibration capture waits for the board to stand still longer than that:
//! otherwise one camera's latest frame may show the board still at its new place while the
//! other's shows it still at the old one.

use crate::stereo::Side;

/// The motion series' grid step (s).
const GRID_S: f64 = 1.0 / 60.0;
/// The largest delay looked for (s).
pub const MAX_DELAY_S: f64 = 1.0;
/// Only the latest seconds are correlated.
const WINDOW_S: f64 = 30.0;
/// A delay is trusted when its correlation is at least this.
pub const MIN_CORRELATION: f64 = 0.5;
/// Delays whose correlation is at least this share of the best's fit almost as well: a motion
/// that repeats (a board moved every second) cannot tell them apart.
pub const AS_GOOD: f64 = 0.9;

/// One camera's motion meter: each frame's change from the one before (run on the camera's own
/// thread: decoding every frame is no work for the session's).
#[derive(Default)]
pub struct Meter {
    previous: Option<Blocks>,
}

impl Meter {
    /// The mean absolute change in grey levels of this frame (encoded bytes) from the previous
    /// one; `None` for the first, or a frame that does not decode.
    pub fn change(&mut self, bytes: &[u8]) -> Option<f64> {
        let small = blocks(bytes)?;
        let change = self.previous.as_ref().and_then(|p| p.mean_change(&small));
        self.previous = Some(small);
        change
    }
}

/// The two cameras' motion so far.
#[derive(Default)]
pub struct Motion {
    /// Per camera: (time, mean absolute change in grey levels), in time order.
    series: [Vec<(f64, f64)>; 2],
}

/// The right camera's delay behind the left (s; negative: the left is behind), how well the
/// motions agree at it (correlation, at most 1), and the largest delay either way that fits
/// [`AS_GOOD`] (s): what a capture must wait out.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Delay {
    pub right_minus_left_s: f64,
    pub correlation: f64,
    pub largest_s: f64,
}

impl Motion {
    /// Adds a frame's change ([`Meter::change`]) of `side` taken at `time_s`.
    pub fn add(&mut self, side: Side, time_s: f64, change: f64) {
        let series = &mut self.series[side as usize];
        series.push((time_s, change));
        let old = series.partition_point(|s| s.0 < time_s - WINDOW_S - MAX_DELAY_S);
        series.drain(..old);
    }

    /// The right camera's delay behind the left, when both have seen the same motion.
    pub fn delay(&self) -> Option<Delay> {
        delay(&self.series[0], &self.series[1])
    }
}

/// A grey image's 8 × 8 block means.
pub(super) struct Blocks {
    pub size: [usize; 2],
    pub means: Vec<f64>,
}

impl Blocks {
    /// The mean absolute difference from `other`, when it has the same size.
    fn mean_change(&self, other: &Blocks) -> Option<f64> {
        (self.size == other.size && !self.means.is_empty()).then(|| {
            self.means
                .iter()
                .zip(&other.means)
                .map(|(a, b)| (a - b).abs())
                .sum::<f64>()
                / self.means.len() as f64
        })
    }
}

/// A frame's grey levels in 8 × 8 blocks: a JPEG's luma alone by zune-jpeg (libjpeg's warnings
/// on a webcam's frames would reach the terminal), anything else through OpenCV.
pub(super) fn blocks(bytes: &[u8]) -> Option<Blocks> {
    let (grey, width, height) = if bytes.starts_with(&[0xff, 0xd8]) {
        use zune_core::colorspace::ColorSpace;
        use zune_core::options::DecoderOptions;
        let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::Luma);
        let mut decoder = zune_jpeg::JpegDecoder::new_with_options(bytes, options);
        let grey = decoder.decode().ok()?;
        let info = decoder.info()?;
        (grey, usize::from(info.width), usize::from(info.height))
    } else {
        use opencv::prelude::*;
        let image = crate::cv::decode_image(
            &opencv::core::Vector::from_slice(bytes),
            opencv::imgcodecs::IMREAD_GRAYSCALE,
        )
        .ok()?;
        let grey = image.data_bytes().ok()?.to_vec();
        (grey, image.cols() as usize, image.rows() as usize)
    };
    if grey.len() < width * height {
        return None;
    }
    let size = [width / 8, height / 8];
    let mut means = vec![0.0; size[0] * size[1]];
    for y in 0..size[1] * 8 {
        let row = &grey[y * width..y * width + size[0] * 8];
        for (bx, block) in row.chunks_exact(8).enumerate() {
            means[(y / 8) * size[0] + bx] += block.iter().map(|&g| f64::from(g)).sum::<f64>();
        }
    }
    for m in &mut means {
        *m /= 64.0;
    }
    Some(Blocks { size, means })
}

/// The lag of `right` behind `left` (each (time, motion), in time order) with the largest
/// normalised correlation, sampled every `GRID_S` over their common span (at least twice
/// [`MAX_DELAY_S`]); `None` when either holds no motion or no lag reaches [`MIN_CORRELATION`].
pub fn delay(left: &[(f64, f64)], right: &[(f64, f64)]) -> Option<Delay> {
    let (first, last) = (
        left.first()?.0.max(right.first()?.0),
        left.last()?.0.min(right.last()?.0),
    );
    let lags = (MAX_DELAY_S / GRID_S).round() as usize;
    let n = ((last - first) / GRID_S).floor() as usize;
    // At least twice the largest delay in common.
    if n < 2 * lags {
        return None;
    }
    // Each series as the motion of the frame last seen at each grid time.
    let sample = |series: &[(f64, f64)]| -> Vec<f64> {
        (0..n)
            .map(|k| {
                let t = first + k as f64 * GRID_S;
                let i = series.partition_point(|s| s.0 <= t);
                series[i.saturating_sub(1)].1
            })
            .collect()
    };
    let (l, r) = (sample(left), sample(right));
    let correlation = |lag: isize| -> f64 {
        // left[k] against right[k + lag], over the overlap.
        let (start, end) = (
            0.max(-lag) as usize,
            (n as isize).min(n as isize - lag) as usize,
        );
        let a = &l[start..end];
        let b = &r[(start as isize + lag) as usize..(end as isize + lag) as usize];
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (ma, mb) = (mean(a), mean(b));
        let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
        for (x, y) in a.iter().zip(b) {
            ab += (x - ma) * (y - mb);
            aa += (x - ma) * (x - ma);
            bb += (y - mb) * (y - mb);
        }
        if aa <= 0.0 || bb <= 0.0 {
            0.0
        } else {
            ab / (aa * bb).sqrt()
        }
    };
    let lags = lags as isize;
    let all: Vec<(isize, f64)> = (-lags..=lags).map(|lag| (lag, correlation(lag))).collect();
    let &(lag, best) = all.iter().max_by(|a, b| a.1.total_cmp(&b.1))?;
    let largest = all
        .iter()
        .filter(|(_, c)| *c >= AS_GOOD * best)
        .map(|(lag, _)| lag.unsigned_abs())
        .max()
        .unwrap_or(0);
    (best >= MIN_CORRELATION).then_some(Delay {
        right_minus_left_s: lag as f64 * GRID_S,
        correlation: best,
        largest_s: largest as f64 * GRID_S,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Motion bursts at irregular times, seen by the right camera 0.4 s later, each camera at
    /// 30 fps from its own phase: the delay is found to a grid step and a half; still cameras
    /// give none.
    #[test]
    fn a_later_camera_sees_the_same_motion_later() {
        let bursts = [1.0, 2.7, 3.4, 5.9, 7.2, 8.0, 10.5];
        let motion = |t: f64| {
            bursts
                .iter()
                .map(|b| if (t - b).abs() < 0.1 { 20.0 } else { 0.0 })
                .sum::<f64>()
                + 0.5
        };
        let series = |phase: f64, late: f64| -> Vec<(f64, f64)> {
            (0..360)
                .map(|k| {
                    let t = phase + k as f64 / 30.0;
                    (t + late, motion(t))
                })
                .collect()
        };
        let d = delay(&series(0.0, 0.05), &series(0.013, 0.45)).unwrap();
        assert!(
            (d.right_minus_left_s - 0.4).abs() <= 1.5 * GRID_S + 0.013,
            "{d:?}"
        );
        assert!(d.correlation > 0.8, "{d:?}");
        assert!((d.largest_s - 0.4).abs() <= 3.0 * GRID_S, "{d:?}");
        let d = delay(&series(0.0, 0.45), &series(0.0, 0.05)).unwrap();
        assert!((d.right_minus_left_s + 0.4).abs() <= 1.5 * GRID_S, "{d:?}");
        // Motion every 0.5 s: delays 0.5 s apart fit alike, and the largest is to be waited out.
        let periodic = |late: f64| -> Vec<(f64, f64)> {
            (0..360)
                .map(|k| {
                    let t = k as f64 / 30.0;
                    (t + late, if (t % 0.5) < 0.05 { 20.0 } else { 0.5 })
                })
                .collect()
        };
        let d = delay(&periodic(0.0), &periodic(0.2)).unwrap();
        assert!(d.largest_s >= 0.7 - 1.5 * GRID_S, "{d:?}");
        let still: Vec<(f64, f64)> = (0..360).map(|k| (k as f64 / 30.0, 0.5)).collect();
        assert_eq!(delay(&still, &still), None);
        assert_eq!(delay(&still[..50], &still[..50]), None);
    }
}
