//! The demo: the whole pipeline on the built-in virtual micro-hand, checked against its
//! ground truth, with one report a lab can read.
//!
//! Stages: synth (images, log, truth: `DIR/capture/`) → calibrate (`DIR/calib.yml`) →
//! triangulate (`DIR/triangulated/`) → model: MSVR with the default search and fitness, and the
//! previous model, from the triangulated data (`DIR/model.json`, `DIR/model/`) and, for
//! comparison, the same model (its parameters) fitted on the plant's own data
//! (`DIR/model_plant/`) → inverse: pressures planned for
//! targets the virtual plant can reach, run through the plant (`DIR/inverse_check.csv`) →
//! `DIR/report/index.html` and `DIR/summary.json`.
//!
//! The training grid is 25 kPa (1331 steps): feed-forward needs the model within 0.1 mm between
//! grid levels, and the paper's 50 kPa grid leaves about 0.18 mm there (the report shows both).
//! The search scores its candidates on the 50 kPa points of the grid (`DIR/search/`, the paper's
//! 216 steps), so it takes as long as the paper's; the fit uses every step.

mod cameras;

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};

use super::demo_checks::{check_calibration, check_tips, feedforward, inverse_stats};
use super::demo_plan::{job, with_defaults, Plan};
use super::demo_summary::{
    CalibrationCheck, IntervalCheck, InverseCheck, Score, Summary, TipCheck,
};
use super::fit::{self, FitJob, FitOutcome, Selection};
use super::{io_error, Event, PipelineError, Session};
use crate::calib::file::read_calibration;
use crate::calib::CalibOptions;
use crate::data::{self, names, HAND_INPUTS, HAND_OUTPUTS};
use crate::fsio;
use crate::model::file::ModelFile;
use crate::model::inverse::PlannedTarget;
use crate::select::family::FamilyDecision;
use crate::select::folds::FoldsBy;
use crate::synth::capture::{CaptureConfig, Realism};
use crate::synth::image_format::ImageFormat;
use crate::synth::plant::Plant;
use crate::synth::SynthConfig;
use cameras::Seen;

/// What to run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DemoConfig {
    /// Seed of every random choice.
    pub seed: u64,
    /// A reduced run for a first look and the tests: 8 board pairs, a 125 kPa grid and 50 kPa
    /// sweeps, a short search, 20 inverse targets.
    pub quick: bool,
    /// How the frames are stored.
    pub format: ImageFormat,
    /// What the virtual lab adds to ideal frames.
    pub realism: Realism,
    /// How many cameras film it: 2, a pair; more, on an arc (`synth --cameras`), calibrated
    /// and triangulated as more cameras are, without the pair's finger in motion (step 6).
    pub cameras: usize,
}

/// What the demo did: the summary it wrote to `summary.json`.
pub struct DemoOutcome {
    pub summary: Summary,
    /// Each stage's seconds, and the total (as `timings.json` holds them).
    pub timings: Vec<(String, f64)>,
    /// The report page.
    pub index: PathBuf,
}

/// Runs every stage into `out`, checks each against the virtual capture's truth, and writes
/// `summary.json` and `report/index.html`. Each stage is announced with an [`Event::Stage`],
/// reports its result, and ends with an [`Event::StageTime`].
///
/// # Errors
/// [`PipelineError`] from any stage, or a file that cannot be written.
pub fn run(
    out: &Path,
    config: DemoConfig,
    session: &Session,
) -> Result<DemoOutcome, PipelineError> {
    let started = Instant::now();
    std::fs::create_dir_all(out).map_err(io_error(out))?;
    let mut demo = Demo::new(out, config, session);
    demo.synth()?;
    let seen = if config.cameras == 2 {
        let (calibrated, calibration) = demo.calibrate()?;
        let (triangulated, triangulation) = demo.triangulate()?;
        Seen::Pair {
            calibrated: Box::new(calibrated),
            calibration,
            triangulated: Box::new(triangulated),
            triangulation,
        }
    } else {
        demo.more_cameras()?
    };
    let Models {
        scores,
        intervals,
        auto,
        coarse,
    } = demo.models()?;
    let (file, planned, inverse) = demo.inverse(coarse.as_deref())?;
    let dynamic = Some(demo.dynamic(match seen {
        Seen::Pair { .. } => "calib.yml",
        Seen::Cameras { .. } => "calib.toml",
    })?);
    demo.stage(7, "report".into());
    demo.timings
        .push(("total".into(), started.elapsed().as_secs_f64()));
    let summary = Summary {
        seed: config.seed,
        quick: config.quick,
        realism: config.realism,
        calibration: seen.calibration(),
        cameras: seen.cameras(),
        triangulation: seen.triangulation(),
        scores,
        intervals,
        auto,
        inverse,
        dynamic,
        provenance: session.provenance(Some(config.seed)),
    };
    let index = demo.report(&summary, &seen, &file, &planned)?;
    demo.lap("report");
    Ok(DemoOutcome {
        summary,
        timings: demo.timings,
        index,
    })
}

