//! The triangulate stage: frames, calibration and pressure log → the dataset and the files
//! beside it.

mod cameras;
mod colour;

pub use cameras::{
    more_cameras, run_cameras, run_more_cameras, run_per_frame_cameras, MoreCameras,
    TriangulatedCameras, TriangulatedFrames,
};
pub use colour::stored_colour;
pub(super) use colour::write_colour;

use std::fmt;
use std::path::{Path, PathBuf};

use super::outputs::{self, Output};
use super::{io_error, PipelineError, Session, Task};
use crate::calib::file::{read_calibration, CalibrationFile};
use crate::capture::flash::FlashLatency;
use crate::capture::sync_led::SyncLed;
use crate::capture::CAPTURE_FILE;
use crate::session::frames::FrameList;
use crate::session::pressures::{read_pressure_log, PressureLog};
use crate::stereo::Side;
use crate::triangulate::per_frame::{self, PerFrame};
use crate::triangulate::summary::FrameCounts;
use crate::triangulate::{self, output, TriangulateOptions, Triangulation};

/// What the stage did and wrote.
pub struct Triangulated {
    pub triangulation: Triangulation,
    /// The dataset first, then the files beside it.
    pub written: Vec<PathBuf>,
    /// How the cameras stored their frames' colour ([`stored_colour`]).
    pub colour: Option<String>,
}

/// The regulator's log: `given`, else `pressures.csv` beside the frames directory.
///
/// # Errors
/// [`PipelineError::Request`] when none is given and there is no such file.
pub fn pressure_log(frames: &Path, given: Option<PathBuf>) -> Result<PathBuf, PipelineError> {
    given
        .or_else(|| {
            frames
                .parent()
                .map(|d| d.join("pressures.csv"))
                .filter(|p| p.is_file())
        })
        .ok_or_else(|| {
            PipelineError::Request(format!(
                "no pressure log given and no pressures.csv beside {}; give the log (pressures=LOG.csv)",
                frames.display()
            ))
        })
}

/// Both cameras' latencies (ms) measured from the flash `capture` filmed, when the frames'
/// session has them ([`crate::capture::flash`]).
fn flash_latency(frames: &Path) -> Option<[f64; 2]> {
    let json = capture_summary(frames)?;
    let flash: FlashLatency = serde_json::from_value(json["flash"].clone()).ok()?;
    flash.both_ms()
}

/// Both cameras' delays (ms) from the LED `capture --sync-led` blinked, when it measured them.
fn led_delays(frames: &Path) -> Option<[f64; 2]> {
    let json = capture_summary(frames)?;
    let led: SyncLed = serde_json::from_value(json["sync_led"].clone()).ok()?;
    led.both_ms()
}

/// `options` with the cameras' delays `capture` measured, when none were given: the LED's
/// (both cameras on one set of blinks: their clocks' offset too), else the flash's; whether
/// where they came from.
fn with_measured_delays(
    frames: &Path,
    options: &TriangulateOptions,
) -> (TriangulateOptions, Option<String>) {
    let given = options.latency_s.is_some();
    let led = (!given).then(|| led_delays(frames)).flatten();
    let flash = (!given && led.is_none())
        .then(|| flash_latency(frames))
        .flatten();
    let measured = TriangulateOptions {
        latency_s: options
            .latency_s
            .or(led.or(flash).map(|ms| ms.map(|ms| ms / 1e3))),
        clocks_measured: options.clocks_measured || led.is_some(),
        ..options.clone()
    };
    let from = match (led, flash) {
        (Some(_), _) => Some(format!("from the LED in {CAPTURE_FILE}")),
        (None, Some(_)) => Some(format!("from the flash in {CAPTURE_FILE}")),
        (None, None) => None,
    };
    (measured, from)
}

/// The summary in `capture.json` beside the frames' folder, when there is one.
fn capture_summary(frames: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(frames.parent()?.join(CAPTURE_FILE)).ok()?;
    let json: serde_json::Value = serde_json::from_str(&text).ok()?;
    Some(json["summary"].clone())
}

/// Checks every file `run` writes against every file it reads (the frames and their index, the
/// calibration, the log) and against each other.
fn check_outputs(
    frames: &Path,
    listed: &FrameList,
    calib: &Path,
    pressures: &Path,
    log: &PressureLog,
    out: &Path,
) -> Result<(), PipelineError> {
    let index = frames.join("frames.csv");
    let inputs: Vec<&Path> = [calib, pressures, index.as_path()]
        .into_iter()
        .chain(listed.paths.iter().flatten().map(PathBuf::as_path))
        .chain(listed.videos.iter().flatten().map(PathBuf::as_path))
        .collect();
    outputs::check(&inputs, &planned_outputs(out, log))
}

