//! One point seen by any number of cameras: triangulated linearly (the point nearest every
//! view's ray), refined by Gauss-Newton on the reprojection error, each view's
//! residual weighed by its camera's pixel noise, and the views gated by a χ² test instead of a
//! fixed pixel threshold.
//!
//! # The gate
//! With every view's bead found to within its camera's noise σᵢ (px, per axis), the weighed
//! sum of squared residuals χ² = Σ ‖rᵢ‖² / σᵢ² of k views follows a χ² distribution with
//! 2k − 3 degrees of freedom. A point whose χ² lies above that distribution's `level`
//! quantile does not fit its views: one of them is wrong (a reflection, the bead hidden and a
//! red fleck taken, a camera moved). Then every subset of the views, the largest first (down
//! to two), is tried, and the subset of the most views that passes is kept (of several, the
//! one of least χ²); the views left out are named. A gate in units of each camera's noise
//! means the same at any resolution, lens or distance, which a gate in pixels does not.
//!
//! # The covariance
//! The point's 3 × 3 covariance is (Jᵀ W J)⁻¹ at the solution, J the projections' derivative
//! and W = diag(1/σᵢ²): what the beads' pixel noise alone leaves of the point. The cameras'
//! own calibration uncertainty is not in it.

use nalgebra::{Matrix3, Matrix3x4, Vector3};

/// One camera's view of the point.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// The projection K [R | t] of undistorted pixels (the calibration's K, points undistorted
    /// onto it), from the frame the point is wanted in.
    pub projection: Matrix3x4<f64>,
    /// Where the camera sees the point (undistorted px).
    pub px: [f64; 2],
    /// The camera's pixel noise on a bead centre, per axis (px).
    pub sigma_px: f64,
}

/// A point triangulated from the views that agree on it.
#[derive(Clone, Debug, PartialEq)]
pub struct Triangulated {
    pub point: Vector3<f64>,
    /// From the beads' pixel noise (mm², in the point's frame).
    pub covariance: Matrix3<f64>,
    /// The views used (indices into those given), in order, and those left out.
    pub used: Vec<usize>,
    pub left_out: Vec<usize>,
    /// The weighed sum of squared residuals of the views used, and its degrees of freedom.
    pub chi2: f64,
    pub dof: usize,
    /// Each used view's reprojection residual (px).
    pub residuals_px: Vec<f64>,
}

/// Why no point was triangulated.
#[derive(Clone, Debug, PartialEq)]
pub enum Refused {
    /// Fewer than two views (in front of their cameras).
    TooFewViews,
    /// No two views or more agree: the least χ² of any pair, of 1 degree of freedom.
    Inconsistent { chi2: f64 },
}

/// The point of `views` (see the module docs), gated at the χ² quantile `level` (0.99, say).
///
/// # Errors
/// [`Refused`]: fewer than two views, or no subset of two or more that passes the gate.
pub fn triangulate(views: &[View], level: f64) -> Result<Triangulated, Refused> {
    let all: Vec<usize> = (0..views.len()).collect();
    let mut least_pair = f64::INFINITY;
    for size in (2..=views.len()).rev() {
        let mut best: Option<Triangulated> = None;
        for subset in subsets(&all, size) {
            let Some(fit) = fit(views, &subset) else {
                continue;
            };
            if size == 2 {
                least_pair = least_pair.min(fit.chi2);
            }
            let passes = fit.chi2 <= crate::stats::chi_square_quantile(fit.dof, level);
            if passes && best.as_ref().is_none_or(|b| fit.chi2 < b.chi2) {
                best = Some(fit);
            }
        }
        if let Some(mut best) = best {
            best.left_out = all
                .iter()
                .filter(|i| !best.used.contains(i))
                .copied()
                .collect();
            return Ok(best);
        }
    }
    match least_pair.is_finite() {
        true => Err(Refused::Inconsistent { chi2: least_pair }),
        false => Err(Refused::TooFewViews),
    }
}

