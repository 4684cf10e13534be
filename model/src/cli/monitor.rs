//! `handcap monitor`: a triangulated session replayed against a fitted model, an online band
//! and two alarms (the finger changed, a camera moved).

use std::path::{Path, PathBuf};

use crate::monitor::Settings;
use crate::pipeline::monitor;

#[derive(clap::Args)]
pub struct Args {
    /// The session's rows, as `handcap triangulate` writes them (per frame or per step): the
    /// model's inputs and outputs, a time column, and `reproj_px` for the camera alarm; or a
    /// session directory as `capture` writes it, with --calib: triangulated per frame first
    /// (into OUT/rows.csv)
    session: PathBuf,
    /// The session directory's calibration, to triangulate it with
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Model file written by `handcap model` (with intervals)
    #[arg(long)]
    model: PathBuf,
    /// Directory to write monitor.csv, monitor.json, the figure and, after a model alarm,
    /// after_change.csv (the rows from the change on, to refit the model on)
    #[arg(long)]
    out: PathBuf,
    /// The time column (default: the model's, else time_s)
    #[arg(long)]
    time: Option<String>,
    #[command(flatten)]
    settings: SettingsArgs,
}

/// How the monitor watches (`monitor`, and `capture --model`).
#[derive(clap::Args)]
pub struct SettingsArgs {
    /// The monitor's online band's coverage
    #[arg(long, default_value_t = Settings::default().level, value_parser = super::level)]
    level: f64,
    /// One look for the monitor's alarms every this many seconds (rows a frame apart are not
    /// independent; a second apart nearly are)
    #[arg(long, default_value_t = Settings::default().look_s, value_parser = super::finite)]
    look_s: f64,
    /// Hours of looks between false alarms, at least, on average
    #[arg(long, default_value_t = Settings::default().false_alarm_hours, value_parser = super::finite)]
    false_alarm_hours: f64,
    /// The alarms' references: the session's first this many seconds
    #[arg(long, default_value_t = Settings::default().baseline_s, value_parser = super::finite)]
    baseline_s: f64,
}

impl SettingsArgs {
    /// The settings the flags give.
    pub fn settings(&self) -> Settings {
        Settings {
            level: self.level,
            look_s: self.look_s,
            false_alarm_hours: self.false_alarm_hours,
            baseline_s: self.baseline_s,
            ..Settings::default()
        }
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let rows = match (a.session.is_dir(), &a.calib) {
        (true, Some(calib)) => triangulate(&a.session, calib, &a.out)?,
        (true, None) => super::usage!(
            "{} is a session directory: give its calibration with --calib to triangulate it, or give the rows triangulate wrote",
            a.session.display()
        ),
        (false, Some(_)) => super::usage!("--calib is for a session directory; {} is a file of rows, already triangulated", a.session.display()),
        (false, None) => a.session.clone(),
    };
    let watch = monitor::Watch {
        session: &rows,
        model: &a.model,
        out: &a.out,
        time: a.time.as_deref(),
        settings: a.settings.settings(),
    };
    let watched = super::with_session(|s| monitor::run(&watch, s.provenance(None)))?;
    println!("{}", super::said(&watched.to_string()));
    Ok(())
}

/// `handcap triangulate SESSION/frames --calib CALIB --per-frame --out OUT/rows.csv`, run as
/// its own process (triangulation is the camera binary's: this one links no OpenCV); the rows.
fn triangulate(session: &Path, calib: &Path, out: &Path) -> anyhow::Result<PathBuf> {
    let rows = out.join("rows.csv");
    std::fs::create_dir_all(out)?;
    let status = std::process::Command::new(std::env::current_exe()?)
        .arg("triangulate")
        .arg(session.join("frames"))
        .arg("--calib")
        .arg(calib)
        .arg("--per-frame")
        .arg("--out")
        .arg(&rows)
        .status()?;
    if !status.success() {
        anyhow::bail!(
            "triangulating {} failed (its message above); the monitor needs its rows",
            session.display()
        );
    }
    Ok(rows)
}