impl std::fmt::Display for DemoOutcome {
    /// The total time and where the report is.
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        if let Some((_, total)) = self.timings.iter().find(|(k, _)| k == "total") {
            writeln!(f, "total {total:.1} s")?;
        }
        writeln!(f, "report: {}", self.index.display())
    }
}

/// What step 4 fitted: the models' scores and intervals, and the coarse rows the search scored
/// (if any).
struct Models {
    scores: Vec<Score>,
    intervals: Vec<IntervalCheck>,
    /// The family `handcap model`'s defaults picked, and why.
    auto: FamilyDecision,
    coarse: Option<PathBuf>,
}

/// A run under way: where it writes, its sizes, and each stage's time so far.
struct Demo<'a> {
    out: &'a Path,
    config: DemoConfig,
    plan: Plan,
    synth: SynthConfig,
    capture: CaptureConfig,
    session: &'a Session<'a>,
    /// Each stage's seconds, as `timings.json` holds them (the report's comes after).
    timings: Vec<(String, f64)>,
    clock: Instant,
}

impl<'a> Demo<'a> {
    fn new(out: &'a Path, config: DemoConfig, session: &'a Session<'a>) -> Self {
        let plan = Plan::new(config.quick, config.seed);
        let synth = SynthConfig {
            seed: config.seed,
            grid_step_kpa: plan.grid_step_kpa,
            sweep_step_kpa: plan.sweep_step_kpa,
            ..SynthConfig::default()
        };
        let capture = CaptureConfig {
            rig: crate::synth::camera::RigConfig {
                cameras: config.cameras,
                ..Default::default()
            },
            views: plan.views,
            window_s: plan.window_s,
            format: config.format,
            realism: config.realism,
            ..CaptureConfig::default()
        };
        Demo {
            out,
            config,
            plan,
            synth,
            capture,
            session,
            timings: Vec::new(),
            clock: Instant::now(),
        }
    }

    fn stage(&self, step: usize, text: String) {
        self.session.emit(Event::Stage { step, of: 7, text });
    }

    /// A stage ended: its time shown and recorded.
    fn lap(&mut self, name: &str) {
        let seconds = self.clock.elapsed().as_secs_f64();
        self.session.emit(Event::StageTime { name, seconds });
        self.clock = Instant::now();
        self.timings.push((name.to_string(), seconds));
    }

    fn note(&self, text: String) {
        self.session.emit(Event::Note(text));
    }

    fn capture_dir(&self) -> PathBuf {
        self.out.join("capture")
    }

    /// Step 1: the virtual capture.
    fn synth(&mut self) -> Result<(), PipelineError> {
        let capture = self.capture_dir();
        self.stage(
            1,
            format!(
                "synth: the virtual micro-hand filmed by {} webcams → {}",
                match self.config.cameras {
                    2 => "two".to_string(),
                    n => n.to_string(),
                },
                capture.display()
            ),
        );
        let synthesized =
            super::synth::run(&capture, &self.synth, Some(&self.capture), self.session)?;
        if synthesized.capture.is_some_and(|c| c.interrupted) {
            return Err(PipelineError::Interrupted(
                "interrupted while rendering the capture; run the demo again".into(),
            ));
        }
        self.lap("synth");
        Ok(())
    }

