//! `handcap triangulate DIR/frames --calib calib.yml --pressures DIR/pressures.csv --out
//! dataset.csv`: the tip in every frame pair, in the hand frame, one row per pressure step.

use std::path::PathBuf;

use crate::pipeline::triangulate::{self, Triangulated};
use crate::triangulate::per_frame::PerFrameSummary;
use crate::triangulate::summary::FrameCounts;
use crate::triangulate::TriangulateOptions;

use super::usage;

#[derive(clap::Args)]
pub struct Args {
    /// Directory with frames.csv and left_NNNNN / right_NNNNN images (PNG or JPEG)
    frames: PathBuf,
    /// Stereo calibration with the hand axes (R_hand), as `handcap calibrate` writes it
    #[arg(long)]
    calib: PathBuf,
    /// Regulator log: time_s,P1_kpa,P2_kpa,P3_kpa, one row per commanded step (default: the
    /// frames directory's parent's pressures.csv)
    #[arg(long)]
    pressures: Option<PathBuf>,
    /// Dataset to write (CSV); the other files go beside it
    #[arg(long, default_value = "dataset.csv")]
    out: PathBuf,
    /// Largest left/right timestamp difference of a pair, ms
    #[arg(long, default_value_t = 1e3 * TriangulateOptions::default().max_dt_s)]
    max_dt_ms: f64,
    /// Frames earlier than this into their pressure step are skipped, s
    #[arg(long, default_value_t = TriangulateOptions::default().settle_s)]
    settle_s: f64,
    /// Largest reprojection error of a used pair, px
    #[arg(long, default_value_t = TriangulateOptions::default().max_reproj_px)]
    max_reproj_px: f64,
    /// Triangulate the raw matches, without the Hartley-Sturm correction
    #[arg(long)]
    no_correct_matches: bool,
    /// Rows with fewer frame pairs are flagged
    #[arg(long, default_value_t = TriangulateOptions::default().min_frames)]
    min_frames: usize,
    /// Rows whose frame pairs lie further apart are flagged, mm
    #[arg(long, default_value_t = TriangulateOptions::default().max_spread_mm)]
    max_spread_mm: f64,
    /// The finger's length, mm: a row whose tip lies further than this (+1 mm) from the base
    /// (this far up the hand's z axis from the rest tip) is flagged `reach`
    #[arg(long, default_value_t = TriangulateOptions::default().finger_mm)]
    finger_mm: f64,
    /// Marker area limits (pixels above half its peak redness): MIN,MAX
    #[arg(long, value_delimiter = ',', num_args = 1..=2, default_values_t = [TriangulateOptions::default().marker.min_area_px, TriangulateOptions::default().marker.max_area_px])]
    marker_area_px: Vec<usize>,
    /// For FRAMES holding left.<video> and right.<video> without frames.csv: when each video's
    /// first frame was taken, on the pressure log's clock (s); LEFT,RIGHT or one time for both
    #[arg(long, value_delimiter = ',', num_args = 1..=2, value_parser = super::finite)]
    video_start_s: Vec<f64>,
    /// Each camera's delay from exposure to timestamp, when known (e.g. from filming an LED the
    /// regulator lights), ms: LEFT,RIGHT or one for both; 0 takes the stamps as they are.
    /// Default: measured from the tip's motion after each command
    #[arg(long, value_delimiter = ',', num_args = 1..=2, value_parser = super::finite)]
    latency_ms: Vec<f64>,
    /// One row per left frame instant instead of one per pressure step, for a finger in motion
    /// (a dynamic protocol): the right camera's track interpolated to each left frame's time
    /// (and the cameras' clock offset measured from the motion), the pressures in force then;
    /// columns time_s, the log's others, P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,frame,reproj_px,
    /// flag. The log must start with a rest hold at 0, 0, 0 kPa (the hand frame's origin)
    #[arg(long, conflicts_with_all = ["max_dt_ms", "settle_s", "min_frames", "max_spread_mm"])]
    per_frame: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let pressures = triangulate::pressure_log(&a.frames, a.pressures.clone())?;
    let mut options = TriangulateOptions {
        max_dt_s: a.max_dt_ms / 1e3,
        settle_s: a.settle_s,
        max_reproj_px: a.max_reproj_px,
        correct_matches: !a.no_correct_matches,
        min_frames: a.min_frames,
        finger_mm: a.finger_mm,
        max_spread_mm: a.max_spread_mm,
        ..TriangulateOptions::default()
    };
    let [min, max] = a.marker_area_px[..] else {
        usage!("--marker-area-px takes two numbers, MIN,MAX");
    };
    (options.marker.min_area_px, options.marker.max_area_px) = (min, max);
    options.video_start_s = super::left_right("--video-start-s", &a.video_start_s)?;
    options.latency_s =
        super::left_right("--latency-ms", &a.latency_ms)?.map(|ms| ms.map(|ms| ms / 1e3));
    if a.per_frame {
        let done = super::with_session(|s| {
            triangulate::run_per_frame(&a.frames, &a.calib, &pressures, &options, &a.out, s)
        })?;
        print_per_frame(&done.per_frame.summary);
        super::print_written(&done.written);
        if done.per_frame.summary.interrupted {
            return Err(super::Interrupted("interrupted: the dataset holds the frames examined before Ctrl-C; run again for all of them".into()).into());
        }
        return Ok(());
    }
    let done = super::with_session(|s| {
        triangulate::run(&a.frames, &a.calib, &pressures, &options, &a.out, s)
    })?;
    // Files first (written above), then the printing: a closed pipe must not cost the results.
    print_summary(&done);
    super::print_written(&done.written);
    if done.triangulation.summary.interrupted {
        return Err(super::Interrupted("interrupted: the dataset holds the frames examined before Ctrl-C; run again for all of them".into()).into());
    }
    Ok(())
}

