//! The OpenCV fits: each camera alone, both together, the pairs that disagree with the others,
//! and the bootstrap over pairs.

use nalgebra::{Matrix3, Rotation3, Vector3};
use opencv::calib3d;
use opencv::core::{self, Mat, Point2f, Point3f, Size, TermCriteria, Vector};
use rayon::prelude::*;

use super::{
    uncertainty, BoardSpec, Bootstrap, CalibError, CalibOptions, KnownIntrinsics, PairCorners,
    PairReport, View,
};
use crate::cv::{self, fixed, points, values};
use crate::geometry::{relative, CamFromBoard, Intrinsics, RightFromLeft};
use crate::stereo::StereoRig;

/// The rig from `usable` pairs without those that contradict the others' geometry, then
/// without the worst outlier while there is one (module docs of [`super`], step 5), keeping at
/// least `needed`; each dropped pair's report says why.
///
/// # Errors
/// An OpenCV failure.
pub(super) fn without_outliers(
    board: &BoardSpec,
    size: [i32; 2],
    usable: &mut Vec<PairCorners>,
    reports: &mut [PairReport],
    options: &CalibOptions,
    needed: usize,
) -> Result<StereoFit, CalibError> {
    for (k, why) in inconsistent_pairs(board, size, usable)?.into_iter().rev() {
        if usable.len() > needed {
            let dropped = usable.remove(k);
            reports[dropped.report].rejected = Some(why);
        }
    }
    let mut rig;
    loop {
        rig = stereo(board, size, usable, &options.intrinsics)?;
        let errors: Vec<f64> = rig.per_view.iter().map(|e| e[0].max(e[1])).collect();
        let median = crate::stats::upper_median(&mut errors.clone()).expect("pairs");
        let (worst, &err) = errors
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .expect("pairs");
        let limit = (options.reject_factor * median).max(options.reject_floor_px);
        if err <= limit || usable.len() <= needed {
            break;
        }
        let dropped = usable.remove(worst);
        reports[dropped.report].rejected = Some(format!(
            "outlier: error {err:.3} px > {:.1} × median {median:.3} px",
            options.reject_factor
        ));
    }
    Ok(rig)
}

/// [`Bootstrap`]: `options.bootstrap` recalibrations of `usable` drawn with replacement,
/// their spread about `rig`.
pub(super) fn bootstrap(
    board: &BoardSpec,
    size: [i32; 2],
    usable: &[PairCorners],
    options: &CalibOptions,
    rig: &StereoRig,
) -> Result<Bootstrap, CalibError> {
    use rand::{Rng, SeedableRng};
    let fits: Vec<StereoRig> = (0..options.bootstrap)
        .into_par_iter()
        .map(|round| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(options.seed);
            rng.set_stream(round as u64);
            let drawn: Vec<PairCorners> = (0..usable.len())
                .map(|_| usable[rng.random_range(0..usable.len())].clone())
                .collect();
            Ok(stereo(board, size, &drawn, &options.intrinsics)?.cams)
        })
        .collect::<Result<_, CalibError>>()?;
    let sd = |value: &dyn Fn(&StereoRig) -> f64| {
        let values: Vec<f64> = fits.iter().map(value).collect();
        crate::stats::mean_sd(&values).map_or(0.0, |(_, sd)| sd)
    };
    let camera = |c: usize| -> [f64; 9] {
        std::array::from_fn(|i| {
            sd(&|fit: &StereoRig| uncertainty::intrinsic([&fit.left, &fit.right][c], i))
        })
    };
    let solved = options.intrinsics.iter().all(Option::is_none);
    let turn = |fit: &StereoRig| {
        (rig.right_from_left.rotation.inverse() * fit.right_from_left.rotation).scaled_axis()
    };
    Ok(Bootstrap {
        rounds: options.bootstrap,
        seed: options.seed,
        parameters: uncertainty::ParameterSd {
            intrinsics: [solved.then(|| camera(0)), solved.then(|| camera(1))],
            translation_mm: std::array::from_fn(|a| {
                sd(&|fit: &StereoRig| fit.right_from_left.translation[a])
            }),
            baseline_mm: sd(&|fit: &StereoRig| fit.right_from_left.translation.norm()),
            rotation_deg: std::array::from_fn(|a| sd(&|fit: &StereoRig| turn(fit)[a].to_degrees())),
        },
    })
}

/// The OpenCV results of one stereo calibration.
pub(super) struct StereoFit {
    pub cams: StereoRig,
    pub e: [f64; 9],
    pub f: [f64; 9],
    pub rms: f64,
    pub per_view: Vec<[f64; 2]>,
}

pub(super) fn criteria() -> Result<TermCriteria, CalibError> {
    Ok(cv::criteria(100, 1e-9)?)
}

