//! The marker's centre to a small fraction of a pixel on the frames webcams give: MJPEG with
//! 4:2:0 chroma at quality ~85.
//!
//! The region finder ([`super::marker`]) gates the marker by colour and gives the centroid of
//! its redness above half the peak. On JPEG frames that centroid errs by ~0.2 px, a bias that
//! stays put while the bead does (so more frames per step do not help) and moves when it moves:
//! redness 2R − G − B is pure chroma (3.518 Cr − 1.428 Cb), and a JPEG stores chroma at half
//! resolution (4:2:0) and quantises it coarsely. Measured on our renders, it is the
//! quantisation more than the halving: 4:2:0 at quality 100 places the bead to 0.04 px, at 85
//! to 0.14 px across the baseline (u), and 0.1 px in u is 0.045 mm in depth on this rig.
//! Luma, full-resolution and finely quantised, does not place the bead by itself either: on one
//! side the bead meets the pale finger, elsewhere a wall of any brightness, and a highlight
//! sits on it; centroids of luma contrast, luma edge circles and luma disc fits with a
//! background per sector were all measured worse than the fit below on the realistic capture
//! (a dark disc over a background extended radially from just outside it: 0.065 px between
//! steps in u and 0.14 in v on PNG frames, where the fit below gives 0.01).
//!
//! The fit: over the chroma samples within 12 px (and 2.5 radii) of the centroid, the stored
//! redness is modelled as what the encoder stored of
//!
//!   r(x) = A · ½ erfc((|x − c| − ρ) / √2 β) + b₀ + b₁ (x − c₀ₓ) + b₂ (y − c₀ᵧ) + k · Y(x)
//!          + m · (G − B)(x),
//!
//! a disc of radius ρ whose edge the optics blur by β (the bead's image) on a tilted background
//! whose redness also goes with its luma Y (the pale finger is slightly red, a wall need not
//! be) and with its other hue, G − B, each term averaged over the chroma's 2 × 2 blocks. Two
//! materials under any shading (the finger and the wall) have colours in one plane through
//! black, where redness is exactly k · Y + m · (G − B); with Y alone the finger's shaded rim,
//! dark yet still the finger's hue, read as red beside the bead and pulled it towards the
//! finger (0.086 px at quality 100 in the unit scene, 0.29 px in the demo's right camera at
//! rest). G − B barely shares JPEG noise with redness (correlation 0.06) and a red bead has
//! little of it. A Gaussian bead, as before, fits a bead of 3 px about as well but not a
//! larger one: flat-topped, its image biased the Gaussian
//! by its phase against the samples (radius 5, 7, 9 px: 0.10, 0.15, 0.74 px off, in a window
//! it outgrew; the disc: 0.04, 0.02, 0.02), and a closer camera or a larger bead is what a lab
//! may well have. On the lab captures the disc also does better (seeds 31-35: 0.030-0.048 mm
//! against 0.031-0.049).
//!
//! k and m are taken first from the samples beyond the bead (1.5 radii + 3 px from the
//! centroid), m shrunk towards 0 unless the background's G − B varies beyond JPEG's noise
//! (`HUE_PRIOR`), not fitted with it: the bead is as dark as it is red, so beside a plain
//! wall k · Y alone can stand for the bead, and a joint fit then settled nowhere (on JPEG
//! 4:2:0 renders of a bead alone, 14 of 60 at quality 85 and 25 of 60 at 100 fell back to the
//! centroid; with k from the background all are fitted). The stored samples are recovered
//! from the decoded pixels by undoing libjpeg's interpolation (least squares over an 80 px
//! region, exact away from its edges), and the residuals are weighed by the quantisation
//! noise the file's own chroma table implies (each 8 × 8 block's coefficients are rounded to
//! their steps q: uniform noise of variance q²/12 per coefficient, so the coarse high
//! frequencies count little): generalised least squares. A and b are solved linearly for
//! each (c, ρ, β), and those by Levenberg-Marquardt. The disc is symmetric about c, as the
//! bead's image is. PNG frames have no sampling and no quantisation: the same fit with unit
//! weights on the pixels.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::OnceLock;

use nalgebra::{DMatrix, DVector, Matrix4, Vector4};

use crate::image::ChromaSampling;

