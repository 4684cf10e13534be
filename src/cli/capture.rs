//! `handcap capture`: two cameras → `DIR/frames/` + `frames.csv` (and `pressures.csv` when a
//! protocol drives the regulator), the layout `triangulate` reads (`crate::capture`).

use std::path::PathBuf;

use anyhow::bail;
use indicatif::{ProgressBar, ProgressStyle};

use crate::capture::{self, CaptureOptions, Ending, Stats};
use crate::session::protocol;

#[derive(clap::Args)]
pub struct Args {
    /// Left camera: a device index (0), a device path (/dev/video0), a video file, or a URL or
    /// GStreamer pipeline OpenCV opens
    #[arg(long)]
    left: String,
    /// Right camera, as --left
    #[arg(long)]
    right: String,
    /// Session directory to create (frames/, frames.csv, pressures.csv, capture.json)
    #[arg(long)]
    out: PathBuf,
    /// Frame size and rate asked of the cameras
    #[arg(long, default_value_t = 1280)]
    width: u32,
    #[arg(long, default_value_t = 720)]
    height: u32,
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Pressure protocol to drive (step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s; `handcap protocol`
    /// writes the paper's, or a dynamic one); needs --set-pressure or --regulator
    #[arg(long)]
    protocol: Option<PathBuf>,
    /// A regulator process started once and kept running: each protocol row is one line
    /// `time_s P1_kpa P2_kpa P3_kpa` on its input, sent at the row's time (for dynamic
    /// protocols, tens of commands a second); a line it prints back in the same form is the
    /// pressure it measured, logged beside the command (P1_measured_kpa, …). If it exits,
    /// stops reading for 2 s or prints anything else, the session ends, everything kept
    #[arg(long, requires = "protocol", conflicts_with = "set_pressure")]
    regulator: Option<String>,
    /// Command run at each step, {p1} {p2} {p3} (kPa) and {step} filled in, e.g.
    /// 'python3 regulator.py {p1} {p2} {p3}'; pressures above 300 kPa are refused first
    #[arg(long, requires = "protocol")]
    set_pressure: Option<String>,
    /// Command run once if the protocol's session ends early (Ctrl-C, a signal, a camera lost,
    /// a failing command), e.g. 'python3 regulator.py 0 0 0' to vent the muscles; its result
    /// goes to capture.json
    #[arg(long, requires = "protocol")]
    on_abort: Option<String>,
    /// Command that switches on a light both cameras see (an LED, a lamp on a relay) and
    /// returns once it is on, e.g. 'gpioset gpiochip0 17=1'; run 1 s into the session, before
    /// the protocol: each camera's latency is measured from it, written to capture.json and
    /// used by triangulate
    #[arg(long, conflicts_with = "calib")]
    flash: Option<String>,
    /// Stop after this many seconds (default: the protocol's end, or Ctrl-C)
    #[arg(long, value_parser = super::finite)]
    duration_s: Option<f64>,
    /// A camera or stream silent this long has stopped, and ends the session (s; a slow
    /// network or a busy machine may need more)
    #[arg(long, default_value_t = crate::capture::STALL_S, value_parser = super::finite)]
    stall_s: f64,
    /// Board pairs for `calibrate` instead of the finger's frames: a pair is taken when the
    /// board is seen in both cameras (a chessboard whole, a ChArUco board at least in part),
    /// still, somewhere new (OUT/calib/left_NN.jpg, …)
    #[arg(long, conflicts_with_all = ["protocol", "set_pressure"])]
    calib: bool,
    /// With --calib: how many pairs
    #[arg(long, default_value_t = 20, requires = "calib")]
    pairs: usize,
    /// With --calib: one still pair of the board standing at the finger's base, as
    /// OUT/calib/left_ref, right_ref (run after the pairs)
    #[arg(long, requires = "calib")]
    reference: bool,
    /// With --calib: the board (default: calib/board.yml's)
    #[command(flatten)]
    board: super::board::BoardArgs,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let options = options(&a)?;
    if options.protocol.is_none() && a.duration_s.is_none() && !a.calib {
        println!("filming until Ctrl-C (no --protocol, no --duration-s); log the regulator on the clock capture.json describes");
    }
    let bar = ProgressBar::new_spinner()
        .with_style(ProgressStyle::with_template("{spinner} {elapsed} {msg}").expect("template"));
    let steps = options.protocol.as_ref().map_or(0, |(s, _)| s.len());
    let wanted = options
        .calibration
        .as_ref()
        .map(|c| if c.reference { 1 } else { c.pairs });
    let say = |s: &Stats| match wanted {
        Some(n) => board_line(s, n),
        None => line(s, steps),
    };
    let live = |s: &Stats| {
        bar.set_message(say(s));
        bar.tick();
    };
    let summary = super::with_session(|session| {
        crate::pipeline::capture::run(&a.out, &options, session, &live)
    })?;
    bar.finish_and_clear();
    for (side, refused) in ["left", "right"].iter().zip(&summary.refused) {
        if !refused.is_empty() {
            println!("{side} camera: the backend refused {}", refused.join(", "));
        }
    }
    println!("{}", say(&summary.stats));
    let out = a.out.display();
    if wanted.is_some() {
        println!(
            "wrote {out}/calib/ ({} pairs and board.yml), {out}/capture.json; then: handcap calibrate {out}/calib",
            summary.stats.board_pairs,
        );
    } else {
        println!(
            "wrote {out}/frames/ ({} left, {} right frames), {out}/frames/frames.csv{}, {out}/capture.json",
            summary.stats.frames[0],
            summary.stats.frames[1],
            if steps > 0 { format!(", {out}/pressures.csv") } else { String::new() },
        );
    }
    if let Some(flash) = &summary.flash {
        println!("{}", flash_line(flash));
    }
    if matches!(
        options.protocol,
        Some((_, capture::Regulator::Streaming(_)))
    ) {
        let [median, latest] = summary.stats.command_late_ms;
        println!(
            "regulator: {} lines written, {median:.2} ms after they were due (median), {latest:.2} ms at most",
            summary.stats.steps_done
        );
    }
    if let Some(result) = &summary.on_abort {
        eprintln!("ran --on-abort: {result}");
    }
    ended(&summary, &a.out)
}

/// The session's settings from the flags: the protocol read with how the regulator is told it,
/// the calibration board.
fn options(a: &Args) -> anyhow::Result<CaptureOptions> {
    let protocol = match (&a.protocol, &a.set_pressure, &a.regulator) {
        (Some(path), Some(command), _) => Some((
            protocol::read(path)?,
            capture::Regulator::PerStep(command.clone()),
        )),
        (Some(path), None, Some(command)) => Some((
            protocol::read(path)?,
            capture::Regulator::Streaming(command.clone()),
        )),
        (Some(_), None, None) => {
            super::usage!("--protocol needs --set-pressure (a command per step) or --regulator (one process, a line per step)")
        }
        _ => None,
    };
    if a.board.any() && !a.calib {
        super::usage!("--board, --square-mm, --marker-mm and --dictionary describe the calibration board: add --calib");
    }
    let calibration = match a.board.flags().over(&crate::calib::file::default_board()) {
        Ok(board) => a.calib.then_some(capture::BoardPairs {
            board,
            pairs: a.pairs,
            reference: a.reference,
        }),
        Err(e) => super::usage!("{e}"),
    };
    Ok(CaptureOptions {
        sources: [a.left.clone(), a.right.clone()],
        width: a.width,
        height: a.height,
        fps: a.fps,
        protocol,
        duration_s: a.duration_s,
        stall_s: a.stall_s,
        calibration,
        on_abort: a.on_abort.clone(),
        flash: a.flash.clone(),
    })
}

/// A calibration capture's live line: the pairs taken, why the last look was refused, the
/// cameras' delay.
fn board_line(s: &Stats, wanted: usize) -> String {
    format!(
        "board pairs {}/{wanted}{}{}",
        s.board_pairs,
        if s.board_refused.is_empty() {
            String::new()
        } else {
            format!(" ({})", s.board_refused)
        },
        s.board_delay_ms.map_or(String::new(), |ms| format!(
            "; the right camera sees the board {ms:+.0} ms after the left"
        ))
    )
}

/// How the session ended, as the command's result: a session ended early is an error saying
/// why (everything filmed is kept).
fn ended(summary: &capture::CaptureSummary, out: &std::path::Path) -> anyhow::Result<()> {
    let kept = "every frame before it is kept and listed";
    let over = summary.stats.over_hold;
    match &summary.ending {
        Ending::ProtocolDone if over > 0 => bail!(
            "{over} of {} steps: the --set-pressure command returned only after the step's hold was over (commands took {:.0} ms median, {:.0} ms at most), so the finger never settled in them and triangulate finds no row there; hold each step longer than the regulator takes; {kept}",
            summary.stats.steps_done,
            summary.stats.command_ms[0],
            summary.stats.command_ms[1]
        ),
        Ending::ProtocolDone | Ending::Duration | Ending::PairsTaken => Ok(()),
        Ending::Interrupted => {
            Err(super::Interrupted(format!("interrupted: {kept} in {}", out.display())).into())
        }
        Ending::CameraStopped {
            side,
            time_s,
            frames,
        } => bail!(
            "the {} camera stopped delivering at {time_s:.2} s, after {frames} frames; {kept}",
            side.name()
        ),
        Ending::CommandFailed { step, message } => {
            bail!("--set-pressure failed at step {step}: {message}; {kept}")
        }
        Ending::FlashFailed { message } => bail!("--flash failed: {message}; {kept}"),
        Ending::WriteFailed { message } => bail!(
            "{message}; the session stopped{}, and {kept} (free space, or film to another disk)",
            if summary.on_abort.is_some() { " and --on-abort ran" } else { "" }
        ),
        // Never the end of a session `capture` returns: the first while filming, the second
        // is returned as an error.
        Ending::Filming | Ending::ThreadFailed { .. } => {
            bail!("the session ended unexpectedly; {kept}")
        }
    }
}

/// The live line: frames, rates, drops, frames stamped late, skew, steps.
fn line(s: &Stats, steps: usize) -> String {
    let progress = match (steps, s.over_hold) {
        (0, _) => String::new(),
        (_, 0) => format!(", step {}/{steps}", s.steps_done),
        (_, over) => format!(
            ", step {}/{steps} ({over} of them unsettled: the command took longer than the hold)",
            s.steps_done
        ),
    };
    let late = if s.late.iter().sum::<usize>() > 0 {
        format!(
            ", stamped late {}/{} (up to {:.0} ms: frames queued, the machine or network fell behind; triangulate leaves them out)",
            s.late[0],
            s.late[1],
            s.late_max_ms[0].max(s.late_max_ms[1])
        )
    } else {
        String::new()
    };
    format!(
        "left {} frames {:.1} fps, right {} frames {:.1} fps, drops {}/{}{late}, left/right skew {:.1} ms (median){progress}",
        s.frames[0], s.fps[0], s.frames[1], s.fps[1], s.drops[0], s.drops[1], s.skew_ms
    )
}

/// What the flash measured.
fn flash_line(f: &crate::capture::flash::FlashLatency) -> String {
    let one = |k: usize| match (f.latency_ms[k], f.within_ms[k]) {
        (Some(ms), Some(within)) => format!("{ms:.0} ms (± {within:.0})"),
        _ => "not seen".into(),
    };
    let mut line = format!(
        "camera latency from the flash: left {}, right {}",
        one(0),
        one(1)
    );
    if f.both_ms().is_some() {
        line += "; triangulate takes them from capture.json";
    }
    for why in &f.unmeasured {
        line += &format!("; {why}");
    }
    line
}
