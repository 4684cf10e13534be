//! The inverse along a path in time (`handcap inverse MODEL --trajectory target.csv`): the
//! commands whose predicted outputs follow the path (the dynamic inverse), and from the
//! commands played and the outputs measured, the next repetition's (iterative learning
//! control). The commands file has [`super::inverse::planned_columns`] after the time.

use std::fmt;
use std::path::{Path, PathBuf};

use super::inverse::{planned_columns, Limits};
use super::outputs::{self, Output};
use super::PipelineError;
use crate::data::{self, Columns};
use crate::model::file::ModelFile;
use crate::model::interval::RowRadii;
use crate::model::trajectory::{self, Dynamic, PathPlan, PlanOptions};
use crate::model::Predict;
use crate::plot::{self, LinePlot, Mark, Series};

/// What a trajectory run is given.
pub struct Request<'a> {
    pub model: &'a Path,
    pub target: &'a Path,
    pub out: &'a Path,
    /// The commands played and the outputs measured meanwhile (learning).
    pub learn: Option<(&'a Path, &'a Path)>,
    /// The share of the measured error corrected per repetition, in (0, 1].
    pub gain: f64,
    /// Largest change of a `_kpa` input per unit of time (kPa/s).
    pub max_rate: f64,
    /// Weight of the commands' smoothness against the squared output error.
    pub smoothness: f64,
    pub limits: Limits,
    /// The level of the interval written around each planned output (`interval_radius`).
    pub level: Option<f64>,
}

/// What [`run`] planned.
pub struct Planned {
    /// The commands file written.
    pub out: PathBuf,
    pub rows: usize,
    pub how: How,
    /// Rows out of the model's reach at their times (flagged `reached` 0).
    pub missed: usize,
    /// The path figure's stem (`.svg`, `.png`).
    pub figure: PathBuf,
    /// The interval around each planned output, when asked and the model has one.
    pub interval: Option<RowRadii>,
    /// Why there is none, when asked.
    pub notes: Vec<String>,
}

/// How the commands were planned.
pub enum How {
    /// Along the path with the model's history (its memory named), against the pointwise
    /// inverse of the settled map played at the same times (tracking RMS of each).
    Anticipated {
        memory: String,
        rms: f64,
        pointwise_rms: f64,
    },
    /// Each row the pointwise inverse: a static model cannot anticipate the lag.
    Pointwise { rms: f64 },
    /// From a run measured (the measured file, its tracking RMS and largest error).
    Learned {
        measured: PathBuf,
        rms: f64,
        largest: f64,
        /// The share of the error corrected.
        gain: f64,
    },
}

impl Planned {
    /// Rows out of reach, when the plan has some (for a learning step: of the reference the
    /// model aims at, the target moved by the error measured).
    pub fn warning(&self) -> Option<String> {
        let what = match self.how {
            How::Learned { .. } => {
                " have their corrected reference (the target moved by the error measured)"
            }
            _ => " are",
        };
        (self.missed > 0).then(|| format!(
            "{} of {} rows{what} out of the model's reach within the box (or its lag) at their times: followed as closely as it allows, reached=0 in {}",
            self.missed,
            self.rows,
            self.out.display()
        ))
    }
}

impl fmt::Display for Planned {
    /// How the commands were planned and what was written.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let rows = self.rows;
        match &self.how {
            How::Anticipated { memory, rms, pointwise_rms } => writeln!(f,
                "planned {rows} rows along the path with the model's history ({memory}): predicted tracking RMS {rms:.4} (the pointwise inverse of the settled map, played at the same times: {pointwise_rms:.4})"
            ),
            How::Pointwise { rms } => writeln!(f,
                "planned {rows} rows, each the pointwise inverse (the model has no history: it cannot anticipate the actuator's lag); model error RMS {rms:.4}"
            ),
            How::Learned { measured, rms, largest, gain } => writeln!(f,
                "the run learned from ({}): tracking RMS {rms:.4}, largest {largest:.4} over {rows} rows; next commands planned with gain {gain}",
                measured.display(),
            ),
        }?;
        if let Some(interval) = &self.interval {
            writeln!(f, "{interval} (the interval_radius column)")?;
        }
        writeln!(
            f,
            "wrote {} and {}.svg/.png (the path: target, the model's prediction{})",
            self.out.display(),
            self.figure.display(),
            if matches!(self.how, How::Learned { .. }) {
                ", the run measured"
            } else {
                ""
            }
        )
    }
}

/// An input file that cannot be used.
fn refused(text: String) -> PipelineError {
    PipelineError::Input(text)
}

