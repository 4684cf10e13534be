//! The per-frame rows: each left frame's step and located point, the hand frame's origin from
//! the first rest hold, and the points in the hand frame.

use std::collections::BTreeMap;

use nalgebra::Vector3;

use super::{ClockOffset, FrameRow, Tip, Track};
use crate::geometry::HandFromLeft;
use crate::session::pressures::PressureLog;
use crate::triangulate::scene::EVERY;
use crate::triangulate::{options, TriangulateError, TriangulateOptions};

/// Step 4-5's rows: one per frame of the rows' camera (`left`, its frames' numbers by record
/// `frame_of`), in time order, with its step in the log, and the point located there (in the
/// world: the left camera's frame) with its reprojection error, or the flag saying why there
/// is none.
pub(super) fn frame_rows(
    left: &Track,
    frame_of: impl Fn(usize) -> usize,
    log: &PressureLog,
    located: impl IntoIterator<Item = Tip<(Vector3<f64>, f64)>>,
) -> (Vec<FrameRow>, Vec<Option<Vector3<f64>>>) {
    let mut rows = Vec::with_capacity(left.order.len());
    let mut points = Vec::with_capacity(left.order.len());
    for ((k, &i), found) in left.order.iter().enumerate().zip(located) {
        let t = left.times[k];
        let step = log.step_at(t);
        let mut row = FrameRow {
            frame: frame_of(i),
            time_s: t,
            step,
            tip_mm: None,
            reproj_px: None,
            scene_px: Vec::new(),
            flags: Vec::new(),
        };
        if step.is_none() {
            row.flags.push("outside_log");
        }
        match found {
            Ok((point, reproj_px)) => {
                row.reproj_px = Some(reproj_px);
                points.push(Some(point));
            }
            Err(flag) => {
                row.flags.push(flag);
                points.push(None);
            }
        }
        rows.push(row);
    }
    (rows, points)
}

/// Each camera's still scene ([`crate::triangulate::scene`]; `scene` per frame record, where
/// measured) on the rows whose own frame is one the scene is measured in (its number a
/// multiple of [`EVERY`]): per camera of `tracks`, its frame measured nearest the row's
/// instant on that camera's clock (its stamps `clocks` ahead of the rows' camera's), the
/// rows' camera's own frame unless it was unreadable or its scene could not be told.
pub(super) fn with_scene(
    rows: &mut [FrameRow],
    tracks: &[&Track],
    clocks: &[ClockOffset],
    scene: &[Option<f64>],
) {
    for row in rows.iter_mut() {
        row.scene_px = scene_near(row.frame, row.time_s, tracks, clocks, scene);
    }
}

/// [`with_scene`] for one row: its frame `frame` at `time_s`; empty when the scene is not
/// measured in that frame (or nowhere: `scene` empty). Live and afterwards alike.
pub(super) fn scene_near(
    frame: usize,
    time_s: f64,
    tracks: &[&Track],
    clocks: &[ClockOffset],
    scene: &[Option<f64>],
) -> Vec<Option<f64>> {
    if scene.is_empty() || !frame.is_multiple_of(EVERY) {
        return Vec::new();
    }
    let measured = |track: &Track, pos: usize| scene[track.order[pos]];
    (tracks.iter().zip(clocks))
        .map(|(track, clock)| track.nearest_with(clock.stamp_of(time_s), EVERY, &measured))
        .collect()
}

/// The hand frame's origin: the median tip over the first rest hold, its rows and spread.
pub(super) struct RestOrigin {
    pub point: Vector3<f64>,
    pub rows: usize,
    pub spread_mm: f64,
}

/// How many steps the log's first rest hold is: the steps at 0 kPa (within `zero_kpa`) it
/// starts with.
pub(super) fn rest_steps(log: &PressureLog, options: &TriangulateOptions) -> usize {
    log.steps
        .iter()
        .take_while(|s| s.pressures_kpa.iter().all(|p| p.abs() <= options.zero_kpa))
        .count()
}

