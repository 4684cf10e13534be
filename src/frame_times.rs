//! Two cameras' frame times: each one's period and the frames it dropped, and how far apart the
//! two are; one definition for `capture`'s live line and summary and `triangulate`'s clock
//! report and messages.
//!
//! The period is the median interval between consecutive frames. The frames dropped in a run of
//! frames are the slots its span holds on the camera's clock, less its frames ([`slots`]: a line
//! fitted to the stamps, so that a period a per cent off does not miscount a long run). A frame
//! stamped late (jitter) lengthens one interval and shortens the next, so it changes neither
//! the span's count nor the result; counting long intervals instead (over 1.5 periods) takes
//! such a frame for a drop.
//!
//! A frame stamped late (a reader that stalled, a busy machine: the frames waited in a queue
//! and were stamped when read) shows in the frames queued behind it: they arrive faster than
//! the camera makes them ([`late`]).

use crate::stats::Line;

/// The camera's frame period from its `times` (sorted, s); 0 with fewer than two times.
///
/// A camera that films all the time gives intervals of one period (a drop's double interval
/// and a burst's near-zero ones aside). A capture that keeps only the frames around its steps
/// (one or two per step, as the virtual capture does) has intervals of one period within a
/// step and of many between steps, and a median of a whole step. Either way the intervals are
/// whole multiples of the period. So each k = 1, 2, … proposes the median of the intervals
/// within a quarter of the median interval ÷ k (when at least [`ONE_PERIOD_SHARE`] of them
/// are), refined as the span of the intervals ÷ the periods they hold: first those of up to
/// 12 periods, then all, then those within a quarter period of a multiple (the short
/// intervals of a step alone can be biased: two frames are kept in a short window more often
/// when their stamps' jitter brings them together). The proposal that explains the most
/// intervals (at least [`PERIOD_FIT_SHARE`]), the longest of equals, is the period: a step's
/// length leaves the intervals within a step unexplained, a fraction of the period has no
/// intervals of its own. With no proposal (a jittery stream), the mean of the intervals within
/// half a median of the median.
pub fn period(times: &[f64]) -> f64 {
    let gaps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    let Some(median) = crate::stats::upper_median(&mut gaps.clone()) else {
        return 0.0;
    };
    if median <= 0.0 {
        return 0.0;
    }
    // The span ÷ periods of the intervals of 1..=`most` periods of `p` (within a quarter
    // period of their multiple when `close`), and how many they are.
    let refine = |p: f64, most: f64, close: bool| -> (f64, usize) {
        let (mut span, mut periods, mut count) = (0.0, 0.0, 0usize);
        for g in &gaps {
            let n = (g / p).round();
            if n >= 1.0 && n <= most && (!close || (g - n * p).abs() <= 0.25 * p) {
                span += g;
                periods += n;
                count += 1;
            }
        }
        (if periods > 0.0 { span / periods } else { p }, count)
    };
    let mut best: Option<(f64, f64)> = None; // (share explained, period)
    for k in 1..=MAX_PERIODS_PER_INTERVAL {
        let guess = median / k as f64;
        if guess < MIN_PERIOD_S {
            break;
        }
        let mut ones: Vec<f64> = gaps
            .iter()
            .copied()
            .filter(|g| (g - guess).abs() <= 0.25 * guess)
            .collect();
        if (ones.len() as f64) < ONE_PERIOD_SHARE * gaps.len() as f64 {
            continue;
        }
        let Some(proposed) = crate::stats::median(&mut ones) else {
            continue;
        };
        let (p, _) = refine(proposed, 12.0, false);
        let (p, _) = refine(p, f64::INFINITY, false);
        let (p, explained) = refine(p, f64::INFINITY, true);
        let share = explained as f64 / gaps.len() as f64;
        if share < PERIOD_FIT_SHARE {
            continue;
        }
        let better = match best {
            None => true,
            Some((s, q)) => share > s + 0.005 || (share >= s - 0.005 && p > q),
        };
        if better {
            best = Some((share, p));
        }
    }
    if let Some((_, p)) = best {
        return p;
    }
    let near: Vec<f64> = gaps
        .into_iter()
        .filter(|g| (g - median).abs() <= 0.5 * median)
        .collect();
    near.iter().sum::<f64>() / near.len() as f64
}

