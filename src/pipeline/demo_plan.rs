//! The sizes of a demo run (the full one and `--quick`), and the model job its steps ask for.

use std::path::PathBuf;

use super::fit::{FitJob, Selection};
use crate::data::{names, HAND_INPUTS, HAND_OUTPUTS};
use crate::model::history::HistoryChoice;
use crate::model::msvr::{Loss, MsvrParams};
use crate::search::aco_paper::AcoPaper;
use crate::search::aco_r::AcoR;
use crate::search::Method;
use crate::select::family::FamilyChoice;
use crate::select::fitness::FitnessKind;
use crate::select::folds::FoldsBy;
use crate::select::tune::{BasisChoice, Pinned};
use crate::session::protocol::DynamicDesign;
use crate::synth::capture::CaptureConfig;
use crate::triangulate::TriangulateOptions;

/// The sizes of a run.
pub(super) struct Plan {
    pub views: usize,
    pub grid_step_kpa: f64,
    pub sweep_step_kpa: f64,
    /// The search scores candidates on the grid points at this step only (none: all of them),
    /// so that a dense grid keeps the search fast; the fit uses every row.
    pub search_grid_kpa: Option<f64>,
    /// Frames kept per step: stamped this far into it (s).
    pub window_s: [f64; 2],
    pub triangulate: TriangulateOptions,
    pub aco: AcoPaper,
    pub targets: usize,
    /// The dynamic session (its seed the run's), and its model searches' candidate budget.
    pub dynamic: DynamicDesign,
    pub dynamic_budget: Option<usize>,
}

impl Plan {
    pub(super) fn new(quick: bool, seed: u64) -> Self {
        let aco = AcoPaper {
            seed,
            ..AcoPaper::default()
        };
        if quick {
            Plan {
                views: 8,
                grid_step_kpa: 125.0,
                sweep_step_kpa: 50.0,
                search_grid_kpa: None,
                window_s: CaptureConfig::default().window_s,
                triangulate: TriangulateOptions::default(),
                aco: AcoPaper {
                    ants: 8,
                    max_iter: 6,
                    ..aco
                },
                targets: 20,
                // The full demo's dynamic session, searched with a third of its budget: two
                // trials of 5 s taught the history model too little to tell ladders apart
                // (held out no better than static).
                dynamic: DynamicDesign {
                    duration_s: 8.0,
                    trials: 3,
                    seed,
                    ..DynamicDesign::default()
                },
                dynamic_budget: Some(40),
            }
        } else {
            // A 25 kPa training grid (1331 steps): the 50 kPa grid of the paper leaves 0.18 mm of
            // interpolation error between its levels, too much for feed-forward. One or two
            // frames per camera and step (the finger holds still, so a pair may be up to 50 ms
            // apart) keep the capture to about 3300 frames.
            Plan {
                views: 20,
                grid_step_kpa: 25.0,
                sweep_step_kpa: 10.0,
                search_grid_kpa: Some(50.0),
                window_s: [0.10, 0.14],
                triangulate: TriangulateOptions {
                    max_dt_s: 0.05,
                    min_frames: 1,
                    ..TriangulateOptions::default()
                },
                aco,
                targets: 100,
                // Three trials of 8 s: about 700 training rows, whose searches take 120
                // candidates each (`handcap model`'s default from 700 rows; 200 below).
                dynamic: DynamicDesign {
                    duration_s: 8.0,
                    trials: 3,
                    seed,
                    ..DynamicDesign::default()
                },
                dynamic_budget: Some(120),
            }
        }
    }
}

pub(super) fn job(
    plan: &Plan,
    data: PathBuf,
    search_on: Option<PathBuf>,
    tests: Vec<PathBuf>,
    out: PathBuf,
    report: PathBuf,
) -> FitJob {
    FitJob {
        data,
        inputs: names(&HAND_INPUTS),
        outputs: names(&HAND_OUTPUTS),
        // The paper's model, its headline.
        family: FamilyChoice::MSVR,
        params: MsvrParams::default(),
        pinned: Pinned::default(),
        selection: Selection::Search {
            method: Method::AcoPaper(plan.aco),
            budget: None,
            fitness: FitnessKind::Cv { folds: 5 },
            folds_by: FoldsBy::Auto,
            seed: plan.aco.seed,
        },
        search_on,
        intervals: false,
        tests,
        out,
        report: Some(report),
        max_rows: None,
        basis: BasisChoice::Auto,
        time: None,
        group: None,
        weight: None,
        history: HistoryChoice::None,
    }
}

/// `job` as `handcap model` runs it with its defaults, to be shown beside the paper's MSVR:
/// `auto`'s pick among the families, each searched by ACO_R on the robust loss.
pub(super) fn with_defaults(plan: &Plan, job: FitJob) -> FitJob {
    let seed = plan.aco.seed;
    FitJob {
        family: FamilyChoice::Auto,
        params: MsvrParams::default().loss(Loss::Robust),
        selection: Selection::Search {
            method: Method::AcoR(AcoR {
                seed,
                ..AcoR::default()
            }),
            budget: None,
            fitness: FitnessKind::Cv { folds: 5 },
            folds_by: FoldsBy::Auto,
            seed,
        },
        ..job
    }
}
