//! What to capture next: the image regions no board reached, the tilts not taken, and how many
//! more pairs would bring the calibration's deviations within handcap's targets.
//!
//! # Rules
//! - Coverage: each image is cut into 8 × 6 cells; a corner block (2 × 2 cells at each of the
//!   image's corners) without a single board corner leaves the distortion there to
//!   extrapolation: two more pairs for each such corner.
//! - Tilt: the boards' normals in the left camera; their spread (standard deviation) about the
//!   camera's x and y axes below [`MIN_TILT_SD_DEG`] leaves the focal length and the principal
//!   point to be told apart by too little foreshortening: four more pairs tilted about that axis.
//! - Marker noise: when 0.1 px in each image moves the tip more than 0.1 mm, no calibration
//!   helps: the cameras are too far or too close together.
//! - Deviations: above a target (below), the pairs that would bring it there if each new pair
//!   is like the ones taken (a deviation falls as 1/√pairs): n · ((sd / target)² − 1); beyond
//!   [`MAX_MORE_PAIRS`] the advice is to take better pairs instead.

use serde::Serialize;

use super::uncertainty::{Uncertainty, DISPLACEMENT_MM, MARKER_NOISE_PX};
use super::PairCorners;
use crate::geometry::CamFromBoard;
use crate::stereo::StereoRig;

/// Cells across and down each image.
pub const CELLS: [usize; 2] = [8, 6];

/// Tilt spread (standard deviation, degrees) below which more tilted views are asked for.
pub const MIN_TILT_SD_DEG: f64 = 8.0;

/// Targets: the focal lengths' and the baseline's deviation relative to their value (half of the
/// 0.5 % DESIGN.md allows, so that two deviations stay inside it), and a tip displacement's
/// deviation from the calibration along any axis (mm).
pub const FOCAL_TARGET: f64 = 0.0025;
pub const BASELINE_TARGET: f64 = 0.0025;
pub const TIP_TARGET_MM: f64 = 0.05;

/// Coverage and tilt of the boards used, and what to capture next.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Guidance {
    /// Per camera, the cells holding corners: rows top to bottom, cells left to right.
    pub cells: [[[bool; CELLS[0]]; CELLS[1]]; 2],
    /// The boards' tilt spread about the left camera's x (top towards or away from the camera)
    /// and y (a side towards it) axes, degrees.
    pub tilt_sd_deg: [f64; 2],
    /// One sentence per thing to capture; empty when nothing more is needed.
    pub advice: Vec<String>,
}

impl Guidance {
    /// Share of each image's cells that hold corners.
    pub fn coverage(&self) -> [f64; 2] {
        self.cells.map(|cells| {
            let hit = cells.iter().flatten().filter(|&&c| c).count();
            hit as f64 / (CELLS[0] * CELLS[1]) as f64
        })
    }

    /// A camera's cells as text: `#` a cell with corners, `.` one without, a line per row.
    pub fn map(&self, camera: usize) -> Vec<String> {
        self.cells[camera]
            .iter()
            .map(|row| row.iter().map(|&c| if c { '#' } else { '.' }).collect())
            .collect()
    }
}

/// The cells of one image holding at least one corner.
fn cells(size: [i32; 2], pairs: &[PairCorners], side: usize) -> [[bool; CELLS[0]]; CELLS[1]] {
    let mut cells = [[false; CELLS[0]]; CELLS[1]];
    let (nx, ny) = (CELLS[0] as f32, CELLS[1] as f32);
    for c in pairs.iter().flat_map(|p| p.view(side).px) {
        let i = ((c[0] / size[0] as f32) * nx).clamp(0.0, nx - 1.0) as usize;
        let j = ((c[1] / size[1] as f32) * ny).clamp(0.0, ny - 1.0) as usize;
        cells[j][i] = true;
    }
    cells
}

