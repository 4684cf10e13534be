//! The monitor stage: a triangulated session replayed in time order against a fitted model —
//! the model's prediction, the measured tip, the error, the online band and the alarms
//! ([`crate::monitor`]) — written as `monitor.csv`, `monitor.json` and a figure, and, after a
//! model alarm, the rows from the change on (`after_change.csv`, to refit the model on).

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::outputs::{self, Output};
use super::PipelineError;
use crate::data::{self, Columns, Csv};
use crate::model::file::ModelFile;
use crate::model::interval::percent;
use crate::monitor::{self, Channel, Monitored, Settings};
use crate::plot::{self, LinePlot, Mark, Series};
use crate::provenance::Provenance;

/// The column of the tips' reprojection residual (px) `triangulate` writes, read when present.
pub const RESIDUAL_COLUMN: &str = "reproj_px";

/// A camera's still-scene column `triangulate --per-frame` writes, `scene_<camera>_px` (how
/// far its view of the still scene lay from the session's first frame's), read when present.
const SCENE_COLUMN: (&str, &str) = ("scene_", "_px");

/// Camera `camera`'s still-scene column ([`SCENE_COLUMN`]).
pub fn scene_column(camera: &str) -> String {
    format!("{}{camera}{}", SCENE_COLUMN.0, SCENE_COLUMN.1)
}

/// What to watch.
pub struct Watch<'a> {
    pub session: &'a Path,
    pub model: &'a Path,
    pub out: &'a Path,
    /// The time column; the model's own when it has input history.
    pub time: Option<&'a str>,
    pub settings: Settings,
}

/// What [`run`] found and wrote.
#[derive(Serialize)]
pub struct Watched {
    pub session: PathBuf,
    pub model: PathBuf,
    pub settings: Settings,
    pub rows: usize,
    /// From the first row's time to the last's (s): within `settings.baseline_s`, no alarm
    /// was armed.
    pub span_s: f64,
    #[serde(flatten)]
    pub monitored: Monitored,
    /// The rows from the first model alarm's change on, when one was raised.
    pub after_change: Option<PathBuf>,
    pub provenance: Provenance,
    #[serde(skip)]
    pub out: PathBuf,
    /// Live (`capture --model`): the frames the monitor skipped while it was behind, per
    /// camera.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skipped: Option<[usize; 2]>,
}

/// Replays `watch.session` against `watch.model` and writes into `watch.out`.
///
/// # Errors
/// Unreadable files, a model without intervals, a session without the model's columns or a
/// time column, settings out of range.
pub fn run(watch: &Watch, provenance: Provenance) -> Result<Watched, PipelineError> {
    watch.settings.check().map_err(PipelineError::Request)?;
    let names = [
        "monitor.csv",
        "monitor.json",
        AFTER_CHANGE,
        "monitor.png",
        "monitor.svg",
        "monitor.md",
    ];
    let files: Vec<Output> = names
        .iter()
        .map(|n| Output::new(watch.out.join(n), "the monitor's output"))
        .collect();
    outputs::check(&[watch.session, watch.model], &files)?;
    let replay = Replay::read(watch)?;
    // The files watched, by their hashes, as every other output names its inputs.
    let mut provenance = provenance;
    for path in [watch.session, watch.model] {
        provenance = provenance.with_input(path).map_err(super::io_error(path))?;
    }
    // The band follows the errors over their rows' widening factors, as the radius was
    // calibrated.
    let widened: Vec<f64> = (replay.errors.iter().zip(&replay.factors))
        .map(|(e, d)| e / d)
        .collect();
    let errors = monitor::Series {
        times: &replay.times,
        values: &widened,
    };
    let geometry = replay
        .geometry
        .as_ref()
        .map(|(times, values)| monitor::Series { times, values });
    let outputs = monitor::Outputs {
        predicted: &replay.predicted.values,
        measured: &replay.measured.values,
        rest: &replay.rest,
    };
    let scene: Vec<monitor::Scene> = replay
        .scene
        .iter()
        .map(|(camera, (times, values))| (camera.as_str(), monitor::Series { times, values }))
        .collect();
    let monitored = monitor::watch(
        errors,
        geometry,
        &scene,
        Some(outputs),
        replay.radius,
        &watch.settings,
    );
    let misfit = monitored
        .baseline_median_px
        .and_then(|r| monitor::misfit(r, watch.settings.baseline_s));
    if let Some(line) = misfit {
        return Err(PipelineError::Input(format!(
            "{}: {line}",
            watch.session.display()
        )));
    }
    std::fs::create_dir_all(watch.out).map_err(super::io_error(watch.out))?;
    let after_change = after_change(watch, &replay.time, &monitored)?;
    let watched = Watched {
        session: watch.session.to_path_buf(),
        model: watch.model.to_path_buf(),
        settings: watch.settings.clone(),
        rows: replay.times.len(),
        span_s: span(&replay.times),
        monitored,
        after_change,
        provenance,
        out: watch.out.to_path_buf(),
        skipped: None,
    };
    write(&replay, &watched)?;
    Ok(watched)
}