/// Side of the square of pixels the chroma planes are recovered over (a multiple of 16, so of
/// every block and coding unit); the bead sits in its middle.
const REGION: usize = 80;
/// Half-side of the window (px) whose chroma samples are fitted: at least this, and at least
/// this many of the bead's radii.
const MIN_HALF_WINDOW: usize = 12;
const WINDOW_RADII: f64 = 2.5;
/// Variance of a stored redness sample that the quantisation does not explain (levels²): the
/// sensor's noise (about 0.7 levels² per channel at mid-grey, × 6 for 2R − G − B, ÷ 4 over a
/// 2 × 2 block) and the decoder's rounding to 8 bits; without it the fit trusts the finely
/// quantised coefficients of a quality-95 file too much (tip RMS 0.047 mm against 0.027 with
/// it, on a clean 4:2:0 capture; 2 and 16 measured too).
const PIXEL_NOISE: f64 = 4.0;
/// The luma slope's samples lie beyond this many radii plus 3 px (the blurred edge) from the
/// start.
const BEAD_EXTENT: f64 = 1.5;
/// Variance (levels²) per sample of the background's G − B below which its slope is shrunk
/// towards 0, in a file of quality 85: about JPEG's chroma noise there. Without it the slope
/// follows the bead's ringing beside a plain wall (beads alone 0.109, 0.116 px RMS at radius
/// 2.5 against 0.091, 0.098 with it); 10, 100 and 300 measured too (per-frame tip median over
/// nine seeds 0.0510, 0.0500, 0.0511 mm; 30: 0.0489; the luma alone: 0.0511). Other files get
/// it scaled by their chroma steps' squares (the quantisation noise's variance,
/// [`hue_prior`]): held at 30 in a finely quantised file it shrank a real slope, and the dark
/// rim of a shaded tube, which keeps the tube's hue, pulled the bead 0.051 px at quality 100
/// (0.009 scaled).
const HUE_PRIOR_Q85: f64 = 30.0;
/// The blur of the bead's edge the fit starts from (px): a sharp webcam's.
const START_EDGE_PX: f64 = 0.8;