/// One camera calibrated alone: K, distortion, each view's board pose, and the reprojection RMS (px).
pub(super) fn single_camera(
    board: &BoardSpec,
    size: [i32; 2],
    views: &[View],
) -> Result<(Mat, Mat, Vec<CamFromBoard>, f64), CalibError> {
    let object: Vector<Vector<Point3f>> =
        views.iter().map(|v| board.object_points(v.ids)).collect();
    let image: Vector<Vector<Point2f>> = views.iter().map(|v| points(v.px)).collect();
    let (mut k, mut d) = (Mat::default(), Mat::default());
    let (mut rv, mut tv) = (Vector::<Mat>::new(), Vector::<Mat>::new());
    let rms = calib3d::calibrate_camera(
        &object,
        &image,
        Size::new(size[0], size[1]),
        &mut k,
        &mut d,
        &mut rv,
        &mut tv,
        0,
        criteria()?,
    )?;
    let poses = rv
        .iter()
        .zip(tv.iter())
        .map(|(r, t)| {
            let mut m = Mat::default();
            calib3d::rodrigues(&r, &mut m, &mut core::no_array())?;
            Ok(CamFromBoard::new(
                Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&fixed::<9>(&m)?)),
                Vector3::from_row_slice(&fixed::<3>(&t)?),
            ))
        })
        .collect::<Result<Vec<_>, CalibError>>()?;
    Ok((k, d, poses, rms))
}

/// Pairs whose own left → right pose disagrees with the others' (median): more than 2° of
/// rotation or 10 % of the baseline away. Such a pair (a wrong partner image, a camera that
/// moved) would pull the joint calibration everywhere, so it goes first.
fn inconsistent_pairs(
    board: &BoardSpec,
    size: [i32; 2],
    usable: &[PairCorners],
) -> Result<Vec<(usize, String)>, CalibError> {
    let side = |c: usize| -> Vec<View> { usable.iter().map(|u| u.view(c)).collect() };
    let (_, _, pl, _) = single_camera(board, size, &side(0))?;
    let (_, _, pr, _) = single_camera(board, size, &side(1))?;
    let between: Vec<_> = pl.iter().zip(&pr).map(|(l, r)| relative(l, r)).collect();
    let median = |k: usize| {
        let mut v: Vec<f64> = between.iter().map(|x| x.translation[k]).collect();
        crate::stats::upper_median(&mut v).expect("pairs")
    };
    let t_med = Vector3::new(median(0), median(1), median(2));
    // The reference rotation: the pair whose translation is nearest the median.
    let reference = between
        .iter()
        .map(|x| ((x.translation - t_med).norm(), x.rotation))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, rotation)| rotation)
        .expect("pairs");
    let mut out = Vec::new();
    for (k, x) in between.iter().enumerate() {
        let angle = (x.rotation * reference.inverse()).angle().to_degrees();
        let off = (x.translation - t_med).norm() / t_med.norm();
        if angle > 2.0 || off > 0.10 {
            out.push((
                k,
                format!(
                    "left and right disagree with the other pairs: relative pose {angle:.1}° and {:.0} % of the baseline off (wrong partner image, or a camera moved?)",
                    100.0 * off
                ),
            ));
        }
    }
    Ok(out)
}

/// The joint calibration: each camera's intrinsics from its own calibration (or as known), then
/// both cameras and the pose together (`stereoCalibrate`, refining the intrinsics), or, when a
/// camera's intrinsics are known, the pose alone with both cameras' intrinsics fixed
/// (`CALIB_FIX_INTRINSIC`: OpenCV fixes both or neither; the other camera keeps its own
/// calibration's).
pub(super) fn stereo(
    board: &BoardSpec,
    size: [i32; 2],
    usable: &[PairCorners],
    known: &[Option<KnownIntrinsics>; 2],
) -> Result<StereoFit, CalibError> {
    let image_size = Size::new(size[0], size[1]);
    let object: Vector<Vector<Point3f>> =
        usable.iter().map(|u| board.object_points(&u.ids)).collect();
    let left: Vector<Vector<Point2f>> = usable.iter().map(|u| points(&u.left)).collect();
    let right: Vector<Vector<Point2f>> = usable.iter().map(|u| points(&u.right)).collect();
    let camera = |side: usize| match &known[side] {
        Some(k) => Ok((
            cv::mat(3, &k.intrinsics.k)?,
            cv::mat(1, &k.intrinsics.dist)?,
        )),
        None => {
            let views: Vec<View> = usable.iter().map(|u| u.view(side)).collect();
            single_camera(board, size, &views).map(|(k, d, _, _)| (k, d))
        }
    };
    let (mut k1, mut d1) = camera(0)?;
    let (mut k2, mut d2) = camera(1)?;
    let flags = if known.iter().any(Option::is_some) {
        calib3d::CALIB_FIX_INTRINSIC
    } else {
        calib3d::CALIB_USE_INTRINSIC_GUESS
    };
    let (mut r, mut t, mut e, mut f, mut per_view) = (
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
        Mat::default(),
    );
    let rms = calib3d::stereo_calibrate_extended(
        &object,
        &left,
        &right,
        &mut k1,
        &mut d1,
        &mut k2,
        &mut d2,
        image_size,
        &mut r,
        &mut t,
        &mut e,
        &mut f,
        &mut per_view,
        flags,
        criteria()?,
    )?;
    let errors = values(&per_view)?;
    Ok(StereoFit {
        cams: StereoRig {
            image_size: size,
            left: Intrinsics {
                k: fixed(&k1)?,
                dist: values(&d1)?,
            },
            right: Intrinsics {
                k: fixed(&k2)?,
                dist: values(&d2)?,
            },
            right_from_left: RightFromLeft::new(
                Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&fixed::<9>(&r)?)),
                Vector3::from(fixed::<3>(&t)?),
            ),
        },
        e: fixed(&e)?,
        f: fixed(&f)?,
        rms,
        per_view: errors.chunks(2).map(|c| [c[0], c[1]]).collect(),
    })
}
