//! How far each camera's view of the still scene moved since its first frame (`triangulate
//! --per-frame`'s `scene_left_px`, `scene_right_px`): the frame shrunk to a grey thumbnail
//! ([`THUMB`] × [`THUMB`] pixels summed), each of its tiles' shift against the camera's first
//! thumbnail by phase correlation (OpenCV's `phaseCorrelate` under a Hanning window), a shift
//! and a turn about the centre fitted to the tiles, and how far they moved the tiles (RMS), in
//! the frame's pixels; in one frame in [`EVERY`] of each camera.
//!
//! The finger moves over a small part of the picture; the wall, the bench and the rig around it
//! do not, unless the camera moved. The bead's reprojection residual (the cameras' agreement)
//! cannot see every move: a camera of a side-by-side pair that pans moves its beads along their
//! epipolar lines, and the tip shifts in depth with no residual to tell. The still scene sees
//! a camera turned any way (a pan or a tilt shifts its picture, a roll turns it), and says
//! which camera turned. A picture with nothing to lock on (a
//! plain backdrop) gives no shift rather than a guess: a correlation peak under
//! [`MIN_RESPONSE`].

use opencv::core::{Mat, Rect, Size, CV_32F};
use opencv::prelude::*;

use crate::image::RgbImage;

/// Pixels of the frame per thumbnail pixel, each way: a 0.5° turn of a 1280 × 720 webcam moves
/// its picture about 8 px, two thumbnail pixels; phase correlation's sub-pixel peak places
/// it to about a tenth of that.
pub const THUMB: usize = 4;

/// The still scene is measured in the frames whose number is a multiple of this: five times a
/// second at 30 fps, for a monitor that looks once a second (a frame's measure costs 1.4 ms on
/// one core, about half what finding its bead does).
pub const EVERY: usize = 6;

/// The thumbnail's tiles, across and down, each correlated on its own: the finger moves in a
/// few of them, which the fit leaves out ([`Thumbnail::motion_from`]).
pub const TILES: [i32; 2] = [4, 3];

/// The least correlation peak (0-1) a tile's shift is taken from: a textured tile of a still
/// scene peaks at 0.6-1 (the virtual lab's wall), one the finger crosses lower; noise against
/// noise (a plain backdrop, its means taken out) peaks near 4/√(its pixels), 0.06 for a tile
/// of 80 × 60.
pub const MIN_RESPONSE: f64 = 0.2;

/// A frame shrunk to grey ([`THUMB`] × [`THUMB`] blocks of luma summed, the last partial
/// blocks left out).
#[derive(Clone, Debug)]
pub struct Thumbnail(Mat);

impl Thumbnail {
    /// The thumbnail of `image`.
    ///
    /// # Errors
    /// OpenCV's, making the matrix.
    pub fn of(image: &RgbImage) -> opencv::Result<Thumbnail> {
        let (w, h) = (image.width / THUMB, image.height / THUMB);
        // Luma in integers (ITU-R 601 weights over 256), summed over each block.
        let mut sums = vec![0u32; w];
        let mut grey = Vec::with_capacity(w * h);
        for j in 0..h {
            sums.fill(0);
            for y in j * THUMB..(j + 1) * THUMB {
                let line = &image.data[3 * y * image.width..][..3 * w * THUMB];
                for (sum, block) in sums.iter_mut().zip(line.chunks_exact(3 * THUMB)) {
                    *sum += block
                        .chunks_exact(3)
                        .map(|p| {
                            77 * u32::from(p[0]) + 150 * u32::from(p[1]) + 29 * u32::from(p[2])
                        })
                        .sum::<u32>();
                }
            }
            grey.extend(sums.iter().map(|&s| s as f32));
        }
        let mat = Mat::from_slice(&grey)?.reshape(1, h as i32)?.try_clone()?;
        Ok(Thumbnail(mat))
    }

