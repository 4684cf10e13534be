//! The triangulation stage with more than two cameras: held steps seen by any number of
//! cameras ([`crate::triangulate::cameras`]).

use std::fmt;
use std::path::{Path, PathBuf};

use super::super::outputs::{self, Output};
use super::super::{io_error, PipelineError, Session, Task};
use crate::session::pressures::read_pressure_log;
use crate::triangulate::{self, TriangulateOptions};

/// Whether `calib` is the calibration of cameras other than a pair `left`, `right` (an
/// Anipose TOML, as `handcap calibrate` writes for more cameras): [`run_cameras`]'s.
pub fn more_cameras(calib: &Path) -> bool {
    let toml = calib
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    toml && crate::calib::file::read_cameras_toml(calib).is_ok_and(|(cameras, _)| {
        let names: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
        names != ["left", "right"]
    })
}

/// What the stage did with more than two cameras, and wrote.
pub struct TriangulatedCameras {
    pub found: triangulate::cameras::Found,
    /// Frames of cameras the calibration does not have, by name (not read).
    pub not_calibrated: std::collections::BTreeMap<String, usize>,
    /// The frames each camera listed, in the calibration's order.
    pub listed: Vec<usize>,
    pub cameras: Vec<String>,
    /// The regulator's log the tips' steps index.
    pub log: crate::session::pressures::PressureLog,
    pub written: Vec<PathBuf>,
}

/// The tip of every held step of the log at `pressures` seen by the cameras of `calib` (more
/// than a pair, [`triangulate::cameras`]) in `frames`; writes the dataset `out`.
///
/// # Errors
/// [`PipelineError`]: unreadable inputs, a calibration without the hand frame's axes, no step
/// at rest with a tip, `out` naming an input, or a file that cannot be written;
/// [`PipelineError::Interrupted`] after writing the steps of the frames examined before
/// Ctrl-C.
pub fn run_cameras(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
    session: &Session,
) -> Result<TriangulatedCameras, PipelineError> {
    options.check().map_err(PipelineError::Request)?;
    let (cameras, hand) = crate::calib::file::read_cameras_toml(calib)?;
    if cameras.len() < 2 {
        return Err(PipelineError::Place(format!(
            "{} has {} camera: a tip takes two or more seeing it; calibrate the cameras together (handcap calibrate with <camera>_NN views)",
            calib.display(),
            cameras.len()
        )));
    }
    let Some(hand) = hand else {
        return Err(PipelineError::Place(format!(
            "{} has no hand_rotation in its [metadata]: calibrate with <camera>_ref views of the reference board (handcap calibrate writes it)",
            calib.display()
        )));
    };
    let log = read_pressure_log(pressures)?;
    let (listed, not_calibrated) = triangulate::cameras::read_frames(frames, &cameras)?;
    let index = frames.join("frames.csv");
    let inputs: Vec<&Path> = [calib, pressures, index.as_path()]
        .into_iter()
        .chain(listed.iter().map(|f| f.path.as_path()))
        .collect();
    outputs::check(&inputs, &[Output::new(out, "the dataset")])?;
    // The covariance of the cameras' unknowns, from the JSON `calibrate` wrote beside (its
    // intrinsics have five distortion coefficients, as `calibrate` writes them).
    let json = calib.with_extension("json");
    let five = cameras.iter().all(|c| c.intrinsics.dist.len() >= 5);
    let covariance = if json.is_file() && five {
        crate::calib::file::read_cameras_covariance(&json, cameras.len())?
    } else {
        None
    };
    let calibration = triangulate::cameras::Calibration {
        cameras,
        hand,
        covariance,
    };
    let result = triangulate::cameras::triangulate(
        &listed,
        &calibration,
        &log,
        options,
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::super::Event::Finished(Task::Frames));
    let found = result.map_err(|e| PipelineError::Place(e.to_string()))?;
    let cameras = calibration.cameras;
    let text = triangulate::cameras::csv(&found, |_| true, &cameras, &log);
    crate::fsio::write_bytes(out, text.as_bytes()).map_err(io_error(out))?;
    let mut written = vec![out.to_path_buf()];
    // OUT_<phase>.csv, as a pair's dataset has them.
    if let Some(col) = log.extra_columns.iter().position(|c| c == "phase") {
        let phase_of = |t: &triangulate::cameras::StepTip| log.steps[t.step].extra[col].as_str();
        let phases = triangulate::output::first_appearances(found.tips.iter().map(phase_of));
        for phase in phases {
            let path = triangulate::output::phase_path(out, phase);
            let text = triangulate::cameras::csv(&found, |t| phase_of(t) == phase, &cameras, &log);
            crate::fsio::write_bytes(&path, text.as_bytes()).map_err(io_error(&path))?;
            written.push(path);
        }
    }
    if found.interrupted {
        return Err(PipelineError::Interrupted(format!(
            "interrupted: {} holds the steps of the frames examined before Ctrl-C; run again for all of them",
            out.display()
        )));
    }
    Ok(TriangulatedCameras {
        found,
        not_calibrated,
        listed: (0..cameras.len())
            .map(|c| listed.iter().filter(|f| f.camera == c).count())
            .collect(),
        cameras: cameras.into_iter().map(|c| c.name).collect(),
        log,
        written,
    })
}