    /// Step 2: calibration, against the rig's truth.
    fn calibrate(
        &mut self,
    ) -> Result<(super::calibrate::Calibrated, CalibrationCheck), PipelineError> {
        self.stage(
            2,
            format!(
                "calibrate: {} chessboard pairs → calib.yml",
                self.plan.views
            ),
        );
        let capture = self.capture_dir();
        let calib_dir = capture.join("calib");
        let board = super::calibrate::board(&calib_dir, &Default::default(), self.session)?;
        let calibrated = super::calibrate::run(
            &calib_dir,
            &board,
            &CalibOptions {
                validate: true,
                ..CalibOptions::default()
            },
            &self.out.join("calib.yml"),
            self.session,
        )?;
        self.session.emit(Event::Outcome(&calibrated));
        let truth = read_calibration(&capture.join("truth/rig.yml"))?;
        let check = check_calibration(&calibrated.calibration, &truth);
        self.lap("calibrate");
        Ok((calibrated, check))
    }

    /// Step 3: triangulation, against the true tips.
    fn triangulate(
        &mut self,
    ) -> Result<(super::triangulate::Triangulated, Vec<TipCheck>), PipelineError> {
        self.stage(
            3,
            "triangulate: the red tip in every frame pair → dataset".into(),
        );
        let capture = self.capture_dir();
        let triangulated = super::triangulate::run(
            &capture.join("frames"),
            &self.out.join("calib.yml"),
            &capture.join("pressures.csv"),
            &self.plan.triangulate,
            &self.out.join("triangulated/dataset.csv"),
            self.session,
        )?;
        self.session.emit(Event::Outcome(&triangulated));
        let checks = check_tips(&triangulated.triangulation, &capture.join("truth/tips.csv"))?;
        self.note_tips(&checks);
        self.lap("triangulate");
        Ok((triangulated, checks))
    }

    /// The tips' errors, a line per phase.
    fn note_tips(&self, checks: &[TipCheck]) {
        for t in checks {
            self.note(format!(
                "      tip vs truth, {}: RMS {:.4} mm, max {:.4} mm over {} steps; mean error {:.4} mm",
                t.phase,
                t.rms_mm,
                t.max_mm,
                t.rows,
                Vector3::from(t.mean_mm).norm()
            ));
        }
    }

