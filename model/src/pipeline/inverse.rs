//! The inverse as a stage: the inputs (pressures) that put a model's outputs at targets, for
//! feed-forward control. `handcap inverse --targets` writes a row per target, the demo's check
//! the same columns with the plant's answer beside them, and [`super::trajectory`] the same
//! along a path: the columns are named by [`planned_columns`] alone.

use std::fmt;
use std::path::Path;

use super::outputs::{self, Output};
use super::PipelineError;
use crate::data::{self, Columns};
use crate::hand::MAX_PRESSURE_KPA;
use crate::model::file::ModelFile;
use crate::model::interval::percent;
use crate::model::interval::RowRadii;
use crate::model::inverse::{self, InverseOptions, InverseSolution, PlannedTarget};
use crate::model::{Differentiable, Predict};

/// Where the inverse may look, and when a target counts as reached.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Upper bound of every `_kpa` input (kPa; at most the regulator's [`MAX_PRESSURE_KPA`]).
    pub max_kpa: f64,
    /// A target is reached when the model's outputs are this close (output units).
    pub reach: f64,
}

impl Limits {
    /// The inverse's options for `model`: inside its training range, `_kpa` inputs within
    /// 0-`max_kpa`.
    ///
    /// # Errors
    /// [`PipelineError::Request`] for a cap outside (0, 300] kPa or a reach that is not
    /// positive.
    pub fn options(&self, model: &dyn Differentiable) -> Result<InverseOptions, PipelineError> {
        if !(self.max_kpa > 0.0 && self.max_kpa <= MAX_PRESSURE_KPA) {
            return Err(PipelineError::Request(format!(
                "max_kpa={} must lie in (0, {MAX_PRESSURE_KPA}]: the regulator caps the supply",
                self.max_kpa
            )));
        }
        if self.reach.is_nan() || self.reach <= 0.0 {
            return Err(PipelineError::Request(format!(
                "reach={} must be positive",
                self.reach
            )));
        }
        let cap = |name: &str| name.ends_with("_kpa").then_some((0.0, self.max_kpa));
        Ok(InverseOptions {
            reach: self.reach,
            ..InverseOptions::within_training_range(model, cap)
        })
    }
}

/// The columns of planned inputs: the inputs (named as the model's), the model's outputs there
/// (`x_mm_model`, …), the distance from the target (`error`) and whether it is within reach
/// (`reached`, 1 or 0). `inputs` and `achieved` hold one row per plan, row after row.
pub fn planned_columns(
    model: &dyn Differentiable,
    inputs: Vec<f64>,
    achieved: Vec<f64>,
    error: &[f64],
    reached: &[bool],
) -> [Columns; 3] {
    let verdict = error
        .iter()
        .zip(reached)
        .flat_map(|(&e, &r)| [e, f64::from(u8::from(r))])
        .collect();
    [
        Columns::new(model.inputs().to_vec(), inputs),
        Columns::new(suffixed(model.outputs(), "_model"), achieved),
        Columns::new(vec!["error".into(), "reached".into()], verdict),
    ]
}

/// `names`, each with `suffix` (`x_mm` → `x_mm_model`).
fn suffixed(names: &[String], suffix: &str) -> Vec<String> {
    names.iter().map(|n| format!("{n}{suffix}")).collect()
}

/// [`planned_columns`] of pointwise solutions.
fn solution_columns(model: &dyn Differentiable, solutions: &[InverseSolution]) -> [Columns; 3] {
    let error: Vec<f64> = solutions.iter().map(|s| s.error).collect();
    let reached: Vec<bool> = solutions.iter().map(|s| s.reached).collect();
    planned_columns(
        model,
        solutions.iter().flat_map(|s| s.inputs.clone()).collect(),
        solutions.iter().flat_map(|s| s.achieved.clone()).collect(),
        &error,
        &reached,
    )
}

/// A file of targets to plan for.
pub struct Targets<'a> {
    pub model: &'a Path,
    /// A CSV with the model's output columns.
    pub targets: &'a Path,
    pub out: &'a Path,
    pub limits: Limits,
    /// The coverage of the interval written around each planned tip (`None`: no interval).
    pub level: Option<f64>,
}

/// What [`plan_targets`] planned.
pub struct PlannedTargets {
    pub solutions: Vec<InverseSolution>,
    /// The reach a target counts as reached within.
    pub reach: f64,
    /// The box searched, e.g. "P1_kpa 0-250, P2_kpa 0-250, P3_kpa 0-250".
    pub bounds: String,
    /// What the user should know about the plan (the model's history, a missing interval).
    pub notes: Vec<String>,
}

