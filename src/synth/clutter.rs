//! What a lab wall behind the micro-hand looks like to a webcam: posters and boxes of muted
//! colours, printed text, shelf edges and dark cables — and, in one camera only, red things
//! that are not the marker (a red cable and a red push-pin).
//!
//! Drawn in image space (the wall is far behind the finger, so parallax does not matter), as
//! albedos that the view's illumination field then lights. Every choice comes from the seed.
//! A camera turned about its centre (a knock) sees the same wall moved: [`turned`].

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::camera::Camera;
use super::canvas::{splitmix, uniform};

/// Albedo of the bare wall.
const WALL: [f64; 3] = [0.58, 0.57, 0.54];
/// The red of the distractors: the bead's paint.
const RED: [f64; 3] = super::scene::BEAD;

/// A rectangle of the image the clutter keeps clear of red things (the finger's workspace).
pub type Keep = [f64; 4];

/// The albedo image (RGB, row-major, 0-1) of a cluttered wall, `red` adding the red cable and
/// push-pin outside `keep_clear` (pixel box [u0, v0, u1, v1] widened by 40 px).
pub fn wall(width: usize, height: usize, seed: u64, red: bool, keep_clear: Keep) -> Vec<f64> {
    let key = splitmix(seed ^ 0x434c_5554);
    let mut k = 0u64;
    let mut u = || {
        k += 1;
        uniform(key, k)
    };
    let (w, h) = (width as f64, height as f64);
    let mut img: Vec<f64> = (0..width * height).flat_map(|_| WALL).collect();

    // Posters and boxes: muted colours, some with lines of print.
    for _ in 0..28 {
        let (cw, ch) = (w * (0.05 + 0.2 * u()), h * (0.05 + 0.25 * u()));
        let (x0, y0) = (u() * (w - cw), u() * (h - ch));
        let colour = muted(u(), 0.25 * u(), 0.15 + 0.75 * u());
        let print = u() < 0.4;
        let ink = muted(u(), 0.2 * u(), 0.05 + 0.2 * u());
        let (pitch, phase) = (3.0 + 4.0 * u(), 10.0 * u());
        fill(&mut img, width, [x0, y0, x0 + cw, y0 + ch], |x, y| {
            let in_margin = x - x0 < 6.0 || x0 + cw - x < 6.0;
            let line = ((y - y0 + phase) / pitch).floor() as i64;
            let word = ((x * 0.11 + line as f64 * 1.7).sin() > -0.2) && line % 3 != 2;
            if print && !in_margin && word && (y - y0 + phase).rem_euclid(pitch) < 1.5 {
                ink
            } else {
                colour
            }
        });
    }
    // Shelf edges and dark cables.
    for _ in 0..5 {
        let (y, thick, shade) = (u() * h, 2.0 + 3.0 * u(), 0.15 + 0.2 * u());
        fill(&mut img, width, [0.0, y, w, y + thick], |_, _| [shade; 3]);
    }
    for _ in 0..6 {
        let shade = 0.05 + 0.15 * u();
        let path = wander(&mut u, w, h);
        stroke(&mut img, width, height, &path, 1.0 + 1.5 * u(), [shade; 3]);
    }
    if red {
        // A red cable that loops through the picture's edge region and a push-pin head,
        // both away from the finger's workspace.
        let clear = [
            keep_clear[0] - 40.0,
            keep_clear[1] - 40.0,
            keep_clear[2] + 40.0,
            keep_clear[3] + 40.0,
        ];
        let outside =
            |p: &[f64; 2]| p[0] < clear[0] || p[0] > clear[2] || p[1] < clear[1] || p[1] > clear[3];
        for _ in 0..100 {
            let path = wander(&mut u, w, h);
            if path.iter().all(outside) {
                stroke(&mut img, width, height, &path, 2.5, RED);
                break;
            }
        }
        for _ in 0..100 {
            let c = [20.0 + u() * (w - 40.0), 20.0 + u() * (h - 40.0)];
            if outside(&c) {
                stroke(&mut img, width, height, &[c, c], 4.5, RED);
                break;
            }
        }
    }
    img
}