/// A file's time column and the columns `names`, rows in increasing time.
fn read_timed(
    path: &Path,
    time: &str,
    names: &[String],
) -> Result<(Vec<f64>, Columns), PipelineError> {
    let mut all = vec![time.to_string()];
    all.extend_from_slice(names);
    let (columns, lines) = data::read_columns_with_lines(path, &all)?;
    let t: Vec<f64> = columns.iter_rows().map(|r| r[0]).collect();
    if t.len() < 2 {
        return Err(refused(format!(
            "{}: {} rows; a trajectory needs 2 or more",
            path.display(),
            t.len()
        )));
    }
    if let Some(k) = (1..t.len()).find(|&k| t[k] <= t[k - 1]) {
        return Err(refused(format!(
            "{}: line {}: {time} {} does not increase (the row before has {}); give the rows in time order",
            path.display(),
            lines[k],
            t[k],
            t[k - 1]
        )));
    }
    let values = columns.iter_rows().flat_map(|r| r[1..].to_vec()).collect();
    Ok((t, Columns::new(names.to_vec(), values)))
}

/// `measured` (times `at`, rows of `q`) linearly interpolated at `time`; refused when its
/// times do not cover them (to within one of its own steps).
fn resample(
    path: &Path,
    at: &[f64],
    measured: &Columns,
    time: &[f64],
) -> Result<Vec<f64>, PipelineError> {
    let step = at
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min);
    let (first, last) = (at[0], at[at.len() - 1]);
    let (t0, t1) = (time[0], time[time.len() - 1]);
    if first > t0 + step || last < t1 - step {
        return Err(refused(format!(
            "{}: its rows run from {first} to {last}, the trajectory from {t0} to {t1}: give the outputs measured over the whole run (on the commands' clock)",
            path.display()
        )));
    }
    let q = measured.width();
    let mut out = Vec::with_capacity(time.len() * q);
    let mut j = 0;
    for &t in time {
        while j + 2 < at.len() && at[j + 1] < t {
            j += 1;
        }
        let w = ((t - at[j]) / (at[j + 1] - at[j])).clamp(0.0, 1.0);
        let (a, b) = (measured.row(j), measured.row(j + 1));
        out.extend((0..q).map(|o| a[o] + w * (b[o] - a[o])));
    }
    Ok(out)
}

/// Plans the commands along `r.target` (or learns them from a run), writes them to `r.out`
/// and the path figure beside it (`OUT_path.svg`/`.png`).
///
/// # Errors
/// An output that would replace an input, a gain outside (0, 1], an unreadable or unusable
/// model, target, commands or run file.
pub fn run(r: &Request) -> Result<Planned, PipelineError> {
    let figure = r.out.with_file_name(format!(
        "{}_path",
        r.out.file_stem().unwrap_or_default().to_string_lossy()
    ));
    check(r, &figure)?;
    let file = ModelFile::load(r.model)?;
    let steady = file.steady_state();
    let dynamic = Dynamic {
        model: file.model.differentiable(),
        history: file.history(),
    };
    let time_column = time_column(r.target, file.history().map(|h| h.time.as_str()))?;
    let time_column = time_column.as_str();
    let (names_in, names_out) = (steady.inputs().to_vec(), steady.outputs().to_vec());
    let (time, targets) = read_timed(r.target, time_column, &names_out)?;
    let rate = names_in
        .iter()
        .map(|n| match n.ends_with("_kpa") {
            true => r.max_rate,
            false => f64::INFINITY,
        })
        .collect();
    let options = PlanOptions {
        inverse: r.limits.options(&steady)?,
        rate: Some(rate),
        smoothness: r.smoothness,
        max_iter: 30,
    };
    let (plan, how, seen) = match r.learn {
        None => {
            let start = trajectory::pointwise(dynamic, &steady, &time, &targets.values, &options)?;
            let plan = trajectory::plan(dynamic, &time, &targets.values, &start, &options);
            let how = match file.history() {
                Some(h) => How::Anticipated {
                    memory: h.memory.to_string(),
                    rms: plan.rms(),
                    pointwise_rms: start.rms(),
                },
                None => How::Pointwise { rms: plan.rms() },
            };
            (plan, how, None)
        }
        Some((previous, measured)) => {
            let previous = read_previous(previous, time_column, &names_in, &time)?;
            let (t_run, run) = read_timed(measured, time_column, &names_out)?;
            let seen = resample(measured, &t_run, &run, &time)?;
            let errors = trajectory::distances(&seen, &targets.values, names_out.len());
            let plan = trajectory::learn(
                dynamic,
                &time,
                &targets.values,
                &previous.values,
                &seen,
                r.gain,
                &options,
            )?;
            let how = How::Learned {
                measured: measured.to_path_buf(),
                rms: trajectory::rms(&errors),
                largest: errors.iter().copied().fold(0.0, f64::max),
                gain: r.gain,
            };
            (plan, how, Some(seen))
        }
    };
    let mut notes = Vec::new();
    let features = Columns::new(
        file.model.predictor().inputs().to_vec(),
        plan.features.clone(),
    );
    let interval = super::inverse::radii_at(&file, &features, r.level, &mut notes);
    write(r.out, &steady, time_column, &time, &plan, interval.as_ref())?;
    path_figure(
        &figure,
        &names_out,
        &targets.values,
        &plan.predicted,
        seen.as_deref(),
    )?;
    Ok(Planned {
        out: r.out.to_path_buf(),
        rows: time.len(),
        how,
        missed: plan.reached.iter().filter(|&&r| !r).count(),
        figure,
        interval,
        notes,
    })
}

