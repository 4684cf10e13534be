//! The monitor live (`capture --view-calib CALIB --model MODEL`): each left frame the track
//! takes goes, with the command in force at its time, through the model (its input history
//! run frame by frame, as `handcap monitor` runs it through a file's rows) and the same
//! [`Monitor`]. The page shows the error, the band and the alarms; each alarm is said on a
//! line as it fires; at the session's end `OUT/monitor/` holds what `handcap monitor` writes
//! (`monitor.csv`, `monitor.json`, the figure), with the frames the examiner skipped while it
//! was behind counted, and after a finger alarm `after_change.csv`: the rows from the change
//! on (time, the pressures the model was given, the measured tip), to refit the model on.

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Vector3};
use serde::Serialize;

use crate::data::Columns;
use crate::model::file::ModelFile;
use crate::model::history::Running;
use crate::model::interval::Widener;
use crate::monitor::{Alarm, Monitor, Settings};
use crate::pipeline::monitor::{self as watch_files, Replay, Watched};
use crate::provenance::Provenance;
use crate::session::pressures::PRESSURE_COLUMNS;

/// The outputs a live model predicts: the tip in the hand frame.
const TIP_COLUMNS: [&str; 3] = ["x_mm", "y_mm", "z_mm"];
/// The page's window of the error and the band (s).
const WINDOW_S: f64 = 30.0;
/// The rows kept while the hand frame's origin is not known (s): a session that never shows
/// its rest hold keeps the last ten minutes, not every frame.
const PENDING_S: f64 = 600.0;

/// The model a session is watched against, read and checked before filming.
#[derive(Clone, Debug)]
pub struct Watching {
    pub path: PathBuf,
    file: std::sync::Arc<ModelFile>,
    radius: f64,
    /// The radius' widening off the training rows, when the model's radius widens.
    widener: Option<Widener>,
    pub settings: Settings,
}

impl Watching {
    /// Reads the model at `path` for `settings`.
    ///
    /// # Errors
    /// One line naming the file: unreadable, without intervals, or a model whose inputs are not
    /// the regulator's pressures or whose outputs are not the tip.
    pub fn read(path: &Path, settings: Settings) -> Result<Watching, String> {
        settings
            .check()
            .map_err(|e| format!("--model's monitor: {e}"))?;
        let name = path.display();
        let file = ModelFile::load(path).map_err(|e| e.to_string())?;
        let radius = file.interval_radius(settings.level).map_err(|e| {
            format!("{name}: interval: {e}; the monitor needs a model fitted with --intervals")
        })?;
        let widener = file
            .interval_widener()
            .map_err(|e| format!("{name}: {e}"))?;
        let predictor = file.model.predictor();
        let inputs = file.history().map_or(predictor.inputs(), |h| &h.inputs[..]);
        if inputs != PRESSURE_COLUMNS || predictor.outputs() != TIP_COLUMNS {
            return Err(format!(
                "{name} maps {} to {}; the live monitor gives it the commands {} and the tip {}: fit the model on triangulate's rows",
                inputs.join(","),
                predictor.outputs().join(","),
                PRESSURE_COLUMNS.join(","),
                TIP_COLUMNS.join(",")
            ));
        }
        Ok(Watching {
            path: path.to_path_buf(),
            file: std::sync::Arc::new(file),
            radius,
            widener,
            settings,
        })
    }
}

/// The monitor on the page.
#[derive(Clone, Debug, Default, Serialize)]
pub(super) struct TrustPage {
    /// Why nothing is watched yet, while nothing is, or why the camera channel is not.
    waiting: Option<String>,
    level: f64,
    rows: usize,
    /// The share of rows the band held.
    coverage: f64,
    /// The last [`WINDOW_S`]: time (s), error and band (mm).
    points: Vec<[f64; 3]>,
    /// The last [`WINDOW_S`] of the still scene: time (s), and how far the left and the right
    /// camera's view of it lay from its first frame's (px), where measured.
    scene: Vec<(f64, Option<f64>, Option<f64>)>,
    /// Each channel's statistic now, and the alarm's threshold; the finger's response test's
    /// statistic and threshold.
    finger_stat: f64,
    camera_stat: Option<f64>,
    threshold: f64,
    response_stat: Option<f64>,
    response_threshold: f64,
    alarms: Vec<Alarm>,
}

