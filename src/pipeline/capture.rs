//! Filming a session as a stage: the settings checked, then [`crate::capture::capture`] with the
//! session's interrupt, its figures handed to `live` about once a second. How the session
//! ended is in the summary ([`crate::capture::Ending`]); [`ended`] says it as a result,
//! [`live_line`] the figures as they come.

use std::fmt;
use std::path::Path;

use super::{PipelineError, Session};
use crate::capture::{self, CaptureOptions, CaptureSummary, Ending, Stats};

/// Films a session into `out` (`frames/`, `frames/frames.csv`, `pressures.csv` when a protocol
/// runs, `capture.json`).
///
/// # Errors
/// [`PipelineError::Request`] for settings that cannot work; [`PipelineError::Camera`] (a
/// capture error) for a camera that does not open, `out` holding a capture, a file that cannot
/// be written.
pub fn run(
    out: &Path,
    options: &CaptureOptions,
    session: &Session,
    live: &(dyn Fn(&Stats) + Sync),
) -> Result<CaptureSummary, PipelineError> {
    options.check().map_err(PipelineError::Request)?;
    Ok(capture::capture(out, options, live, session.interrupt)?)
}

/// The live line of a session filming under `options`: the board pairs taken, or the frames,
/// their rates and the protocol's steps.
pub fn live_line(stats: &Stats, options: &CaptureOptions) -> String {
    match &options.calibration {
        Some(c) => board_line(stats, if c.reference { 1 } else { c.pairs }),
        None => steps_line(
            stats,
            &names(options),
            options.protocol.as_ref().map_or(0, |(s, _)| s.len()),
        ),
    }
}

/// How the session ended, as a result: a session ended early is an error saying why
/// (everything filmed is kept).
pub fn ended(summary: &CaptureSummary, out: &Path) -> Result<(), PipelineError> {
    let kept = "every frame before it is kept and listed";
    let over = summary.stats.over_hold;
    match &summary.ending {
        Ending::ProtocolDone if over > 0 => Err(format!(
            "{over} of {} steps: the regulator's command returned only after the step's hold was over (commands took {:.0} ms median, {:.0} ms at most), so the finger never settled in them and triangulate finds no row there; hold each step longer than the regulator takes; {kept}",
            summary.stats.steps_done,
            summary.stats.command_ms[0],
            summary.stats.command_ms[1]
        )),
        Ending::ProtocolDone | Ending::Duration | Ending::PairsTaken => return Ok(()),
        Ending::Interrupted => {
            return Err(PipelineError::Interrupted(format!(
                "interrupted: {kept} in {}",
                out.display()
            )))
        }
        Ending::CameraStopped {
            camera,
            time_s,
            frames,
        } => Err(format!(
            "the {camera} camera stopped delivering at {time_s:.2} s, after {frames} frames; {kept}"
        )),
        Ending::CommandFailed { step, message } => {
            Err(format!("the regulator's command failed at step {step}: {message}; {kept}"))
        }
        Ending::FlashFailed { message } => Err(format!("the flash command failed: {message}; {kept}")),
        Ending::WriteFailed { message } => Err(format!(
            "{message}; the session stopped{}, and {kept} (free space, or film to another disk)",
            if summary.on_abort.is_some() { " and the abort command ran" } else { "" }
        )),
        // Never the end of a session `capture` returns: the first while filming, the second
        // is returned as an error.
        Ending::Filming | Ending::ThreadFailed { .. } => {
            Err(format!("the session ended unexpectedly; {kept}"))
        }
    }
    .map_err(PipelineError::Stopped)
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

/// The session's cameras' names.
fn names(options: &CaptureOptions) -> Vec<&str> {
    options.sources.iter().map(|s| s.name.as_str()).collect()
}

/// A session's live line: each camera's (of `names`) frames and rate, drops, frames stamped
/// late, skew, steps.
fn steps_line(s: &Stats, names: &[&str], steps: usize) -> String {
    let progress = match (steps, s.over_hold) {
        (0, _) => String::new(),
        (_, 0) => format!(", step {}/{steps}", s.steps_done),
        (_, over) => format!(
            ", step {}/{steps} ({over} of them unsettled: the command took longer than the hold)",
            s.steps_done
        ),
    };
    let each = |v: &[usize]| v.iter().map(usize::to_string).collect::<Vec<_>>().join("/");
    let late = if s.late.iter().sum::<usize>() > 0 {
        format!(
            ", stamped late {} (up to {:.0} ms: frames queued, the machine or network fell behind; triangulate leaves them out)",
            each(&s.late),
            s.late_max_ms.iter().copied().fold(0.0, f64::max)
        )
    } else {
        String::new()
    };
    let cameras: Vec<String> = names
        .iter()
        .zip(s.frames.iter().zip(&s.fps))
        .map(|(name, (frames, fps))| format!("{name} {frames} frames {fps:.1} fps"))
        .collect();
    let skew = match names {
        ["left", "right"] => "left/right skew".to_string(),
        _ => format!("skew from {} (the largest)", names[0]),
    };
    format!(
        "{}, drops {}{late}, {skew} {:.1} ms (median){progress}",
        cameras.join(", "),
        each(&s.drops),
        s.skew_ms
    )
}

/// What a session filmed and wrote, as `handcap capture` says it at the end.
pub struct Filmed<'a> {
    summary: &'a CaptureSummary,
    out: &'a Path,
    options: &'a CaptureOptions,
    /// How the cameras stored their frames' colour: what their JPEG quality allows, said
    /// before the session is triangulated ([`super::triangulate::stored_colour`]).
    colour: Option<String>,
}

