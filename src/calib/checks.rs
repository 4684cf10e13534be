//! The calibration's checks: epipolar distance, the boards triangulated back,
//! rectification, and the hand frame's axes from the reference pair.

use nalgebra::{Matrix3, Rotation3, Vector3};
use opencv::calib3d;
use opencv::core::{self, Mat, Size};

use super::{BoardCheck, BoardSpec, CalibError, PairCorners, StereoFit, View};
use crate::cv::{fixed, mat, points};
use crate::geometry::{CamFromBoard, Intrinsics};
use crate::stereo::Side;

/// Corners as `f64`.
fn wide(c: &[[f32; 2]]) -> Vec<[f64; 2]> {
    c.iter()
        .map(|p| [f64::from(p[0]), f64::from(p[1])])
        .collect()
}

/// Mean distance (px) of each undistorted corner from the epipolar line of its partner, both
/// ways.
pub(super) fn epipolar_error(rig: &StereoFit, pairs: &[PairCorners]) -> Result<f64, CalibError> {
    let f = Matrix3::from_row_slice(&rig.f);
    let (mut sum, mut n) = (0.0, 0usize);
    for pair in pairs {
        let ul = rig.cams.undistorted(Side::Left, &wide(&pair.left))?;
        let ur = rig.cams.undistorted(Side::Right, &wide(&pair.right))?;
        for (a, b) in ul.iter().zip(&ur) {
            let (pa, pb) = (Vector3::new(a[0], a[1], 1.0), Vector3::new(b[0], b[1], 1.0));
            let line_r = f * pa;
            let line_l = f.transpose() * pb;
            sum += line_r.dot(&pb).abs() / line_r.x.hypot(line_r.y);
            sum += line_l.dot(&pa).abs() / line_l.x.hypot(line_l.y);
            n += 2;
        }
    }
    Ok(sum / n as f64)
}

/// Triangulates every used board and compares it with the printed one: the distance between
/// neighbouring corners both images show, and each board's flatness.
pub(super) fn board_check(
    board: &BoardSpec,
    rig: &StereoFit,
    pairs: &[PairCorners],
) -> Result<BoardCheck, CalibError> {
    let (mut steps, mut plane_sq, mut plane_n) = (Vec::new(), 0.0, 0usize);
    for pair in pairs {
        let pts = rig
            .cams
            .triangulate(&wide(&pair.left), &wide(&pair.right))?;
        let n = pts.len();
        let index = |id: usize| pair.ids.binary_search(&id).ok();
        for (k, &id) in pair.ids.iter().enumerate() {
            for next in board.neighbours(id) {
                if let Some(m) = index(next) {
                    steps.push((pts[m] - pts[k]).norm() / board.square_mm);
                }
            }
        }
        let centre = pts.iter().sum::<Vector3<f64>>() / n as f64;
        let mut cov = Matrix3::zeros();
        for p in &pts {
            let d = p - centre;
            cov += d * d.transpose();
        }
        let eig = cov.symmetric_eigen();
        plane_sq += eig.eigenvalues.min();
        plane_n += n;
    }
    let (mean, sd) = crate::stats::mean_sd(&steps).expect("boards have corners");
    Ok(BoardCheck {
        neighbour_mean_squares: mean,
        neighbour_sd_squares: sd,
        planarity_rms_mm: (plane_sq.max(0.0) / plane_n as f64).sqrt(),
    })
}

type Rectification = ([f64; 9], [f64; 9], [f64; 12], [f64; 12], [f64; 16]);

pub(super) fn rectify(rig: &StereoFit, size: [i32; 2]) -> Result<Rectification, CalibError> {
    let (mut r1, mut r2, mut p1, mut p2, mut q) = (
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
    );
    calib3d::stereo_rectify(
        &mat(3, &rig.cams.left.k)?,
        &mat(1, &rig.cams.left.dist)?,
        &mat(3, &rig.cams.right.k)?,
        &mat(1, &rig.cams.right.dist)?,
        Size::new(size[0], size[1]),
        &mat(3, &rig.cams.right_from_left.rotation_rows())?,
        &mat(3, &rig.cams.right_from_left.translation_array())?,
        &mut r1,
        &mut r2,
        &mut p1,
        &mut p2,
        &mut q,
        calib3d::CALIB_ZERO_DISPARITY,
        0.0,
        Size::new(size[0], size[1]),
        None,
        None,
    )?;
    Ok((
        fixed(&r1)?,
        fixed(&r2)?,
        fixed(&p1)?,
        fixed(&p2)?,
        fixed(&q)?,
    ))
}

/// Left-camera → hand-frame rotation from the reference board's corners in the left image.
pub(super) fn hand_axes(
    board: &BoardSpec,
    rig: &StereoFit,
    view: View,
) -> Result<Rotation3<f64>, CalibError> {
    Ok(hand_from(board_pose(board, &rig.cams.left, view)?.rotation))
}

/// A frame → hand-frame rotation from the reference board's rotation in that frame (a
/// camera's, whose image's right is the frame's x).
pub(super) fn hand_from(mut from_board: Rotation3<f64>) -> Rotation3<f64> {
    // The board read so that its x axis points to the image's right: a chessboard's corners
    // may be found from either end, and a ChArUco board may be laid upside down. Turning it
    // half round about its normal is reading its corners in reverse.
    if (from_board * Vector3::x()).x < 0.0 {
        from_board *= Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI);
    }
    // Board axes in the hand frame: x → x, y → −z, z → +y.
    let hand_from_board = Rotation3::from_matrix_unchecked(Matrix3::new(
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0,
    ));
    hand_from_board * from_board.inverse()
}

/// The board's pose in a camera from its corners (`solvePnP`, iterative).
pub(super) fn board_pose(
    board: &BoardSpec,
    camera: &Intrinsics,
    view: View,
) -> Result<CamFromBoard, CalibError> {
    let (mut rvec, mut tvec) = (Mat::default(), Mat::default());
    calib3d::solve_pnp(
        &board.object_points(view.ids),
        &points(view.px),
        &mat(3, &camera.k)?,
        &mat(1, &camera.dist)?,
        &mut rvec,
        &mut tvec,
        false,
        calib3d::SOLVEPNP_ITERATIVE,
    )?;
    let mut rotation = Mat::default();
    calib3d::rodrigues(&rvec, &mut rotation, &mut core::no_array())?;
    Ok(CamFromBoard::new(
        Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&fixed::<9>(&rotation)?)),
        Vector3::from(fixed::<3>(&tvec)?),
    ))
}