/// A left frame the track took: its time, the command in force, its tip in the left camera
/// with its residual, or why none, and how far each camera's view of the still scene lay from
/// its first frame's then (px; left, right), where measured.
type Taken = (
    f64,
    [f64; 3],
    Result<(Vector3<f64>, f64), &'static str>,
    Vec<Option<f64>>,
);

/// The cameras' names in the still scene's channels (`triangulate --per-frame`'s).
const CAMERAS: [&str; 2] = ["left", "right"];

/// The monitor of a live session.
pub struct Trust {
    watching: Watching,
    monitor: Monitor,
    running: Option<Running>,
    /// Rows taken before the hand frame's origin was known (the last [`PENDING_S`]).
    pending: Vec<Taken>,
    replay: Replay,
    /// The pressures each watched row gave the model (before its history's filters).
    inputs: Vec<[f64; 3]>,
    page: TrustPage,
}

impl Trust {
    pub(super) fn new(watching: Watching) -> Trust {
        let columns = |prefix: &str| {
            Columns::new(
                TIP_COLUMNS.map(|c| format!("{prefix}{c}")).to_vec(),
                Vec::new(),
            )
        };
        let rest = watching.file.at_rest();
        Trust {
            monitor: Monitor::new(watching.radius, &watching.settings).with_rest(rest.clone()),
            page: TrustPage {
                waiting: Some("the hand frame's origin is not known yet".into()),
                level: watching.settings.level,
                threshold: watching.settings.threshold(),
                response_threshold: watching.settings.response_threshold(),
                ..TrustPage::default()
            },
            replay: Replay {
                time: "time_s".into(),
                times: Vec::new(),
                predicted: columns(""),
                measured: columns(""),
                errors: Vec::new(),
                factors: Vec::new(),
                geometry: Some((Vec::new(), Vec::new())),
                scene: Vec::new(),
                radius: watching.radius,
                rest,
            },
            watching,
            running: None,
            pending: Vec::new(),
            inputs: Vec::new(),
        }
    }

    /// A left frame the track took, at `time_s` under `command`: watched once the hand frame
    /// is known.
    pub(super) fn take(&mut self, taken: Taken) {
        let old = self.pending.partition_point(|p| p.0 < taken.0 - PENDING_S);
        self.pending.drain(..old);
        self.pending.push(taken);
    }

    /// Watches the rows taken, in the hand frame `r · (p − origin)` once it is known; the
    /// alarms that fired, each as a line to say.
    pub(super) fn watch(&mut self, hand: Option<(Rotation3<f64>, Vector3<f64>)>) -> Vec<String> {
        let Some((r, origin)) = hand else {
            return Vec::new();
        };
        let mut said = Vec::new();
        for (t, command, found, scene) in std::mem::take(&mut self.pending) {
            let file = &self.watching.file;
            let mut x = vec![0.0; file.model.predictor().inputs().len()];
            if let (None, Some(h)) = (&self.running, file.history()) {
                self.running = Some(h.running(&command, t));
            }
            match &mut self.running {
                Some(running) => running.step(&command, t, &mut x),
                None => x.copy_from_slice(&command),
            }
            if let [left, right] = scene[..] {
                self.page.scene.push((t, left, right));
            }
            for (camera, px) in CAMERAS.into_iter().zip(scene) {
                let Some(px) = px else { continue };
                let samples =
                    crate::monitor::named(&mut self.replay.scene, camera, Default::default);
                samples.0.push(t);
                samples.1.push(px);
                said.extend(self.monitor.scene(camera, t, px).map(|a| a.to_string()));
            }
            let px = match found {
                Ok((_, px)) => px,
                Err(crate::monitor::DISAGREED) => f64::INFINITY,
                Err(_) => continue,
            };
            let geometry = self.replay.geometry.get_or_insert_with(Default::default);
            geometry.0.push(t);
            geometry.1.push(px);
            said.extend(self.monitor.geometry(t, px).map(|a| a.to_string()));
            let Ok((p, _)) = found else { continue };
            let measured = r * (p - origin);
            let mut predicted = [0.0; 3];
            file.model.predictor().predict_row(&x, &mut predicted);
            let error = (Vector3::from(predicted) - measured).norm();
            let factor = (self.watching.widener.as_ref()).map_or(1.0, |w| w.factor(&x));
            let response = self.monitor.outputs(t, &predicted, measured.as_slice());
            said.extend(response.map(|a| a.to_string()));
            // The band follows the error over the row's widening factor, as the radius was
            // calibrated.
            let (seen, alarm) = self.monitor.error(t, error / factor);
            said.extend(alarm.map(|a| a.to_string()));
            self.replay.times.push(t);
            self.inputs.push(command);
            self.replay.predicted.values.extend(predicted);
            self.replay.measured.values.extend(measured.iter());
            self.replay.errors.push(error);
            self.replay.factors.push(factor);
            self.page.points.push([t, error, seen.band * factor]);
            self.page.finger_stat = seen.model_stat;
            self.page.camera_stat = seen.geometry_stat;
            self.page.response_stat = seen.response_stat;
        }
        let misfit = self.monitor.misfit();
        if misfit.is_some() && self.page.waiting != misfit {
            said.extend(misfit.clone());
        }
        self.page.waiting = misfit;
        let newest = self.replay.times.last().copied().unwrap_or_default();
        let old = self
            .page
            .points
            .partition_point(|p| p[0] < newest - WINDOW_S);
        self.page.points.drain(..old);
        let old = (self.page.scene).partition_point(|p| p.0 < newest - WINDOW_S);
        self.page.scene.drain(..old);
        self.page.rows = self.replay.times.len();
        self.page.coverage = self.monitor.coverage();
        self.page.alarms = self.monitor.alarms().to_vec();
        said
    }