impl fmt::Display for TriangulatedCameras {
    /// What the stage found, as `handcap triangulate` prints it.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let found = &self.found;
        let mut by_count: Vec<usize> = vec![0; self.cameras.len() + 1];
        for tip in &found.tips {
            by_count[tip.used.len()] += 1;
        }
        let counts: Vec<String> = (2..by_count.len())
            .rev()
            .filter(|&n| by_count[n] > 0)
            .map(|n| format!("{} by {n}", by_count[n]))
            .collect();
        writeln!(
            f,
            "{} steps with a tip ({}), cameras {}; {} seen by fewer than two cameras, {} whose views no two agreed on",
            found.tips.len(),
            counts.join(", "),
            self.cameras.join(", "),
            found.steps_unseen,
            found.steps_inconsistent
        )?;
        if let Some(why) = &found.unreadable {
            writeln!(
                f,
                "{} frames unreadable, left out; the first: {why}",
                found.frames_unreadable
            )?;
        }
        for (name, n) in &self.not_calibrated {
            writeln!(
                f,
                "skipped {n} frames of camera {name}: not in the calibration"
            )?;
        }
        // A camera that listed far fewer frames than the others stopped or dropped frames.
        let mut counts: Vec<f64> = self.listed.iter().map(|&n| n as f64).collect();
        let median = crate::stats::median(&mut counts).unwrap_or(0.0);
        for (name, &n) in self.cameras.iter().zip(&self.listed) {
            if 2.0 * (n as f64) < median {
                writeln!(
                    f,
                    "camera {name} listed {n} frames where the cameras' median is {median}: it stopped or dropped frames (its steps have fewer views)"
                )?;
            }
        }
        if let Some(px) = found.bead_noise_px {
            writeln!(
                f,
                "the beads' error the steps' residuals show: {px:.3} px (the gate and the covariances assume {} px, scaled up to more){}",
                crate::triangulate::cameras::BEAD_NOISE_PX,
                if found.calibration_in_covariance {
                    "; the calibration's uncertainty is in them"
                } else {
                    "; the calibration has no covariance beside it (cal.json): its uncertainty is not in them"
                }
            )?;
        }
        let left_out = found.tips.iter().filter(|t| !t.left_out.is_empty()).count();
        writeln!(
            f,
            "{} of {} frames in settled steps without a marker, {} with several candidates (the one the cameras agree on kept); {left_out} steps with a camera left out by the gate; origin from {} steps at rest",
            found.frames_without_marker, found.frames_in_steps, found.frames_with_several, found.rest_steps
        )
    }
}