/// The bead's centre fitted near `start` (the thresholded centroid) with starting radius
/// `radius` (px, the core's), or `None` when the region leaves the image or the fit does not
/// settle on a bead (diverged, moved more than 1.5 px, a size outside 0.4-3 × the start, or
/// no red bump).
pub fn refine(
    width: usize,
    height: usize,
    rgb: &[u8],
    sampling: &ChromaSampling,
    start: [f64; 2],
    radius: f64,
) -> Option<[f64; 2]> {
    let [bx, by] = sampling.block;
    if !matches!(bx, 1 | 2) || !matches!(by, 1 | 2) {
        return None;
    }
    // The region: aligned to 16 px, the start near its middle.
    let origin = |c: f64, size: usize| -> Option<usize> {
        let o = (c.round() as i64 - (REGION / 2) as i64).max(0) as usize / 16 * 16;
        (o + REGION <= size).then_some(o)
    };
    let (x0, y0) = (origin(start[0], width)?, origin(start[1], height)?);
    let n = REGION;
    let (mut red, mut luma, mut hue) = (
        DMatrix::zeros(n, n),
        DMatrix::zeros(n, n),
        DMatrix::zeros(n, n),
    );
    for j in 0..n {
        for i in 0..n {
            let p = &rgb[3 * ((y0 + j) * width + x0 + i)..][..3];
            let [r, g, b] = [p[0], p[1], p[2]].map(f64::from);
            red[(j, i)] = 2.0 * r - g - b;
            luma[(j, i)] = 0.299 * r + 0.587 * g + 0.114 * b;
            hue[(j, i)] = g - b;
        }
    }
    let half_window = (MIN_HALF_WINDOW as f64).max(WINDOW_RADII * radius);
    let plane = Plane::new(sampling, [x0 as f64, y0 as f64], start, half_window);
    let (red, luma, hue) = (plane.recover(&red), plane.mean(&luma), plane.recover(&hue));
    // The background's redness that goes with its luma and hue, taken out before the bead is
    // fitted.
    let [k, m] = plane.background_slopes(&red, &luma, &hue, BEAD_EXTENT * radius + 3.0);
    let observed = plane.white_samples(&(red - luma * k - hue * m));
    // The terms that do not move with the bead.
    let (lx, ly) = (plane.local[0], plane.local[1]);
    let fixed = [
        plane.white(|_, _| 1.0),
        plane.white(|_, i| i as f64 - lx),
        plane.white(|j, _| j as f64 - ly),
    ];
    let rows = observed.len();
    // The residuals for a bead (centre x, y, radius, edge), and the bead's amplitude.
    let residual = |p: &Vector4<f64>| -> Option<(DVector<f64>, f64)> {
        let bump = plane.white(|j, i| disc(p, i as f64, j as f64));
        let column = |k: usize, c: usize| if c == 0 { bump[k] } else { fixed[c - 1][k] };
        let mut ata = Matrix4::<f64>::zeros();
        let mut atb = Vector4::<f64>::zeros();
        for k in 0..rows {
            let a = Vector4::from_fn(|c, _| column(k, c));
            ata += a * a.transpose();
            atb += a * observed[k];
        }
        let coef = ata.cholesky()?.solve(&atb);
        let r = DVector::from_fn(rows, |k, _| {
            (0..4).map(|c| column(k, c) * coef[c]).sum::<f64>() - observed[k]
        });
        Some((r, coef[0]))
    };
    let local = plane.local;
    let mut p = Vector4::new(local[0], local[1], radius, START_EDGE_PX);
    let (mut r, mut amplitude) = residual(&p)?;
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..50 {
        // Forward-difference Jacobian of the residuals.
        let h = 1e-4;
        let mut jac = DMatrix::<f64>::zeros(rows, 4);
        for q in 0..4 {
            let mut pq = p;
            pq[q] += h;
            let (rq, _) = residual(&pq)?;
            jac.set_column(q, &((rq - &r) / h));
        }
        let jtj: Matrix4<f64> = (jac.transpose() * &jac).fixed_view::<4, 4>(0, 0).into();
        let jtr: Vector4<f64> = (jac.transpose() * &r).fixed_view::<4, 1>(0, 0).into();
        // Go on while a step is taken and still moves the parameters.
        let mut go_on = false;
        while lambda < 1e8 {
            let damped = jtj + Matrix4::from_diagonal(&jtj.diagonal()) * lambda;
            let Some(step) = damped.cholesky().map(|c| c.solve(&-jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let trial = p + step;
            let valid = trial[2] > 0.0 && trial[3] > 0.2;
            if let Some((rt, at)) = residual(&trial).filter(|_| valid) {
                let ct = rt.norm_squared();
                if ct < cost {
                    (p, r, cost, amplitude) = (trial, rt, ct, at);
                    lambda = (lambda / 10.0).max(1e-9);
                    go_on = step.norm() >= 1e-4;
                    break;
                }
            }
            lambda *= 10.0;
        }
        if !go_on {
            break;
        }
    }
    let moved = (p[0] - local[0]).hypot(p[1] - local[1]);
    let size = p[2].hypot(p[3]);
    (moved <= 1.5 && size >= 0.4 * radius && size <= 3.0 * radius && amplitude > 0.0)
        .then(|| [p[0] + x0 as f64, p[1] + y0 as f64])
}

/// The image of a disc (centre `p[0]`, `p[1]`, radius `p[2]`) whose edge the optics and the
/// pixels blur by a Gaussian of `p[3]` px, at (x, y): ½ erfc((|x − c| − ρ) / √2 β), exact for
/// a straight edge and close for a disc a few β across.
fn disc(p: &Vector4<f64>, x: f64, y: f64) -> f64 {
    let r = ((x - p[0]).powi(2) + (y - p[1]).powi(2)).sqrt();
    0.5 * erfc((r - p[2]) / (std::f64::consts::SQRT_2 * p[3]))
}

/// The complementary error function to 1.5 × 10⁻⁷ (Abramowitz and Stegun 7.1.26), smooth,
/// with one `exp`: the fit evaluates it some 10⁵ times a frame, and `libm`'s took a quarter
/// of triangulate's time.
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.327_591_1 * z);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let tail = poly * (-z * z).exp();
    if x >= 0.0 {
        tail
    } else {
        2.0 - tail
    }
}