/// The target's time column: the model's (a history model's time column) when the file has
/// it, else `time_s` (the name every handcap file in time uses); the model's when neither is
/// there (the error then names it). The commands, and the runs learned from, use the same.
fn time_column(target: &Path, model: Option<&str>) -> Result<String, PipelineError> {
    let header = data::header(target)?;
    let has = |name: &str| header.iter().any(|h| h == name);
    Ok(match model {
        Some(name) if has(name) || !has("time_s") => name.to_string(),
        _ => "time_s".to_string(),
    })
}

/// The request's outputs against its inputs, and its gain.
fn check(r: &Request, figure: &Path) -> Result<(), PipelineError> {
    let mut inputs: Vec<&Path> = vec![r.model, r.target];
    if let Some((previous, measured)) = r.learn {
        inputs.extend([previous, measured]);
    }
    let mut written = vec![Output::new(r.out, "the commands")];
    written.extend(plot::line_plot_files(figure).map(|f| Output::new(f, "the path figure")));
    outputs::check(&inputs, &written)?;
    if !(r.gain > 0.0 && r.gain <= 1.0) {
        return Err(PipelineError::Request(format!(
            "gain={} must lie in (0, 1]",
            r.gain
        )));
    }
    if !(r.max_rate > 0.0 && r.smoothness >= 0.0) {
        return Err(PipelineError::Request(format!(
            "max_rate={} must be positive and smoothness={} 0 or more",
            r.max_rate, r.smoothness
        )));
    }
    Ok(())
}

/// The commands played in the previous repetition: the trajectory's rows, at its times.
fn read_previous(
    path: &Path,
    time_column: &str,
    inputs: &[String],
    time: &[f64],
) -> Result<Columns, PipelineError> {
    let (t_prev, previous) = read_timed(path, time_column, inputs)?;
    let same = |k: usize| {
        t_prev
            .get(k)
            .is_some_and(|t| (t - time[k]).abs() <= 1e-9 * time[k].abs().max(1.0))
    };
    if let Some(k) = (0..time.len()).find(|&k| !same(k)) {
        return Err(refused(format!(
            "{}: row {} ({}) is not the trajectory's row {} ({time_column} {}): give the commands planned for this trajectory",
            path.display(),
            k + 1,
            t_prev
                .get(k)
                .map_or("missing".to_string(), |t| format!("{time_column} {t}")),
            k + 1,
            time[k]
        )));
    }
    if t_prev.len() != time.len() {
        return Err(refused(format!(
            "{}: {} rows, the trajectory {}: give the commands planned for this trajectory",
            path.display(),
            t_prev.len(),
            time.len()
        )));
    }
    Ok(previous)
}

/// The path in the plane of the first two outputs: the target, the model's prediction along
/// the commands, and the run measured (learning).
fn path_figure(
    stem: &Path,
    outputs: &[String],
    targets: &[f64],
    predicted: &[f64],
    measured: Option<&[f64]>,
) -> Result<(), PipelineError> {
    let q = outputs.len();
    if q < 2 {
        return Ok(());
    }
    let points = |v: &[f64]| v.chunks(q).map(|r| (r[0], r[1])).collect();
    let mut series = vec![
        Series {
            label: "target".into(),
            points: points(targets),
            mark: Mark::Line,
            colour: plot::BLACK_INDEX,
        },
        Series {
            label: "model, along the commands written".into(),
            points: points(predicted),
            mark: Mark::Line,
            colour: 0,
        },
    ];
    if let Some(m) = measured {
        series.push(Series {
            label: "the run measured".into(),
            points: points(m),
            mark: Mark::Points,
            colour: 2,
        });
    }
    let plot = LinePlot {
        title: "The path".into(),
        x_label: outputs[0].clone(),
        y_label: outputs[1].clone(),
        series,
        log_y: false,
        x_names: Vec::new(),
    };
    plot::write_line_plot(stem, &plot)
        .map_err(|e| PipelineError::Place(format!("writing {}.svg: {e}", stem.display())))
}

/// The commands file: the time, then [`super::inverse::planned_columns`] along the path, then
/// each row's interval radius when there is one.
fn write(
    out: &Path,
    model: &dyn crate::model::Differentiable,
    time_column: &str,
    time: &[f64],
    plan: &PathPlan,
    interval: Option<&RowRadii>,
) -> Result<(), PipelineError> {
    let time = Columns::new(vec![time_column.to_string()], time.to_vec());
    let planned = planned_columns(
        model,
        plan.inputs.clone(),
        plan.predicted.clone(),
        &plan.error,
        &plan.reached,
    );
    let radius = interval.map(|i| Columns::new(vec!["interval_radius".into()], i.radii.clone()));
    let blocks: Vec<&Columns> = std::iter::once(&time)
        .chain(&planned)
        .chain(radius.as_ref())
        .collect();
    Ok(data::write_csv(out, &blocks)?)
}