    pub(super) fn page(&self) -> TrustPage {
        self.page.clone()
    }

    /// Writes the session watched into `out` (the session `session`; `skipped`, the frames
    /// the examiner skipped per camera), and after a finger alarm `after_change.csv`.
    ///
    /// # Errors
    /// A file that cannot be written.
    pub fn write(
        self,
        out: &Path,
        session: &Path,
        skipped: [usize; 2],
        provenance: Provenance,
    ) -> Result<Watched, crate::pipeline::PipelineError> {
        let monitored = self.monitor.finish();
        let after_change = match watch_files::change_s(&monitored) {
            Some(change) => Some(write_after(&self.replay, &self.inputs, out, change)?),
            None => None,
        };
        let watched = Watched {
            session: session.to_path_buf(),
            model: self.watching.path.clone(),
            settings: self.watching.settings.clone(),
            rows: self.replay.times.len(),
            span_s: crate::pipeline::monitor::span(&self.replay.times),
            monitored,
            after_change,
            provenance,
            out: out.to_path_buf(),
            skipped: Some(skipped),
        };
        watch_files::write(&self.replay, &watched)?;
        Ok(watched)
    }
}

/// `out/after_change.csv`: the rows watched (`replay`, the pressures `given` to the model) from
/// `change` (s) on, as a refit reads them (`handcap model after_change.csv --inputs
/// P1_kpa,P2_kpa,P3_kpa --outputs x_mm,y_mm,z_mm --time time_s`).
fn write_after(
    replay: &Replay,
    given: &[[f64; 3]],
    out: &Path,
    change: f64,
) -> Result<PathBuf, crate::pipeline::PipelineError> {
    let times = &replay.times;
    let rows: Vec<usize> = (0..times.len()).filter(|&i| times[i] >= change).collect();
    let time = Columns::new(
        vec![replay.time.clone()],
        rows.iter().map(|&i| times[i]).collect(),
    );
    let inputs = Columns::new(
        PRESSURE_COLUMNS.map(String::from).to_vec(),
        rows.iter().flat_map(|&i| given[i]).collect(),
    );
    let tip = replay.measured.select_rows(&rows);
    let path = out.join(watch_files::AFTER_CHANGE);
    std::fs::create_dir_all(out).map_err(crate::pipeline::io_error(out))?;
    crate::data::write_csv(&path, &[&time, &inputs, &tip])?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model that predicts the tip (0, 0, 10) mm whatever the pressures (its one centre's
    /// coefficients are zero), its 90 % radius 1 mm.
    const STILL: &str = r#"{"format": "handcap-model", "version": 1, "kind": "msvr",
        "model": {"inputs": ["P1_kpa", "P2_kpa", "P3_kpa"], "outputs": ["x_mm", "y_mm", "z_mm"],
            "params": {"c": 10.0, "epsilon": 0.1, "sigma": 0.5, "tol": 1e-08, "max_iter": 500,
                       "loss": "robust", "basis": {"kind": "exact"}},
            "scaler": {"min": [0.0, 0.0, 0.0], "max": [250.0, 250.0, 250.0]},
            "support_vectors": [[0.0, 0.0, 0.0]], "coefficients": [[0.0, 0.0, 0.0]],
            "bias": [0.0, 0.0, 10.0],
            "fit": {"rows": 3, "iterations": 1, "objective": 0.0, "support_vectors": 1,
                    "converged": true, "stop": "tolerance"}},
        "intervals": {"folds": {"scheme": "shuffle", "reason": "test"}, "rows": 9,
            "radii": [{"level": 0.9, "radius": 1.0}], "groups": [],
            "scores": [0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]},
        "provenance": {"handcap_version": "0.1.0", "command": ["test"], "seed": null,
                       "inputs": []}}"#;

    /// A live session of 60 s at 10 rows a second watched against [`STILL`]: the tip on the
    /// prediction within 0.2 mm, then from `moved_at` on 3 mm away.
    fn watched(out: &Path, moved_at: f64) -> Watched {
        let model = out.join("model.json");
        std::fs::write(&model, STILL).unwrap();
        let settings = Settings {
            baseline_s: 10.0,
            false_alarm_hours: 0.1,
            ..Settings::default()
        };
        let mut trust = Trust::new(Watching::read(&model, settings).unwrap());
        for k in 0..600 {
            let t = k as f64 / 10.0;
            let wobble = 0.2 * (k as f64 * 0.7).sin();
            let tip = if t < moved_at {
                Vector3::new(wobble, 0.0, 10.0)
            } else {
                Vector3::new(3.0, wobble, 10.0)
            };
            trust.take((t, [k as f64, 20.0, 30.0], Ok((tip, 0.1)), Vec::new()));
            trust.watch(Some((Rotation3::identity(), Vector3::zeros())));
        }
        let provenance = Provenance::new(vec!["test".into()], None);
        trust
            .write(&out.join("monitor"), out, [0, 0], provenance)
            .unwrap()
    }

    #[test]
    fn after_the_fingers_alarm_the_rows_from_the_change_on_are_written_to_refit_on() {
        let dir = tempfile::tempdir().unwrap();
        let watched = watched(dir.path(), 30.0);
        let alarm = &watched.monitored.alarms[0];
        assert_eq!(alarm.channel, crate::monitor::Channel::Finger);
        assert!(
            (29.0..=31.0).contains(&alarm.change_s),
            "the change dated at {} s",
            alarm.change_s
        );
        let path = watched.after_change.expect("after_change.csv");
        assert_eq!(path, dir.path().join("monitor/after_change.csv"));
        let header = crate::data::header(&path).unwrap();
        assert_eq!(
            header,
            ["time_s", "P1_kpa", "P2_kpa", "P3_kpa", "x_mm", "y_mm", "z_mm"]
        );
        let rows = crate::data::read_columns(&path, &header).unwrap();
        let first = (alarm.change_s * 10.0).ceil() as usize;
        assert_eq!(rows.rows(), 600 - first, "every row from the change on");
        for (i, row) in rows.iter_rows().enumerate() {
            let k = first + i;
            assert!((row[0] - k as f64 / 10.0).abs() < 1e-9, "{row:?}");
            assert_eq!(row[1..4], [k as f64, 20.0, 30.0], "the pressures given");
            if row[0] >= 30.0 {
                assert_eq!((row[4], row[6]), (3.0, 10.0), "the tip measured");
            }
        }
    }

    #[test]
    fn without_a_fingers_alarm_no_rows_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let watched = watched(dir.path(), f64::INFINITY);
        assert!(watched.monitored.alarms.is_empty());
        assert!(watched.after_change.is_none());
        assert!(!dir.path().join("monitor/after_change.csv").exists());
        assert!(dir.path().join("monitor/monitor.csv").exists());
    }
}
