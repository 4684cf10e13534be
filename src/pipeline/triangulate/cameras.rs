//! The triangulation stage with more than two cameras: held steps seen by any number of
//! cameras ([`crate::triangulate::cameras`]).

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use super::super::outputs;
use super::super::{PipelineError, Session, Task};
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
    pub not_calibrated: BTreeMap<String, usize>,
    /// The frames each camera listed, in the calibration's order.
    pub listed: Vec<usize>,
    pub cameras: Vec<String>,
    /// The regulator's log the tips' steps index.
    pub log: crate::session::pressures::PressureLog,
    pub written: Vec<PathBuf>,
    /// How the cameras stored their frames' colour ([`super::stored_colour`]).
    pub colour: Option<String>,
}

/// What `triangulate` read for more cameras: the calibration, the log, the frames listed and
/// those of cameras the calibration does not have (by name).
struct Inputs {
    calibration: triangulate::cameras::Calibration,
    log: crate::session::pressures::PressureLog,
    listed: Vec<triangulate::cameras::Frame>,
    not_calibrated: BTreeMap<String, usize>,
}

impl Inputs {
    /// Reads the cameras of `calib` (and the covariance of their unknowns from the JSON
    /// `calibrate` wrote beside, for intrinsics of five distortion coefficients, as it writes
    /// them), the log at `pressures`, the frames of `frames`; checks that `out` names no input.
    fn read(
        frames: &Path,
        calib: &Path,
        pressures: &Path,
        out: &Path,
    ) -> Result<Inputs, PipelineError> {
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
        outputs::check(&inputs, &super::planned_outputs(out, &log))?;
        let json = calib.with_extension("json");
        let five = cameras.iter().all(|c| c.intrinsics.dist.len() >= 5);
        let covariance = if json.is_file() && five {
            crate::calib::file::read_cameras_covariance(&json, cameras.len())?
        } else {
            None
        };
        Ok(Inputs {
            calibration: triangulate::cameras::Calibration {
                cameras,
                hand,
                covariance,
            },
            log,
            listed,
            not_calibrated,
        })
    }

    /// The frames each camera listed, in the calibration's order.
    fn listed_per_camera(&self) -> Vec<usize> {
        (0..self.calibration.cameras.len())
            .map(|c| self.listed.iter().filter(|f| f.camera == c).count())
            .collect()
    }

    /// How the calibrated cameras stored their frames' colour in `frames`.
    fn colour(&self, frames: &Path) -> Option<String> {
        let names: Vec<&str> = (self.calibration.cameras.iter())
            .map(|c| c.name.as_str())
            .collect();
        super::stored_colour(frames, &names)
    }
}

/// What `triangulate` did with more than two cameras: held steps, or one row per frame.
pub enum MoreCameras {
    Steps(TriangulatedCameras),
    Frames(TriangulatedFrames),
}

impl MoreCameras {
    /// The files written.
    pub fn written(&self) -> &[PathBuf] {
        match self {
            MoreCameras::Steps(s) => &s.written,
            MoreCameras::Frames(f) => &f.written,
        }
    }
}

impl fmt::Display for MoreCameras {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            MoreCameras::Steps(s) => s.fmt(f),
            MoreCameras::Frames(r) => r.fmt(f),
        }
    }
}

/// [`run_per_frame_cameras`] with `per_frame`, else [`run_cameras`].
///
/// # Errors
/// As theirs.
pub fn run_more_cameras(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    per_frame: bool,
    out: &Path,
    session: &Session,
) -> Result<MoreCameras, PipelineError> {
    let pair_only = [
        (options.latency_s.is_some(), "--latency-ms"),
        (options.video_start_s.is_some(), "--video-start-s"),
    ];
    if let Some((_, flag)) = pair_only.iter().find(|p| p.0) {
        return Err(PipelineError::Request(format!(
            "{flag} takes a pair's LEFT,RIGHT; {} holds more cameras, whose frames are images and whose clocks --per-frame measures from the motion",
            calib.display()
        )));
    }
    Ok(if per_frame {
        MoreCameras::Frames(run_per_frame_cameras(
            frames, calib, pressures, options, out, session,
        )?)
    } else {
        MoreCameras::Steps(run_cameras(
            frames, calib, pressures, options, out, session,
        )?)
    })
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
    let inputs = Inputs::read(frames, calib, pressures, out)?;
    let (calibration, log) = (&inputs.calibration, &inputs.log);
    let result = triangulate::cameras::triangulate(
        &inputs.listed,
        calibration,
        log,
        options,
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::super::Event::Finished(Task::Frames));
    let found = result.map_err(|e| PipelineError::Place(e.to_string()))?;
    let provenance = super::provenance(session, frames, calib, pressures)?;
    let written = found.write(out, log, &calibration.cameras, options, &provenance)?;
    if found.interrupted {
        return Err(PipelineError::Interrupted(format!(
            "interrupted: {} holds the steps of the frames examined before Ctrl-C; run again for all of them",
            out.display()
        )));
    }
    let (listed, colour) = (inputs.listed_per_camera(), inputs.colour(frames));
    Ok(TriangulatedCameras {
        found,
        not_calibrated: inputs.not_calibrated,
        listed,
        cameras: inputs
            .calibration
            .cameras
            .into_iter()
            .map(|c| c.name)
            .collect(),
        log: inputs.log,
        written,
        colour,
    })
}