/// Standard deviation of the boards' tilt about the left camera's x and y axes (degrees).
fn tilt_sd(poses: &[CamFromBoard]) -> [f64; 2] {
    let angles: Vec<[f64; 2]> = poses
        .iter()
        .map(|p| {
            let n = p.rotation * nalgebra::Vector3::z();
            [n.y.atan2(n.z).to_degrees(), n.x.atan2(n.z).to_degrees()]
        })
        .collect();
    std::array::from_fn(|a| {
        let values: Vec<f64> = angles.iter().map(|v| v[a]).collect();
        crate::stats::mean_sd(&values).map_or(0.0, |(_, sd)| sd)
    })
}

/// Most pairs the advice asks for: beyond, more pairs like these are not the remedy.
pub const MAX_MORE_PAIRS: usize = 100;

/// "take N more pairs {how} for {goal}": the pairs like the `n` taken that bring `sd` down to
/// `target`; beyond [`MAX_MORE_PAIRS`], what to do instead.
fn more_pairs(n: usize, sd: f64, target: f64, how: &str, goal: &str) -> String {
    let more = (n as f64 * ((sd / target).powi(2) - 1.0)).ceil().max(1.0);
    if more > MAX_MORE_PAIRS as f64 {
        format!("more pairs like these will not get it to {goal}: take pairs with the board larger in the image and tilted more, and check that each pair's two images are taken together")
    } else {
        format!("take {more} more pairs {how} for {goal}")
    }
}