/// Chroma samples of one 8 × 8 block in the window, with the inverse of the Cholesky factor of
/// their quantisation noise's covariance (`None`: no quantisation, unit weights).
type Group = (Vec<(usize, usize)>, Option<Rc<DMatrix<f64>>>);

/// The chroma plane of a region as the file stored it, and the fit's window in it.
struct Plane {
    block: [usize; 2],
    /// The start in region pixels.
    local: [f64; 2],
    /// Per axis, what recovers the stored samples from the decoded pixels (the
    /// pseudo-inverse of the decoder's interpolation; the identity at full resolution).
    recover: [&'static DMatrix<f64>; 2],
    /// The window's samples, grouped by 8 × 8 block of the stored plane.
    groups: Vec<Group>,
    /// Samples in the window.
    size: usize,
    /// The shrinkage of the background's G − B slope ([`hue_prior`]).
    hue_prior: f64,
}

impl Plane {
    fn new(
        sampling: &ChromaSampling,
        origin: [f64; 2],
        start: [f64; 2],
        half_window: f64,
    ) -> Plane {
        let block = sampling.block;
        let local = [start[0] - origin[0], start[1] - origin[1]];
        let recover = block.map(|b| if b == 2 { halved() } else { identity() });
        // The window: samples whose pixels lie within `half_window` of the start.
        let span = |axis: usize| {
            let b = block[axis] as f64;
            let lo = ((local[axis] - half_window) / b).floor().max(0.0) as usize;
            let hi = (((local[axis] + half_window) / b).ceil() as usize).min(REGION / block[axis]);
            lo..hi
        };
        let mut grouped: std::collections::BTreeMap<(usize, usize), Vec<(usize, usize)>> =
            std::collections::BTreeMap::new();
        for j in span(1) {
            for i in span(0) {
                grouped.entry((j / 8, i / 8)).or_default().push((j, i));
            }
        }
        let groups: Vec<Group> = grouped
            .into_values()
            .map(|samples| {
                // The samples' places in their block (in order), one bit each.
                let mask = samples
                    .iter()
                    .fold(0u64, |m, (j, i)| m | 1 << ((j % 8) * 8 + i % 8));
                let whitening = sampling.steps.and_then(|q| whitening(&q, mask));
                (samples, whitening)
            })
            .collect();
        let size = groups.iter().map(|(g, _)| g.len()).sum();
        Plane {
            block,
            local,
            recover,
            groups,
            size,
            hue_prior: hue_prior(sampling),
        }
    }

    /// The stored chroma samples behind decoded pixels.
    fn recover(&self, pixels: &DMatrix<f64>) -> DMatrix<f64> {
        self.recover[1] * pixels * self.recover[0].transpose()
    }

    /// A full-resolution plane averaged over each chroma sample's pixels.
    fn mean(&self, pixels: &DMatrix<f64>) -> DMatrix<f64> {
        let [bx, by] = self.block;
        DMatrix::from_fn(REGION / by, REGION / bx, |j, i| {
            pixels.view((by * j, bx * i), (by, bx)).mean()
        })
    }

    /// How much redness the background has per level of luma and of G − B: the least-squares
    /// k and m of red ≈ b₀ + b₁ x + b₂ y + k · luma + m · hue over the window's samples farther
    /// than `beyond` px from the start, each shrunk towards 0 where its term barely varies
    /// there (a plain wall).
    fn background_slopes(
        &self,
        red: &DMatrix<f64>,
        luma: &DMatrix<f64>,
        hue: &DMatrix<f64>,
        beyond: f64,
    ) -> [f64; 2] {
        let [bx, by] = self.block.map(|b| b as f64);
        let mut ata = nalgebra::Matrix5::<f64>::zeros();
        let mut atb = nalgebra::Vector5::<f64>::zeros();
        for &(j, i) in self.groups.iter().flat_map(|(samples, _)| samples) {
            // The sample's centre in region pixels.
            let x = bx * i as f64 + (bx - 1.0) / 2.0 - self.local[0];
            let y = by * j as f64 + (by - 1.0) / 2.0 - self.local[1];
            if x.hypot(y) > beyond {
                let a = nalgebra::Vector5::new(1.0, x, y, luma[(j, i)], hue[(j, i)]);
                ata += a * a.transpose();
                atb += a * red[(j, i)];
            }
        }
        // Priors: one level² of luma variance per sample, the file's `hue_prior` of G − B.
        ata[(3, 3)] += ata[(0, 0)];
        ata[(4, 4)] += ata[(0, 0)] * self.hue_prior;
        ata.cholesky().map_or([0.0; 2], |c| {
            let s = c.solve(&atb);
            [s[3], s[4]]
        })
    }