/// What the per-frame stage did with more than two cameras, and wrote.
pub struct TriangulatedFrames {
    pub per_frame: triangulate::per_frame::PerFrameCameras,
    /// Frames of cameras the calibration does not have, by name (not read).
    pub not_calibrated: BTreeMap<String, usize>,
    pub written: Vec<PathBuf>,
    /// How the cameras stored their frames' colour ([`super::stored_colour`]).
    pub colour: Option<String>,
}

/// One row per frame of the first camera, the finger in motion, seen by the cameras of
/// `calib` (more than a pair, [`triangulate::per_frame::triangulate_per_frame_cameras`]) in
/// `frames`; writes the dataset `out`, its phases and its summary.
///
/// # Errors
/// As [`run_cameras`], and the per-frame refusals of a pair (stamps going back, a camera's
/// frames apart in time, no tip in the first rest hold);
/// [`PipelineError::Interrupted`] after writing the rows of the frames examined before Ctrl-C.
pub fn run_per_frame_cameras(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
    session: &Session,
) -> Result<TriangulatedFrames, PipelineError> {
    options.check().map_err(PipelineError::Request)?;
    let inputs = Inputs::read(frames, calib, pressures, out)?;
    let result = triangulate::per_frame::triangulate_per_frame_cameras(
        &inputs.listed,
        &inputs.calibration,
        &inputs.log,
        options,
        &frames.join("frames.csv"),
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::super::Event::Finished(Task::Frames));
    let per_frame = result.map_err(|e| PipelineError::Place(e.to_string()))?;
    let provenance = super::provenance(session, frames, calib, pressures)?;
    let cameras = &inputs.calibration.cameras;
    let written = per_frame.write(out, &inputs.log, cameras, options, &provenance)?;
    if per_frame.summary.interrupted {
        return Err(PipelineError::Interrupted(format!(
            "interrupted: {} holds the rows of the frames examined before Ctrl-C; run again for all of them",
            out.display()
        )));
    }
    Ok(TriangulatedFrames {
        per_frame,
        colour: inputs.colour(frames),
        not_calibrated: inputs.not_calibrated,
        written,
    })
}

impl fmt::Display for TriangulatedFrames {
    /// What the stage found, as `handcap triangulate --per-frame` prints it.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let s = &self.per_frame.summary;
        let by: Vec<String> = s
            .by_cameras
            .iter()
            .rev()
            .map(|(n, rows)| format!("{rows} by {n}"))
            .collect();
        let flagged: Vec<String> = s.flagged.iter().map(|(k, n)| format!("{n} {k}")).collect();
        writeln!(
            f,
            "{} rows (one per {} frame), {} with a tip and no flag; with a tip: {}; flagged: {}",
            s.rows,
            s.rows_camera,
            s.good_rows,
            if by.is_empty() {
                "none".into()
            } else {
                by.join(", ")
            },
            if flagged.is_empty() {
                "none".into()
            } else {
                flagged.join(", ")
            }
        )?;
        super::write_colour(f, self.colour.as_ref())?;
        for c in &s.cameras {
            let clock = if c.name == s.rows_camera {
                "the rows' clock".to_string()
            } else if s.clocks_measured {
                "clock measured".to_string()
            } else if c.clock_frames == 0 {
                "clock offset not measured (no motion both saw), taken as 0".to_string()
            } else {
                format!(
                    "clock {:+.1} ms (drift {:+.1} ms) from {} moving frames",
                    c.clock_offset_ms, c.clock_drift_ms, c.clock_frames
                )
            };
            writeln!(
                f,
                "camera {}: {} frames, {} without a marker, {} unreadable; in {} rows' tips; {clock}",
                c.name, c.listed, c.without_marker, c.unreadable, c.rows_used
            )?;
        }
        for (name, n) in &self.not_calibrated {
            writeln!(
                f,
                "skipped {n} frames of camera {name}: not in the calibration"
            )?;
        }
        writeln!(
            f,
            "origin from {} rows at rest (spread {:.4} mm)",
            s.origin_rows, s.origin_spread_mm
        )
    }
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
        super::write_colour(f, self.colour.as_ref())?;
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