/// What became of the frames, one line.
fn frames_line(f: &FrameCounts) -> String {
    format!(
        "frames: {} left, {} right; marker missing in {} / {}, several candidates in {} / {}, unreadable {} / {}, no file {} / {}",
        f.listed[0],
        f.listed[1],
        f.marker_missing[0],
        f.marker_missing[1],
        f.several_candidates[0],
        f.several_candidates[1],
        f.unreadable[0],
        f.unreadable[1],
        f.no_file[0],
        f.no_file[1],
    )
}

/// What a per-frame run found, in a few lines.
pub fn print_per_frame(s: &PerFrameSummary) {
    println!("{}", frames_line(&s.frames));
    let flagged: Vec<String> = s.flagged.iter().map(|(k, v)| format!("{v} {k}")).collect();
    println!(
        "rows: {} (one per left frame), {} with a tip and no flag{}",
        s.rows,
        s.good_rows,
        if flagged.is_empty() {
            String::new()
        } else {
            format!("; flagged: {}", flagged.join(", "))
        }
    );
    if s.clock_frames > 0 {
        println!(
            "clock: the right camera's stamps run {:+.2} ms ahead of the left's (from the motion of {} frames); tracks interpolated across it",
            s.clock_offset_ms, s.clock_frames
        );
    } else {
        println!(
            "clock: too little motion to measure the cameras' offset; stamps taken as they are"
        );
    }
    println!(
        "origin: {} rows of the first rest hold, spread {:.4} mm RMS; reprojection {:.3} / {:.3} / {:.3} px (median / 95 % / max)",
        s.origin_rows, s.origin_spread_mm, s.reproj_px[0], s.reproj_px[1], s.reproj_px[2]
    );
}