/// Every subset of `items` of `size`, in lexicographic order.
fn subsets(items: &[usize], size: usize) -> Vec<Vec<usize>> {
    if size == 0 {
        return vec![Vec::new()];
    }
    let mut out = Vec::new();
    for (k, &first) in items.iter().enumerate() {
        for mut rest in subsets(&items[k + 1..], size - 1) {
            rest.insert(0, first);
            out.push(rest);
        }
    }
    out
}

/// The point of every view, ungated (linear, then Gauss-Newton); `None` as [`fit`]'s.
pub fn through(views: &[View]) -> Option<Vector3<f64>> {
    let all: Vec<usize> = (0..views.len()).collect();
    fit(views, &all).map(|t| t.point)
}

/// The point of the views `used`: linear, then Gauss-Newton; `None` when it lies behind one
/// of their cameras or the views do not fix it.
fn fit(views: &[View], used: &[usize]) -> Option<Triangulated> {
    let views: Vec<&View> = used.iter().map(|&i| &views[i]).collect();
    let mut point = nearest_to_rays(&views)?;
    for _ in 0..20 {
        let (jtwj, jtwr) = normal_equations(&views, &point)?;
        let mut step = jtwj.try_inverse()? * jtwr;
        // A step that would put the point behind a camera is halved until it does not.
        while views.iter().any(|v| residual(v, &(point + step)).is_none()) {
            step /= 2.0;
            if step.norm() < 1e-9 {
                return None;
            }
        }
        point += step;
        if step.norm() < 1e-12 * point.norm().max(1.0) {
            break;
        }
    }
    let (jtwj, _) = normal_equations(&views, &point)?;
    let residuals_px: Vec<f64> = views
        .iter()
        .map(|v| residual(v, &point).map(|(r, _)| r.norm()))
        .collect::<Option<_>>()?;
    let chi2 = views
        .iter()
        .zip(&residuals_px)
        .map(|(v, r)| (r / v.sigma_px).powi(2))
        .sum();
    Some(Triangulated {
        point,
        covariance: jtwj.try_inverse()?,
        used: used.to_vec(),
        left_out: Vec::new(),
        chi2,
        dof: 2 * views.len() - 3,
        residuals_px,
    })
}

/// The point nearest every view's ray in the least-squares sense (Σ of squared distances, a
/// linear solve): each ray from its camera's centre −M⁻¹p₄ along M⁻¹(u, v, 1). Unlike the
/// direct linear transform's algebraic error, a distance keeps views that disagree from
/// putting the point hundreds of millimetres off, or behind the cameras.
fn nearest_to_rays(views: &[&View]) -> Option<Vector3<f64>> {
    let (mut a, mut b) = (Matrix3::zeros(), Vector3::zeros());
    for v in views {
        let m = v.projection.fixed_view::<3, 3>(0, 0).into_owned();
        let m_inv = m.try_inverse()?;
        let centre = -(m_inv * v.projection.column(3));
        let d = (m_inv * Vector3::new(v.px[0], v.px[1], 1.0)).normalize();
        let across = Matrix3::identity() - d * d.transpose();
        a += across;
        b += across * centre;
    }
    a.try_inverse().map(|a| a * b)
}

/// The residual (px) of the point in a view, and the projection's derivative (2 × 3); `None`
/// for a point behind the camera.
fn residual(
    view: &View,
    point: &Vector3<f64>,
) -> Option<(nalgebra::Vector2<f64>, nalgebra::Matrix2x3<f64>)> {
    let p = &view.projection;
    let x = p * point.push(1.0);
    if x[2] <= 0.0 {
        return None;
    }
    let (u, v) = (x[0] / x[2], x[1] / x[2]);
    let m = p.fixed_view::<3, 3>(0, 0);
    let j = nalgebra::Matrix2x3::from_rows(&[
        (m.row(0) - m.row(2) * u) / x[2],
        (m.row(1) - m.row(2) * v) / x[2],
    ]);
    Some((nalgebra::Vector2::new(view.px[0] - u, view.px[1] - v), j))
}