/// Every file a triangulation into `out` may write: the dataset, one per phase of `log`, and
/// the files beside it.
fn planned_outputs(out: &Path, log: &PressureLog) -> Vec<Output> {
    let mut planned = vec![Output::new(out, "the dataset")];
    if let Some(col) = log.extra_columns.iter().position(|c| c == "phase") {
        let mut phases: Vec<&str> = log.steps.iter().map(|s| s.extra[col].as_str()).collect();
        phases.sort_unstable();
        phases.dedup();
        planned.extend(phases.into_iter().map(|phase| {
            Output::new(
                output::phase_path(out, phase),
                format!("the dataset of phase `{phase}`"),
            )
        }));
    }
    planned.extend(
        output::BESIDE
            .iter()
            .map(|(suffix, role)| Output::new(output::beside(out, suffix), *role)),
    );
    planned
}

/// The run's inputs, read and checked: `frames` a directory, the options in their ranges, the
/// calibration, the log, the frame list, and no output naming an input.
fn read_inputs(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
) -> Result<(CalibrationFile, PressureLog, FrameList), PipelineError> {
    if !frames.is_dir() {
        return Err(PipelineError::Place(format!(
            "{} is not a directory of frames",
            frames.display()
        )));
    }
    options.check().map_err(PipelineError::Request)?;
    let calibration = read_calibration(calib)?;
    let log = read_pressure_log(pressures)?;
    let listed = FrameList::read(frames, options.video_start_s)?;
    check_outputs(frames, &listed, calib, pressures, &log, out)?;
    Ok((calibration, log, listed))
}

/// Finds the tip in every frame pair of `frames`, in the hand frame of `calib`, one row per
/// step of the log at `pressures`; writes `out` and the files beside it. Ctrl-C stops at the
/// next frame: the files hold the frames examined, and the summary says `interrupted`.
///
/// # Errors
/// [`PipelineError`]: unreadable inputs, no usable step, `out` naming an input, or a file that
/// cannot be written.
pub fn run(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
    session: &Session,
) -> Result<Triangulated, PipelineError> {
    // Delays not given: the LED or the flash `capture` filmed measured them, when it did; the
    // LED's, both cameras' on one set of blinks, are also their clocks' offset.
    let (options, from) = &with_measured_delays(frames, options);
    let (calibration, log, listed) = read_inputs(frames, calib, pressures, options, out)?;
    let result = triangulate::triangulate(
        &listed,
        &calibration,
        &log,
        options,
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::Event::Finished(Task::Frames));
    let mut triangulation = result?;
    if from.is_some() {
        triangulation.summary.latency.from.clone_from(from);
    }
    let provenance = provenance(session, frames, calib, pressures)?;
    let written = triangulation.write(out, &provenance)?;
    Ok(Triangulated {
        triangulation,
        written,
        colour: stored_colour(frames, &PAIR),
    })
}

/// The run's provenance: the calibration, the log and the frame list (when there is one) as its
/// inputs.
pub(super) fn provenance(
    session: &Session,
    frames: &Path,
    calib: &Path,
    pressures: &Path,
) -> Result<crate::provenance::Provenance, PipelineError> {
    let mut provenance = session.provenance(None);
    let index = frames.join("frames.csv");
    let listed_by = Some(index.as_path()).filter(|p| p.exists());
    for input in [calib, pressures].into_iter().chain(listed_by) {
        provenance = provenance.with_input(input).map_err(io_error(input))?;
    }
    Ok(provenance)
}

/// What the per-frame stage did and wrote.
pub struct TriangulatedPerFrame {
    pub per_frame: PerFrame,
    pub written: Vec<PathBuf>,
    /// How the cameras stored their frames' colour ([`stored_colour`]).
    pub colour: Option<String>,
}