/// A free-running camera's stamps put back on its own clock: the camera exposes every
/// `period` on a crystal, the computer's stamps add the USB's jitter and its queues. Each
/// frame's slot n ([`slots`]: a dropped frame skips one, frames handed over together keep
/// their own), then the line t = a + b · n fitted by least squares, once more without the
/// stamps more than a quarter period off it (a queued frame's); the line's
/// times, and the RMS of the stamps about it (s). `None` when the stamps do not lie on one line
/// (an RMS over a sixth of a period: a camera that changed its rate or paused), or with fewer
/// than three frames.
pub fn regular(times: &[f64], period: f64) -> Option<(Vec<f64>, f64)> {
    if times.len() < 3 || period.is_nan() || period <= 0.0 {
        return None;
    }
    // Each frame's slot on the camera's clock: a queue's frames, the opening burst's too,
    // each in its own slot, and a drop a slot skipped.
    let slots: Vec<f64> = slots(times, period).into_iter().map(|n| n as f64).collect();
    let fit = |keep: &dyn Fn(usize) -> bool| -> Option<(f64, f64)> {
        let points: Vec<(f64, f64)> = (0..times.len())
            .filter(|&k| keep(k))
            .map(|k| (slots[k], times[k]))
            .collect();
        if points.len() < 3 {
            return None;
        }
        let line = Line::fit(&points)?;
        Some((line.at(0.0), line.slope))
    };
    let (a, b) = fit(&|_| true)?;
    let (a, b) = fit(&|k| (times[k] - a - b * slots[k]).abs() <= period / 4.0)?;
    let rms = (times
        .iter()
        .zip(&slots)
        .map(|(t, n)| (t - a - b * n).powi(2))
        .sum::<f64>()
        / times.len() as f64)
        .sqrt();
    (rms <= period / 6.0).then(|| (slots.iter().map(|n| a + b * n).collect(), rms))
}

/// The share of a camera's intervals of about one period that make a proposal in [`period`]:
/// fewer are a burst's, not the camera's.
pub const ONE_PERIOD_SHARE: f64 = 0.05;

/// The share of a camera's intervals that must be whole multiples of its [`period`].
pub const PERIOD_FIT_SHARE: f64 = 0.9;

/// The most camera periods one median interval is taken to hold ([`period`]): a capture that
/// keeps one frame a step, at 30 fps and 2 s a step.
pub const MAX_PERIODS_PER_INTERVAL: usize = 64;

/// The shortest camera period [`period`] finds (s): 240 fps, a fast webcam's; a queue's
/// frames read out faster than this are a burst.
pub const MIN_PERIOD_S: f64 = 1.0 / 240.0;

/// How far ahead a burst is looked for (s): a frame queued longer is still found late by this
/// much at least.
pub const LATE_WINDOW_S: f64 = 2.0;

/// A frame stamped more than this share of a period late may be paired with the other
/// camera's wrong exposure: it is late.
pub const LATE_SHARE: f64 = 0.5;

/// For each of `times` (one camera's, sorted, s; its [`period`]): how late it was stamped, at
/// least (s), when that is over [`LATE_SHARE`] of the period; `None` when it was stamped on
/// time.
///
/// Frames k < j made every `period` s were exposed at least (j − k)·period apart, so when they
/// arrived closer than that, frame k waited in a queue: its stamp is at least (j − k)·period −
/// (t_j − t_k) late (the most over every j up to [`LATE_WINDOW_S`] ahead). A dropped frame only
/// lengthens such spans, so drops never make a frame look late; a queue that never drains (a
/// constant latency) is the latency's to measure, not this.
pub fn late(times: &[f64], period: f64) -> Vec<Option<f64>> {
    if period <= 0.0 {
        return vec![None; times.len()];
    }
    let window = (LATE_WINDOW_S / period).ceil() as usize;
    (0..times.len())
        .map(|k| {
            let waited = times[k + 1..times.len().min(k + window + 1)]
                .iter()
                .enumerate()
                .map(|(n, t)| (n + 1) as f64 * period - (t - times[k]))
                .fold(0.0, f64::max);
            (waited > LATE_SHARE * period).then_some(waited)
        })
        .collect()
}

