//! Each row's tip from the cameras' candidates at its instant (module docs of [`super`],
//! steps 3-4).

use nalgebra::Matrix3x4;
use rayon::prelude::*;

use super::super::clock_offset::ClockOffset;
use super::super::track::{Track, MAX_SPREAD_PX};
use super::super::{Centres, Tip};
use crate::triangulate::cameras::{agreed, view_of, Calibration, Group};
use crate::triangulate::nview;

/// A row's tip, and the frames' centres it was seen as.
pub(super) struct Located {
    /// In the world (the first camera's frame); its views' indices are the cameras'.
    pub tip: nview::Triangulated,
    /// The views used: (camera, distorted px at the row's instant).
    pub pixels: Vec<(usize, [f64; 2])>,
    /// The frames the chosen views came from: (camera, position in its track, centre).
    pub frames: Vec<(usize, usize, [f64; 2])>,
}

/// What locates the rows: the cameras, their tracks and clocks, the rows' camera.
pub(super) struct Locator<'a> {
    pub calibration: &'a Calibration,
    pub tracks: &'a [Track],
    pub clocks: &'a [ClockOffset],
    pub first: usize,
    pub projections: Vec<Matrix3x4<f64>>,
}

/// A camera's candidate point at a row's instant, and the frames' centres it came from.
struct Candidate {
    px: [f64; 2],
    frames: Vec<(usize, [f64; 2])>,
}

impl Locator<'_> {
    /// Every row's tip from the candidates `centres` gives (module docs, steps 3-4), in
    /// parallel; or the flag saying why there is none.
    pub(super) fn locate_all(&self, centres: &Centres<'_>) -> Vec<Tip<Located>> {
        let rows = &self.tracks[self.first];
        (0..rows.order.len())
            .into_par_iter()
            .map(|k| self.locate(centres, k))
            .collect()
    }

    /// Row `k`'s tip.
    fn locate(&self, centres: &Centres<'_>, k: usize) -> Tip<Located> {
        let t = self.tracks[self.first].times[k];
        let mut fast = false;
        // Why the rows' camera's own frame gave no view, when it could not be examined.
        let mut own_flag = None;
        let mut choices: Vec<(usize, Vec<Group>)> = Vec::new();
        let mut sources: Vec<Vec<Candidate>> = Vec::new();
        for (c, track) in self.tracks.iter().enumerate() {
            if track.order.is_empty() {
                continue;
            }
            let found = if c == self.first {
                self.own(centres, k)
            } else {
                self.interpolated(track, centres, self.clocks[c].stamp_of(t))
            };
            let candidates = match found {
                Ok(list) if !list.is_empty() => list,
                Err("fast") => {
                    fast = true;
                    continue;
                }
                Err(flag @ ("skipped" | "no_image")) if c == self.first => {
                    own_flag = Some(flag);
                    continue;
                }
                _ => continue,
            };
            let camera = &self.calibration.cameras[c].intrinsics;
            let groups = candidates
                .iter()
                .map(|cand| Group {
                    view: view_of(camera, &self.projections[c], cand.px),
                    frames: 1,
                    px: cand.px,
                })
                .collect();
            choices.push((c, groups));
            sources.push(candidates);
        }
        if choices.len() < 2 {
            return Err(match (fast, own_flag) {
                (true, _) => "fast",
                (false, Some(flag)) => flag,
                (false, None) => "unseen",
            });
        }
        let (mut tip, chosen) = agreed(&choices).map_err(|why| match why {
            nview::Refused::TooFewViews => "unseen",
            nview::Refused::Inconsistent { .. } => "reprojection",
        })?;
        let mut pixels = Vec::new();
        let mut frames = Vec::new();
        for &i in &tip.used {
            let (c, candidate) = (choices[i].0, &sources[i][chosen[i]]);
            pixels.push((c, candidate.px));
            frames.extend(candidate.frames.iter().map(|&(pos, px)| (c, pos, px)));
        }
        tip.used = tip.used.iter().map(|&i| choices[i].0).collect();
        tip.left_out = tip.left_out.iter().map(|&i| choices[i].0).collect();
        Ok(Located {
            tip,
            pixels,
            frames,
        })
    }

    /// The rows' camera's candidates in its frame `k`, but those around which its own track
    /// jerks (smeared over a jump: no better than an interpolation); `fast` when that leaves
    /// none.
    fn own(&self, centres: &Centres<'_>, k: usize) -> Result<Vec<Candidate>, &'static str> {
        let track = &self.tracks[self.first];
        let all = centres(track.order[k])?;
        let steady: Vec<Candidate> = all
            .iter()
            .filter(|&&px| {
                track
                    .jerk_around(k, px, centres)
                    .is_none_or(|jerk| jerk <= track.px(MAX_SPREAD_PX))
            })
            .map(|&px| Candidate {
                px,
                frames: vec![(k, px)],
            })
            .collect();
        if steady.is_empty() && !all.is_empty() {
            return Err("fast");
        }
        Ok(steady)
    }

    /// A camera's candidates at `t` on its clock: from the two frames around it, else (none
    /// there) from those either side with one of the two left out, as if dropped, where
    /// exactly one of the two ways gives points.
    fn interpolated(
        &self,
        track: &Track,
        centres: &Centres<'_>,
        t: f64,
    ) -> Result<Vec<Candidate>, &'static str> {
        let (a, b, _) = track.around(t)?;
        track.around_or_dropped((a, b), |a, b| {
            let (points, _) = track.at_instant(centres, a, b, t)?;
            Ok(points
                .into_iter()
                .map(|((p, q), px)| Candidate {
                    px,
                    frames: vec![(a, p), (b, q)],
                })
                .collect())
        })
    }
}