    /// What the encoder stores of the window of a full-resolution plane (`pixel(row,
    /// column)` in region pixels): the mean over each sample's block, each 8 × 8 group of
    /// samples whitened by its quantisation noise.
    fn white(&self, pixel: impl Fn(usize, usize) -> f64) -> DVector<f64> {
        let [bx, by] = self.block;
        self.whiten(|j, i| {
            let mut sum = 0.0;
            for dj in 0..by {
                for di in 0..bx {
                    sum += pixel(by * j + dj, bx * i + di);
                }
            }
            sum / (bx * by) as f64
        })
    }

    /// The window of stored samples, whitened as [`Self::white`] does.
    fn white_samples(&self, samples: &DMatrix<f64>) -> DVector<f64> {
        self.whiten(|j, i| samples[(j, i)])
    }

    fn whiten(&self, sample: impl Fn(usize, usize) -> f64) -> DVector<f64> {
        let mut out = Vec::with_capacity(self.size);
        for (group, whitening) in &self.groups {
            let v = DVector::from_iterator(group.len(), group.iter().map(|&(j, i)| sample(j, i)));
            match whitening {
                Some(w) => out.extend((w.as_ref() * v).iter()),
                None => out.extend(v.iter()),
            }
        }
        DVector::from_vec(out)
    }
}

/// [`HUE_PRIOR_Q85`] scaled by the file's chroma quantisation noise against quality 85's: the
/// sum of its steps' squares over that of libjpeg's table at 85 (a file without quantisation,
/// PNG, as steps of 1: 30 × 64 / 47 718 ≈ 0.04; quality 95: 3.3).
fn hue_prior(sampling: &ChromaSampling) -> f64 {
    let power = |steps: &[f64; 64]| steps.iter().map(|q| q * q).sum::<f64>();
    let steps = sampling.steps.unwrap_or([1.0; 64]);
    HUE_PRIOR_Q85 * power(&steps) / power(&crate::image::ijg_chroma(85))
}

/// The inverse of the Cholesky factor of the quantisation noise's covariance of the samples
/// of an 8 × 8 block at the places `mask` holds (row-major bits), for the steps `q`: the
/// stored coefficients are the block's 2-D DCT, rounding each to its step adds uniform noise
/// of variance q²/12, so the samples' covariance is Pᵀ diag(q²/12) P (plus the noise besides).
/// A file's tables rarely change and a window cuts blocks in few ways, so each thread keeps
/// the last table's covariance and its factors by mask. `None` when the covariance is not
/// positive definite.
fn whitening(q: &[f64; 64], mask: u64) -> Option<Rc<DMatrix<f64>>> {
    type Factors = std::collections::HashMap<u64, Option<Rc<DMatrix<f64>>>>;
    type Last = RefCell<Option<([f64; 64], DMatrix<f64>, Factors)>>;
    thread_local! {
        static LAST: Last = const { RefCell::new(None) };
    }
    LAST.with_borrow_mut(|last| {
        if last.as_ref().is_none_or(|(steps, ..)| steps != q) {
            let p = dct8();
            let p2 = p.kronecker(&p);
            let noise = DVector::from_iterator(64, q.iter().map(|v| v * v / 12.0));
            let white = DMatrix::<f64>::identity(64, 64) * PIXEL_NOISE;
            let cov = p2.transpose() * DMatrix::from_diagonal(&noise) * p2 + white;
            *last = Some((*q, cov, Factors::new()));
        }
        let (_, cov, factors) = last.as_mut()?;
        factors
            .entry(mask)
            .or_insert_with(|| {
                let at: Vec<usize> = (0..64).filter(|k| mask >> k & 1 == 1).collect();
                let sub = DMatrix::from_fn(at.len(), at.len(), |a, b| cov[(at[a], at[b])]);
                sub.cholesky()?.l().try_inverse().map(Rc::new)
            })
            .clone()
    })
}

/// The orthonormal 8-point DCT-II, as JPEG codes blocks.
fn dct8() -> DMatrix<f64> {
    DMatrix::from_fn(8, 8, |u, x| {
        let scale = if u == 0 {
            (1.0f64 / 8.0).sqrt()
        } else {
            (2.0f64 / 8.0).sqrt()
        };
        scale * ((2 * x + 1) as f64 * u as f64 * std::f64::consts::PI / 16.0).cos()
    })
}

fn identity() -> &'static DMatrix<f64> {
    static I: OnceLock<DMatrix<f64>> = OnceLock::new();
    I.get_or_init(|| DMatrix::identity(REGION, REGION))
}

