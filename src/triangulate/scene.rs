//! How far each camera's view of the still scene moved since its first frame (`triangulate
//! --per-frame`'s `scene_left_px`, `scene_right_px`): the frame shrunk to a grey thumbnail
//! ([`THUMB`] × [`THUMB`] pixels averaged), and its shift against the camera's first
//! thumbnail by phase correlation (OpenCV's `phaseCorrelate` under a Hanning window, tile by
//! tile), in the frame's pixels; in one frame in [`EVERY`] of each camera.
//!
//! The finger moves over a small part of the picture; the wall, the bench and the rig around it
//! do not, unless the camera moved. The bead's reprojection residual (the cameras' agreement)
//! cannot see every move: a camera of a side-by-side pair that pans moves its beads along their
//! epipolar lines, and the tip shifts in depth with no residual to tell. The still scene sees
//! any turn of a camera, and says which camera turned. A picture with nothing to lock on (a
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
/// few of them, and the median of the tiles' shifts is the still scene's.
pub const TILES: [i32; 2] = [4, 3];

/// The least correlation peak (0-1) a tile's shift is taken from: a textured tile of a still
/// scene peaks at 0.6-1 (the virtual lab's wall), one the finger crosses lower; noise against
/// noise (a plain backdrop, its means taken out) peaks near 4/√(its pixels), 0.06 for a tile
/// of 80 × 60.
pub const MIN_RESPONSE: f64 = 0.2;

/// A frame shrunk to grey ([`THUMB`] × [`THUMB`] blocks of luma averaged, the last partial
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

    /// How far the scene in `self` lies from where it lay in `reference` ([x, y] in the frame's
    /// pixels): the median over the tiles ([`TILES`]) whose correlation peaks at
    /// [`MIN_RESPONSE`] or more, of at least half the tiles; `None` when fewer agree to be
    /// measured, or the two are of different sizes.
    ///
    /// # Errors
    /// OpenCV's.
    pub fn shift_from(&self, reference: &Thumbnail) -> opencv::Result<Option<[f64; 2]>> {
        let size = self.0.size()?;
        let [across, down] = TILES;
        let (w, h) = (size.width / across, size.height / down);
        if size != reference.0.size()? || w < 8 || h < 8 {
            return Ok(None);
        }
        let mut window = Mat::default();
        opencv::imgproc::create_hanning_window(&mut window, Size::new(w, h), CV_32F)?;
        let mut shifts = Vec::new();
        for (i, j) in (0..down).flat_map(|j| (0..across).map(move |i| (i, j))) {
            let tile = Rect::new(i * w, j * h, w, h);
            let (a, b) = (centred(&reference.0, tile)?, centred(&self.0, tile)?);
            let mut response = 0.0;
            let shift = opencv::imgproc::phase_correlate(&a, &b, &window, Some(&mut response))?;
            if std::env::var("TILEDBG").is_ok() {
                eprintln!(
                    "tile {i},{j} resp {response:.3} {:.3},{:.3}",
                    shift.x, shift.y
                );
            }
            if response >= MIN_RESPONSE {
                shifts.push([shift.x, shift.y]);
            }
        }
        if 2 * shifts.len() < (across * down) as usize {
            return Ok(None);
        }
        let scale = THUMB as f64;
        let median = |c: usize| {
            let mut v: Vec<f64> = shifts.iter().map(|s| s[c]).collect();
            crate::stats::quantiles(&mut v, [0.5]).map_or(0.0, |[m]| scale * m)
        };
        Ok(Some([median(0), median(1)]))
    }
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

    /// How far `thumbnail` of camera `camera` lies from that camera's first (px), when it can
    /// be told ([`Thumbnail::shift_from`]).
    pub fn shift(&self, camera: usize, thumbnail: &Thumbnail) -> Option<f64> {
        let first = self.0.get(camera)?.as_ref()?;
        thumbnail.shift_from(first).ok().flatten().map(length)
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

/// The length of a shift (px).
pub fn length(shift: [f64; 2]) -> f64 {
    shift[0].hypot(shift[1])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The virtual lab's cluttered wall (1280 × 720, albedo to 8 bits), shifted by `by` whole
    /// pixels, with a 'finger' (a bright bar) drawn at `finger` px from the left.
    fn wall(by: [usize; 2], finger: usize) -> RgbImage {
        let (w, h) = (1280, 720);
        let albedo = crate::synth::clutter::wall(w + 40, h + 40, 7, false, [0.0; 4]);
        let mut data = Vec::with_capacity(3 * w * h);
        for y in 0..h {
            for x in 0..w {
                let k = (y + 20 - by[1]) * (w + 40) + x + 20 - by[0];
                let bar = (finger..finger + 24).contains(&x) && (200..500).contains(&y);
                data.extend((0..3).map(|c| {
                    if bar {
                        240
                    } else {
                        (220.0 * albedo[3 * k + c]) as u8
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

    /// A picture moved by (12, 8) px reads as moved by that much, whichever way; the finger
    /// moving across a still one moves nothing; a plain one gives no shift at all.
    #[test]
    fn the_still_scene_shift_is_the_pictures_not_the_fingers() {
        let reference = Thumbnail::of(&wall([0, 0], 600)).unwrap();
        let moved = Thumbnail::of(&wall([12, 8], 600)).unwrap();
        let [x, y] = moved.shift_from(&reference).unwrap().unwrap();
        assert!((x - 12.0).abs() < 0.5 && (y - 8.0).abs() < 0.5, "{x} {y}");
        let [x, y] = reference.shift_from(&moved).unwrap().unwrap();
        assert!((x + 12.0).abs() < 0.5 && (y + 8.0).abs() < 0.5, "{x} {y}");
        // Twice over: OpenCV's phaseCorrelate would window its inputs in place.
        for _ in 0..2 {
            let finger = Thumbnail::of(&wall([0, 0], 640)).unwrap();
            let shift = finger.shift_from(&reference).unwrap().unwrap();
            assert!(length(shift) < 0.1, "{shift:?}");
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
        assert_eq!(plain(2).shift_from(&plain(1)).unwrap(), None);
        let small = Thumbnail::of(&RgbImage {
            width: 64,
            height: 48,
            data: vec![0; 3 * 64 * 48],
            ..RgbImage::default()
        })
        .unwrap();
        assert_eq!(small.shift_from(&reference).unwrap(), None);
    }
}