/// An albedo from hue (0-1), saturation and value.
/// The wall `albedo` that camera `from` sees, as camera `to` sees it: `to` is `from` turned
/// about its centre, so each of its pixels shows the wall where its ray met `from`'s image
/// (through both lenses' distortion, bilinear between `from`'s pixels, its edge held beyond).
/// The wall moves in a turned camera's image as the far scene of a real one does (a 0.5°
/// tilt: about 8 px), which is what tells a camera that moved from the still scene.
pub fn turned(albedo: &[f64], from: &Camera, to: &Camera) -> Vec<f64> {
    let (w, h) = (to.width as usize, to.height as usize);
    let (fw, fh) = (from.width as usize, from.height as usize);
    let to_from = from.pose.rotation * to.pose.rotation.inverse();
    let at = |i: usize, j: usize, c: usize| albedo[3 * (j.min(fh - 1) * fw + i.min(fw - 1)) + c];
    (0..h)
        .into_par_iter()
        .flat_map_iter(|j| {
            (0..w).flat_map(move |i| {
                let (x, y) = to.intrinsics.undistort(i as f64, j as f64);
                let ray = to_from * Vector3::new(x, y, 1.0);
                let [u, v] = from
                    .intrinsics
                    .pixel(&Point3::from(ray))
                    .unwrap_or([-1.0, -1.0])
                    .map(|p| p.max(0.0));
                let (i0, j0) = (u.floor() as usize, v.floor() as usize);
                let (a, b) = (u - u.floor(), v - v.floor());
                (0..3).map(move |c| {
                    (1.0 - b) * ((1.0 - a) * at(i0, j0, c) + a * at(i0 + 1, j0, c))
                        + b * ((1.0 - a) * at(i0, j0 + 1, c) + a * at(i0 + 1, j0 + 1, c))
                })
            })
        })
        .collect()
}

fn muted(hue: f64, saturation: f64, value: f64) -> [f64; 3] {
    let rgb = |n: f64| {
        let k = (n + hue * 6.0) % 6.0;
        value * (1.0 - saturation * (k.min(4.0 - k).clamp(0.0, 1.0)))
    };
    [rgb(5.0), rgb(3.0), rgb(1.0)]
}

/// Sets every pixel whose centre lies in `rect` to `colour(x, y)`.
fn fill(img: &mut [f64], width: usize, rect: [f64; 4], colour: impl Fn(f64, f64) -> [f64; 3]) {
    let height = img.len() / 3 / width;
    let clamp = |v: f64, n: usize| (v.max(0.0) as usize).min(n);
    for y in clamp(rect[1].ceil(), height)..clamp(rect[3].ceil(), height) {
        for x in clamp(rect[0].ceil(), width)..clamp(rect[2].ceil(), width) {
            let c = colour(x as f64, y as f64);
            img[3 * (y * width + x)..3 * (y * width + x) + 3].copy_from_slice(&c);
        }
    }
}

/// A smooth random path across the image: a sine-wobbled line between two edge points.
fn wander(u: &mut impl FnMut() -> f64, w: f64, h: f64) -> Vec<[f64; 2]> {
    let edge = |t: f64, side: f64| match (side * 4.0) as u32 {
        0 => [t * w, 0.0],
        1 => [w, t * h],
        2 => [t * w, h],
        _ => [0.0, t * h],
    };
    let (a, b) = (edge(u(), u()), edge(u(), u()));
    let (amp, freq, phase) = (20.0 + 60.0 * u(), 1.0 + 3.0 * u(), 6.3 * u());
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy).max(1.0);
    (0..=200)
        .map(|i| {
            let t = f64::from(i) / 200.0;
            let off = amp * (std::f64::consts::TAU * freq * t + phase).sin();
            [
                a[0] + t * dx - off * dy / len,
                a[1] + t * dy + off * dx / len,
            ]
        })
        .collect()
}

/// Draws a round-capped polyline of half-width `radius` (a point when the path is one point
/// twice), anti-aliased by the share of 4 × 4 samples inside it.
fn stroke(
    img: &mut [f64],
    width: usize,
    height: usize,
    path: &[[f64; 2]],
    radius: f64,
    colour: [f64; 3],
) {
    // The samples each segment covers, united per pixel.
    let mut covered: std::collections::HashMap<usize, u16> = std::collections::HashMap::new();
    let span = |a: f64, b: f64, n: usize| (a.max(0.0) as usize)..((b.max(0.0) as usize).min(n));
    for s in path.windows(2) {
        let (lo, hi) = (
            [s[0][0].min(s[1][0]) - radius, s[0][1].min(s[1][1]) - radius],
            [s[0][0].max(s[1][0]) + radius, s[0][1].max(s[1][1]) + radius],
        );
        for y in span(lo[1], hi[1] + 2.0, height) {
            for x in span(lo[0], hi[0] + 2.0, width) {
                let mask = (0..16u16)
                    .filter(|k| {
                        let (a, b) = ((k % 4) as f64 / 4.0 - 0.375, (k / 4) as f64 / 4.0 - 0.375);
                        segment_gap([x as f64 + a, y as f64 + b], s[0], s[1]) <= radius
                    })
                    .fold(0u16, |m, k| m | 1 << k);
                if mask != 0 {
                    *covered.entry(y * width + x).or_default() |= mask;
                }
            }
        }
    }
    for (i, mask) in covered {
        let cover = f64::from(mask.count_ones()) / 16.0;
        for c in 0..3 {
            img[3 * i + c] = cover * colour[c] + (1.0 - cover) * img[3 * i + c];
        }
    }
}

fn segment_gap(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}
