//! `handcap demo`: the pipeline end to end on the built-in virtual micro-hand.
//!
//! This build runs: virtual plant → datasets (`DIR/data/`) → MSVR with (C, ε, σ) chosen by the
//! default search (the paper's colony, cross-validated fitness), and the previous physics model
//! (default and calibrated) → held-out errors and Figures 7-14 on the two sweeps →
//! `DIR/model.json` and `DIR/report/`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;

use handcap::data::{names, HAND_INPUTS, HAND_OUTPUTS};
use handcap::model::msvr::MsvrParams;
use handcap::provenance::Provenance;
use handcap::search::aco_paper::AcoPaper;
use handcap::search::fitness::FitnessKind;
use handcap::search::Method;
use handcap::synth::{self, SynthConfig};

use super::model::{self, Job, Selection, PAPER_C, PAPER_EPSILON, PAPER_SIGMA};

#[derive(clap::Args)]
pub struct Args {
    /// Output directory
    #[arg(long, default_value = "handcap-demo")]
    out: PathBuf,
    /// Seed of every random choice
    #[arg(long, default_value_t = synth::DEFAULT_SEED)]
    seed: u64,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let started = Instant::now();
    let data_dir = a.out.join("data");
    println!("[1/2] synth: virtual micro-hand → {}", data_dir.display());
    let config = SynthConfig {
        seed: a.seed,
        ..SynthConfig::default()
    };
    let provenance = Provenance::new(super::command_line(), Some(a.seed));
    synth::write_datasets(&data_dir, &config, &provenance)
        .with_context(|| format!("synth into {}", data_dir.display()))?;
    let synth_s = started.elapsed().as_secs_f64();
    println!("      done in {synth_s:.2} s");

    println!(
        "[2/2] model: MSVR, (C, ε, σ) by the paper's ant colony on 5-fold CV, and the previous model; tested on the sweeps"
    );
    let job = Job {
        data: data_dir.join("train.csv"),
        inputs: names(&HAND_INPUTS),
        outputs: names(&HAND_OUTPUTS),
        params: MsvrParams::new(PAPER_C, PAPER_EPSILON, PAPER_SIGMA),
        selection: Selection::Search {
            method: Method::AcoPaper(AcoPaper {
                seed: a.seed,
                ..AcoPaper::default()
            }),
            fitness: FitnessKind::Cv { folds: 5 },
            group_by: None,
            seed: a.seed,
        },
        tests: vec![data_dir.join("sweep_a.csv"), data_dir.join("sweep_b.csv")],
        out: a.out.join("model.json"),
        report: Some(a.out.join("report")),
    };
    let outcome = model::execute(&job)?;
    model::print_summary(&outcome);
    println!(
        "      done in {:.2} s",
        started.elapsed().as_secs_f64() - synth_s
    );
    println!(
        "report: {}/report/report.md, metrics: {}/report/metrics.csv",
        a.out.display(),
        a.out.display()
    );
    Ok(())
}