pub fn print_summary(done: &Triangulated) {
    let t = &done.triangulation;
    let s = &t.summary;
    let f = &s.frames;
    println!("{}", frames_line(f));
    if let Some(first) = &f.first_unreadable {
        println!("  first unreadable: {first}");
    }
    if f.stamped_late.iter().sum::<usize>() > 0 {
        println!(
            "  stamped late (they arrived faster than the camera makes them: they had waited in a queue, the capture machine or network fell behind), left out of the pairs: {} left, {} right frames, up to {:.0} ms",
            f.stamped_late[0], f.stamped_late[1], f.late_max_ms
        );
    }
    let pairs: Vec<String> = s.pairs.iter().map(|(k, v)| format!("{v} {k}")).collect();
    println!(
        "pairs: {} formed ({} left, {} right frames unpaired): {}",
        s.pairs_formed,
        s.unpaired[0],
        s.unpaired[1],
        pairs.join(", ")
    );
    println!(
        "reprojection of used pairs: median {:.3} px, 95 % {:.3} px, max {:.3} px",
        s.reproj_px[0], s.reproj_px[1], s.reproj_px[2]
    );
    let [mean, sd, p95] = s.epipolar_px;
    println!(
        "epipolar residual of the used pairs: mean {mean:+.3} px, sd {sd:.3} px, 95 % within {p95:.3} px (a mean away from 0 or a wide spread: a biased detection or a drifted calibration)"
    );
    if s.centroid_only[0] + s.centroid_only[1] > 0 {
        println!(
            "  marker placed by its colour centroid only (the sub-pixel fit did not settle) in {} left, {} right used frames",
            s.centroid_only[0], s.centroid_only[1]
        );
    }
    for end in s.video_ended.iter().flatten() {
        println!(
            "  {} ends after {} frames, before the last {} frames frames.csv lists for it (cut short?): those are counted missing",
            end.path.display(),
            end.frames,
            end.missing
        );
    }
    let decoded: Vec<String> = ["left", "right"]
        .iter()
        .zip(&s.decoded_video)
        .filter_map(|(side, codec)| codec.as_ref().map(|c| format!("{side} {c}")))
        .collect();
    if !decoded.is_empty() {
        println!(
            "  videos not Motion-JPEG ({}): their frames reach the marker's fit decoded, their colour's sampling unknown (MPEG-4 copies of a lab capture: tip 0.11 mm RMS against 0.04 from its JPEGs); record the webcam's own Motion-JPEG stream (ffmpeg -input_format mjpeg … -c:v copy) for the full accuracy",
            decoded.join(", ")
        );
    }
    let mut latency = s.latency.describe().into_iter();
    println!("{}", latency.next().expect("a first line"));
    for line in latency {
        println!("  {line}");
    }
    let c = &s.clock;
    println!(
        "clock: a pair's frames {:.1} ms apart (median, 95 % within {:.1}), drift {:+.1} ms over the session; frame periods {}; frames dropped within steps {}/{}",
        c.skew_ms[0], c.skew_ms[1], c.drift_ms, c.periods(), c.dropped[0], c.dropped[1]
    );
    if let Some([median, largest]) = c.command_ms {
        println!(
            "  the regulator's commands took {median:.0} ms (median), {largest:.0} ms at most; settling counted from their end"
        );
    }
    if !c.settling_only.is_empty() {
        println!(
            "  {} steps were filmed only while settling (no frame later than --settle-s after the command returned): hold each step longer{}",
            c.settling_only.len(),
            if c.command_ms.is_some_and(|[_, largest]| largest > 1e3 * t.options.settle_s) {
                ", or make the regulator's command return sooner"
            } else {
                ""
            }
        );
    }
    println!(
        "hand origin: {} pairs over {} zero-pressure steps, spread {:.4} mm",
        s.origin.pairs, s.origin.zero_steps, s.origin.spread_mm
    );
    println!(
        "steps: {} logged, {} rows ({} flagged), {} without a tip; spread of a step's pairs: median {:.4} mm, 95 % {:.4} mm, max {:.4} mm",
        s.steps_logged,
        s.rows,
        s.rows_flagged,
        s.steps_without_tip.len(),
        s.step_spread_mm[0],
        s.step_spread_mm[1],
        s.step_spread_mm[2],
    );
    for r in t.rows.iter().filter(|r| !r.flags.is_empty()).take(10) {
        println!(
            "  flagged step {} ({}, {}, {} kPa): {} ({} pairs, spread {:.3} mm)",
            r.step,
            r.pressures_kpa[0],
            r.pressures_kpa[1],
            r.pressures_kpa[2],
            r.flags.join(", "),
            r.n_frames,
            r.spread_mm
        );
    }
}
