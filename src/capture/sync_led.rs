//! Each camera's delay measured from an LED (`capture --sync-led`, with a serial regulator):
//! the board's LED, in view of the cameras, blinks [`BLINKS`] at the session's start and
//! again at its end, each switch on the session's clock when the board made it (its `OK ms`,
//! through the board's clock measured against the session's on the fastest round trips). A
//! camera's frame shows the LED as bright as the share of its exposure the LED was lit, so
//! every frame near a switch tells where its exposure lay; one delay d (exposure's middle →
//! stamp) and one exposure length fit all of them: each frame's lit share, (level − dark) /
//! (lit − dark) in the blocks that blink, against the share its exposure [stamp − d ∓ e/2]
//! overlaps the LED's on-times. A frame straddling a switch places it within the frame;
//! switches at many phases of the frame clock place d to a millisecond or two.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::motion::{blocks, Blocks};
use crate::stereo::Side;

/// The LED's on and off times in turn (s), from the first switch on (eight blinks): irregular, so that the
/// switches fall at many phases of a 30 fps frame clock.
pub const BLINKS: [f64; 16] = [
    0.21, 0.29, 0.23, 0.27, 0.19, 0.31, 0.25, 0.26, 0.18, 0.33, 0.22, 0.28, 0.20, 0.30, 0.24, 0.27,
];

/// Frames this long before the first switch and after the last are measured too (s): dark
/// frames, and the last switch's latest frames at any delay up to it.
const MARGIN_S: f64 = 0.6;

/// A block blinks when its level over the frames spans at least this many grey levels.
const RISE: f64 = 30.0;

/// A camera's fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LedFit {
    /// From the exposure's middle to the frame's stamp (ms).
    pub delay_ms: f64,
    /// This camera's stamps relative to the left camera's, for the same instant (ms).
    pub clock_offset_ms: f64,
    /// The exposure the frames' shares fit best (ms).
    pub exposure_ms: f64,
    /// Frames that saw part of a switch (lit for part of their exposure), and the fit's RMS
    /// residual in lit share.
    pub partial_frames: usize,
    pub rms_share: f64,
}

/// What `--sync-led` measured: the switches, and each camera's fit, by name.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SyncLed {
    /// The switches' times (session clock, s), on first.
    pub switches_s: Vec<f64>,
    pub left: Option<LedFit>,
    pub right: Option<LedFit>,
    /// Why a camera was not measured.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unmeasured: Vec<String>,
}

impl SyncLed {
    /// Both cameras' delays (ms), when both were measured.
    pub fn both_ms(&self) -> Option<[f64; 2]> {
        Some([self.left.as_ref()?.delay_ms, self.right.as_ref()?.delay_ms])
    }

    /// Measures both cameras from their frames on disk: `frames` is (camera, stamp, file).
    pub fn measure(switches_s: Vec<f64>, frames: &[(Side, f64, &Path)]) -> SyncLed {
        let mut out = SyncLed {
            switches_s,
            left: None,
            right: None,
            unmeasured: Vec::new(),
        };
        let (Some(&first), Some(&last)) = (out.switches_s.first(), out.switches_s.last()) else {
            return out;
        };
        let near = |t: f64| {
            out.switches_s
                .chunks(BLINKS.len())
                .any(|run| t >= run[0] - MARGIN_S && t <= run[run.len() - 1] + MARGIN_S)
        };
        let mut fits = [None, None];
        for side in [Side::Left, Side::Right] {
            // The stamps put back on the camera's own clock (as triangulate puts them): the
            // transport's jitter would blur the part-lit frames' places.
            let mut mine: Vec<(f64, &Path)> = frames
                .iter()
                .filter(|f| f.0 == side)
                .map(|f| (f.1, f.2))
                .collect();
            mine.sort_by(|a, b| a.0.total_cmp(&b.0));
            let stamps: Vec<f64> = mine.iter().map(|f| f.0).collect();
            let period = crate::frame_times::period(&stamps);
            if let Some((regular, _)) = crate::frame_times::regular(&stamps, period) {
                for (f, t) in mine.iter_mut().zip(regular) {
                    f.0 = t;
                }
            }
            let levels: Vec<(f64, Blocks)> = mine
                .iter()
                .filter(|(t, _)| *t >= first - MARGIN_S && *t <= last + MARGIN_S && near(*t))
                .filter_map(|(t, path)| Some((*t, blocks(&std::fs::read(path).ok()?)?)))
                .collect();
            match lamp_levels(&levels).and_then(|l| fit(&l, &out.switches_s, period)) {
                Ok(f) => fits[side as usize] = Some(f),
                Err(why) => out.unmeasured.push(format!("{}: {why}", side.name())),
            }
        }
        let left_ms = fits[0].as_ref().map(|f: &LedFit| f.delay_ms);
        for f in fits.iter_mut().flatten() {
            f.clock_offset_ms = left_ms.map_or(0.0, |l| f.delay_ms - l);
        }
        [out.left, out.right] = fits;
        out
    }
}