/// `handcap inverse --targets`: every target planned (a history model at its steady state)
/// and written with the targets, [`planned_columns`] and `interval_radius`.
///
/// # Errors
/// An output that would replace an input, an unreadable model or targets file, limits out of
/// range, or a failed solve.
pub fn plan_targets(job: &Targets) -> Result<PlannedTargets, PipelineError> {
    outputs::check(
        &[job.model, job.targets],
        &[Output::new(job.out, "the planned inputs")],
    )?;
    let file = ModelFile::load(job.model)?;
    let (steady, mut notes) = steady_state(&file);
    let model: &dyn Differentiable = &steady;
    let options = job.limits.options(model)?;
    let (targets, lines) = data::read_columns_with_lines(job.targets, model.outputs())?;
    if targets.rows() == 0 {
        return Err(data::DataError::NoRows {
            path: job.targets.into(),
            what: "--targets".into(),
        }
        .into());
    }
    // A target no model gives is named by its line.
    let solutions: Vec<InverseSolution> = targets
        .iter_rows()
        .zip(&lines)
        .map(|(t, line)| {
            inverse::solve(model, t, &options).map_err(|e| {
                PipelineError::Input(format!("{}: line {line}: {e}", job.targets.display()))
            })
        })
        .collect::<Result<_, _>>()?;
    let planned = solution_columns(model, &solutions);
    let planned_inputs = solutions.iter().map(|s| &s.inputs[..]);
    let interval = planned_radii(&file, planned_inputs, job.level, &mut notes)
        .map(|r| Columns::new(vec!["interval_radius".into()], r.radii));
    let mut blocks: Vec<&Columns> = std::iter::once(&targets).chain(&planned).collect();
    blocks.extend(&interval);
    data::write_csv(job.out, &blocks)?;
    Ok(PlannedTargets {
        solutions,
        reach: job.limits.reach,
        bounds: bounds(model, &options),
        notes,
    })
}

impl fmt::Display for PlannedTargets {
    /// How many targets were reached, one line.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let n = self.solutions.len();
        let missed = self.solutions.iter().filter(|s| !s.reached).count();
        let mean = self.solutions.iter().map(|s| s.error).sum::<f64>() / n as f64;
        write!(
            f,
            "{n} targets: {} reached within {}, {missed} out of reach (nearest points written); mean model error {mean:.5}",
            n - missed,
            self.reach
        )
    }
}

/// What [`plan_one`] planned for a single target.
pub struct PlannedOne {
    pub solution: InverseSolution,
    pub target: Vec<f64>,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    /// The box searched ([`bounds`]).
    pub bounds: String,
    /// The interval's level and radius around the planned tip, when there is one.
    pub interval: Option<(f64, f64)>,
    /// What the user should know (the model's history, a missing interval).
    pub notes: Vec<String>,
}

/// One target planned (a history model at its steady state).
///
/// # Errors
/// An unreadable model file, limits out of range, or a failed solve.
pub fn plan_one(
    model: &Path,
    target: &[f64],
    limits: Limits,
    level: Option<f64>,
) -> Result<PlannedOne, PipelineError> {
    let file = ModelFile::load(model)?;
    let (steady, mut notes) = steady_state(&file);
    let model: &dyn Differentiable = &steady;
    let options = limits.options(model)?;
    let solution = inverse::solve(model, target, &options)?;
    let interval = planned_radii(&file, [&solution.inputs[..]], level, &mut notes)
        .map(|r| (r.level, r.radii[0]));
    Ok(PlannedOne {
        solution,
        target: target.to_vec(),
        inputs: model.inputs().to_vec(),
        outputs: model.outputs().to_vec(),
        bounds: bounds(model, &options),
        interval,
        notes,
    })
}

