//! `handcap inverse model.json --target X,Y,Z` or `--targets targets.csv --out pressures.csv`:
//! the pressures that put the model's tip where it is wanted (feed-forward).

use std::path::PathBuf;

use anyhow::bail;

use super::usage;

use crate::model::file::ModelFile;
use crate::model::inverse::solve;
use crate::model::Differentiable;
use crate::pipeline::inverse::{self, Limits};
use crate::pipeline::trajectory::{self, How};

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("what").required(true).args(["target", "targets", "trajectory"])))]
pub struct Args {
    /// Model file written by `handcap model`
    model: PathBuf,
    /// One target, comma-separated in the model's output columns (e.g. x_mm,y_mm,z_mm)
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_parser = super::finite,
        conflicts_with = "targets"
    )]
    target: Option<Vec<f64>>,
    /// CSV of targets with the model's output columns
    #[arg(long, requires = "out")]
    targets: Option<PathBuf>,
    /// CSV of a path in time: the time column (the model's, or time_s) and the model's output
    /// columns; writes the commands (each held until the next row's time) that make the
    /// model's predicted outputs follow it, the finger starting at rest. A history model's are
    /// planned over the whole path, its lag anticipated
    #[arg(long, requires = "out", conflicts_with_all = ["target", "targets"])]
    trajectory: Option<PathBuf>,
    /// With --trajectory: the commands played in the previous repetition (a --trajectory
    /// output), for learning (with --measured)
    #[arg(long, requires = "trajectory")]
    previous: Option<PathBuf>,
    /// With --previous: the outputs measured while those commands played (the time column and
    /// the output columns, at any instants that cover the path, e.g. `triangulate
    /// --per-frame`'s rows on the commands' clock)
    #[arg(long, requires = "trajectory")]
    measured: Option<PathBuf>,
    /// Learning gain: the share of the measured error corrected per repetition
    #[arg(long, default_value_t = 0.5, value_parser = super::finite)]
    gain: f64,
    /// Largest change of a `_kpa` command per second along a trajectory (a regulator's slew)
    #[arg(long, default_value_t = 600.0, value_parser = super::finite)]
    max_rate: f64,
    /// Weight of the commands' smoothness along a trajectory (against the squared output error)
    #[arg(long, default_value_t = 0.1, value_parser = super::finite)]
    smoothness: f64,
    /// CSV to write: the targets, the inputs found, the model's outputs there, the error
    #[arg(long)]
    out: Option<PathBuf>,
    /// Upper bound of every `_kpa` input (never above the regulator's 300 kPa); inputs also stay
    /// inside the model's training range
    #[arg(long, default_value_t = 250.0)]
    max_kpa: f64,
    /// A target is reached when the model's output is this close (output units)
    #[arg(long, default_value_t = 0.01)]
    reach: f64,
    /// The coverage of the interval reported around each planned tip (conformal: the real
    /// tip lies within the radius this share of the time); 0 leaves it out
    #[arg(
        long,
        value_name = "LEVEL",
        default_value_t = 0.9,
        allow_hyphen_values = true,
        value_parser = interval_level
    )]
    interval: f64,
}

/// `--interval`: a level in (0, 1), or 0 for none.
fn interval_level(s: &str) -> Result<f64, String> {
    match super::finite(s)? {
        0.0 => Ok(0.0),
        _ => super::level(s),
    }
}

fn describe(names: &[String], values: &[f64]) -> String {
    names
        .iter()
        .zip(values)
        .map(|(n, v)| format!("{n} {v:.4}"))
        .collect::<Vec<_>>()
        .join(", ")
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let limits = Limits {
        max_kpa: a.max_kpa,
        reach: a.reach,
    };
    let level = (a.interval > 0.0).then_some(a.interval);
    match (&a.target, &a.targets, &a.trajectory) {
        (Some(target), None, None) => one_target(&a, target, limits, level),
        (None, Some(targets), None) => {
            let out = a.out.as_ref().expect("clap requires --out with --targets");
            let planned = inverse::plan_targets(&inverse::Targets {
                model: &a.model,
                targets,
                out,
                limits,
                level,
            })?;
            for note in &planned.notes {
                eprintln!("note: {note}");
            }
            let solutions = &planned.solutions;
            let missed = solutions.iter().filter(|s| !s.reached).count();
            let mean = solutions.iter().map(|s| s.error).sum::<f64>() / solutions.len() as f64;
            println!(
                "{} targets: {} reached within {}, {missed} out of reach (nearest points written); mean model error {mean:.5}",
                solutions.len(),
                solutions.len() - missed,
                a.reach
            );
            println!("wrote {}", out.display());
            Ok(())
        }
        (None, None, Some(target)) => along(&a, target, limits),
        _ => usage!("give --target X,Y,Z or --targets FILE.csv --out FILE.csv"),
    }
}