    /// Step 4: models from the triangulated data (the pipeline) and from the plant's own data.
    fn models(&mut self) -> Result<Models, PipelineError> {
        self.stage(
            4,
            "model: MSVR, (C, ε, σ) by the paper's ant colony on 5-fold CV, and the previous model; `handcap model`'s default (auto) beside them"
                .into(),
        );
        let (out, plan, capture) = (self.out, &self.plan, self.capture_dir());
        let tri_dir = out.join("triangulated");
        let plant_tests = [capture.join("sweep_a.csv"), capture.join("sweep_b.csv")];
        let (tri_train, plant_train) =
            (tri_dir.join("dataset_train.csv"), capture.join("train.csv"));
        let coarse = |from: &Path, name: &str| {
            plan.search_grid_kpa
                .map(|step| coarse_rows(from, step, &out.join("search").join(name)))
                .transpose()
        };
        let tri_coarse = coarse(&tri_train, "triangulated_train.csv")?;
        let tri_tests = [
            tri_dir.join("dataset_sweep_a.csv"),
            tri_dir.join("dataset_sweep_b.csv"),
        ];
        let paper = job(
            plan,
            tri_train,
            tri_coarse.clone(),
            tri_tests.into_iter().chain(plant_tests.clone()).collect(),
            out.join("model.json"),
            out.join("model"),
        );
        let images = fit::run(&paper, self.session)?;
        self.session.emit(Event::Fitted(&images));
        // What a user gets from `handcap model` on the same rows, beside the paper's method.
        let defaults = FitJob {
            out: out.join("model_auto.json"),
            report: Some(out.join("model_auto")),
            ..paper
        };
        let auto = fit::run(&with_defaults(plan, defaults), self.session)?;
        let picked = auto.report.family.clone();
        self.note(format!(
            "      `handcap model`'s default (auto) picks {}: {}",
            picked.used.title(),
            picked.verdict()
        ));
        // The same model (the parameters the search chose) fitted on the plant's own rows:
        // what the camera path costs, without a second search.
        let crate::model::ModelSpec::Msvr(params) = images.report.spec;
        let plant_job = FitJob {
            params,
            selection: Selection::Fixed {
                folds: 5,
                folds_by: FoldsBy::Auto,
            },
            intervals: true,
            ..job(
                plan,
                plant_train,
                None,
                plant_tests.to_vec(),
                out.join("model_plant.json"),
                out.join("model_plant"),
            )
        };
        let plant_data = fit::run(&plant_job, self.session)?;
        let fitted = [
            ("triangulated frames", &images),
            ("the plant's data", &plant_data),
        ];
        let auto_scores = scores_of("triangulated frames", &auto)
            .into_iter()
            .filter(|x| x.model == picked.used.name())
            .map(|x| Score {
                model: Score::auto_model(picked.used),
                ..x
            });
        let scores = fitted
            .iter()
            .flat_map(|(trained_on, outcome)| scores_of(trained_on, outcome))
            .chain(auto_scores)
            .collect();
        let intervals = fitted
            .iter()
            .filter_map(|(trained_on, outcome)| {
                Some(IntervalCheck {
                    trained_on: trained_on.to_string(),
                    intervals: outcome.report.intervals.clone()?,
                })
            })
            .collect();
        self.lap("model");
        Ok(Models {
            scores,
            intervals,
            auto: picked,
            coarse: tri_coarse,
        })
    }