impl std::fmt::Display for SyncLed {
    /// What the LED measured, one line.
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        let one = |fit: &Option<LedFit>| match fit {
            Some(f) => format!(
                "{:.1} ms (exposure {:.0} ms, {} frames part-lit)",
                f.delay_ms, f.exposure_ms, f.partial_frames
            ),
            None => "not seen".into(),
        };
        write!(
            f,
            "camera delays from the LED's {} switches: left {}, right {}",
            self.switches_s.len(),
            one(&self.left),
            one(&self.right)
        )?;
        if self.both_ms().is_some() {
            f.write_str("; triangulate takes them from capture.json")?;
        }
        for why in &self.unmeasured {
            write!(f, "; {why}")?;
        }
        Ok(())
    }
}

/// Each frame's level in the blocks that blink (their mean grey), or why there are none.
fn lamp_levels(frames: &[(f64, Blocks)]) -> Result<Vec<(f64, f64)>, String> {
    let Some(size) = frames.first().map(|f| f.1.size) else {
        return Err("no frames around the LED's blinks".into());
    };
    if frames.iter().any(|f| f.1.size != size) {
        return Err("its frames changed size".into());
    }
    let n = frames[0].1.means.len();
    let blinking: Vec<usize> = (0..n)
        .filter(|&b| {
            let mut v: Vec<f64> = frames.iter().map(|f| f.1.means[b]).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() * 19 / 20] - v[v.len() / 20] >= RISE
        })
        .collect();
    if blinking.len() < 2 {
        return Err("no LED blinked in its view (is it in view, and off before?)".into());
    }
    // Each frame's lamp against the rest of its image: the lights' flicker and the exposure's
    // drift brighten both alike.
    let steady: Vec<usize> = (0..n).filter(|b| !blinking.contains(b)).collect();
    let mean = |b: &Blocks, of: &[usize]| {
        of.iter().map(|&k| b.means[k]).sum::<f64>() / of.len().max(1) as f64
    };
    Ok(frames
        .iter()
        .map(|(t, b)| {
            let rest = mean(b, &steady);
            (*t, mean(b, &blinking) / rest.max(1.0))
        })
        .collect())
}

/// Share of [a, b] the LED was on, given its switches (on first, alternating); the state at
/// `a` when the interval is empty.
pub(crate) fn on_share(switches: &[f64], a: f64, b: f64) -> f64 {
    let first = switches.partition_point(|&s| s <= a);
    let mut on = first % 2 == 1;
    if b <= a {
        return f64::from(u8::from(on));
    }
    let (mut lit, mut from) = (0.0, a);
    for &s in switches[first..].iter().take_while(|&&s| s < b) {
        if on {
            lit += s - from;
        }
        (from, on) = (s, !on);
    }
    if on {
        lit += b - from;
    }
    lit / (b - a)
}

/// The levels against the shares a delay d and an exposure e predict: a line (dark + share ×
/// the lamp's brightness) fitted by least squares: its residuals, slope and the shares.
fn line(levels: &[(f64, f64)], switches: &[f64], d: f64, e: f64) -> (Vec<f64>, f64, Vec<f64>) {
    let shares: Vec<f64> = levels
        .iter()
        .map(|&(t, _)| on_share(switches, t - d - e / 2.0, t - d + e / 2.0))
        .collect();
    let n = levels.len() as f64;
    let mean_x = shares.iter().sum::<f64>() / n;
    let mean_y = levels.iter().map(|l| l.1).sum::<f64>() / n;
    let (mut vx, mut vxy) = (0.0, 0.0);
    for (x, &(_, y)) in shares.iter().zip(levels) {
        vx += (x - mean_x).powi(2);
        vxy += (x - mean_x) * (y - mean_y);
    }
    let slope = if vx > 0.0 { vxy / vx } else { 0.0 };
    let residuals = shares
        .iter()
        .zip(levels)
        .map(|(x, &(_, y))| y - mean_y - slope * (x - mean_x))
        .collect();
    (residuals, slope, shares)
}

/// The (d, e) of least squared residual, d every `step` s over `delays`, e every millisecond
/// up to the frame period or every 0.1 ms within 1 ms of `near_e`.
fn scan(
    levels: &[(f64, f64)],
    switches: &[f64],
    delays: impl Iterator<Item = f64>,
    exposures: &[f64],
) -> (f64, f64) {
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for d in delays {
        for &e in exposures {
            let (residuals, slope, _) = line(levels, switches, d, e);
            let cost = match slope > 0.0 {
                true => residuals.iter().map(|r| r * r).sum::<f64>(),
                false => f64::INFINITY,
            };
            if cost < best.0 {
                best = (cost, d, e);
            }
        }
    }
    (best.1, best.2)
}