/// `--target X,Y,Z`: the inputs printed, or the nearest reachable point when out of reach.
fn one_target(a: &Args, target: &[f64], limits: Limits, level: Option<f64>) -> anyhow::Result<()> {
    let file = ModelFile::load(&a.model)?;
    let (steady, notes) = inverse::steady_state(&file);
    for note in notes {
        eprintln!("note: {note}");
    }
    let model: &dyn Differentiable = &steady;
    let options = limits.options(model)?;
    let s = solve(model, target, &options)?;
    if !s.reached {
        bail!(
            "target ({}) is out of reach within {}: the nearest reachable point is ({}), {:.4} away, at {}",
            describe(model.outputs(), target),
            inverse::bounds(model, &options),
            describe(model.outputs(), &s.achieved),
            s.error,
            describe(model.inputs(), &s.inputs)
        );
    }
    println!("{}", describe(model.inputs(), &s.inputs));
    println!(
        "model tip: {} (error {:.5})",
        describe(model.outputs(), &s.achieved),
        s.error
    );
    let mut notes = Vec::new();
    match (level, inverse::interval_radius(&file, level, &mut notes)) {
        (Some(level), Some(r)) => println!(
            "the real tip lies within {r:.4} of it {} % of the time (conformal interval, marginal over inputs like the held-out ones)",
            level * 100.0
        ),
        _ => notes.iter().for_each(|n| eprintln!("note: {n}")),
    }
    Ok(())
}

/// `--trajectory`: the dynamic inverse, or with `--previous` and `--measured` a repetition of
/// learning.
fn along(a: &Args, target: &std::path::Path, limits: Limits) -> anyhow::Result<()> {
    let learn = match (&a.previous, &a.measured) {
        (Some(p), Some(m)) => Some((p.as_path(), m.as_path())),
        (None, None) => None,
        _ => usage!("--previous and --measured go together: the commands played and the outputs measured while they were"),
    };
    let out = a
        .out
        .as_ref()
        .expect("clap requires --out with --trajectory");
    let planned = trajectory::run(&trajectory::Request {
        model: &a.model,
        target,
        out,
        learn,
        gain: a.gain,
        max_rate: a.max_rate,
        smoothness: a.smoothness,
        limits,
    })?;
    let rows = planned.rows;
    match &planned.how {
        How::Anticipated { memory, rms, pointwise_rms } => println!(
            "planned {rows} rows along the path with the model's history ({memory}): predicted tracking RMS {rms:.4} (the pointwise inverse of the settled map, played at the same times: {pointwise_rms:.4})"
        ),
        How::Pointwise { rms } => println!(
            "planned {rows} rows, each the pointwise inverse (the model has no history: it cannot anticipate the actuator's lag); model error RMS {rms:.4}"
        ),
        How::Learned { measured, rms, largest } => println!(
            "the run learned from ({}): tracking RMS {rms:.4}, largest {largest:.4} over {rows} rows; next commands planned with gain {}",
            measured.display(),
            a.gain
        ),
    }
    let learned = matches!(planned.how, How::Learned { .. });
    if planned.missed > 0 && !learned {
        eprintln!(
            "warning: {} of {rows} rows are out of the model's reach within the box (or its lag) at their times: followed as closely as it allows, reached=0 in {}",
            planned.missed,
            out.display()
        );
    }
    println!(
        "wrote {} and {}.svg/.png (the path: target, the model's prediction{})",
        out.display(),
        planned.figure.display(),
        if learned { ", the run measured" } else { "" }
    );
    Ok(())
}
