//! Where the virtual calibration boards stand.

use std::sync::Arc;

use nalgebra::{Matrix3, Point3, Rotation3, Unit, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::{CaptureConfig, SynthError};
use crate::geometry::WorldFromBoard;
use crate::synth::camera::{Camera, Rig};
use crate::synth::scene::{Board, Markers};

/// The board at the finger's base that fixes the hand frame's axes (module docs).
pub(super) fn reference_board(c: &CaptureConfig, markers: &Arc<Markers>) -> Board {
    let s = c.board.square_mm;
    let (wide, tall) = ((c.board.cols - 1) as f64 * s, (c.board.rows - 1) as f64 * s);
    // Columns x, y, z of board → hand: x = hand x, y = hand −z, z = hand +y.
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::new(
        1.0, 0.0, 0.0, //
        0.0, 0.0, 1.0, //
        0.0, -1.0, 0.0,
    ));
    Board {
        spec: c.board,
        pose: WorldFromBoard::new(rotation, Vector3::new(-wide / 2.0, 5.0, 25.0 + tall / 2.0)),
        markers: markers.clone(),
    }
}

/// Random board poses: 110-230 mm from the rig, tilted up to 40°, turned in-plane up to 20°,
/// spread over the images. Both cameras see a chessboard whole; of a ChArUco board every other
/// view is partly out of an image (at least half its corners in both, some out of one),
/// pushed towards the images' edges where distortion is strongest.
pub(super) fn board_poses(
    c: &CaptureConfig,
    rig: &Rig,
    markers: &Arc<Markers>,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Board>, SynthError> {
    let s = c.board.square_mm;
    let half = Vector3::new(
        (c.board.cols - 1) as f64 * s / 2.0,
        (c.board.rows - 1) as f64 * s / 2.0,
        0.0,
    );
    let eye = Point3::from((rig.left.pose.centre().coords + rig.right.pose.centre().coords) / 2.0);
    let aim = Point3::from(c.rig.aim_mm);
    let axis = (aim - eye).normalize();
    let mut boards = Vec::new();
    for _ in 0..20_000 {
        if boards.len() == c.views {
            break;
        }
        let partial = c.board.pattern.kind().seen_in_part() && boards.len() % 2 == 1;
        let distance = rng.random_range(110.0..230.0);
        let spread = distance * if partial { 0.6 } else { 0.35 };
        let side = Vector3::x();
        let up = axis.cross(&side).normalize();
        let centre = eye
            + axis * distance
            + side * rng.random_range(-spread..spread)
            + up * rng.random_range(-spread * 0.6..spread * 0.6);
        // Facing the rig: board z away from the cameras, board x along hand x.
        let z = (centre - eye).normalize();
        let x = (side - z * side.dot(&z)).normalize();
        let y = z.cross(&x);
        let facing = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        let tilt_axis =
            Unit::new_normalize(x * rng.random_range(-1.0..1.0) + y * rng.random_range(-1.0..1.0));
        let tilt =
            Rotation3::from_axis_angle(&tilt_axis, rng.random_range(0.0..40f64.to_radians()));
        let spin = Rotation3::from_axis_angle(
            &Unit::new_normalize(z),
            rng.random_range(-20f64..20.0).to_radians(),
        );
        let rotation = tilt * spin * facing;
        let board = Board {
            spec: c.board,
            pose: WorldFromBoard::new(rotation, (centre - rotation * half).coords),
            markers: markers.clone(),
        };
        let wanted = if partial {
            partly_visible(&board, rig)
        } else {
            facing_both(&board, rig)
                && [&rig.left, &rig.right]
                    .iter()
                    .all(|cam| board.paper_corners().iter().all(|p| inside(cam, p, 15.0)))
        };
        if wanted {
            boards.push(board);
        }
    }
    if boards.len() < c.views {
        return Err(SynthError::BadCapture(format!(
            "could place only {} of {} board views inside both images; use a smaller --square-mm",
            boards.len(),
            c.views
        )));
    }
    Ok(boards)
}

/// Both cameras see the board's front at under 70°.
fn facing_both(board: &Board, rig: &Rig) -> bool {
    let normal = board.pose.rotation * Vector3::z();
    [&rig.left, &rig.right].iter().all(|cam| {
        let view = (Point3::from(board.pose.translation) - cam.pose.centre()).normalize();
        view.dot(&normal) >= 70f64.to_radians().cos()
    })
}

/// At least half the inner corners inside both images (15 px margin), and one outside an
/// image.
fn partly_visible(board: &Board, rig: &Rig) -> bool {
    let corners = board.corners();
    let cams = [&rig.left, &rig.right];
    let seen = corners
        .iter()
        .filter(|p| cams.iter().all(|cam| inside(cam, p, 15.0)))
        .count();
    facing_both(board, rig)
        && 2 * seen >= corners.len()
        && cams
            .iter()
            .any(|cam| corners.iter().any(|p| !inside(cam, p, 0.0)))
}

fn inside(cam: &Camera, p: &Point3<f64>, margin: f64) -> bool {
    cam.project(p).is_some_and(|[u, v]| {
        u >= margin
            && v >= margin
            && u <= f64::from(cam.width) - 1.0 - margin
            && v <= f64::from(cam.height) - 1.0 - margin
    })
}