/// Writes `watched` (the rows of `replay`) into its directory, made if need be: `monitor.csv`,
/// the figure and `monitor.json`.
///
/// # Errors
/// A file that cannot be written.
pub fn write(replay: &Replay, watched: &Watched) -> Result<(), PipelineError> {
    let out = &watched.out;
    std::fs::create_dir_all(out).map_err(super::io_error(out))?;
    let monitored = &watched.monitored;
    replay.write(&out.join("monitor.csv"), monitored)?;
    write_figure(
        &out.join("monitor"),
        replay,
        monitored,
        watched.settings.level,
    )?;
    let path = out.join("monitor.md");
    crate::fsio::write_bytes(&path, section(watched).as_bytes()).map_err(super::io_error(&path))?;
    let json = serde_json::to_vec_pretty(watched).expect("the monitor's summary serialises");
    let path = out.join("monitor.json");
    crate::fsio::write_bytes(&path, &json).map_err(super::io_error(&path))
}

/// `monitor.md`: the session watched as a section of a report: what was watched, the band's
/// coverage, each channel's reference, the alarms and the figure.
fn section(watched: &Watched) -> String {
    let (m, settings) = (&watched.monitored, &watched.settings);
    let mut md = format!(
        "## The session watched\n\n`{}` against `{}`: {} rows; the online {} % band held {:.1} % of them (it started at the model's radius {:.4}). A look every {} s; the first {} s the baseline; at most one false alarm per {} h of looks.\n\n",
        watched.session.display(),
        watched.model.display(),
        watched.rows,
        percent(settings.level),
        100.0 * m.coverage,
        m.start_radius,
        settings.look_s,
        settings.baseline_s,
        settings.false_alarm_hours,
    );
    md.push_str("| channel | reference |\n|---|---|\n");
    md.push_str(&format!(
        "| finger (the model's error) | {:.4} |\n",
        m.model_reference
    ));
    let px = |r: Option<f64>| r.map_or("none (no baseline)".to_string(), |r| format!("{r:.3} px"));
    if m.baseline_median_px.is_some() {
        md.push_str(&format!(
            "| camera (the beads' residual) | {} |\n",
            px(m.geometry_reference_px)
        ));
    }
    for (camera, reference) in &m.scene_references_px {
        md.push_str(&format!(
            "| camera (the still scene, {camera}) | {} |\n",
            px(*reference)
        ));
    }
    if m.alarms.is_empty() {
        md.push_str("\nNo alarm.\n");
    } else {
        md.push_str(
            "\n| alarm | raised (s) | the change began (s) | what to do |\n|---|---|---|---|\n",
        );
        for a in &m.alarms {
            let camera = a
                .camera
                .as_ref()
                .map_or_else(String::new, |c| format!(" ({c})"));
            md.push_str(&format!(
                "| {}{camera} | {:.1} | {:.1} | {} |\n",
                a.channel.name(),
                a.time_s,
                a.change_s,
                a.advice
            ));
        }
    }
    if let Some(path) = &watched.after_change {
        md.push_str(&format!(
            "\nThe rows from the change on: `{}`.\n",
            path.display()
        ));
    }
    md.push_str(
        "\n![The model's error, the band and the alarms as the session ran](monitor.png)\n",
    );
    md
}