    /// How the scene in `self` moved from where it lay in `reference`, from the tiles
    /// ([`TILES`]) whose correlation peaks at [`MIN_RESPONSE`] or more, at least half of them;
    /// `None` when fewer lock on, or the two are of different sizes.
    ///
    /// # Errors
    /// OpenCV's.
    pub fn motion_from(&self, reference: &Thumbnail) -> opencv::Result<Option<Motion>> {
        let size = self.0.size()?;
        let [across, down] = TILES;
        let (w, h) = (size.width / across, size.height / down);
        if size != reference.0.size()? || w < 8 || h < 8 {
            return Ok(None);
        }
        let mut window = Mat::default();
        opencv::imgproc::create_hanning_window(&mut window, Size::new(w, h), CV_32F)?;
        let scale = THUMB as f64;
        // Each tile's centre from the picture's (px of the frame), and its shift.
        let mut tiles = Vec::new();
        for (i, j) in (0..down).flat_map(|j| (0..across).map(move |i| (i, j))) {
            let tile = Rect::new(i * w, j * h, w, h);
            let (a, b) = (centred(&reference.0, tile)?, centred(&self.0, tile)?);
            let mut response = 0.0;
            let shift = opencv::imgproc::phase_correlate(&a, &b, &window, Some(&mut response))?;
            if response >= MIN_RESPONSE {
                let centre = |k: i32, n: i32, of: i32| {
                    scale * f64::from(n) * (f64::from(k) + 0.5 - 0.5 * f64::from(of))
                };
                let c = [centre(i, w, across), centre(j, h, down)];
                tiles.push((c, [scale * shift.x, scale * shift.y]));
            }
        }
        if 2 * tiles.len() < (across * down) as usize {
            return Ok(None);
        }
        // A shift and a turn about the picture's centre (a camera rolled about its axis moves
        // the tiles on either side of the centre apart), fitted to the tiles by least squares,
        // then again without the tiles it leaves more than three times the median residual
        // (at least half a pixel) from it: those the finger crossed.
        let (mut shift, mut roll_rad) = fit_motion(&tiles);
        let off = |(c, s): &([f64; 2], [f64; 2]), shift: [f64; 2], roll: f64| {
            (s[0] - shift[0] + roll * c[1]).hypot(s[1] - shift[1] - roll * c[0])
        };
        let mut residuals: Vec<f64> = tiles.iter().map(|t| off(t, shift, roll_rad)).collect();
        let [median] = crate::stats::quantiles(&mut residuals, [0.5]).unwrap_or([0.0]);
        let kept: Vec<_> = (tiles.iter())
            .filter(|t| off(t, shift, roll_rad) <= (3.0 * median).max(0.5))
            .copied()
            .collect();
        if 2 * kept.len() < (across * down) as usize {
            return Ok(None);
        }
        (shift, roll_rad) = fit_motion(&kept);
        let squares = kept.iter().map(|(c, _)| {
            (shift[0] - roll_rad * c[1]).powi(2) + (shift[1] + roll_rad * c[0]).powi(2)
        });
        let moved_px = (squares.sum::<f64>() / kept.len() as f64).sqrt();
        Ok(Some(Motion {
            shift,
            roll_rad,
            moved_px,
        }))
    }
}

/// The shift [x, y] and the turn θ (rad) that carry the tiles' centres `c` (from the picture's
/// centre) by their shifts `s` best (least squares): s ≈ shift + θ (−c_y, c_x).
fn fit_motion(tiles: &[([f64; 2], [f64; 2])]) -> ([f64; 2], f64) {
    let (mut ata, mut atb) = (
        nalgebra::Matrix3::<f64>::zeros(),
        nalgebra::Vector3::<f64>::zeros(),
    );
    for ([cx, cy], [sx, sy]) in tiles {
        for (row, value) in [([1.0, 0.0, -cy], sx), ([0.0, 1.0, *cx], sy)] {
            let a = nalgebra::Vector3::from(row);
            ata += a * a.transpose();
            atb += a * *value;
        }
    }
    match ata.lu().solve(&atb) {
        Some(x) => ([x[0], x[1]], x[2]),
        None => ([0.0; 2], 0.0),
    }
}

