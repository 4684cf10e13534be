//! Where the virtual calibration boards stand.

use std::sync::Arc;

use nalgebra::{Matrix3, Point3, Rotation3, Unit, Vector3};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::{CaptureConfig, SynthError};
use crate::geometry::WorldFromBoard;
use crate::synth::camera::{Camera, Rig, ARC_STEP_DEG};
use crate::synth::scene::{Board, Markers};

/// A board and the cameras (places in the rig) that photograph it.
pub(super) struct Sighted {
    pub board: Board,
    pub by: Vec<usize>,
}

/// The boards a capture photographs for calibration, the reference last: a pair sees every
/// board ([`board_poses`]), more cameras each its share ([`arc_board_poses`]).
///
/// # Errors
/// [`SynthError::BadCapture`] when the boards do not fit the images, or fewer than two cameras
/// see the reference whole.
pub(super) fn calibration_boards(
    c: &CaptureConfig,
    rig: &Rig,
    seed: u64,
) -> Result<Vec<Sighted>, SynthError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4341_5054);
    let markers = Arc::new(
        Markers::of(&c.board)
            .map_err(|e| SynthError::BadCapture(format!("the board's markers: {e}")))?,
    );
    let everyone: Vec<usize> = (0..rig.cameras.len()).collect();
    let mut boards: Vec<Sighted> = if rig.cameras.len() == 2 {
        let boards = board_poses(c, rig, &markers, &mut rng)?;
        boards
            .into_iter()
            .map(|board| Sighted {
                board,
                by: everyone.clone(),
            })
            .collect()
    } else {
        arc_board_poses(c, rig, &markers, &mut rng)?
    };
    let board = reference_board(c, &markers);
    let by = if rig.cameras.len() == 2 {
        everyone
    } else {
        seen_by(&board, rig)
    };
    if c.calibration_images && by.len() < 2 {
        return Err(SynthError::BadCapture(format!(
            "the reference board at the finger's base is seen whole by {} of the cameras; two must see it: use a smaller --square-mm",
            by.len()
        )));
    }
    boards.push(Sighted { board, by });
    Ok(boards)
}

