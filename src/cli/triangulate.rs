//! `handcap triangulate DIR/frames --calib calib.yml --pressures DIR/pressures.csv --out
//! dataset.csv`: the tip in every frame pair, in the hand frame, one row per pressure step.

use std::path::PathBuf;

use crate::pipeline::triangulate;
use crate::triangulate::TriangulateOptions;

use super::usage;

#[derive(clap::Args)]
pub struct Args {
    /// Directory with frames.csv and left_NNNNN / right_NNNNN images (PNG or JPEG)
    frames: PathBuf,
    /// Stereo calibration with the hand axes (R_hand), as `handcap calibrate` writes it; or,
    /// for more cameras, the calibration.toml it writes for them (the held steps only, each
    /// row with the cameras it used and its standard deviations)
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
    /// flag. The log must start with a rest hold at 0, 0, 0 kPa (the hand frame's origin).
    /// With more cameras (an Anipose TOML), one row per frame of the first camera, every other
    /// camera's track interpolated to it (its clock offset measured from the motion), the tip
    /// from the cameras that agree, as for steps; the columns of steps' rows with more cameras
    /// (sd_*, cov_*, n_cameras, cameras, left_out, chi2) beside frame, reproj_px, flag
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
    if triangulate::more_cameras(&a.calib) {
        let done = super::with_session(|s| {
            let (frames, calib, per_frame) = (&a.frames, &a.calib, a.per_frame);
            triangulate::run_more_cameras(frames, calib, &pressures, &options, per_frame, &a.out, s)
        })?;
        print!("{done}");
        super::print_written(done.written());
        return Ok(());
    }
    // Files first (written by the stage), then the printing: a closed pipe must not cost the
    // results.
    let interrupted = if a.per_frame {
        let done = super::with_session(|s| {
            triangulate::run_per_frame(&a.frames, &a.calib, &pressures, &options, &a.out, s)
        })?;
        print!("{done}");
        super::print_written(&done.written);
        done.per_frame.summary.interrupted
    } else {
        let done = super::with_session(|s| {
            triangulate::run(&a.frames, &a.calib, &pressures, &options, &a.out, s)
        })?;
        print!("{}", super::flags(&done.to_string()));
        super::print_written(&done.written);
        done.triangulation.summary.interrupted
    };
    if interrupted {
        return Err(crate::pipeline::PipelineError::Interrupted("interrupted: the dataset holds the frames examined before Ctrl-C; run again for all of them".into()).into());
    }
    Ok(())
}
