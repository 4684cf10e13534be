//! A dynamic session without images, for hours of session in seconds: the plant's tip at each
//! camera frame, each camera's view of the bead from the true rig with its pixel noise, and
//! the tip triangulated from those views on the rig as calibrated — the rows `triangulate
//! --per-frame` would give, with faults injected at given times ([`super::faults`]).
//!
//! The views are triangulated without a gate (every residual is reported, however large),
//! where `triangulate` would refuse a row whose beads disagree by more than its gate.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3x4, Point3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::camera::RigConfig;
use super::dynamics::{Dynamics, Motion};
use super::faults::{Fault, Timeline};
use super::plant::{PlantParams, Pressures};
use super::SynthError;
use crate::data::Csv;
use crate::session::protocol::{self, Step};
use crate::triangulate::nview::{self, View};

/// The cameras' frame rate (Hz).
pub const FPS: f64 = 30.0;

/// A bead centre's pixel noise per axis (px): a per-frame tip of about 0.04 mm, as the
/// rendered sessions give.
pub const PIXEL_NOISE_PX: f64 = 0.1;

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

impl std::fmt::Display for Written {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        writeln!(
            f,
            "wrote {} ({} rows, one per frame at {FPS} fps, no images; {} frames fixed no point) and the true tips {}",
            self.session.display(),
            self.rows,
            self.unseen,
            self.truth.display()
        )
    }
}

/// What `manifest.json` records of a session without images.
#[derive(serde::Serialize)]
struct Manifest<'a> {
    format: &'static str,
    seed: u64,
    fps: f64,
    pixel_noise_px: f64,
    faults: &'a [Fault],
    plant: &'a PlantParams,
    files: [&'static str; 2],
    provenance: &'a crate::provenance::Provenance,
}

/// Plays `steps` on the plant seen by the rig of `seed` and writes `out/session.csv`
/// (`time_s,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,reproj_px`) and `out/truth.csv`
/// (`time_s,x_mm,y_mm,z_mm`, the true tip), one row per frame at [`FPS`], and
/// `out/manifest.json` (the seed, the faults, the plant).
///
/// # Errors
/// A plant error, or a file that cannot be written.
pub fn write(
    out: &Path,
    steps: &[Step],
    seed: u64,
    plant: &PlantParams,
    faults: &[Fault],
    provenance: &crate::provenance::Provenance,
) -> Result<Written, SynthError> {
    let rig = RigConfig::default().build(seed);
    let (starts, end) = protocol::start_times(steps);
    let commands: Vec<(f64, Pressures)> = starts
        .iter()
        .zip(steps)
        .map(|(&t, s)| (t, s.pressures))
        .collect();
    let motion = Motion::simulate(&commands, &Dynamics::PNEUMATIC, plant.hysteresis_kpa, end);
    let timeline = Timeline::new(plant, &rig, faults);
    let calibrated = [rig.left().projection(), rig.right().projection()];
    let knocked = timeline
        .knocked()
        .map(|(at, camera)| (*at, camera.projection()));
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
        let tip = timeline.tip(&motion, t)?;
        let point = Point3::from(tip);
        let right = match knocked {
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
    let manifest = Manifest {
        format: "handcap synth --no-images (a session without images)",
        seed,
        fps: FPS,
        pixel_noise_px: PIXEL_NOISE_PX,
        faults,
        plant,
        files: ["session.csv", "truth.csv"],
        provenance,
    };
    let json = serde_json::to_vec_pretty(&manifest).expect("the manifest serialises");
    let path = out.join("manifest.json");
    crate::fsio::write_bytes(&path, &json).map_err(super::capture::io_err(&path))?;
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let tilt: Fault = "camera@10=0.2".parse().unwrap();
        let provenance = crate::provenance::Provenance::new(vec!["test".into()], Some(1));
        let w = write(
            dir.path(),
            &steps,
            1,
            &PlantParams::default(),
            &[tilt],
            &provenance,
        );
        let w = w.unwrap();
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