/// The board at the finger's base that fixes the hand frame's axes (module docs).
fn reference_board(c: &CaptureConfig, markers: &Arc<Markers>) -> Board {
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
fn board_poses(
    c: &CaptureConfig,
    rig: &Rig,
    markers: &Arc<Markers>,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Board>, SynthError> {
    let eye =
        Point3::from((rig.left().pose.centre().coords + rig.right().pose.centre().coords) / 2.0);
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
        let board = facing_from(c, markers, eye, centre, side, 40.0, rng);
        let wanted = if partial {
            partly_visible(&board, rig)
        } else {
            rig.cameras
                .iter()
                .all(|cam| facing(&board, cam, 70.0) && whole(&board, cam))
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

/// A board centred at `centre` facing `eye` (board z away from it, board x along `side`),
/// then tilted up to `tilt_deg` about a random axis in its plane and turned in-plane up to 20°.
fn facing_from(
    c: &CaptureConfig,
    markers: &Arc<Markers>,
    eye: Point3<f64>,
    centre: Point3<f64>,
    side: Vector3<f64>,
    tilt_deg: f64,
    rng: &mut ChaCha8Rng,
) -> Board {
    let s = c.board.square_mm;
    let half = Vector3::new(
        (c.board.cols - 1) as f64 * s / 2.0,
        (c.board.rows - 1) as f64 * s / 2.0,
        0.0,
    );
    let z = (centre - eye).normalize();
    let x = (side - z * side.dot(&z)).normalize();
    let y = z.cross(&x);
    let facing = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    let tilt_axis =
        Unit::new_normalize(x * rng.random_range(-1.0..1.0) + y * rng.random_range(-1.0..1.0));
    let tilt = Rotation3::from_axis_angle(&tilt_axis, rng.random_range(0.0..tilt_deg.to_radians()));
    let spin = Rotation3::from_axis_angle(
        &Unit::new_normalize(z),
        rng.random_range(-20f64..20.0).to_radians(),
    );
    let rotation = tilt * spin * facing;
    Board {
        spec: c.board,
        pose: WorldFromBoard::new(rotation, (centre - rotation * half).coords),
        markers: markers.clone(),
    }
}

/// Where a rig of more than two cameras sees each board: random boards around the aim point,
/// each facing a random direction along the arc, kept when two or more cameras see it whole at
/// under [`ARC_FACING_DEG`] — never both ends of the arc, so that they are tied only through
/// the cameras between — until every camera has seen `c.views`. The boards and, for each, the
/// cameras (places in the rig) that see it.
fn arc_board_poses(
    c: &CaptureConfig,
    rig: &Rig,
    markers: &Arc<Markers>,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Sighted>, SynthError> {
    let n = rig.cameras.len();
    let aim = Point3::from(c.rig.aim_mm);
    let reach = (n - 1) as f64 / 2.0 * ARC_STEP_DEG + 20.0;
    let middle = rig
        .cameras
        .iter()
        .map(|cam| cam.pose.centre().coords)
        .sum::<Vector3<f64>>()
        / n as f64;
    let mut seen = vec![0; n];
    let mut boards = Vec::new();
    for _ in 0..50_000 {
        if seen.iter().all(|&k| k >= c.views) {
            break;
        }
        let turn = Rotation3::from_axis_angle(
            &Vector3::z_axis(),
            rng.random_range(-reach..reach).to_radians(),
        );
        // Where a camera at this azimuth would stand, at the arc's mean distance.
        let eye = aim + turn * (Point3::from(middle) - aim).normalize() * c.rig.distance_mm;
        let toward = (aim - eye).normalize();
        let side = turn * Vector3::x();
        let up = toward.cross(&side).normalize();
        let centre = aim
            + toward * rng.random_range(-70.0..20.0)
            + side * rng.random_range(-35.0..35.0)
            + up * rng.random_range(-25.0..25.0);
        let board = facing_from(c, markers, eye, centre, side, 35.0, rng);
        let by = seen_by(&board, rig);
        let needed = by.iter().any(|&i| seen[i] < c.views);
        if by.len() >= 2 && !(by.contains(&0) && by.contains(&(n - 1))) && needed {
            for &i in &by {
                seen[i] += 1;
            }
            boards.push(Sighted { board, by });
        }
    }
    if let Some(short) = seen.iter().position(|&k| k < c.views) {
        return Err(SynthError::BadCapture(format!(
            "could place only {} of {} board views inside {}'s image; use a smaller --square-mm",
            seen[short],
            c.views,
            rig.names()[short]
        )));
    }
    Ok(boards)
}

/// The cameras (places in the rig) that see the whole board at under [`ARC_FACING_DEG`].
fn seen_by(board: &Board, rig: &Rig) -> Vec<usize> {
    (0..rig.cameras.len())
        .filter(|&i| {
            facing(board, &rig.cameras[i], ARC_FACING_DEG) && whole(board, &rig.cameras[i])
        })
        .collect()
}

/// A camera of an arc sees a board whose front turns at most this far from it (°).
const ARC_FACING_DEG: f64 = 60.0;

/// The camera sees the board's front at under `limit_deg`.
fn facing(board: &Board, cam: &Camera, limit_deg: f64) -> bool {
    let normal = board.pose.rotation * Vector3::z();
    let view = (Point3::from(board.pose.translation) - cam.pose.centre()).normalize();
    view.dot(&normal) >= limit_deg.to_radians().cos()
}

/// The board's paper lies inside the camera's image (15 px margin).
fn whole(board: &Board, cam: &Camera) -> bool {
    board.paper_corners().iter().all(|p| inside(cam, p, 15.0))
}

/// At least half the inner corners inside both images (15 px margin), and one outside an
/// image.
fn partly_visible(board: &Board, rig: &Rig) -> bool {
    let corners = board.corners();
    let seen = corners
        .iter()
        .filter(|p| rig.cameras.iter().all(|cam| inside(cam, p, 15.0)))
        .count();
    rig.cameras.iter().all(|cam| facing(board, cam, 70.0))
        && 2 * seen >= corners.len()
        && rig
            .cameras
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
