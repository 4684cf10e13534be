//! Each camera's delay measured from an LED (`capture --sync-led`, with a serial regulator):
//! the board's LED, in view of the cameras, blinks [`BLINKS`] at the session's start and
//! again at its end, each switch on the session's clock as its `LED` line was written. A
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

/// The LED's on and off times in turn (s), from the first switch on: irregular, so that the
/// switches fall at many phases of a 30 fps frame clock.
pub const BLINKS: [f64; 8] = [0.21, 0.29, 0.23, 0.27, 0.19, 0.31, 0.25, 0.26];

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
    pub fn measure(switches_s: Vec<f64>, frames: &[(Side, f64, &Path)], period_s: f64) -> SyncLed {
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
            let levels: Vec<(f64, Blocks)> = frames
                .iter()
                .filter(|(s, t, _)| {
                    *s == side && *t >= first - MARGIN_S && *t <= last + MARGIN_S && near(*t)
                })
                .filter_map(|(_, t, path)| Some((*t, blocks(&std::fs::read(path).ok()?)?)))
                .collect();
            match lamp_levels(&levels).and_then(|l| fit(&l, &out.switches_s, period_s)) {
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
    Ok(frames
        .iter()
        .map(|(t, b)| {
            let level = blinking.iter().map(|&k| b.means[k]).sum::<f64>() / blinking.len() as f64;
            (*t, level)
        })
        .collect())
}

/// Share of [a, b] the LED was on, given its switches (on first, alternating).
fn on_share(switches: &[f64], a: f64, b: f64) -> f64 {
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

/// The delay and exposure that fit `levels` (stamp, grey) best, by a scan: every 0.5 ms of
/// delay up to 1 s and every millisecond of exposure up to the frame period, then 0.05 ms
/// around the best.
fn fit(levels: &[(f64, f64)], switches: &[f64], period_s: f64) -> Result<LedFit, String> {
    let mut sorted: Vec<f64> = levels.iter().map(|l| l.1).collect();
    sorted.sort_by(f64::total_cmp);
    let (dark, lit) = (sorted[sorted.len() / 20], sorted[sorted.len() * 19 / 20]);
    let shares: Vec<(f64, f64)> = levels
        .iter()
        .map(|&(t, l)| (t, ((l - dark) / (lit - dark)).clamp(-0.2, 1.2)))
        .collect();
    let cost = |d: f64, e: f64| {
        shares
            .iter()
            .map(|&(t, s)| (s - on_share(switches, t - d - e / 2.0, t - d + e / 2.0)).powi(2))
            .sum::<f64>()
    };
    let exposures: Vec<f64> = (0..=(period_s * 1e3) as usize)
        .map(|ms| ms as f64 / 1e3)
        .collect();
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for k in 0..=2000 {
        let d = k as f64 * 5e-4;
        for &e in &exposures {
            let c = cost(d, e);
            if c < best.0 {
                best = (c, d, e);
            }
        }
    }
    let (_, d0, e0) = best;
    for k in -20..=20 {
        let d = d0 + k as f64 * 5e-5;
        for j in -10..=10 {
            let e = (e0 + j as f64 * 1e-4).max(0.0);
            let c = cost(d, e);
            if c < best.0 {
                best = (c, d, e);
            }
        }
    }
    let (c, d, e) = best;
    let partial = shares
        .iter()
        .filter(|&&(t, _)| {
            let s = on_share(switches, t - d - e / 2.0, t - d + e / 2.0);
            s > 0.02 && s < 0.98
        })
        .count();
    if d <= 0.0 || d >= 1.0 {
        return Err(format!(
            "the LED's blinks fit no delay within 0-1000 ms (best {:.0} ms)",
            1e3 * d
        ));
    }
    Ok(LedFit {
        delay_ms: 1e3 * d,
        clock_offset_ms: 0.0,
        exposure_ms: 1e3 * e,
        partial_frames: partial,
        rms_share: (c / shares.len() as f64).sqrt(),
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
