//! The demo's steps 2 and 3 with more than two cameras (`demo --cameras N`), and what steps 2
//! and 3 found either way.

use super::super::demo_checks::{check_cameras, check_cameras_tips};
use super::super::demo_summary::{CalibrationCheck, CamerasCheck, TipCheck};
use super::super::{io_error, Event, PipelineError};
use super::Demo;

/// What steps 2 and 3 found: a pair's calibration and triangulation, or more cameras'; each
/// with its checks against the truth.
pub(super) enum Seen {
    Pair {
        calibrated: Box<super::super::calibrate::Calibrated>,
        calibration: CalibrationCheck,
        triangulated: Box<super::super::triangulate::Triangulated>,
        triangulation: Vec<TipCheck>,
    },
    Cameras {
        check: CamerasCheck,
        triangulation: Vec<TipCheck>,
    },
}

impl Seen {
    pub(super) fn calibration(&self) -> Option<CalibrationCheck> {
        match self {
            Seen::Pair { calibration, .. } => Some(calibration.clone()),
            Seen::Cameras { .. } => None,
        }
    }

    pub(super) fn cameras(&self) -> Option<CamerasCheck> {
        match self {
            Seen::Pair { .. } => None,
            Seen::Cameras { check, .. } => Some(check.clone()),
        }
    }

    pub(super) fn triangulation(&self) -> Vec<TipCheck> {
        match self {
            Seen::Pair { triangulation, .. } | Seen::Cameras { triangulation, .. } => {
                triangulation.clone()
            }
        }
    }
}

impl Demo<'_> {
    /// Steps 2 and 3 with more than two cameras: their calibration against the rig they were
    /// rendered with, their tips against the true tips.
    pub(super) fn more_cameras(&mut self) -> Result<Seen, PipelineError> {
        let n = self.config.cameras;
        self.stage(
            2,
            format!("calibrate: {n} cameras' board views → calib.toml, calib.json"),
        );
        let capture = self.capture_dir();
        let calib_dir = capture.join("calib");
        let board = super::super::calibrate::board(&calib_dir, &Default::default(), self.session)?;
        let listing = crate::calib::cameras::list(&calib_dir).map_err(io_error(&calib_dir))?;
        let calib = self.out.join("calib.yml");
        let calibrated = super::super::calibrate::run_cameras(
            &calib_dir,
            &listing,
            &board,
            &std::collections::BTreeMap::new(),
            false,
            &calib,
            self.session,
        )?;
        self.session.emit(Event::Outcome(&calibrated));
        self.lap("calibrate");
        self.stage(
            3,
            format!("triangulate: the red tip seen by {n} cameras → dataset"),
        );
        let dataset = self.out.join("triangulated/dataset.csv");
        let triangulated = super::super::triangulate::run_cameras(
            &capture.join("frames"),
            &crate::calib::file::toml_path(&calib),
            &capture.join("pressures.csv"),
            &self.plan.triangulate,
            &dataset,
            self.session,
        )?;
        self.session.emit(Event::Outcome(&triangulated));
        let tips = capture.join("truth/tips.csv");
        let triangulation = check_cameras_tips(&triangulated.found, &triangulated.log, &tips)?;
        let check = check_cameras(
            &calibrated.calibration,
            &capture.join("truth/cameras.toml"),
            &triangulated.found,
            &tips,
        )?;
        self.note_tips(&triangulation);
        self.note(format!(
            "      {:.1} % of the true tips inside their row's 95 % ellipsoid",
            100.0 * check.ellipsoid_coverage
        ));
        self.lap("triangulate");
        Ok(Seen::Cameras {
            check,
            triangulation,
        })
    }
}
