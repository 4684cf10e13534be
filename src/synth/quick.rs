//! A dynamic session without images, for hours of session in seconds: the plant's tip at each
//! camera frame, each camera's view of the bead from the true rig with its pixel noise, and
//! the tip triangulated from those views on the rig as calibrated — the rows `triangulate
//! --per-frame` would give, with faults injected at given times.
//!
//! # Faults (`KIND@T=AMOUNT`)
//! - `camera@T=DEG`: the right camera tilts by DEG degrees about its own x axis at T (a bump).
//!   Its beads leave their epipolar lines by about f·tan(DEG), so the reprojection residual
//!   says so, and the tip moves. A pan (about the camera's y axis) would move the bead along
//!   the epipolar lines of a side-by-side pair: the tip would shift in depth with no residual
//!   to tell, which two cameras cannot see and the model's errors can.
//! - `stiffness@T=SHARE`: from T the finger's bending and axial stiffness are 1 + SHARE times
//!   what they were (−0.1: 10 % softer).
//! - `leak@T=SHARE`: muscle 1 loses up to SHARE of its pressure, linearly over the minute after
//!   T (a slow leak: what the regulator is told is not what the muscle holds).
//!
//! The views are triangulated without a gate (every residual is reported, however large),
//! where `triangulate` would refuse a row whose beads disagree by more than its gate.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use nalgebra::{Matrix3, Matrix3x4, Point3, Rotation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use super::camera::{Camera, RigConfig};
use super::dynamics::{Dynamics, Motion};
use super::plant::{Plant, PlantParams, Pressures};
use super::SynthError;
use crate::data::Csv;
use crate::session::protocol::{self, Step};
use crate::triangulate::nview::{self, View};

/// The cameras' frame rate (Hz).
pub const FPS: f64 = 30.0;

/// A bead centre's pixel noise per axis (px): a per-frame tip of about 0.04 mm, as the
/// rendered sessions give.
pub const PIXEL_NOISE_PX: f64 = 0.1;

/// What goes wrong, and when.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Fault {
    pub kind: FaultKind,
    pub at_s: f64,
    pub amount: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    Camera,
    Stiffness,
    Leak,
}

impl FromStr for Fault {
    type Err = String;

    fn from_str(s: &str) -> Result<Fault, String> {
        let usage = || {
            format!("{s:?} is not a fault: give KIND@T=AMOUNT, KIND one of camera, stiffness, leak (e.g. stiffness@40=-0.1)")
        };
        let (kind, rest) = s.split_once('@').ok_or_else(usage)?;
        let (at, amount) = rest.split_once('=').ok_or_else(usage)?;
        let kind = match kind {
            "camera" => FaultKind::Camera,
            "stiffness" => FaultKind::Stiffness,
            "leak" => FaultKind::Leak,
            _ => return Err(usage()),
        };
        let number = |v: &str| v.trim().parse::<f64>().ok().filter(|v| v.is_finite());
        let (Some(at_s), Some(amount)) = (number(at), number(amount)) else {
            return Err(usage());
        };
        let fine = match kind {
            FaultKind::Camera => amount.abs() <= 10.0,
            FaultKind::Stiffness => amount > -0.9 && amount <= 10.0,
            FaultKind::Leak => (0.0..=1.0).contains(&amount),
        };
        if at_s < 0.0 || !fine {
            return Err(format!("{s}: the time must be ≥ 0 s and the amount within a camera's ±10°, a stiffness share above −0.9, a leak's share within 0-1"));
        }
        Ok(Fault { kind, at_s, amount })
    }
}

/// The finger as the faults make it at each instant.
struct Finger {
    before: Plant,
    /// The finger from the stiffness fault on.
    after: Option<(f64, Plant)>,
    leak: Option<(f64, f64)>,
}