/// Frames missing from a run of `times` (sorted, s) taken every `period` s: the [`slots`] the
/// run spans, from its first frame stamped on time ([`late`]), less its frames. Frames a
/// stream hands over in a queue as it opens (a reader's first frames often are) say nothing
/// of a frame lost between them.
pub fn dropped(times: &[f64], period: f64) -> usize {
    let live = late(times, period)
        .iter()
        .position(Option::is_none)
        .unwrap_or(0);
    let times = &times[live..];
    let slots = slots(times, period);
    match (slots.first(), slots.last()) {
        (Some(first), Some(last)) => ((last - first + 1) as usize).saturating_sub(times.len()),
        _ => 0,
    }
}

/// How far (share of a period) before the line of its slots' earliest stamps (the tenth
/// percentile) a stamp may fall and still be its slot's in [`slots`]; a stamp may fall up to the
/// rest of the period after it: a stamp's latency varies upwards.
const EARLY_SHARE: f64 = 0.25;

/// How many frames ahead [`slots`] looks for those that show a frame waited in a queue.
const QUEUE_LOOKAHEAD: usize = 8;

/// Each of `times`' (sorted, s) slot on its camera's clock, counted from 0 at the first
/// frame; empty when `period` is not positive.
///
/// A stamp is the exposure, the camera's and driver's latency, and what the frame waited in a
/// queue. The wait shows in the frames after it (they came faster than a period apart), so
/// each stamp is first taken back to t_j − (j − k)·period at the latest over the next
/// [`QUEUE_LOOKAHEAD`] frames. A line slot ↦ time is then fitted to the first 16 frames and
/// widened, twice as many frames each time, each frame's slot found from the line fitted to
/// those before it (the median-interval period of a jittery stream can be a per cent off: a
/// slot a hundred frames on, counted from it, would be one off), the line refitted without
/// the stamps more than a quarter period off it and lowered to their tenth percentile, and a
/// slot allowed [`EARLY_SHARE`] of a period early, the rest late. Last, from the end back, a frame
/// sits a slot before the next one at least: a frame queued longer than the look-ahead, or a
/// first frame a driver hands over late, so neither hides a drop nor makes one.
pub fn slots(times: &[f64], period: f64) -> Vec<i64> {
    let n = times.len();
    if n == 0 || period.is_nan() || period <= 0.0 {
        return Vec::new();
    }
    let earliest: Vec<f64> = (0..n)
        .map(|k| {
            times[k..n.min(k + QUEUE_LOOKAHEAD + 1)]
                .iter()
                .enumerate()
                .map(|(j, t)| t - j as f64 * period)
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    let (mut origin, mut step) = (earliest[0], period);
    let mut slots = vec![0i64; n];
    let mut known = 1;
    while known < n {
        let upto = (2 * known).max(16).min(n);
        for k in known..upto {
            slots[k] = ((earliest[k] - origin) / step + EARLY_SHARE).floor() as i64;
        }
        known = upto;
        let fit = |keep: &dyn Fn(usize) -> bool| {
            let points: Vec<(f64, f64)> = (0..known)
                .filter(|&k| keep(k))
                .map(|k| (slots[k] as f64, earliest[k]))
                .collect();
            Line::fit(&points).filter(|line| line.slope > 0.0)
        };
        if let Some(line) = fit(&|_| true) {
            let off = |k: usize| (earliest[k] - line.at(slots[k] as f64)).abs();
            let line = fit(&|k| off(k) <= period / 4.0).unwrap_or(line);
            let mut below: Vec<f64> = (0..known)
                .map(|k| earliest[k] - line.at(slots[k] as f64))
                .collect();
            let floor = crate::stats::quantiles(&mut below, [0.1]).map_or(0.0, |[q]| q);
            (origin, step) = (line.at(0.0) + floor, line.slope);
        }
    }
    for k in (0..n - 1).rev() {
        slots[k] = slots[k].min(slots[k + 1] - 1);
    }
    let first = slots[0];
    slots.iter().map(|s| s - first).collect()
}

/// The median distance (s) from each `left` time to the nearest `right` time (both sorted); 0
/// when either is empty.
pub fn skew(left: &[f64], right: &[f64]) -> f64 {
    if right.is_empty() {
        return 0.0;
    }
    let mut d: Vec<f64> = left
        .iter()
        .map(|t| {
            let k = right.partition_point(|r| r < t);
            [k.checked_sub(1), Some(k)]
                .into_iter()
                .flatten()
                .filter_map(|k| right.get(k))
                .map(|r| (r - t).abs())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    crate::stats::median(&mut d).unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn late_frames_are_not_drops_and_missing_ones_are() {
        let p = 1.0 / 30.0;
        let mut times: Vec<f64> = (0..90).map(|k| k as f64 * p).collect();
        // Frame 10 stamped 60 % of a period late: one long and one short interval.
        times[10] += 0.6 * p;
        assert!((period(&times) - p).abs() < 1e-12);
        assert_eq!(dropped(&times, p), 0);
        // Frames 40-42 lost.
        times.drain(40..43);
        assert_eq!(dropped(&times, period(&times)), 3);
        // The first frame handed over 1.3 periods late, 3 lost after it: still 3.
        times[0] += 1.3 * p;
        assert_eq!(dropped(&times, p), 3);
        assert_eq!(dropped(&[], p), 0);
        assert_eq!(dropped(&[1.0], 0.0), 0);
    }

    /// A busy machine's stamps, as the lab's are beside two busy processes: the first three
    /// frames handed over in a queue (93, 60, 27 ms late; a frame lost between them would not
    /// be seen: none is), every stamp late by 4 ms on average
    /// (exponentially: a tenth of them over 9 ms), two 40 ms late, one frame in ten lost, the
    /// last stamp 20 ms late. Every drop is counted, none made up.
    #[test]
    fn drops_are_counted_through_a_late_start_and_a_busy_machines_jitter() {
        let p = 1.0 / 30.0;
        let late = |k: usize| match k {
            50 | 90 => 0.040,
            _ => -0.004 * (1.0 - (k * 7919 % 101) as f64 / 101.0).ln(),
        };
        let kept: Vec<usize> = (0..120).filter(|k| k % 10 != 7 || *k == 7).collect();
        let mut times: Vec<f64> = kept.iter().map(|&k| k as f64 * p + late(k)).collect();
        for (t, queued) in times.iter_mut().zip([0.093, 0.060, 0.027]) {
            *t += queued;
        }
        *times.last_mut().unwrap() += 0.020;
        let lost = 120 - kept.len();
        assert_eq!(dropped(&times, period(&times)), lost);
        assert_eq!(dropped(&times, 1.01 * p), lost, "a per cent off the period");
        let slots = slots(&times, p);
        assert_eq!(slots.last().copied(), Some(119));
    }

    /// A reader that stalls 0.4 s (12 frames queue) then reads the queue at once: the queued
    /// frames are found late by what they waited, less the last one's few ms; jitter, drops
    /// and a slower camera are not.
    #[test]
    fn frames_queued_behind_a_stall_are_late_and_jitter_and_drops_are_not() {
        let p = 1.0 / 30.0;
        let jitter = |k: usize| 0.004 * (((k * 7919) % 11) as f64 / 10.0 - 0.5);
        let exposed: Vec<f64> = (0..300).map(|k| k as f64 * p).collect();
        let mut times: Vec<f64> = exposed
            .iter()
            .enumerate()
            .map(|(k, e)| e + 0.050 + jitter(k))
            .collect();
        // Frames 100-111 read 1 ms apart once frame 111 came: the first 11 waited 43-367 ms.
        let read = exposed[111] + 0.050;
        for (n, t) in times[100..112].iter_mut().enumerate() {
            *t = read + 0.001 * n as f64;
        }
        // Frames 200-203 dropped.
        times.drain(200..204);
        let found = late(&times, period(&times));
        for (k, l) in found.iter().enumerate() {
            let truth = if (100..112).contains(&k) {
                times[k] - exposed[k] - 0.050
            } else {
                0.0
            };
            match l {
                Some(l) => assert!(
                    (l - truth).abs() < 0.006,
                    "frame {k}: {l} s late, truly {truth}"
                ),
                None => assert!(
                    truth <= LATE_SHARE * p + 0.006,
                    "frame {k} missed, {truth} late"
                ),
            }
        }
        assert_eq!(found.iter().flatten().count(), 11, "{found:?}");
        // A camera at 15 fps throughout: nothing late.
        let slow: Vec<f64> = (0..100).map(|k| k as f64 * 2.0 * p + jitter(k)).collect();
        assert!(late(&slow, period(&slow)).iter().all(Option::is_none));
        assert!(late(&[], 0.0).is_empty() && late(&[1.0], 0.0) == [None]);
    }

    /// The virtual capture keeps the frames stamped 100-140 ms (or 100-200 ms) into each
    /// 0.3 s step: one or two (or three) per camera and step, a period apart within a step.
    /// Their period is the camera's, not the step's, and nothing is late.
    #[test]
    fn frames_kept_around_steps_have_the_cameras_period_and_none_is_late() {
        let p = 1.0 / 29.97;
        // Stamp jitter of ±2 ms, spread evenly (a multiplicative hash of the frame number).
        let jitter = |k: u64| {
            0.004
                * ((k.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 11) as f64 / (1u64 << 53) as f64 - 0.5)
        };
        for window in [0.10..0.14, 0.10..0.20] {
            let kept: Vec<f64> = (0..20_000)
                .map(|k| 0.011 + k as f64 * p + jitter(k))
                .filter(|t| window.contains(&t.rem_euclid(0.3)))
                .collect();
            let across = kept.windows(2).filter(|w| w[1] - w[0] > 0.1).count();
            let within = kept.len() - 1 - across;
            assert!(within > 0 && across > 0, "{window:?}");
            assert!(
                (period(&kept) - p).abs() < 1e-5,
                "{window:?}: {} s",
                period(&kept)
            );
            assert!(late(&kept, period(&kept)).iter().all(Option::is_none));
        }
    }

    #[test]
    fn a_first_frame_stamped_half_a_period_late_leaves_the_clock_where_the_others_put_it() {
        let p = 1.0 / 30.0;
        // ±2 ms of jitter; the first frame 17 ms late (a camera's first frame, a busy start).
        let jitter = |k: usize| 0.004 * (((k * 7919) % 11) as f64 / 10.0 - 0.5);
        let mut times: Vec<f64> = (0..300).map(|k| 0.046 + k as f64 * p + jitter(k)).collect();
        times[0] += 0.017;
        let (regular, _) = regular(&times, period(&times)).unwrap();
        for (k, t) in regular.iter().enumerate().skip(1) {
            assert!((t - 0.046 - k as f64 * p).abs() < 5e-4, "frame {k}: {t}");
        }
    }

    /// A stream's first three frames handed over at once (the lab's opening queue: stamped
    /// 7, 9 and 16 ms, the next 53 ms) are the three exposures before the fourth, not one.
    #[test]
    fn frames_a_stream_hands_over_at_once_as_it_opens_keep_their_own_slots() {
        let p = 1.0 / 30.0;
        let exposed = |k: usize| 0.053 + (k as f64 - 3.0) * p;
        let mut times: Vec<f64> = (0..300).map(exposed).collect();
        times[..3].copy_from_slice(&[0.007, 0.009, 0.016]);
        let (regular, _) = regular(&times, period(&times)).unwrap();
        for (k, t) in regular.iter().enumerate() {
            assert!((t - exposed(k)).abs() < 1e-3, "frame {k}: {t}");
        }
    }

    #[test]
    fn skew_is_the_median_distance_to_the_nearest_partner() {
        let left = [0.0, 1.0, 2.0];
        let right = [0.01, 0.97, 2.5];
        assert!((skew(&left, &right) - 0.03).abs() < 1e-12);
        assert_eq!(skew(&left, &[]), 0.0);
    }
}