/// Times and values of one channel.
pub type Samples = (Vec<f64>, Vec<f64>);

/// Per camera (its name), its still-scene channel.
pub type SceneSamples = Vec<(String, Samples)>;

/// A session's rows as the monitor replays them.
pub struct Replay {
    /// The time column's name, and its values.
    pub time: String,
    pub times: Vec<f64>,
    pub predicted: Columns,
    pub measured: Columns,
    /// The distance from each prediction to its measured tip.
    pub errors: Vec<f64>,
    /// Each row's widening factor of the radius (1 where the model's radius is the same
    /// everywhere): the band around a row is the online band times it.
    pub factors: Vec<f64>,
    /// Every row's time and reprojection residual (px; +∞ where the views disagreed), when
    /// the rows have residuals.
    pub geometry: Option<Samples>,
    /// Per camera (its name), the rows' times and how far its view of the still scene lay
    /// from the session's first frame's (px), where the rows have that.
    pub scene: SceneSamples,
    /// The model file's radius at the level, and its outputs at rest.
    pub radius: f64,
    pub rest: Vec<f64>,
}

impl Replay {
    fn read(watch: &Watch) -> Result<Replay, PipelineError> {
        let file = ModelFile::load(watch.model)?;
        let radius = file.interval_radius(watch.settings.level).map_err(|e| {
            PipelineError::Input(format!("{}: interval: {e}", watch.model.display()))
        })?;
        let predictor = file.model.predictor();
        let (_, x) = file.read_inputs(watch.session)?;
        if x.rows() == 0 {
            return Err(data::DataError::NoRows {
                path: watch.session.into(),
                what: "the monitor".into(),
            }
            .into());
        }
        let predicted = predictor.predict(&x)?;
        let factors = file
            .interval_widener()
            .map_err(|e| PipelineError::Input(format!("{}: {e}", watch.model.display())))?
            .map_or_else(|| vec![1.0; x.rows()], |w| w.factors(&x));
        let measured = data::read_columns(watch.session, predictor.outputs())?;
        let time = match (watch.time, file.history()) {
            (Some(t), _) => t.to_string(),
            (None, Some(h)) => h.time.clone(),
            (None, None) => "time_s".to_string(),
        };
        let times: Vec<f64> = data::read_columns(watch.session, std::slice::from_ref(&time))
            .map_err(|e| {
                PipelineError::Input(format!("{e}; name the session's time column with --time"))
            })?
            .column(0)
            .collect();
        if let Some(k) = times.windows(2).position(|w| w[1] < w[0]) {
            return Err(PipelineError::Input(format!(
                "{}: {time} goes back at data row {} ({} after {}); the monitor replays rows in time order: sort the file by {time}",
                watch.session.display(),
                k + 2,
                times[k + 1],
                times[k]
            )));
        }
        let errors: Vec<f64> = (0..x.rows())
            .map(|i| {
                let (p, m) = (predicted.row(i), measured.row(i));
                p.iter()
                    .zip(m)
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .collect();
        let (geometry, scene) = geometry(watch.session, &time)?;
        Ok(Replay {
            time,
            times,
            predicted,
            measured,
            errors,
            factors,
            geometry,
            scene,
            radius,
            rest: file.at_rest(),
        })
    }

    /// The value of `samples` at model row `i`'s time, when it has one then (a still scene is
    /// measured on one row in six).
    fn at(&self, samples: &Samples, i: usize) -> Option<f64> {
        let (times, values) = samples;
        let k = times.partition_point(|&t| t < self.times[i]);
        (times.get(k) == Some(&self.times[i])).then(|| values[k])
    }

    /// `monitor.csv`: each row's time, prediction, measured tip, error, band, statistics and
    /// alarm.
    fn write(&self, path: &Path, monitored: &Monitored) -> Result<(), PipelineError> {
        let outputs = &self.measured.names;
        let mut csv = Csv::new(
            std::iter::once(self.time.clone())
                .chain(outputs.iter().map(|o| format!("predicted_{o}")))
                .chain(outputs.iter().cloned())
                .chain(
                    [
                        "error",
                        "band",
                        "covered",
                        "model_cusum",
                        "response_cusum",
                        RESIDUAL_COLUMN,
                        "geometry_cusum",
                    ]
                    .map(String::from),
                )
                .chain(self.scene.iter().map(|(camera, _)| scene_column(camera)))
                .chain(["alarm".to_string()]),
        );
        let number = data::format_number;
        for (i, row) in monitored.rows.iter().enumerate() {
            let mut record = vec![number(self.times[i])];
            record.extend(self.predicted.row(i).iter().map(|&v| number(v)));
            record.extend(self.measured.row(i).iter().map(|&v| number(v)));
            record.extend([
                number(self.errors[i]),
                number(row.band * self.factors[i]),
                u8::from(row.covered).to_string(),
                number(row.model_stat),
                row.response_stat.map_or_else(String::new, number),
                (self.geometry.as_ref())
                    .and_then(|g| self.at(g, i))
                    .map_or_else(String::new, number),
                row.geometry_stat.map_or_else(String::new, number),
            ]);
            record.extend(
                (self.scene.iter()).map(|(_, s)| self.at(s, i).map_or_else(String::new, number)),
            );
            record.push(row.alarm.map_or_else(String::new, |c| c.name().to_string()));
            csv.row(record);
        }
        Ok(csv.write(path)?)
    }
}

/// Every row's time and reprojection residual, flagged rows too: a row the triangulation
/// refused because its views disagree (`reprojection`) is +∞, a miss of the camera channel;
/// rows flagged for anything else say nothing of the cameras (`None` without a
/// [`RESIDUAL_COLUMN`]). And each camera's still-scene column ([`SCENE_COLUMN`]), its rows
/// with a value, whatever their flags.
fn geometry(path: &Path, time: &str) -> Result<(Option<Samples>, SceneSamples), PipelineError> {
    let table = data::Table::open(path, "a time column and reproj_px")?;
    let residual = table.column(RESIDUAL_COLUMN).ok();
    let (prefix, suffix) = SCENE_COLUMN;
    let scene: Vec<(usize, String)> = (table.header.iter().enumerate())
        .filter_map(|(k, name)| {
            let camera = name.strip_prefix(prefix)?.strip_suffix(suffix)?;
            (!camera.is_empty()).then(|| (k, camera.to_string()))
        })
        .collect();
    if residual.is_none() && scene.is_empty() {
        return Ok((None, Vec::new()));
    }
    let at = table.column(time)?;
    let flag = table.column("flag").ok();
    let mut residuals: Samples = (Vec::new(), Vec::new());
    let mut scenes: Vec<Samples> = vec![(Vec::new(), Vec::new()); scene.len()];
    for (line, record) in table.records()? {
        let number = |k: usize| record.get(k).and_then(|c| c.parse::<f64>().ok());
        let Some(t) = number(at) else {
            return table.fail(line, format!("{time} is not a number"));
        };
        let flags = flag.and_then(|k| record.get(k)).unwrap_or("");
        let value = if flags.split(';').any(|f| f == monitor::DISAGREED) {
            Some(f64::INFINITY)
        } else {
            residual.and_then(number).filter(|r| r.is_finite())
        };
        if let Some(value) = value {
            residuals.0.push(t);
            residuals.1.push(value);
        }
        for ((k, _), samples) in scene.iter().zip(&mut scenes) {
            if let Some(px) = number(*k).filter(|v| v.is_finite()) {
                samples.0.push(t);
                samples.1.push(px);
            }
        }
    }
    let cameras = scene.into_iter().map(|(_, camera)| camera);
    Ok((residual.map(|_| residuals), cameras.zip(scenes).collect()))
}

/// The file of the rows from the finger's change on.
pub const AFTER_CHANGE: &str = "after_change.csv";

/// When the finger changed, by its alarm (none: the finger did not alarm).
pub fn change_s(monitored: &Monitored) -> Option<f64> {
    monitored
        .alarms
        .iter()
        .find(|a| a.channel == Channel::Finger)
        .map(|a| a.change_s)
}

/// After a model alarm, `after_change.csv`: the session's rows from the change on, as they
/// were; without one, no such file (a previous run's would pass for this one's).
fn after_change(
    watch: &Watch,
    time: &str,
    monitored: &Monitored,
) -> Result<Option<PathBuf>, PipelineError> {
    let path = watch.out.join(AFTER_CHANGE);
    match change_s(monitored) {
        Some(change) => {
            data::copy_rows(watch.session, &path, &[time.to_string()], |t| {
                t[0] >= change
            })?;
            Ok(Some(path))
        }
        None => match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(super::io_error(&path)(e)),
            _ => Ok(None),
        },
    }
}

/// The errors, the band and the alarms over time.
fn write_figure(
    stem: &Path,
    replay: &Replay,
    monitored: &Monitored,
    level: f64,
) -> Result<(), PipelineError> {
    let (times, errors) = (&replay.times, &replay.errors);
    let at = |f: &dyn Fn(usize) -> f64| -> Vec<(f64, f64)> {
        (0..times.len()).map(|i| (times[i], f(i))).collect()
    };
    let top = errors
        .iter()
        .copied()
        .fold(monitored.start_radius, f64::max);
    let series = vec![
        Series {
            label: "error (prediction to measured tip)".into(),
            points: at(&|i| errors[i]),
            mark: Mark::Points,
            colour: 0,
        },
        Series {
            label: format!("online band ({} %)", percent(level)),
            points: at(&|i| monitored.rows[i].band * replay.factors[i]),
            mark: Mark::Line,
            colour: 1,
        },
        Series {
            label: "alarm".into(),
            points: monitored.alarms.iter().map(|a| (a.time_s, top)).collect(),
            mark: Mark::Points,
            colour: 3,
        },
    ];
    let figure = LinePlot {
        title: "The model's error as the session ran".into(),
        x_label: "time (s)".into(),
        y_label: "distance (output units)".into(),
        series,
        log_y: false,
        x_names: Vec::new(),
    };
    plot::write_line_plot(stem, &figure).map_err(|e| PipelineError::Report(e.into()))
}

/// From the first of `times` (rising) to the last, 0 for none.
pub fn span(times: &[f64]) -> f64 {
    match (times.first(), times.last()) {
        (Some(first), Some(last)) => last - first,
        _ => 0.0,
    }
}

impl std::fmt::Display for Watched {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        let m = &self.monitored;
        writeln!(
            f,
            "{} rows; the online {} % band held {:.1} % of them (it started at the model's radius {:.4})",
            self.rows,
            percent(self.settings.level),
            100.0 * m.coverage,
            m.start_radius
        )?;
        if self.span_s <= self.settings.baseline_s {
            writeln!(
                f,
                "warning: the session lasts {:.1} s, within the baseline of {} s: no alarm could be raised; give --baseline-s shorter than the session",
                self.span_s, self.settings.baseline_s
            )?;
        } else if m.alarms.is_empty() {
            writeln!(
                f,
                "no alarm (at most one false alarm per {} h of looks)",
                self.settings.false_alarm_hours
            )?;
        }
        for a in &m.alarms {
            writeln!(f, "{a}")?;
        }
        if let Some(path) = &self.after_change {
            writeln!(f, "the rows from the change on: {}", path.display())?;
        }
        write!(f, "wrote {}", self.out.join("monitor.csv").display())
    }
}