impl<'a> Filmed<'a> {
    /// The session `summary` filmed into `out` with `options`; reads its frames' colour.
    pub fn new(
        summary: &'a CaptureSummary,
        out: &'a Path,
        options: &'a CaptureOptions,
    ) -> Filmed<'a> {
        let filmed = options.calibration.is_none();
        let colour = filmed
            .then(|| super::triangulate::stored_colour(&out.join("frames"), &names(options)))
            .flatten();
        Filmed {
            summary,
            out,
            options,
            colour,
        }
    }
}

impl fmt::Display for Filmed<'_> {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let (summary, options, out) = (self.summary, self.options, self.out.display());
        let stats = &summary.stats;
        let names = names(options);
        for (name, refused) in names.iter().zip(&summary.refused) {
            if !refused.is_empty() {
                writeln!(
                    f,
                    "{name} camera: the backend refused {}",
                    refused.join(", ")
                )?;
            }
        }
        writeln!(f, "{}", live_line(stats, options))?;
        if options.calibration.is_some() {
            writeln!(
                f,
                "wrote {out}/calib/ ({} pairs and board.yml), {out}/capture.json; then: handcap calibrate {out}/calib",
                stats.board_pairs,
            )?;
        } else {
            let frames: Vec<String> = names
                .iter()
                .zip(&stats.frames)
                .map(|(name, n)| format!("{n} {name}"))
                .collect();
            writeln!(
                f,
                "wrote {out}/frames/ ({} frames), {out}/frames/frames.csv{}, {out}/capture.json",
                frames.join(", "),
                if options.protocol.is_some() {
                    format!(", {out}/pressures.csv")
                } else {
                    String::new()
                },
            )?;
            super::triangulate::write_colour(f, self.colour.as_ref())?;
        }
        if let Some(flash) = &summary.flash {
            writeln!(f, "{flash}")?;
        }
        if let Some(led) = &summary.sync_led {
            writeln!(f, "{led}")?;
        }
        if let Some((_, capture::Regulator::Streaming(_) | capture::Regulator::Serial(..))) =
            &options.protocol
        {
            let [median, latest] = stats.command_late_ms;
            writeln!(
                f,
                "regulator: {} lines written, {median:.2} ms after they were due (median), {latest:.2} ms at most",
                stats.steps_done
            )?;
        }
        Ok(())
    }
}