/// Step 6: the origin from the rows of the log's first rest hold (the steps at 0 kPa it
/// starts with).
///
/// # Errors
/// [`TriangulateError::NoOrigin`] when the log does not start at rest, or no frame of the
/// rest hold has a tip (its frames' flags counted).
pub(super) fn rest_origin(
    rows: &[FrameRow],
    points: &[Option<Vector3<f64>>],
    log: &PressureLog,
    options: &TriangulateOptions,
) -> Result<RestOrigin, TriangulateError> {
    let rest_steps = rest_steps(log, options);
    let in_rest = |r: &FrameRow| r.step.is_some_and(|k| k < rest_steps);
    let at_rest: Vec<Vector3<f64>> = rows
        .iter()
        .zip(points)
        .filter(|(r, _)| in_rest(r))
        .filter_map(|(_, p)| *p)
        .collect();
    if at_rest.is_empty() {
        let why = if rest_steps == 0 {
            "the log does not start with one: a session filmed per frame starts at rest, its first command 0, 0, 0 kPa held a few seconds (handcap protocol --dynamic writes one)".to_string()
        } else {
            let mut why: BTreeMap<&str, usize> = BTreeMap::new();
            for f in rows.iter().filter(|r| in_rest(r)).flat_map(|r| &r.flags) {
                *why.entry(f).or_default() += 1;
            }
            let said: Vec<String> = why.iter().map(|(f, n)| format!("{n} {f}")).collect();
            format!(
                "its rows: {}",
                if said.is_empty() {
                    "none".into()
                } else {
                    said.join(", ")
                }
            )
        };
        return Err(TriangulateError::NoOrigin {
            zero: rest_steps,
            zero_kpa: options.zero_kpa,
            why: format!("no tip in the first rest hold: {why}"),
        });
    }
    let (point, spread_mm) = crate::triangulate::origin_of(&at_rest);
    Ok(RestOrigin {
        point,
        rows: at_rest.len(),
        spread_mm,
    })
}

/// The flag of a tip beyond the finger's reach (its tip written all the same).
pub(super) const REACH: &str = "reach";

/// Each located point in the hand frame; a tip beyond the finger's reach flagged [`REACH`].
pub(super) fn in_hand_frame(
    rows: &mut [FrameRow],
    points: &[Option<Vector3<f64>>],
    hand_from_left: &HandFromLeft,
    options: &TriangulateOptions,
) {
    let base = Vector3::new(0.0, 0.0, options.finger_mm);
    for (row, point) in rows.iter_mut().zip(points) {
        if let Some(p) = point {
            let tip = hand_from_left.apply(&(*p).into()).coords;
            if (tip - base).norm() > options.finger_mm + options::REACH_MARGIN_MM {
                row.flags.push(REACH);
            }
            row.tip_mm = Some(tip.into());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two cameras at 30 fps, the right one's stamps 0.25 s ahead: the still scene of a row is
    /// each camera's measured frame nearest the row's instant on its own clock.
    #[test]
    fn the_scene_of_a_row_is_looked_up_on_each_cameras_own_clock() {
        let stamps = |ahead: f64| (0..60).map(|k| f64::from(k) / 30.0 + ahead).collect();
        let left = Track::of_stamps((0..60).collect(), stamps(0.0), 1000.0);
        let right = Track::of_stamps((60..120).collect(), stamps(0.25), 1000.0);
        // Measured in one frame in six: the left's value its frame number, the right's 100 more.
        let scene: Vec<Option<f64>> = (0..120)
            .map(|i: usize| {
                (i % 60)
                    .is_multiple_of(EVERY)
                    .then(|| (i % 60 + 100 * (i / 60)) as f64)
            })
            .collect();
        let ahead = ClockOffset {
            offset_s: 0.25,
            ..ClockOffset::default()
        };
        let tracks = [&left, &right];
        // Frame 12 at 0.4 s: the right camera filmed that instant at 0.65 s, its frame 12.
        let near = |clocks: [ClockOffset; 2]| scene_near(12, 0.4, &tracks, &clocks, &scene);
        assert_eq!(
            near([ClockOffset::default(), ahead]),
            [Some(12.0), Some(112.0)]
        );
        // On the left's clock alone, the right frame measured nearest 0.4 s is its frame 6.
        assert_eq!(near([ClockOffset::default(); 2]), [Some(12.0), Some(106.0)]);
        // A frame the scene is not measured in has none.
        assert!(scene_near(13, 13.0 / 30.0, &tracks, &[ahead; 2], &scene).is_empty());
    }
}