/// How a camera's picture of the still scene moved ([`Thumbnail::motion_from`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    /// The shift ([x, y], px of the frame).
    pub shift: [f64; 2],
    /// The turn about the picture's centre (rad; x towards y).
    pub roll_rad: f64,
    /// How far the shift and the turn moved the tiles, RMS over those kept (px): what the
    /// channel watches. (The RMS, not the farthest tile: the turn's noise grows with a tile's
    /// distance from the centre.)
    pub moved_px: f64,
}

/// Each camera's first thumbnail (by its place in the rig: a pair's 0 left, 1 right), the
/// reference its later frames' shifts are measured from.
#[derive(Default)]
pub struct FirstFrames(Vec<Option<Thumbnail>>);

impl FirstFrames {
    /// Keeps `thumbnail` as camera `camera`'s first, when it has none yet.
    pub fn offer(&mut self, camera: usize, thumbnail: &Thumbnail) {
        if self.0.len() <= camera {
            self.0.resize(camera + 1, None);
        }
        self.0[camera].get_or_insert_with(|| thumbnail.clone());
    }

    /// How far `thumbnail` of camera `camera` lies from that camera's first (px,
    /// [`Motion::moved_px`]), when it can be told ([`Thumbnail::motion_from`]).
    pub fn shift(&self, camera: usize, thumbnail: &Thumbnail) -> Option<f64> {
        let first = self.0.get(camera)?.as_ref()?;
        let motion = thumbnail.motion_from(first).ok().flatten()?;
        Some(motion.moved_px)
    }
}