impl Finger {
    fn new(params: &PlantParams, faults: &[Fault]) -> Finger {
        let of = |kind| faults.iter().find(|f| f.kind == kind);
        Finger {
            before: Plant::new(params.clone()),
            after: of(FaultKind::Stiffness).map(|f| {
                let scale = 1.0 + f.amount;
                let stiffer = PlantParams {
                    bend_stiffness_x_nmm2: params.bend_stiffness_x_nmm2 * scale,
                    bend_stiffness_y_nmm2: params.bend_stiffness_y_nmm2 * scale,
                    axial_stiffness_n: params.axial_stiffness_n * scale,
                    ..params.clone()
                };
                (f.at_s, Plant::new(stiffer))
            }),
            leak: of(FaultKind::Leak).map(|f| (f.at_s, f.amount)),
        }
    }

    fn tip(&self, t: f64, mut p: Pressures) -> Result<[f64; 3], SynthError> {
        if let Some((at, share)) = self.leak {
            p[0] *= 1.0 - share * ((t - at) / 60.0).clamp(0.0, 1.0);
        }
        let plant = match &self.after {
            Some((at, plant)) if t >= *at => plant,
            _ => &self.before,
        };
        Ok(plant.tip(p)?)
    }
}

/// K [R | t] of a camera's undistorted pixels.
fn projection(camera: &Camera) -> Matrix3x4<f64> {
    let k = Matrix3::from_row_slice(&camera.intrinsics.k);
    let mut rt = Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(camera.pose.rotation.matrix());
    rt.set_column(3, &camera.pose.translation);
    k * rt
}

/// Where `projection` sees `p` (px).
fn see(projection: &Matrix3x4<f64>, p: &Point3<f64>) -> [f64; 2] {
    let h = projection * p.to_homogeneous();
    [h.x / h.z, h.y / h.z]
}

/// What [`write`] wrote.
pub struct Written {
    pub session: PathBuf,
    pub truth: PathBuf,
    pub rows: usize,
    /// Frames whose views fixed no point (the bead behind a camera, or on the baseline).
    pub unseen: usize,
}

