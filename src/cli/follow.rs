//! `handcap follow`: the learning loop along a path closed by one command
//! ([`crate::pipeline::follow`]).

use std::path::PathBuf;

use handcap_model::cli::PlanArgs;

use crate::pipeline::{follow, trajectory};

#[derive(clap::Args)]
pub struct Args {
    /// The model (`handcap model`'s file; a history model anticipates the finger's lag)
    model: PathBuf,
    /// CSV of the path in time, as `inverse --trajectory` takes it (the time column and the
    /// model's outputs)
    #[arg(long)]
    trajectory: PathBuf,
    /// How many repetitions to play, each learning from the one before
    #[arg(long, default_value_t = 6)]
    repetitions: usize,
    /// The cameras' calibration (`handcap calibrate`'s), for the per-frame tip
    #[arg(long)]
    calib: PathBuf,
    /// Folder for every repetition's session, commands and rows, and follow.csv
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    cameras: super::capture::Cameras,
    /// The regulator, as `capture --regulator` takes it: serial:PATH[@BAUD] (handcap's line
    /// protocol) or a process kept running
    #[arg(long)]
    regulator: String,
    /// With a serial regulator: another firmware's commands (as `capture --dialect`)
    #[arg(long)]
    dialect: Option<PathBuf>,
    /// With a serial regulator: each repetition measures the cameras' delays from the board's
    /// LED (as `capture --sync-led`)
    #[arg(long)]
    sync_led: bool,
    /// The rest hold before each repetition's path (s): the hand frame's origin
    #[arg(long, default_value_t = 2.0, value_parser = super::finite)]
    rest_s: f64,
    /// The path's first seconds left out of the tracking RMS (the move from rest onto it)
    #[arg(long, default_value_t = 1.5, value_parser = super::finite)]
    lead_in_s: f64,
    /// `handcap lab`'s truth folder (LAB/truth): each repetition also scored against the
    /// finger's tip at every left exposure
    #[arg(long)]
    truth: Option<PathBuf>,
    /// The session the model was fitted on: after each repetition the model is fitted again
    /// with its own settings on it and the repetitions played (together weighing as much as
    /// its rows), and the next repetition learned with that model: on a finger whose dynamics
    /// the model does not know, it learns them
    #[arg(long, value_name = "SESSION")]
    refit: Option<PathBuf>,
    #[command(flatten)]
    plan: PlanArgs,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if a.rest_s.is_nan() || a.rest_s < 0.5 {
        super::usage!(
            "--rest-s {}: rest at least 0.5 s (the hand frame's origin)",
            a.rest_s
        );
    }
    let request = follow::Follow {
        model: &a.model,
        target: &a.trajectory,
        calib: &a.calib,
        out: &a.out,
        repetitions: a.repetitions,
        bench: crate::capture::CaptureOptions {
            sync_led: a.sync_led,
            ..a.cameras.options()?
        },
        regulator: super::capture::regulator(&a.regulator, a.dialect.as_deref())?,
        rest_s: a.rest_s,
        lead_in_s: a.lead_in_s,
        truth: a.truth.as_deref(),
        refit: a.refit.as_deref(),
        plan: trajectory::Request {
            model: &a.model,
            target: &a.trajectory,
            out: &a.out,
            learn: None,
            gain: a.plan.gain,
            max_rate: a.plan.max_rate,
            smoothness: a.plan.smoothness,
            limits: a.plan.limits(),
            level: None,
        },
    };
    super::with_session(|s| follow::run(&request, s, &|line| println!("{line}")))?;
    println!("wrote {}", a.out.join("follow.csv").display());
    Ok(())
}
