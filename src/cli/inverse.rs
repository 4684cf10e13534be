//! `handcap inverse model.json --target X,Y,Z` or `--targets targets.csv --out pressures.csv`:
//! the pressures that put the model's tip where it is wanted (feed-forward).

use std::path::PathBuf;

use anyhow::{bail, Context};

use super::usage;

use crate::data::{self, Columns};
use crate::hand::MAX_PRESSURE_KPA;
use crate::model::file::ModelFile;
use crate::model::inverse::{self, InverseOptions, InverseSolution};
use crate::model::Differentiable;
use crate::pipeline::outputs::{self, Output};

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

fn options(model: &dyn Differentiable, a: &Args) -> anyhow::Result<InverseOptions> {
    if !(a.max_kpa > 0.0 && a.max_kpa <= MAX_PRESSURE_KPA) {
        usage!(
            "--max-kpa {} must lie in (0, {MAX_PRESSURE_KPA}]: the regulator caps the supply",
            a.max_kpa
        );
    }
    if a.reach.is_nan() || a.reach <= 0.0 {
        usage!("--reach must be positive");
    }
    let cap = |name: &str| name.ends_with("_kpa").then_some((0.0, a.max_kpa));
    Ok(InverseOptions {
        reach: a.reach,
        ..InverseOptions::within_training_range(model, cap)
    })
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
    if let Some(target) = &a.trajectory {
        return run_trajectory(&a, target);
    }
    let file = ModelFile::load(&a.model)?;
    let steady = file.steady_state();
    let model: &dyn Differentiable = &steady;
    if let Some(h) = file.history() {
        eprintln!(
            "note: the model sees the inputs' history ({}); the inputs found hold the tip there once settled (every filter equal to the input)",
            h.memory
        );
    }
    let options = options(model, &a)?;
    // The radius at the planned inputs: a conformal radius is the same for every input.
    let radius = match a.interval {
        0.0 => None,
        level => match file.interval_radius(level) {
            Ok(r) => Some((level, r)),
            Err(e) => {
                eprintln!("note: no interval around the planned tips: {e}");
                None
            }
        },
    };
    match (&a.target, &a.targets) {
        (Some(target), None) => {
            let s = inverse::solve(model, target, &options)?;
            if !s.reached {
                bail!(
                    "target ({}) is out of reach within {}: the nearest reachable point is ({}), {:.4} away, at {}",
                    describe(model.outputs(), target),
                    bounds(model, &options),
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
            if let Some((level, r)) = radius {
                println!(
                    "the real tip lies within {r:.4} of it {} % of the time (conformal interval, marginal over inputs like the held-out ones)",
                    level * 100.0
                );
            }
            Ok(())
        }
        (None, Some(path)) => {
            let out = a.out.as_ref().expect("clap requires --out with --targets");
            outputs::check(&[&a.model, path], &[Output::new(out, "--out")])?;
            let targets = data::read_columns(path, model.outputs())?;
            let solutions: Vec<InverseSolution> = targets
                .iter_rows()
                .map(|t| inverse::solve(model, t, &options))
                .collect::<Result<_, _>>()?;
            write_solutions(out, model, &targets, &solutions, radius.map(|(_, r)| r))?;
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
        _ => usage!("give --target X,Y,Z or --targets FILE.csv --out FILE.csv"),
    }
}

/// `--trajectory`: the dynamic inverse, or with `--previous` and `--measured` a repetition of
/// learning.
fn run_trajectory(a: &Args, target: &std::path::Path) -> anyhow::Result<()> {
    let learn = super::trajectory::paths(&a.previous, &a.measured)?;
    if a.max_rate <= 0.0 || a.smoothness < 0.0 {
        usage!("--max-rate must be positive and --smoothness 0 or more");
    }
    let file = ModelFile::load(&a.model)?;
    let options = options(&file.steady_state(), a)?;
    let out = a
        .out
        .as_ref()
        .expect("clap requires --out with --trajectory");
    let request = super::trajectory::Request {
        model: &a.model,
        target,
        out,
        learn: learn.as_ref().map(|(p, m)| (p.as_path(), m.as_path())),
        gain: a.gain,
        max_rate: a.max_rate,
        smoothness: a.smoothness,
    };
    super::trajectory::run(&request, &file, options)
}

/// The box, e.g. "P1_kpa 0-250, P2_kpa 0-250, P3_kpa 0-250".
fn bounds(model: &dyn Differentiable, o: &InverseOptions) -> String {
    model
        .inputs()
        .iter()
        .enumerate()
        .map(|(j, n)| format!("{n} {}-{}", o.lower[j], o.upper[j]))
        .collect::<Vec<_>>()
        .join(", ")
}

fn write_solutions(
    out: &std::path::Path,
    model: &dyn Differentiable,
    targets: &Columns,
    solutions: &[InverseSolution],
    radius: Option<f64>,
) -> anyhow::Result<()> {
    let inputs = Columns::new(
        model.inputs().to_vec(),
        solutions.iter().flat_map(|s| s.inputs.clone()).collect(),
    );
    let achieved = Columns::new(
        model
            .outputs()
            .iter()
            .map(|n| format!("{n}_model"))
            .collect(),
        solutions.iter().flat_map(|s| s.achieved.clone()).collect(),
    );
    let verdict = Columns::new(
        vec!["error".into(), "reached".into()],
        solutions
            .iter()
            .flat_map(|s| [s.error, f64::from(u8::from(s.reached))])
            .collect(),
    );
    let interval =
        radius.map(|r| Columns::new(vec!["interval_radius".into()], vec![r; solutions.len()]));
    let mut blocks = vec![targets, &inputs, &achieved, &verdict];
    blocks.extend(&interval);
    data::write_csv(out, &blocks).with_context(|| format!("writing {}", out.display()))
}
