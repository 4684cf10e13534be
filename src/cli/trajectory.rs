//! `handcap inverse MODEL --trajectory target.csv --out commands.csv`: commands along a path
//! (the dynamic inverse), and with `--previous commands.csv --measured run.csv` the next
//! repetition's (iterative learning control).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use super::usage;
use crate::data::{self, Columns};
use crate::model::file::ModelFile;
use crate::model::inverse::InverseOptions;
use crate::model::trajectory::{self, Dynamic, PathPlan, PlanOptions};
use crate::model::Predict;
use crate::pipeline::outputs::{self, Output};
use crate::plot::{self, LinePlot, Mark, Series};

/// What a trajectory run was given.
pub struct Request<'a> {
    pub model: &'a Path,
    pub target: &'a Path,
    pub out: &'a Path,
    /// The commands played and the outputs measured meanwhile (learning).
    pub learn: Option<(&'a Path, &'a Path)>,
    pub gain: f64,
    /// Largest change of a `_kpa` input per unit of time (kPa/s).
    pub max_rate: f64,
    pub smoothness: f64,
}

/// A file's time column and the columns `names`, rows in increasing time.
fn read_timed(path: &Path, time: &str, names: &[String]) -> anyhow::Result<(Vec<f64>, Columns)> {
    let mut all = vec![time.to_string()];
    all.extend_from_slice(names);
    let (columns, lines) = data::read_columns_with_lines(path, &all)?;
    let t: Vec<f64> = columns.iter_rows().map(|r| r[0]).collect();
    if t.len() < 2 {
        bail!(
            "{}: {} rows; a trajectory needs 2 or more",
            path.display(),
            t.len()
        );
    }
    if let Some(k) = (1..t.len()).find(|&k| t[k] <= t[k - 1]) {
        bail!(
            "{}: line {}: {time} {} does not increase (the row before has {}); give the rows in time order",
            path.display(),
            lines[k],
            t[k],
            t[k - 1]
        );
    }
    let values = columns.iter_rows().flat_map(|r| r[1..].to_vec()).collect();
    Ok((t, Columns::new(names.to_vec(), values)))
}

