//! `handcap inverse model.json --target X,Y,Z` or `--targets targets.csv --out pressures.csv`:
//! the pressures that put the model's tip where it is wanted (feed-forward).

use std::path::PathBuf;

use anyhow::bail;

use super::usage;

use crate::pipeline::inverse::{self, Limits};
use crate::pipeline::trajectory;

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
    /// CSV to write: the targets, the inputs found, the model's outputs there, the error
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    plan: PlanArgs,
    /// The coverage of the interval reported around each planned tip (conformal: the real
    /// tip lies within the radius this share of the time); 0 leaves it out. Default 0.9, said
    /// in a note when the model has no intervals; a level given is refused then
    #[arg(
        long,
        value_name = "LEVEL",
        allow_hyphen_values = true,
        value_parser = interval_level
    )]
    interval: Option<f64>,
}

/// How commands are planned along a path and learned from a run, and the inverse's limits
/// (`inverse`, `follow`).
#[derive(clap::Args, Clone, Copy)]
pub struct PlanArgs {
    /// Learning gain: the share of the measured error corrected per repetition
    #[arg(long, default_value_t = 0.5, value_parser = super::finite)]
    pub gain: f64,
    /// Largest change of a `_kpa` command per second along a trajectory (a regulator's slew)
    #[arg(long, default_value_t = 600.0, value_parser = super::finite)]
    pub max_rate: f64,
    /// Weight of the commands' smoothness along a trajectory (against the squared output error),
    /// as on a 30 Hz path (a path at another rate is weighed the same over time)
    #[arg(long, default_value_t = 0.1, value_parser = super::finite)]
    pub smoothness: f64,
    /// Upper bound of every `_kpa` input (never above the regulator's 300 kPa); inputs also stay
    /// inside the model's training range
    #[arg(long, default_value_t = crate::hand::DEFAULT_MAX_KPA)]
    pub max_kpa: f64,
    /// A target is reached when the model's output is this close (output units)
    #[arg(long, default_value_t = 0.01)]
    pub reach: f64,
}

impl PlanArgs {
    pub fn limits(&self) -> Limits {
        Limits {
            max_kpa: self.max_kpa,
            reach: self.reach,
        }
    }
}

/// `--interval`: a level in (0, 1), or 0 for none.
fn interval_level(s: &str) -> Result<f64, String> {
    match super::finite(s)? {
        0.0 => Ok(0.0),
        _ => super::level(s),
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let limits = a.plan.limits();
    let level = inverse::asked_level(&a.model, a.interval)?;
    let notes = |notes: &[String]| notes.iter().for_each(|n| super::note(n));
    match (&a.target, &a.targets, &a.trajectory) {
        (Some(target), None, None) => {
            let planned = inverse::plan_one(&a.model, target, limits, level)?;
            notes(&planned.notes);
            if !planned.solution.reached {
                bail!("{planned}");
            }
            print!("{planned}");
        }
        (None, Some(targets), None) => {
            let out = a.out.as_ref().expect("clap requires --out with --targets");
            let planned = inverse::plan_targets(&inverse::Targets {
                model: &a.model,
                targets,
                out,
                limits,
                level,
            })?;
            notes(&planned.notes);
            println!("{planned}");
            println!("wrote {}", out.display());
        }
        (None, None, Some(target)) => {
            let learn = match (&a.previous, &a.measured) {
                (Some(p), Some(m)) => Some((p.as_path(), m.as_path())),
                (None, None) => None,
                _ => usage!("--previous and --measured go together: the commands played and the outputs measured while they were"),
            };
            let planned = trajectory::run(&trajectory::Request {
                model: &a.model,
                target,
                out: a
                    .out
                    .as_ref()
                    .expect("clap requires --out with --trajectory"),
                learn,
                gain: a.plan.gain,
                max_rate: a.plan.max_rate,
                smoothness: a.plan.smoothness,
                limits,
                level,
            })?;
            notes(&planned.notes);
            print!("{planned}");
            if let Some(warning) = planned.warning() {
                super::warn(&warning);
            }
        }
        _ => usage!(
            "give --target X,Y,Z, --targets FILE.csv or --trajectory FILE.csv, with --out FILE.csv"
        ),
    }
    Ok(())
}