/// The tile `tile` of `thumbnail` less its mean, a copy: without the mean, a plain tile is
/// noise that correlates with nothing (with it, the window's own bump would peak at no shift);
/// and OpenCV 4.6's phaseCorrelate windows its inputs in place when their size is already one
/// its DFT takes (as the tiles' are).
fn centred(thumbnail: &Mat, tile: Rect) -> opencv::Result<Mat> {
    let roi = Mat::roi(thumbnail, tile)?;
    let mean = opencv::core::mean_def(&roi)?;
    let mut out = Mat::default();
    roi.convert_to(&mut out, CV_32F, 1.0, -mean[0])?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The virtual lab's cluttered wall (1282 × 722: not a multiple of the blocks or tiles;
    /// albedo to 8 bits), shifted by `by` px and turned by `roll` rad about the picture's
    /// centre (bilinear), with a 'finger' (a bright bar) drawn at `finger` px from the left.
    fn wall(by: [f64; 2], roll: f64, finger: usize) -> RgbImage {
        let (w, h, margin) = (1282, 722, 40);
        let stride = w + 2 * margin;
        let albedo = crate::synth::clutter::wall(stride, h + 2 * margin, 7, false, [0.0; 4]);
        let (cx, cy) = (0.5 * w as f64, 0.5 * h as f64);
        let mut data = Vec::with_capacity(3 * w * h);
        for y in 0..h {
            for x in 0..w {
                // Where this pixel's wall was before the move.
                let (dx, dy) = (x as f64 - cx - by[0], y as f64 - cy - by[1]);
                let (c, s) = (roll.cos(), roll.sin());
                let u = c * dx + s * dy + cx + margin as f64;
                let v = -s * dx + c * dy + cy + margin as f64;
                let (i, j, a, b) = (u as usize, v as usize, u.fract(), v.fract());
                let at = |i: usize, j: usize, k: usize| albedo[3 * (j * stride + i) + k];
                let bar = (finger..finger + 24).contains(&x) && (200..500).contains(&y);
                data.extend((0..3).map(|k| {
                    let value = (1.0 - b) * ((1.0 - a) * at(i, j, k) + a * at(i + 1, j, k))
                        + b * ((1.0 - a) * at(i, j + 1, k) + a * at(i + 1, j + 1, k));
                    if bar {
                        240
                    } else {
                        (220.0 * value) as u8
                    }
                }));
            }
        }
        RgbImage {
            width: w,
            height: h,
            data,
            ..RgbImage::default()
        }
    }

    /// A picture moved by (12, 8) px reads as moved by that much, whichever way; one turned by
    /// 0.3° about its centre reads as turned so (its tiles about 2.1 px RMS), which the tiles'
    /// median shift alone would not see; the finger moving across a still one moves
    /// nothing; a plain one gives no shift at all.
    #[test]
    fn the_still_scene_shift_is_the_pictures_not_the_fingers() {
        let reference = Thumbnail::of(&wall([0.0; 2], 0.0, 600)).unwrap();
        let motion = |image: &RgbImage, from: &Thumbnail| {
            Thumbnail::of(image).unwrap().motion_from(from).unwrap()
        };
        let moved = wall([12.0, 8.0], 0.0, 600);
        let m = motion(&moved, &reference).unwrap();
        let [x, y] = m.shift;
        assert!((x - 12.0).abs() < 0.5 && (y - 8.0).abs() < 0.5, "{m:?}");
        assert!(
            (m.moved_px - 14.42).abs() < 0.5 && m.roll_rad.abs() < 2e-4,
            "{m:?}"
        );
        let back = motion(&wall([0.0; 2], 0.0, 600), &Thumbnail::of(&moved).unwrap()).unwrap();
        assert!((back.shift[0] + 12.0).abs() < 0.5 && (back.shift[1] + 8.0).abs() < 0.5);
        let roll = 0.3_f64.to_radians();
        let turned = motion(&wall([0.0; 2], roll, 600), &reference).unwrap();
        assert!((turned.roll_rad - roll).abs() < 0.15 * roll, "{turned:?}");
        assert!(turned.shift[0].hypot(turned.shift[1]) < 0.3, "{turned:?}");
        assert!(turned.moved_px > 1.5 && turned.moved_px < 2.5, "{turned:?}");
        // Twice over: OpenCV's phaseCorrelate would window its inputs in place.
        for _ in 0..2 {
            let finger = motion(&wall([0.0; 2], 0.0, 640), &reference).unwrap();
            assert!(finger.moved_px < 0.1, "{finger:?}");
        }
        // A plain grey backdrop: sensor noise alone, another in each frame.
        let plain = |seed: u64| {
            use rand::{Rng, SeedableRng};
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let data = (0..3 * 1280 * 720)
                .map(|_| rng.random_range(120..136))
                .collect();
            let image = RgbImage {
                width: 1280,
                height: 720,
                data,
                ..RgbImage::default()
            };
            Thumbnail::of(&image).unwrap()
        };
        assert_eq!(plain(2).motion_from(&plain(1)).unwrap(), None);
        let small = RgbImage {
            width: 64,
            height: 48,
            data: vec![0; 3 * 64 * 48],
            ..RgbImage::default()
        };
        assert_eq!(motion(&small, &reference), None);
    }

    /// The background does not stay still in a lab: someone walks behind the rig, the lights
    /// dim. Neither moves the camera's picture of the still scene: measured 0.11 px for a
    /// person over a quarter of the picture (0.20 over half of it), 0.003 px for the lights at
    /// 70 %, against the channel's reference of at least 0.75 px.
    #[test]
    fn a_person_passing_behind_or_the_lights_dimming_move_nothing() {
        let still = wall([0.0; 2], 0.0, 600);
        let reference = Thumbnail::of(&still).unwrap();
        let moved = |image: &RgbImage| {
            let motion = Thumbnail::of(image)
                .unwrap()
                .motion_from(&reference)
                .unwrap();
            motion.map(|m| m.moved_px)
        };
        // A person: a dark coat with a lighter stripe, 300 × 560 px, in the right third.
        let mut person = still.clone();
        for y in 80..640 {
            for x in 880..1180 {
                let shade = if (x / 40) % 2 == 0 { 30 } else { 70 };
                person.data[3 * (y * person.width + x)..][..3].fill(shade);
            }
        }
        let passing = moved(&person).expect("the tiles the person leaves lock on");
        assert!(passing < 0.3, "{passing} px");
        // The lights at 70 %.
        let mut dim = still.clone();
        dim.data
            .iter_mut()
            .for_each(|v| *v = (f64::from(*v) * 0.7) as u8);
        let dimmed = moved(&dim).expect("a dimmer picture locks on");
        assert!(dimmed < 0.1, "{dimmed} px");
    }
}