/// The pseudo-inverse of libjpeg's interpolation of a halved axis over `REGION` pixels: sample
/// b gives pixel 2b 3/4 of itself and 1/4 of sample b − 1, pixel 2b + 1 3/4 of itself and 1/4
/// of sample b + 1 (edges repeated).
fn halved() -> &'static DMatrix<f64> {
    static H: OnceLock<DMatrix<f64>> = OnceLock::new();
    H.get_or_init(|| {
        let m = REGION / 2;
        let mut up = DMatrix::<f64>::zeros(REGION, m);
        for b in 0..m {
            up[(2 * b, b)] += 0.75;
            up[(2 * b, b.saturating_sub(1))] += 0.25;
            up[(2 * b + 1, b)] += 0.75;
            up[(2 * b + 1, (b + 1).min(m - 1))] += 0.25;
        }
        up.pseudo_inverse(1e-12)
            .expect("the interpolation has full column rank")
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::RgbImage;
    use crate::triangulate::marker::{find_markers, MarkerOptions};
    use rand::{Rng, SeedableRng};

    /// A grey wall (RGB 150, 155, 165) with a red bead (180, 22, 20) of radius `rb` px at
    /// `c`, and with `tube` a pale tube (235, 225, 205) 2.67 times as wide whose rounded end
    /// meets the bead from above; 8 × 8 samples per pixel, a 1-2-1 blur each way (σ 0.7 px),
    /// and 0.7 levels of noise.
    fn bead_scene(c: [f64; 2], rb: f64, tube: Tube, [w, h]: [usize; 2], seed: u64) -> Vec<u8> {
        let rt = rb * 8.8 / 3.3;
        let (wall, bead, pale) = (
            [150.0, 155.0, 165.0],
            [180.0, 22.0, 20.0],
            [235.0, 225.0, 205.0],
        );
        let end = [c[0], c[1] - rb - rt + 1.0];
        let mut lit = vec![0.0; 3 * w * h];
        for y in 0..h {
            for x in 0..w {
                let mut colour = [0.0; 3];
                for s in 0..64 {
                    let px = x as f64 - 0.5 + ((s % 8) as f64 + 0.5) / 8.0;
                    let py = y as f64 - 0.5 + ((s / 8) as f64 + 0.5) / 8.0;
                    let on_tube = (px - end[0]).hypot(py - end[1]) <= rt
                        || ((px - end[0]).abs() <= rt && py < end[1]);
                    // Lambertian under a light at the camera: the rim at the ambient 0.35.
                    let d = if py < end[1] {
                        (px - end[0]).abs()
                    } else {
                        (px - end[0]).hypot(py - end[1])
                    };
                    let shade = match tube {
                        Tube::Shaded => 0.35 + 0.65 * (1.0 - (d / rt).powi(2)).max(0.0).sqrt(),
                        _ => 1.0,
                    };
                    let seen = if (px - c[0]).hypot(py - c[1]) <= rb {
                        bead
                    } else if tube != Tube::None && on_tube {
                        pale.map(|v| v * shade)
                    } else {
                        wall
                    };
                    for k in 0..3 {
                        colour[k] += seen[k] / 64.0;
                    }
                }
                lit[3 * (y * w + x)..][..3].copy_from_slice(&colour);
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let at = |v: &[f64], x: usize, y: usize, k: usize| {
            v[3 * (y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) + k]
        };
        let across: Vec<f64> = (0..3 * w * h)
            .map(|n| {
                let (x, y, k) = (n / 3 % w, n / 3 / w, n % 3);
                (at(&lit, x.saturating_sub(1), y, k)
                    + 2.0 * at(&lit, x, y, k)
                    + at(&lit, x + 1, y, k))
                    / 4.0
            })
            .collect();
        (0..3 * w * h)
            .map(|n| {
                let (x, y, k) = (n / 3 % w, n / 3 / w, n % 3);
                let v = (at(&across, x, y.saturating_sub(1), k)
                    + 2.0 * at(&across, x, y, k)
                    + at(&across, x, y + 1, k))
                    / 4.0;
                let noise: f64 = rng.sample(rand_distr::StandardNormal);
                (v + 0.7 * noise).round().clamp(0.0, 255.0) as u8
            })
            .collect()
    }

    /// The tube behind the bead in [`bead_scene`]: none, evenly lit, or shaded as a cylinder
    /// with a rounded end.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Tube {
        None,
        Plain,
        Shaded,
    }

    /// The bead's centre found in `bead_scene(c, radius, tube, …)` encoded as JPEG 4:2:0 at
    /// `quality`, less `c`, over 24 positions spread over a 16-px coding unit: (RMS, mean) per
    /// axis (px).
    fn placed(radius: f64, tube: Tube, quality: u8) -> ([f64; 2], [f64; 2]) {
        let size = [192, 160];
        let (mut square, mut mean) = ([0.0; 2], [0.0; 2]);
        for k in 0..24u64 {
            let c = [
                90.0 + (k as f64 * 0.618) % 16.0,
                90.0 + (k as f64 * 0.377) % 16.0,
            ];
            let rgb = bead_scene(c, radius, tube, size, k);
            let jpeg = crate::cv::encode_jpeg(size[1] as u32, &rgb, quality).unwrap();
            let mut image = RgbImage::default();
            let mut scratch = opencv::core::Mat::default();
            crate::image::decode_bytes(&jpeg, &mut image, &mut scratch).unwrap();
            assert_eq!(image.chroma.block, [2, 2]);
            let found = find_markers(&image, &MarkerOptions::default());
            let b = &found.blobs[0];
            assert!(b.fitted, "{tube:?} tube, bead at {c:?}: not fitted");
            for a in 0..2 {
                square[a] += (b.centre_px[a] - c[a]).powi(2) / 24.0;
                mean[a] += (b.centre_px[a] - c[a]) / 24.0;
            }
        }
        (square.map(f64::sqrt), mean)
    }

    #[test]
    fn beads_of_any_size_alone_or_at_a_tubes_end_are_placed_on_4_2_0_jpeg() {
        // 24 positions spread over a 16-px coding unit, as JPEG 4:2:0 at a webcam's quality
        // and at 100 (sampling only). Before: a Gaussian bead in a 12-px window, fitted with
        // the luma term, left 14-25 of 60 beads alone unfitted (0.2 px off) and placed beads
        // of radius 5, 7 and 9 px to 0.10, 0.15 and 0.74 px.
        // (radius px, quality, largest RMS per axis px); measured, alone and at the tube:
        // 0.091, 0.098 and 0.062, 0.085 px; 0.050, 0.035 and 0.038, 0.050; 0.012, 0.012 and
        // 0.012, 0.010; 0.034, 0.041 and 0.024, 0.019; 0.020, 0.014 and 0.016, 0.014.
        let cases = [
            (2.5, 85, 0.1),
            (3.3, 85, 0.06),
            (3.3, 100, 0.02),
            (6.0, 85, 0.05),
            (12.0, 85, 0.03),
        ];
        for (radius, quality, limit) in cases {
            for tube in [Tube::None, Tube::Plain] {
                let (rms, _) = placed(radius, tube, quality);
                let case = format!("radius {radius} px, {tube:?} tube, quality {quality}");
                println!("{case}: RMS {rms:.3?} px");
                assert!(rms[0] <= limit && rms[1] <= limit, "{case}: RMS {rms:?} px");
            }
        }
    }

    #[test]
    fn a_shaded_tube_behind_the_bead_pulls_it_less() {
        // The tube's rim is dark but keeps the tube's hue; with the background's redness
        // modelled by its luma alone it reads as red and pulled the bead 0.086 px towards the
        // tube at quality 100 (0.177 at 85); with its G − B too, 0.051 (0.138), and 0.009 at
        // 100 (0.050 at 95) since the G − B slope's shrinkage follows the file's steps rather
        // than quality 85's. Measured with a radius of 3.3 px, the demo's.
        for (quality, limit) in [(100, 0.02), (95, 0.065)] {
            let (_, mean) = placed(3.3, Tube::Shaded, quality);
            println!("shaded tube, quality {quality}: mean {mean:.3?} px");
            assert!(
                mean[1].abs() <= limit,
                "quality {quality}: pulled {mean:?} px"
            );
        }
    }

    #[test]
    fn the_hue_slopes_shrinkage_follows_the_files_chroma_steps() {
        let at = |quality| {
            hue_prior(&ChromaSampling {
                block: [2, 2],
                steps: Some(crate::image::ijg_chroma(quality)),
            })
        };
        assert_eq!(at(85), HUE_PRIOR_Q85);
        assert!((at(95) - 3.35).abs() < 0.01, "{}", at(95));
        assert!(at(100) < 0.05 && hue_prior(&ChromaSampling::FULL) == at(100));
    }

    #[test]
    fn erfc_is_within_its_stated_error() {
        for k in -400..=400 {
            let x = k as f64 / 100.0;
            let err = (erfc(x) - libm::erfc(x)).abs();
            assert!(err < 2e-7, "erfc({x}): {err}");
        }
    }

    #[test]
    fn recovering_the_stored_samples_undoes_libjpegs_interpolation() {
        // Samples → interpolated pixels (as the decoder does) → recovered samples.
        let m = REGION / 2;
        let samples: Vec<f64> = (0..m).map(|b| ((b * 37) % 11) as f64 - 5.0).collect();
        let pixels: Vec<f64> = (0..REGION)
            .map(|x| {
                let b = x / 2;
                let other = if x % 2 == 0 {
                    b.saturating_sub(1)
                } else {
                    (b + 1).min(m - 1)
                };
                0.75 * samples[b] + 0.25 * samples[other]
            })
            .collect();
        let back = halved() * DVector::from_vec(pixels);
        for b in 0..m {
            assert!(
                (back[b] - samples[b]).abs() < 1e-9,
                "{b}: {} vs {}",
                back[b],
                samples[b]
            );
        }
    }

    #[test]
    fn jpeg_headers_give_the_chroma_sampling_and_steps() {
        let rgb: Vec<u8> = (0..3 * 64 * 48).map(|k| (k * 7 % 251) as u8).collect();
        let half = ChromaSampling::of_jpeg(&crate::cv::encode_jpeg(48, &rgb, 85).unwrap());
        assert_eq!(half.block, [2, 2]);
        // libjpeg's chroma table at quality 85: the standard one (DC 17, then 18, 24, 47,
        // 99 …) scaled by 30 %.
        let steps = half.steps.expect("a chroma table");
        assert_eq!(
            (steps[0], steps[1], steps[8], steps[63]),
            (5.0, 5.0, 5.0, 30.0)
        );
        // Its quality read back from the table, at any quality libjpeg writes.
        for quality in 1u8..=100 {
            // Qualities 1-3 write the same table (every step 255): read as 1.
            let file = crate::cv::encode_jpeg(48, &rgb, quality).unwrap();
            let expected = if quality <= 3 { 1 } else { quality };
            assert_eq!(ChromaSampling::of_jpeg(&file).quality(), Some(expected));
        }
        assert_eq!(ChromaSampling::FULL.quality(), None);
        let mut full = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut full, 85)
            .encode(&rgb, 64, 48, image::ColorType::Rgb8)
            .unwrap();
        // The `image` crate writes its tables after the frame header: read all the same.
        let full = ChromaSampling::of_jpeg(&full);
        assert_eq!((full.block, full.quality()), ([1, 1], Some(85)));
        assert_eq!(
            ChromaSampling::of_jpeg(b"\x89PNG...."),
            ChromaSampling::FULL
        );
        assert_eq!(
            ChromaSampling::of_jpeg(&[0xff, 0xd8, 0xff]),
            ChromaSampling::FULL
        );
    }
}