/// Plays `steps` on the plant seen by the rig of `seed` and writes `out/session.csv`
/// (`time_s,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,reproj_px`) and `out/truth.csv`
/// (`time_s,x_mm,y_mm,z_mm`, the true tip), one row per frame at [`FPS`].
///
/// # Errors
/// A plant error, or a file that cannot be written.
pub fn write(
    out: &Path,
    steps: &[Step],
    seed: u64,
    plant: &PlantParams,
    faults: &[Fault],
) -> Result<Written, SynthError> {
    let rig = RigConfig::default().build(seed);
    let (starts, end) = protocol::start_times(steps);
    let commands: Vec<(f64, Pressures)> = starts
        .iter()
        .zip(steps)
        .map(|(&t, s)| (t, s.pressures))
        .collect();
    let motion = Motion::simulate(&commands, &Dynamics::PNEUMATIC, plant.hysteresis_kpa, end);
    let finger = Finger::new(plant, faults);
    let calibrated = [projection(&rig.left), projection(&rig.right)];
    let tilted = faults
        .iter()
        .find(|f| f.kind == FaultKind::Camera)
        .map(|f| {
            let turn = Rotation3::from_axis_angle(&Vector3::x_axis(), f.amount.to_radians());
            let mut right = rig.right.clone();
            right.pose.rotation = turn * right.pose.rotation;
            right.pose.translation = turn * right.pose.translation;
            (f.at_s, projection(&right))
        });
    let noise = Normal::new(0.0, PIXEL_NOISE_PX).expect("a positive noise");
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5155_4943);
    let mut session = Csv::new([
        "time_s",
        "phase",
        "P1_kpa",
        "P2_kpa",
        "P3_kpa",
        "x_mm",
        "y_mm",
        "z_mm",
        "reproj_px",
    ]);
    let mut truth = Csv::new(["time_s", "x_mm", "y_mm", "z_mm"]);
    let fixed = |v: f64, digits: usize| format!("{v:.digits$}");
    let (mut k, mut step, mut unseen) = (0usize, 0usize, 0usize);
    while (k as f64) / FPS < end {
        let t = k as f64 / FPS;
        k += 1;
        while step + 1 < steps.len() && starts[step + 1] <= t {
            step += 1;
        }
        let tip = finger.tip(t, motion.at(t))?;
        let point = Point3::from(tip);
        let right = match tilted {
            Some((at, p)) if t >= at => p,
            _ => calibrated[1],
        };
        let views: Vec<View> = [(calibrated[0], calibrated[0]), (right, calibrated[1])]
            .iter()
            .map(|(seen_by, calibrated)| {
                let px = see(seen_by, &point);
                View {
                    projection: *calibrated,
                    px: [
                        px[0] + noise.sample(&mut rng),
                        px[1] + noise.sample(&mut rng),
                    ],
                    // No gate: every residual is reported (module docs).
                    sigma_px: 1e3,
                }
            })
            .collect();
        let Ok(seen) = nview::triangulate(&views, 0.99) else {
            unseen += 1;
            continue;
        };
        let rms = (seen.residuals_px.iter().map(|r| r * r).sum::<f64>() / 2.0).sqrt();
        let p = steps[step].pressures;
        let mut row = vec![fixed(t, 6), steps[step].phase.clone()];
        row.extend(p.map(crate::data::format_number));
        row.extend((0..3).map(|i| fixed(seen.point[i], 5)));
        row.push(fixed(rms, 4));
        session.row(row);
        truth.row([
            fixed(t, 6),
            fixed(tip[0], 5),
            fixed(tip[1], 5),
            fixed(tip[2], 5),
        ]);
    }
    std::fs::create_dir_all(out).map_err(super::capture::io_err(out))?;
    let written = Written {
        session: out.join("session.csv"),
        truth: out.join("truth.csv"),
        rows: k - unseen,
        unseen,
    };
    session.write(&written.session)?;
    truth.write(&written.truth)?;
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_and_bad_ones_are_named() {
        let f: Fault = "stiffness@40=-0.1".parse().unwrap();
        assert_eq!(f.kind, FaultKind::Stiffness);
        assert_eq!((f.at_s, f.amount), (40.0, -0.1));
        for bad in [
            "stiffness",
            "payload@4=0.2",
            "leak@x=0.1",
            "leak@10=2",
            "camera@-1=0.5",
        ] {
            assert!(bad.parse::<Fault>().is_err(), "{bad}");
        }
    }

    /// Without faults the rows' tips are the truth to the pixel noise's share; a tilted camera
    /// shows in the residual from its time on.
    #[test]
    fn the_rows_are_the_truth_seen_through_the_rig_and_a_tilt_shows() {
        let dir = tempfile::tempdir().unwrap();
        let design = protocol::DynamicDesign {
            duration_s: 20.0,
            trials: 1,
            ..protocol::DynamicDesign::default()
        };
        let steps = protocol::dynamic(&design).unwrap();
        let tilt = Fault {
            kind: FaultKind::Camera,
            at_s: 10.0,
            amount: 0.2,
        };
        let w = write(dir.path(), &steps, 1, &PlantParams::default(), &[tilt]).unwrap();
        let read = |p: &Path, names: &[&str]| {
            crate::data::read_columns(p, &crate::data::names(names)).unwrap()
        };
        let seen = read(&w.session, &["time_s", "x_mm", "y_mm", "z_mm", "reproj_px"]);
        let truth = read(&w.truth, &["x_mm", "y_mm", "z_mm"]);
        let (mut before, mut after) = ((0.0, 0.0, 0), (0.0, 0));
        for i in 0..seen.rows() {
            let (s, t) = (seen.row(i), truth.row(i));
            let off = (0..3).map(|c| (s[c + 1] - t[c]).powi(2)).sum::<f64>();
            if s[0] < 10.0 {
                before = (before.0 + off, before.1 + s[4], before.2 + 1);
            } else {
                after = (after.0 + s[4], after.1 + 1);
            }
        }
        let rms = (before.0 / f64::from(before.2)).sqrt();
        assert!(
            rms > 0.005 && rms < 0.08,
            "tip RMS {rms} mm before the tilt"
        );
        let (r_before, r_after) = (before.1 / f64::from(before.2), after.0 / f64::from(after.1));
        assert!(r_before < 0.15, "{r_before} px");
        assert!(
            r_after > 10.0 * r_before,
            "{r_before} px, then {r_after} px"
        );
    }
}