/// Coverage, tilt and advice for a calibration of `rig` from the corners of `pairs`, the boards
/// at `poses` (left camera), with its `uncertainty` when there is one.
pub fn advise(
    rig: &StereoRig,
    pairs: &[PairCorners],
    poses: &[CamFromBoard],
    uncertainty: Option<&Uncertainty>,
) -> Guidance {
    let size = rig.image_size;
    let guidance_cells = [cells(size, pairs, 0), cells(size, pairs, 1)];
    let tilt_sd_deg = tilt_sd(poses);
    let n = poses.len();
    let mut advice = Vec::new();

    let corners = [
        ("top-left", 0, 0),
        ("top-right", 0, CELLS[0] - 2),
        ("bottom-left", CELLS[1] - 2, 0),
        ("bottom-right", CELLS[1] - 2, CELLS[0] - 2),
    ];
    let mut empty = Vec::new();
    for (name, j, i) in corners {
        let cameras: Vec<&str> = ["left", "right"]
            .into_iter()
            .zip(&guidance_cells)
            .filter(|(_, c)| !(c[j][i] || c[j][i + 1] || c[j + 1][i] || c[j + 1][i + 1]))
            .map(|(camera, _)| camera)
            .collect();
        if !cameras.is_empty() {
            empty.push(format!("{name} ({})", cameras.join(" and ")));
        }
    }
    if !empty.is_empty() {
        advice.push(format!(
            "no board reached the image's {} corner: take {} more pairs with the board near {} (the distortion is measured there)",
            empty.join(", "),
            2 * empty.len(),
            if empty.len() == 1 { "it" } else { "each" }
        ));
    }
    for (axis, how) in [
        (
            0,
            "about its horizontal axis (top towards the cameras, then away)",
        ),
        (
            1,
            "about its vertical axis (one side towards the cameras, then the other)",
        ),
    ] {
        if tilt_sd_deg[axis] < MIN_TILT_SD_DEG {
            advice.push(format!(
                "the boards' tilt {how} varies by only {:.0}° (sd): take 4 more pairs tilted 20-40° that way",
                tilt_sd_deg[axis]
            ));
        }
    }
    if let Some(u) = uncertainty {
        for (c, camera) in [(0, &rig.left), (1, &rig.right)] {
            if let Some(sd) = u.parameters.intrinsics[c] {
                let relative = sd[0].max(sd[1]) / camera.fx();
                if relative > FOCAL_TARGET {
                    advice.push(format!(
                        "the {} camera's focal length is known to ±{:.2} %: {}",
                        ["left", "right"][c],
                        100.0 * relative,
                        more_pairs(
                            n,
                            relative,
                            FOCAL_TARGET,
                            "in varied poses",
                            &format!("±{:.2} %", 100.0 * FOCAL_TARGET)
                        ),
                    ));
                }
            }
        }
        let baseline = rig.right_from_left.translation.norm();
        if u.parameters.baseline_mm / baseline > BASELINE_TARGET {
            advice.push(format!(
                "the baseline is known to ±{:.3} mm ({:.2} %): {}",
                u.parameters.baseline_mm,
                100.0 * u.parameters.baseline_mm / baseline,
                more_pairs(
                    n,
                    u.parameters.baseline_mm / baseline,
                    BASELINE_TARGET,
                    "in varied poses",
                    &format!("±{:.2} %", 100.0 * BASELINE_TARGET)
                ),
            ));
        }
        let worst = |v: [f64; 3]| v.iter().copied().fold(0.0, f64::max);
        let moved = worst(u.tip.displacement);
        if moved > TIP_TARGET_MM {
            advice.push(format!(
                "at the finger the calibration alone leaves a {DISPLACEMENT_MM} mm move of the tip ±{moved:.3} mm uncertain: {}",
                more_pairs(
                    n,
                    moved,
                    TIP_TARGET_MM,
                    "near the finger's distance",
                    &format!("±{TIP_TARGET_MM} mm")
                )
            ));
        }
        let noise = worst(u.tip.marker);
        if noise > 2.0 * TIP_TARGET_MM {
            advice.push(format!(
                "at the finger {MARKER_NOISE_PX} px of marker noise moves the tip ±{noise:.3} mm: bring the cameras closer to the finger or further apart (depth error grows with distance² / baseline)"
            ));
        }
    }
    Guidance {
        cells: guidance_cells,
        tilt_sd_deg,
        advice,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    fn facing(tilt_x_deg: f64, tilt_y_deg: f64) -> CamFromBoard {
        CamFromBoard::new(
            Rotation3::from_euler_angles(tilt_x_deg.to_radians(), tilt_y_deg.to_radians(), 0.0),
            Vector3::new(0.0, 0.0, 200.0),
        )
    }

    #[test]
    fn empty_corners_and_flat_boards_are_asked_for() {
        // Corners only in the image's middle, boards never tilted about y.
        let middle: Vec<[f32; 2]> = (0..20)
            .map(|k| [400.0 + 20.0 * k as f32, 300.0 + 5.0 * k as f32])
            .collect();
        let pairs = [PairCorners {
            report: 0,
            ids: (0..middle.len()).collect(),
            left: middle.clone(),
            right: middle,
        }];
        let poses: Vec<CamFromBoard> = [-20.0, 0.0, 20.0].map(|t| facing(t, 0.0)).to_vec();
        let g = advise(&StereoRig::rectified_for_tests(), &pairs, &poses, None);
        assert!(g.coverage()[0] < 0.2, "{:?}", g.coverage());
        assert_eq!(g.map(0)[0], "........");
        let text = g.advice.join("\n");
        assert!(
            text.contains("top-left (left and right), top-right (left and right), bottom-left (left and right), bottom-right (left and right) corner: take 8 more pairs"),
            "{text}"
        );
        assert!(text.contains("about its vertical axis"), "{text}");
        assert!(!text.contains("about its horizontal axis"), "{text}");
        assert!(
            (g.tilt_sd_deg[0] - 16.33).abs() < 0.01,
            "{:?}",
            g.tilt_sd_deg
        );
    }

    #[test]
    fn deviations_fall_as_one_over_root_pairs() {
        // Twice the target with 10 pairs: 30 more make 40, halving it.
        let more = |sd| more_pairs(10, sd, 1.0, "so", "1");
        assert_eq!(more(2.0), "take 30 more pairs so for 1");
        assert_eq!(more(1.01), "take 1 more pairs so for 1");
        // Far beyond: not a number of pairs but better ones.
        assert!(
            more(100.0).contains("will not get it to 1"),
            "{}",
            more(100.0)
        );
    }
}