/// Jᵀ W J and Jᵀ W r over the views at `point`.
fn normal_equations(views: &[&View], point: &Vector3<f64>) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let mut jtwj = Matrix3::zeros();
    let mut jtwr = Vector3::zeros();
    for v in views {
        let (r, j) = residual(v, point)?;
        let w = 1.0 / (v.sigma_px * v.sigma_px);
        jtwj += j.transpose() * j * w;
        jtwr += j.transpose() * r * w;
    }
    Some((jtwj, jtwr))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A camera at `eye` looking at the origin (a C920's focal length at 1280 × 720).
    fn camera(eye: Vector3<f64>) -> Matrix3x4<f64> {
        let forward = -eye.normalize();
        let right = forward.cross(&Vector3::z()).normalize();
        let down = forward.cross(&right);
        let r = Matrix3::from_rows(&[right.transpose(), down.transpose(), forward.transpose()]);
        let t = -(r * eye);
        let k = Matrix3::new(906.8, 0.0, 640.0, 0.0, 906.8, 360.0, 0.0, 0.0, 1.0);
        let mut rt = Matrix3x4::zeros();
        rt.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        rt.set_column(3, &t);
        k * rt
    }

    /// Four cameras around the finger, 300 mm off, a little above.
    fn rig() -> Vec<Matrix3x4<f64>> {
        (0..4)
            .map(|k| {
                let a = 0.4 + k as f64 * 0.5;
                camera(Vector3::new(300.0 * a.cos(), 300.0 * a.sin(), 60.0))
            })
            .collect()
    }

    fn seen(projection: Matrix3x4<f64>, point: &Vector3<f64>) -> View {
        let x = projection * point.push(1.0);
        View {
            projection,
            px: [x[0] / x[2], x[1] / x[2]],
            sigma_px: 0.1,
        }
    }

    #[test]
    fn views_without_noise_give_the_point_and_a_chi_square_of_nothing() {
        let truth = Vector3::new(3.0, -2.0, 5.0);
        let views: Vec<View> = rig().into_iter().map(|p| seen(p, &truth)).collect();
        let t = triangulate(&views, 0.99).unwrap();
        assert!((t.point - truth).norm() < 1e-9, "{}", t.point);
        assert_eq!((t.used.len(), t.dof), (4, 5));
        assert!(t.chi2 < 1e-12 && t.left_out.is_empty());
        let pair = triangulate(&views[1..3], 0.99).unwrap();
        assert!((pair.point - truth).norm() < 1e-9 && pair.dof == 1);
        assert_eq!(triangulate(&views[..1], 0.99), Err(Refused::TooFewViews));
    }

    /// Beads found with 0.1 px of noise: the χ² averages its degrees of freedom, the gate
    /// refuses about 1 % of clean points, and the errors' spread is the covariance's.
    #[test]
    fn with_noise_the_chi_square_and_the_covariance_are_the_noises() {
        let truth = Vector3::new(1.0, 2.0, -3.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(59);
        let noise = Normal::new(0.0, 0.1).unwrap();
        let (trials, mut chi2, mut gated) = (4000, 0.0, 0);
        let mut scatter = Matrix3::zeros();
        let mut predicted = Matrix3::zeros();
        for _ in 0..trials {
            let views: Vec<View> = rig()
                .into_iter()
                .map(|p| {
                    let mut v = seen(p, &truth);
                    v.px = v.px.map(|c| c + noise.sample(&mut rng));
                    v
                })
                .collect();
            let t = triangulate(&views, 0.99).unwrap();
            if t.used.len() < 4 {
                gated += 1;
                continue;
            }
            chi2 += t.chi2;
            let e = t.point - truth;
            scatter += e * e.transpose();
            predicted += t.covariance;
        }
        let kept = (trials - gated) as f64;
        let mean = chi2 / kept;
        let ratio = scatter.trace() / predicted.trace();
        eprintln!("n-view: mean χ² {mean:.3} (5 dof), {gated} of {trials} gated, spread/covariance {ratio:.3}");
        assert!((mean - 5.0).abs() < 0.25, "mean χ² {mean} of 5 dof");
        let share = gated as f64 / trials as f64;
        assert!(
            (0.004..0.02).contains(&share),
            "{share} of clean points gated at 0.99"
        );
        // The gate trims the largest errors: the spread kept is a little under the covariance.
        assert!(
            (0.85..1.1).contains(&ratio),
            "error spread / covariance {ratio}"
        );
    }

    #[test]
    fn a_view_far_off_is_left_out_and_named() {
        let truth = Vector3::new(-4.0, 1.0, 8.0);
        let mut views: Vec<View> = rig().into_iter().map(|p| seen(p, &truth)).collect();
        // The third camera took a red fleck 2 px (20 σ) away for the bead.
        views[2].px[0] += 2.0;
        let t = triangulate(&views, 0.99).unwrap();
        assert_eq!(
            (t.used.clone(), t.left_out.clone()),
            (vec![0, 1, 3], vec![2])
        );
        assert!((t.point - truth).norm() < 1e-9);
        // Two views that disagree, nothing else: refused, with their χ².
        let mut pair = vec![seen(rig()[0], &truth), seen(rig()[1], &truth)];
        pair[1].px[1] += 3.0;
        match triangulate(&pair, 0.99) {
            Err(Refused::Inconsistent { chi2 }) => assert!(chi2 > 6.63, "{chi2}"),
            other => panic!("{other:?}"),
        }
    }

    /// The virtual rig's pair (seed 5), its right camera knocked by half a degree about its x
    /// axis, the finger's tip near the aim: the beads disagree by 8 px. The direct linear
    /// transform put such a pair's point 800 mm off (or behind the cameras), Gauss-Newton
    /// failed from there, and the pair was refused as too few views. The point nearest the
    /// rays starts it now: gated as inconsistent, or, ungated, a point near the tip.
    #[test]
    fn a_pair_that_disagrees_is_fitted_and_gated_not_lost() {
        use crate::synth::{camera::RigConfig, faults::Timeline, plant::PlantParams};
        let rig = RigConfig::default().build(5);
        let knock = ["camera@0=0.5".parse().unwrap()];
        let timeline = Timeline::new(&PlantParams::default(), &rig, &knock);
        let knocked = &timeline.knocked().unwrap().1;
        let tip = Vector3::new(4.969, 0.121, 0.649);
        let views = [
            seen(rig.left().projection(), &tip),
            View {
                projection: rig.right().projection(),
                ..seen(knocked.projection(), &tip)
            },
        ];
        match triangulate(&views, 0.99) {
            Err(Refused::Inconsistent { chi2 }) => assert!(chi2 > 1e3, "{chi2}"),
            other => panic!("{other:?}"),
        }
        let lax = views.map(|v| View { sigma_px: 1e3, ..v });
        let t = triangulate(&lax, 0.99).unwrap();
        assert!((t.point - tip).norm() < 2.0, "{}", t.point);
        assert!(
            t.residuals_px.iter().all(|r| *r > 2.0),
            "{:?}",
            t.residuals_px
        );
    }

    #[test]
    fn a_camera_the_point_is_behind_does_not_count() {
        let truth = Vector3::new(0.0, 0.0, 0.0);
        let mut views: Vec<View> = rig().into_iter().map(|p| seen(p, &truth)).collect();
        // A camera facing away: its projection puts the point behind it.
        views.push(View {
            projection: -views[0].projection,
            ..views[0]
        });
        let t = triangulate(&views, 0.99).unwrap();
        assert_eq!(t.left_out, vec![4]);
    }
}