/// The tip at every left frame's instant of `frames` (`triangulate --per-frame`), in the hand
/// frame of `calib`, with the pressures of the log at `pressures` in force then; writes `out`,
/// the per-phase files and the summary beside it. Ctrl-C stops at the next frame: the rows of
/// the frames examined are written, the summary says `interrupted`.
///
/// # Errors
/// As [`run`].
pub fn run_per_frame(
    frames: &Path,
    calib: &Path,
    pressures: &Path,
    options: &TriangulateOptions,
    out: &Path,
    session: &Session,
) -> Result<TriangulatedPerFrame, PipelineError> {
    let (options, _) = &with_measured_delays(frames, options);
    let (calibration, log, listed) = read_inputs(frames, calib, pressures, options, out)?;
    let index = frames.join("frames.csv");
    let result = per_frame::triangulate_per_frame(
        &listed,
        &index,
        &calibration,
        &log,
        options,
        &session.counter(Task::Frames),
        session.interrupt,
    );
    session.emit(super::Event::Finished(Task::Frames));
    let per_frame = result?;
    let provenance = provenance(session, frames, calib, pressures)?;
    let written = per_frame.write(out, &log, &provenance)?;
    Ok(TriangulatedPerFrame {
        per_frame,
        written,
        colour: stored_colour(frames, &PAIR),
    })
}

/// The pair's cameras, as their frames are named.
const PAIR: [&str; 2] = [Side::Left.name(), Side::Right.name()];

/// What became of the frames, one line.
fn frames_line(c: &FrameCounts) -> String {
    format!(
        "frames: {} left, {} right; marker missing in {} / {}, several candidates in {} / {}, unreadable {} / {}, no file {} / {}",
        c.listed[0],
        c.listed[1],
        c.marker_missing[0],
        c.marker_missing[1],
        c.several_candidates[0],
        c.several_candidates[1],
        c.unreadable[0],
        c.unreadable[1],
        c.no_file[0],
        c.no_file[1],
    )
}

impl fmt::Display for TriangulatedPerFrame {
    /// What a per-frame run found, in a few lines.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let s = &self.per_frame.summary;
        writeln!(f, "{}", frames_line(&s.frames))?;
        write_colour(f, self.colour.as_ref())?;
        let flagged: Vec<String> = s.flagged.iter().map(|(k, v)| format!("{v} {k}")).collect();
        writeln!(
            f,
            "rows: {} (one per left frame), {} with a tip and no flag{}",
            s.rows,
            s.good_rows,
            if flagged.is_empty() {
                String::new()
            } else {
                format!("; flagged: {}", flagged.join(", "))
            }
        )?;
        if let (true, Some([l, r])) = (s.clocks_measured, s.delays_ms) {
            writeln!(
                f,
                "clock: each camera's delay from the LED in {CAPTURE_FILE} (left {l:.1} ms, right {r:.1} ms) taken out of its stamps; no offset measured from the motion"
            )?;
        } else if s.clock_frames > 0 {
            let drift = if s.clock_drift_ms == 0.0 {
                String::new()
            } else {
                format!(
                    " mid-session, drifting {:+.2} ms from the first frame to the last",
                    s.clock_drift_ms
                )
            };
            writeln!(f,
            "clock: the right camera's stamps run {:+.2} ms ahead of the left's{drift} (from the motion of {} frames); tracks interpolated across it",
            s.clock_offset_ms, s.clock_frames
        )?;
        } else {
            writeln!(
                f,
                "clock: too little motion to measure the cameras' offset; stamps taken as they are"
            )?;
        }
        writeln!(f,
        "origin: {} rows of the first rest hold, spread {:.4} mm RMS; reprojection {:.3} / {:.3} / {:.3} px (median / 95 % / max)",
        s.origin_rows, s.origin_spread_mm, s.reproj_px[0], s.reproj_px[1], s.reproj_px[2]
    )
    }
}