/// `measured` (times `at`, rows of `q`) linearly interpolated at `time`; refused when its
/// times do not cover them (to within one of its own steps).
fn resample(path: &Path, at: &[f64], measured: &Columns, time: &[f64]) -> anyhow::Result<Vec<f64>> {
    let step = at
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min);
    let (first, last) = (at[0], at[at.len() - 1]);
    let (t0, t1) = (time[0], time[time.len() - 1]);
    if first > t0 + step || last < t1 - step {
        bail!(
            "{}: its rows run from {first} to {last}, the trajectory from {t0} to {t1}: give the outputs measured over the whole run (on the commands' clock)",
            path.display()
        );
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

pub fn run(r: &Request, file: &ModelFile, options: InverseOptions) -> anyhow::Result<()> {
    let mut inputs: Vec<&Path> = vec![r.model, r.target];
    if let Some((previous, measured)) = r.learn {
        inputs.extend([previous, measured]);
    }
    let figure = r.out.with_file_name(format!(
        "{}_path",
        r.out.file_stem().unwrap_or_default().to_string_lossy()
    ));
    let mut written = vec![Output::new(r.out, "--out")];
    written.extend(plot::line_plot_files(&figure).map(|f| Output::new(f, "the path figure")));
    outputs::check(&inputs, &written)?;
    if !(r.gain > 0.0 && r.gain <= 1.0) {
        usage!("--gain {} must lie in (0, 1]", r.gain);
    }
    let steady = file.steady_state();
    let dynamic = Dynamic {
        model: file.model.differentiable(),
        history: file.history(),
    };
    let time_column = file.history().map_or("time_s", |h| h.time.as_str());
    let (names_in, names_out) = (steady.inputs().to_vec(), steady.outputs().to_vec());
    let (time, targets) = read_timed(r.target, time_column, &names_out)?;
    let rate = names_in
        .iter()
        .map(|n| {
            if n.ends_with("_kpa") {
                r.max_rate
            } else {
                f64::INFINITY
            }
        })
        .collect();
    let options = PlanOptions {
        inverse: options,
        rate: Some(rate),
        smoothness: r.smoothness,
        max_iter: 30,
    };
    let mut seen = None;
    let plan = match r.learn {
        None => {
            let start = trajectory::pointwise(dynamic, &steady, &time, &targets.values, &options)?;
            let plan = trajectory::plan(dynamic, &time, &targets.values, &start, &options);
            match file.history() {
                Some(h) => println!(
                    "planned {} rows along the path with the model's history ({}): predicted tracking RMS {:.4} (the pointwise inverse of the settled map, played at the same times: {:.4})",
                    time.len(),
                    h.memory,
                    plan.rms(),
                    start.rms()
                ),
                None => println!(
                    "planned {} rows, each the pointwise inverse (the model has no history: it cannot anticipate the actuator's lag); model error RMS {:.4}",
                    time.len(),
                    plan.rms()
                ),
            }
            plan
        }
        Some((previous_path, measured_path)) => {
            let (t_prev, previous) = read_timed(previous_path, time_column, &names_in)?;
            if let Some(k) = (0..time.len()).find(|&k| {
                t_prev
                    .get(k)
                    .is_none_or(|t| (t - time[k]).abs() > 1e-9 * time[k].abs().max(1.0))
            }) {
                bail!(
                    "{}: row {} ({}) is not the trajectory's row {} ({} {}): give the commands planned for this trajectory",
                    previous_path.display(),
                    k + 1,
                    t_prev.get(k).map_or("missing".to_string(), |t| format!("{time_column} {t}")),
                    k + 1,
                    time_column,
                    time[k]
                );
            }
            if t_prev.len() != time.len() {
                bail!(
                    "{}: {} rows, the trajectory {}: give the commands planned for this trajectory",
                    previous_path.display(),
                    t_prev.len(),
                    time.len()
                );
            }
            let (t_run, run) = read_timed(measured_path, time_column, &names_out)?;
            let measured = resample(measured_path, &t_run, &run, &time)?;
            let errors = trajectory::distances(&measured, &targets.values, names_out.len());
            let plan = trajectory::learn(
                dynamic,
                &time,
                &targets.values,
                &previous.values,
                &measured,
                r.gain,
                &options,
            );
            println!(
                "the run learned from ({}): tracking RMS {:.4}, largest {:.4} over {} rows; next commands planned with gain {}",
                measured_path.display(),
                trajectory::rms(&errors),
                errors.iter().copied().fold(0.0, f64::max),
                time.len(),
                r.gain
            );
            seen = Some(measured);
            plan
        }
    };
    let missed = plan.reached.iter().filter(|&&r| !r).count();
    if missed > 0 && r.learn.is_none() {
        eprintln!(
            "warning: {missed} of {} rows are out of the model's reach within the box (or its lag) at their times: followed as closely as it allows, reached=0 in {}",
            time.len(),
            r.out.display()
        );
    }
    write(r.out, time_column, &time, &names_in, &names_out, &plan)
        .with_context(|| format!("writing {}", r.out.display()))?;
    path_figure(
        &figure,
        &names_out,
        &targets.values,
        &plan.predicted,
        seen.as_deref(),
    )?;
    println!(
        "wrote {} and {}.svg/.png (the path: target, the model's prediction{})",
        r.out.display(),
        figure.display(),
        if seen.is_some() {
            ", the run measured"
        } else {
            ""
        }
    );
    Ok(())
}

/// The path in the plane of the first two outputs: the target, the model's prediction along
/// the commands, and the run measured (learning).
fn path_figure(
    stem: &Path,
    outputs: &[String],
    targets: &[f64],
    predicted: &[f64],
    measured: Option<&[f64]>,
) -> anyhow::Result<()> {
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
    plot::write_line_plot(stem, &plot).with_context(|| format!("writing {}.svg", stem.display()))
}

/// The commands file: time, the inputs, the model's outputs along them, the error and reach.
fn write(
    out: &Path,
    time_column: &str,
    time: &[f64],
    inputs: &[String],
    outputs: &[String],
    plan: &PathPlan,
) -> anyhow::Result<()> {
    let time = Columns::new(vec![time_column.to_string()], time.to_vec());
    let commands = Columns::new(inputs.to_vec(), plan.inputs.clone());
    let predicted = Columns::new(
        outputs.iter().map(|n| format!("{n}_model")).collect(),
        plan.predicted.clone(),
    );
    let verdict = Columns::new(
        vec!["error".into(), "reached".into()],
        plan.error
            .iter()
            .zip(&plan.reached)
            .flat_map(|(&e, &r)| [e, f64::from(u8::from(r))])
            .collect(),
    );
    Ok(data::write_csv(
        out,
        &[&time, &commands, &predicted, &verdict],
    )?)
}

/// The paths of a `--trajectory` request, from the flags.
pub fn paths(
    previous: &Option<PathBuf>,
    measured: &Option<PathBuf>,
) -> anyhow::Result<Option<(PathBuf, PathBuf)>> {
    match (previous, measured) {
        (Some(p), Some(m)) => Ok(Some((p.clone(), m.clone()))),
        (None, None) => Ok(None),
        _ => usage!("--previous and --measured go together: the commands played and the outputs measured while they were"),
    }
}