/// The delay and exposure that fit `levels` (time on the camera's clock, lamp level) best: a
/// scan every 0.5 ms of delay up to 1 s and every millisecond of exposure up to the frame
/// period, then 0.05 ms and 0.1 ms around the best; then once more without the frames whose
/// residual is over 4 robust standard deviations (a frame stamped out of its place).
fn fit(levels: &[(f64, f64)], switches: &[f64], period_s: f64) -> Result<LedFit, String> {
    let coarse: Vec<f64> = (0..=(period_s * 1e3) as usize)
        .map(|ms| ms as f64 / 1e3)
        .collect();
    let (d0, e0) = scan(
        levels,
        switches,
        (0..=2000).map(|k| k as f64 * 5e-4),
        &coarse,
    );
    let fine = |levels: &[(f64, f64)], d0: f64, e0: f64| {
        let exposures: Vec<f64> = (-10..=10)
            .map(|j| (e0 + j as f64 * 1e-4).max(0.0))
            .collect();
        scan(
            levels,
            switches,
            (-20..=20).map(|k| d0 + k as f64 * 5e-5),
            &exposures,
        )
    };
    let (d1, e1) = fine(levels, d0, e0);
    let (residuals, _, _) = line(levels, switches, d1, e1);
    let mut spread: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
    spread.sort_by(f64::total_cmp);
    let sigma = 1.4826 * spread[spread.len() / 2];
    let kept: Vec<(f64, f64)> = levels
        .iter()
        .zip(&residuals)
        .filter(|(_, r)| r.abs() <= 4.0 * sigma.max(1e-3))
        .map(|(l, _)| *l)
        .collect();
    let (d, e) = fine(&kept, d1, e1);
    let (residuals, slope, shares) = line(&kept, switches, d, e);
    if d <= 0.0 || d >= 1.0 || slope <= 0.0 {
        return Err(format!(
            "the LED's blinks fit no delay within 0-1000 ms (best {:.0} ms)",
            1e3 * d
        ));
    }
    let rms = (residuals.iter().map(|r| r * r).sum::<f64>() / kept.len() as f64).sqrt();
    Ok(LedFit {
        delay_ms: 1e3 * d,
        clock_offset_ms: 0.0,
        exposure_ms: 1e3 * e,
        partial_frames: shares.iter().filter(|s| **s > 0.02 && **s < 0.98).count(),
        rms_share: rms / slope,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames of a 30 fps camera (phase 7 ms) exposed `e` s, stamped `d` s after their
    /// middle: their grey (40 dark, 200 lit) from the LED's share.
    fn filmed(switches: &[f64], d: f64, e: f64) -> Vec<(f64, f64)> {
        (0..120)
            .map(|k| {
                let mid = 0.007 + k as f64 / 30.0;
                (
                    mid + d,
                    40.0 + 160.0 * on_share(switches, mid - e / 2.0, mid + e / 2.0),
                )
            })
            .collect()
    }

    fn switches(from: f64) -> Vec<f64> {
        let mut t = from;
        BLINKS
            .iter()
            .map(|dt| {
                let s = t;
                t += dt;
                s
            })
            .collect()
    }

    #[test]
    fn the_delay_and_the_exposure_are_found_from_the_part_lit_frames() {
        let on = switches(1.0);
        for (d, e) in [(0.045, 0.012), (0.0813, 0.012), (0.120, 0.020)] {
            let fit = fit(&filmed(&on, d, e), &on, 1.0 / 30.0).unwrap();
            assert!((fit.delay_ms - 1e3 * d).abs() < 0.3, "{fit:?} for {d}");
            assert!((fit.exposure_ms - 1e3 * e).abs() < 1.0, "{fit:?} for {e}");
            assert!(fit.partial_frames >= 1 && fit.rms_share < 0.01, "{fit:?}");
        }
    }

    #[test]
    fn the_share_lit_is_the_overlap_with_the_on_times() {
        let s = [1.0, 1.2, 2.0];
        assert_eq!(on_share(&s, 0.5, 0.9), 0.0);
        assert!((on_share(&s, 0.99, 1.01) - 0.5).abs() < 1e-12);
        assert!((on_share(&s, 1.1, 1.3) - 0.5).abs() < 1e-12);
        assert_eq!(on_share(&s, 2.5, 2.6), 1.0);
        assert_eq!(on_share(&s, 1.1, 1.1), 1.0);
    }
}
