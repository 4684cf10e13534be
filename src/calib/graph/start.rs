//! The starting point of the refinement ([`super`]'s step 2): each camera placed from the
//! first along the tree of its strongest ties, each board from the camera that saw most of it.

use std::collections::BTreeMap;

use nalgebra::{Rotation3, Vector3};

use super::{CamFromCam, GraphError, Sighting, State};
use crate::calib::BoardSpec;
use crate::geometry::{relative, CamFromBoard, CamFromWorld, Intrinsics};

/// How far the corners camera `b` saw lie (px², summed) from a's boards carried by `b_from_a`,
/// over every instant both saw.
pub(super) fn transfer_cost(
    board: &BoardSpec,
    camera_b: &Intrinsics,
    by_instant: &BTreeMap<usize, Vec<usize>>,
    used: &[&Sighting],
    seen_in: &[CamFromBoard],
    (a, b): (usize, usize),
    b_from_a: &CamFromCam,
) -> f64 {
    let mut sum = 0.0;
    for list in by_instant.values() {
        let find = |c: usize| list.iter().copied().find(|&i| used[i].camera == c);
        let (Some(i), Some(j)) = (find(a), find(b)) else {
            continue;
        };
        let carried = seen_in[i].then(b_from_a);
        let corners = board.corners_mm(&used[j].seen.ids);
        for (p, seen) in corners.iter().zip(&used[j].seen.px) {
            let [u, v] = camera_b
                .pixel(&carried.apply(p))
                .unwrap_or([f64::INFINITY; 2]);
            sum += (u - f64::from(seen[0])).powi(2) + (v - f64::from(seen[1])).powi(2);
        }
    }
    sum
}

/// The starting poses (module docs, step 2): each camera from the first along the tree of the
/// ties with the most shared instants, each tie's relative pose the shared instant's that
/// `cost` (a, b, b_from_a) finds best; each board from the camera that saw most corners of it.
pub(super) fn starting_poses(
    intrinsics: &[Intrinsics],
    by_instant: &BTreeMap<usize, Vec<usize>>,
    used: &[&Sighting],
    seen_in: &[CamFromBoard],
    cost: impl Fn(usize, usize, &CamFromCam) -> f64,
) -> Result<State, GraphError> {
    let n = intrinsics.len();
    let mut ties = vec![vec![0usize; n]; n];
    for list in by_instant.values() {
        for &i in list {
            for &j in list {
                ties[used[i].camera][used[j].camera] += usize::from(i != j);
            }
        }
    }
    let mut cameras: Vec<Option<CamFromWorld>> = vec![None; n];
    cameras[0] = Some(CamFromWorld::new(Rotation3::identity(), Vector3::zeros()));
    for _ in 1..n {
        // The strongest tie from a camera placed to one not yet placed.
        let best = (0..n)
            .filter(|&a| cameras[a].is_some())
            .flat_map(|a| {
                (0..n)
                    .filter(|&b| cameras[b].is_none())
                    .map(move |b| (a, b))
            })
            .filter(|&(a, b)| ties[a][b] > 0)
            .max_by_key(|&(a, b)| (ties[a][b], std::cmp::Reverse(b)));
        let Some((a, b)) = best else {
            let camera = (0..n).find(|&c| cameras[c].is_none()).expect("one left");
            return Err(GraphError::Untied { camera });
        };
        let candidates = by_instant.values().filter_map(|list| {
            let find = |c: usize| list.iter().copied().find(|&i| used[i].camera == c);
            Some(relative(&seen_in[find(a)?], &seen_in[find(b)?]))
        });
        let b_from_a = candidates
            .map(|pose| (cost(a, b, &pose), pose))
            .min_by(|x, y| x.0.total_cmp(&y.0))
            .expect("a shared instant")
            .1;
        cameras[b] = Some(cameras[a].expect("placed").then(&b_from_a));
    }
    let cameras: Vec<CamFromWorld> = cameras.into_iter().map(|c| c.expect("placed")).collect();
    let boards = by_instant
        .values()
        .map(|list| {
            let &i = list
                .iter()
                .max_by_key(|&&i| used[i].seen.ids.len())
                .expect("sighted");
            seen_in[i].then(&cameras[used[i].camera].inverse())
        })
        .collect();
    // Five distortion coefficients each, the ones the refinement moves.
    let intrinsics = intrinsics
        .iter()
        .map(|k| {
            let mut k = k.clone();
            k.dist.resize(5, 0.0);
            k
        })
        .collect();
    Ok(State {
        per_camera: 9,
        intrinsics,
        cameras,
        boards,
    })
}