impl fmt::Display for Triangulated {
    /// What the frames gave, step by step, as `handcap triangulate` prints it.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let t = &self.triangulation;
        let s = &t.summary;
        writeln!(f, "{}", frames_line(&s.frames))?;
        write_colour(f, self.colour.as_ref())?;
        let frames = &s.frames;
        if let Some(first) = &frames.first_unreadable {
            writeln!(f, "  first unreadable: {first}")?;
        }
        if frames.stamped_late.iter().sum::<usize>() > 0 {
            writeln!(f,
            "  stamped late (they arrived faster than the camera makes them: they had waited in a queue, the capture machine or network fell behind), left out of the pairs: {} left, {} right frames, up to {:.0} ms",
            frames.stamped_late[0], frames.stamped_late[1], frames.late_max_ms
        )?;
        }
        let pairs: Vec<String> = s.pairs.iter().map(|(k, v)| format!("{v} {k}")).collect();
        writeln!(
            f,
            "pairs: {} formed ({} left, {} right frames unpaired): {}",
            s.pairs_formed,
            s.unpaired[0],
            s.unpaired[1],
            pairs.join(", ")
        )?;
        writeln!(
            f,
            "reprojection of used pairs: median {:.3} px, 95 % {:.3} px, max {:.3} px",
            s.reproj_px[0], s.reproj_px[1], s.reproj_px[2]
        )?;
        let [mean, sd, p95] = s.epipolar_px;
        writeln!(f,
        "epipolar residual of the used pairs: mean {mean:+.3} px, sd {sd:.3} px, 95 % within {p95:.3} px (a mean away from 0 or a wide spread: a biased detection or a drifted calibration)"
    )?;
        if s.centroid_only[0] + s.centroid_only[1] > 0 {
            writeln!(f,
            "  marker placed by its colour centroid only (the sub-pixel fit did not settle) in {} left, {} right used frames",
            s.centroid_only[0], s.centroid_only[1]
        )?;
        }
        for end in s.video_ended.iter().flatten() {
            writeln!(f,
            "  {} ends after {} frames, before the last {} frames frames.csv lists for it (cut short?): those are counted missing",
            end.path.display(),
            end.frames,
            end.missing
        )?;
        }
        let decoded: Vec<String> = ["left", "right"]
            .iter()
            .zip(&s.decoded_video)
            .filter_map(|(side, codec)| codec.as_ref().map(|c| format!("{side} {c}")))
            .collect();
        if !decoded.is_empty() {
            writeln!(f,
            "  videos not Motion-JPEG ({}): their frames reach the marker's fit decoded, their colour's sampling unknown (MPEG-4 copies of a lab capture: tip 0.11 mm RMS against 0.04 from its JPEGs); record the webcam's own Motion-JPEG stream (ffmpeg -input_format mjpeg … -c:v copy) for the full accuracy",
            decoded.join(", ")
        )?;
        }
        let mut latency = s.latency.describe().into_iter();
        writeln!(f, "{}", latency.next().expect("a first line"))?;
        for line in latency {
            writeln!(f, "  {line}")?;
        }
        let c = &s.clock;
        writeln!(f,
        "clock: a pair's frames {:.1} ms apart (median, 95 % within {:.1}), drift {:+.1} ms over the session; frame periods {}; frames dropped within steps {}/{}",
        c.skew_ms[0], c.skew_ms[1], c.drift_ms, c.periods(), c.dropped[0], c.dropped[1]
    )?;
        if let Some([median, largest]) = c.command_ms {
            writeln!(f,
            "  the regulator's commands took {median:.0} ms (median), {largest:.0} ms at most; settling counted from their end"
        )?;
        }
        if !c.settling_only.is_empty() {
            writeln!(f,
            "  {} steps were filmed only while settling (no frame later than settle_s={} after the command returned): hold each step longer{}",
            c.settling_only.len(),
            t.options.settle_s,
            if c.command_ms.is_some_and(|[_, largest]| largest > 1e3 * t.options.settle_s) {
                ", or make the regulator's command return sooner"
            } else {
                ""
            }
        )?;
        }
        writeln!(
            f,
            "hand origin: {} pairs over {} zero-pressure steps, spread {:.4} mm",
            s.origin.pairs, s.origin.zero_steps, s.origin.spread_mm
        )?;
        writeln!(f,
        "steps: {} logged, {} rows ({} flagged), {} without a tip; spread of a step's pairs: median {:.4} mm, 95 % {:.4} mm, max {:.4} mm",
        s.steps_logged,
        s.rows,
        s.rows_flagged,
        s.steps_without_tip.len(),
        s.step_spread_mm[0],
        s.step_spread_mm[1],
        s.step_spread_mm[2],
    )?;
        for r in t.rows.iter().filter(|r| !r.flags.is_empty()).take(10) {
            writeln!(
                f,
                "  flagged step {} ({}, {}, {} kPa): {} ({} pairs, spread {:.3} mm)",
                r.step,
                r.pressures_kpa[0],
                r.pressures_kpa[1],
                r.pressures_kpa[2],
                r.flags.join(", "),
                r.n_frames,
                r.spread_mm
            )?;
        }
        Ok(())
    }
}