    /// Step 5, feed-forward: pressures planned for reachable targets, run through the virtual
    /// plant; with a coarse grid, the same check of a model fitted on it alone.
    fn inverse(
        &mut self,
        coarse: Option<&Path>,
    ) -> Result<(ModelFile, Vec<PlannedTarget>, Vec<InverseCheck>), PipelineError> {
        let plan = &self.plan;
        self.stage(
            5,
            format!(
                "inverse: pressures planned for {} reachable targets, run through the virtual plant",
                plan.targets
            ),
        );
        let plant = Plant::new(self.synth.plant.clone());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.config.seed ^ 0x494e_5645);
        let sources: Vec<Vec<f64>> = (0..plan.targets)
            .map(|_| (0..3).map(|_| rng.random_range(0.0..=250.0)).collect())
            .collect();
        let file = ModelFile::load(&self.out.join("model.json"))?;
        let model = &file.model;
        let planned = feedforward(model.differentiable(), &plant, &sources)?;
        super::inverse::write_feedforward(
            &self.out.join("inverse_check.csv"),
            model.differentiable(),
            &planned,
        )?;
        let mut checks = vec![inverse_stats(
            &format!(
                "MSVR from the triangulated frames ({} kPa grid)",
                plan.grid_step_kpa
            ),
            &planned,
            super::inverse::planned_radii(
                &file,
                planned.iter().map(|t| &t.solution.inputs[..]),
                Some(0.9),
                &mut Vec::new(),
            ),
        )];
        if let (Some(step), Some(coarse)) = (plan.search_grid_kpa, coarse) {
            // The same check with the same parameters fitted on the coarse grid alone: what the
            // training grid's spacing costs.
            let data = data::read_dataset(coarse, &names(&HAND_INPUTS), &names(&HAND_OUTPUTS))?;
            let sparse = model.spec().fit(&data)?;
            checks.push(inverse_stats(
                &format!(
                    "MSVR from the triangulated frames, {step} kPa grid only ({} rows)",
                    data.rows()
                ),
                &feedforward(sparse.differentiable(), &plant, &sources)?,
                None,
            ));
        }
        for c in &checks {
            self.note(format!(
                "      {}: plant tip error mean {:.4} mm, median {:.4}, 90 % {:.4}, max {:.4} ({} of {} reached by the model)",
                c.model, c.mean_mm, c.median_mm, c.p90_mm, c.max_mm, c.reached_by_model, c.targets
            ));
        }
        self.lap("inverse");
        Ok((file, planned, checks))
    }

    /// Step 6: the finger in motion, seen by the cameras of the calibration `calib` (in the
    /// demo's folder).
    fn dynamic(&mut self, calib: &str) -> Result<super::demo_dynamic::DynamicCheck, PipelineError> {
        let plan = &self.plan;
        self.stage(
            6,
            format!(
                "dynamic: {} trials of {} s of random excitation, triangulated per frame, static against input history",
                plan.dynamic.trials, plan.dynamic.duration_s
            ),
        );
        let dynamic = super::demo_dynamic::run(
            &self.out.join("dynamic"),
            &self.synth,
            &self.capture,
            plan.dynamic.clone(),
            plan.dynamic_budget,
            &self.out.join(calib),
            self.session,
        )?;
        let scores: Vec<String> = dynamic
            .scores
            .iter()
            .map(|s| {
                format!(
                    "{} from {} {:.4} mm",
                    s.model, s.trained_on, s.errors.euclid
                )
            })
            .collect();
        self.note(format!(
            "      per-frame tip vs truth: RMS {:.4} mm over {} of {} frames; held-out trial {}: {}",
            dynamic.tip_rms_mm,
            dynamic.unflagged,
            dynamic.rows,
            dynamic.held_out,
            scores.join(", ")
        ));
        self.lap("dynamic");
        Ok(dynamic)
    }

    /// Step 7: `summary.json` (the same bytes for the same seed), `timings.json` (the stage times
    /// apart) and the report's page; returns the page's path.
    fn report(
        &self,
        summary: &Summary,
        seen: &Seen,
        file: &ModelFile,
        planned: &[PlannedTarget],
    ) -> Result<PathBuf, PipelineError> {
        let write_json = |name: &str, json: String| {
            let path = self.out.join(name);
            fsio::write_bytes(&path, (json + "\n").as_bytes()).map_err(io_error(&path))
        };
        write_json(
            "summary.json",
            serde_json::to_string_pretty(summary).expect("the summary serialises"),
        )?;
        write_json(
            "timings.json",
            serde_json::to_string_pretty(&serde_json::json!({ "stages_s": self.timings }))
                .expect("the timings serialise"),
        )?;
        let report_dir = self.out.join("report");
        let index = report_dir.join("index.html");
        std::fs::create_dir_all(&report_dir).map_err(io_error(&report_dir))?;
        super::demo_report::page(
            self.out,
            summary,
            &self.timings,
            match seen {
                Seen::Pair {
                    calibrated,
                    triangulated,
                    ..
                } => Some((&triangulated.triangulation, &calibrated.calibration)),
                Seen::Cameras { .. } => None,
            },
            file.search.as_ref(),
            planned,
        )
        .write(&index)
        .map_err(io_error(&index))?;
        Ok(index)
    }
}

fn scores_of(trained_on: &str, outcome: &FitOutcome) -> Vec<Score> {
    outcome
        .report
        .tests
        .iter()
        .map(|t| Score {
            trained_on: trained_on.to_string(),
            model: t.model.clone(),
            test: t.test.clone(),
            errors: t.errors.clone(),
        })
        .collect()
}

/// The rows of a dataset whose pressures all lie on a `step_kpa` grid, written to `to`.
fn coarse_rows(from: &Path, step_kpa: f64, to: &Path) -> Result<PathBuf, PipelineError> {
    super::create_parent(to).map_err(io_error(to))?;
    let on_grid = |p: &f64| (p / step_kpa - (p / step_kpa).round()).abs() < 1e-9;
    data::copy_rows(from, to, &names(&HAND_INPUTS), |pressures| {
        pressures.iter().all(on_grid)
    })?;
    Ok(to.to_path_buf())
}