/// `names` and `values`, e.g. "P1_kpa 120.0000, P2_kpa 0.0000".
fn named(names: &[String], values: &[f64]) -> String {
    names
        .iter()
        .zip(values)
        .map(|(n, v)| format!("{n} {v:.4}"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl fmt::Display for PlannedOne {
    /// The inputs found and the model's tip there (with its interval); out of reach, the
    /// nearest reachable point.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let s = &self.solution;
        if !s.reached {
            return write!(
                f,
                "target ({}) is out of reach within {}: the nearest reachable point is ({}), {:.4} away, at {}",
                named(&self.outputs, &self.target),
                self.bounds,
                named(&self.outputs, &s.achieved),
                s.error,
                named(&self.inputs, &s.inputs)
            );
        }
        writeln!(f, "{}", named(&self.inputs, &s.inputs))?;
        writeln!(
            f,
            "model tip: {} (error {:.5})",
            named(&self.outputs, &s.achieved),
            s.error
        )?;
        if let Some((level, r)) = self.interval {
            writeln!(
                f,
                "the real tip lies within {r:.4} of it {} % of the time (conformal interval, marginal over inputs like the held-out ones, wider where the inputs are far from the training rows)",
                percent(level)
            )?;
        }
        Ok(())
    }
}

/// The model's conformal radius at `level` around its tip at rest (a history model's filters
/// settled) at each row of `planned` present inputs; `None` without a level, or with a note
/// saying why there is none.
pub fn planned_radii<'a>(
    file: &ModelFile,
    planned: impl IntoIterator<Item = &'a [f64]>,
    level: Option<f64>,
    notes: &mut Vec<String>,
) -> Option<RowRadii> {
    let steady = file.steady_state();
    let planned = Columns::new(
        steady.inputs().to_vec(),
        planned.into_iter().flatten().copied().collect(),
    );
    radii_at(file, &steady.features(&planned), level, notes)
}

/// The model's conformal radius at `level` around its outputs at each row of `features` (the
/// model's own inputs); `None` without a level, or with a note saying why there is none.
pub fn radii_at(
    file: &ModelFile,
    features: &Columns,
    level: Option<f64>,
    notes: &mut Vec<String>,
) -> Option<RowRadii> {
    file.interval_radii(level?, features)
        .map_err(|e| notes.push(format!("no interval around the planned outputs: {e}")))
        .ok()
}

/// The interval's level when none is given: said in a note when the model has none.
pub const DEFAULT_LEVEL: f64 = 0.9;

/// The level of the interval around planned outputs for `--interval` `given`: the default when
/// not given, none for 0; a level given is refused, before anything is planned, where the
/// model file at `model` has no interval at it (no intervals, too few held-out rows for it).
///
/// # Errors
/// [`PipelineError::Input`] naming the file; as [`ModelFile::load`].
pub fn asked_level(model: &Path, given: Option<f64>) -> Result<Option<f64>, PipelineError> {
    match given {
        None => Ok(Some(DEFAULT_LEVEL)),
        Some(0.0) => Ok(None),
        Some(level) => {
            ModelFile::load(model)?
                .interval_radius(level)
                .map_err(|e| {
                    PipelineError::Input(format!("{}: --interval {level}: {e}", model.display()))
                })?;
            Ok(Some(level))
        }
    }
}

/// The model the pointwise inverse plans with: a history model at its steady state (every
/// filter equal to the input), said in the note.
pub fn steady_state(file: &ModelFile) -> (crate::model::history::SteadyState<'_>, Vec<String>) {
    let notes = file
        .history()
        .map(|h| {
            format!(
                "the model sees the inputs' history ({}); the inputs found hold the tip there once settled (every filter equal to the input)",
                h.memory
            )
        })
        .into_iter()
        .collect();
    (file.steady_state(), notes)
}

/// The box, e.g. "P1_kpa 0-250, P2_kpa 0-250, P3_kpa 0-250".
pub fn bounds(model: &dyn Differentiable, o: &InverseOptions) -> String {
    model
        .inputs()
        .iter()
        .enumerate()
        .map(|(j, n)| format!("{n} {}-{}", o.lower[j], o.upper[j]))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The demo's feed-forward check: each target, [`planned_columns`], the plant's outputs at the
/// planned inputs (`x_mm_plant`, …), their distance from the target (`plant_error_mm`) and the
/// inputs that made the target (`source_P1_kpa`, …).
///
/// # Errors
/// [`PipelineError::Data`] when the file cannot be written.
pub fn write_feedforward(
    path: &Path,
    model: &dyn Differentiable,
    rows: &[PlannedTarget],
) -> Result<(), PipelineError> {
    let solutions: Vec<InverseSolution> = rows.iter().map(|r| r.solution.clone()).collect();
    let planned = solution_columns(model, &solutions);
    let targets = Columns::new(
        model.outputs().to_vec(),
        rows.iter().flat_map(|r| r.target.clone()).collect(),
    );
    let plant = Columns::new(
        suffixed(model.outputs(), "_plant"),
        rows.iter().flat_map(|r| r.plant.clone()).collect(),
    );
    let plant_error = Columns::new(
        vec!["plant_error_mm".into()],
        rows.iter().map(|r| r.plant_error).collect(),
    );
    let sources = Columns::new(
        model
            .inputs()
            .iter()
            .map(|n| format!("source_{n}"))
            .collect(),
        rows.iter().flat_map(|r| r.source_inputs.clone()).collect(),
    );
    let mut blocks: Vec<&Columns> = std::iter::once(&targets).chain(&planned).collect();
    blocks.extend([&plant, &plant_error, &sources]);
    Ok(data::write_csv(path, &blocks)?)
}
