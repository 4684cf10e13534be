//! `handcap capture`: two cameras → `DIR/frames/` + `frames.csv` (and `pressures.csv` when a
//! protocol drives the regulator), the layout `triangulate` reads (`handcap::capture`).

use std::path::PathBuf;

use anyhow::bail;
use indicatif::{ProgressBar, ProgressStyle};

use handcap::capture::{self, protocol, CaptureOptions, Ending, Stats};

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
    /// writes the paper's); needs --set-pressure
    #[arg(long, requires = "set_pressure")]
    protocol: Option<PathBuf>,
    /// Command run at each step, {p1} {p2} {p3} (kPa) and {step} filled in, e.g.
    /// 'python3 regulator.py {p1} {p2} {p3}'; pressures above 300 kPa are refused first
    #[arg(long, requires = "protocol")]
    set_pressure: Option<String>,
    /// Stop after this many seconds (default: the protocol's end, or Ctrl-C)
    #[arg(long, value_parser = super::finite)]
    duration_s: Option<f64>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if !(a.fps > 0.0 && a.width > 0 && a.height > 0) {
        super::usage!("--fps, --width and --height must be positive");
    }
    let protocol = match (&a.protocol, &a.set_pressure) {
        (Some(path), Some(command)) => Some((protocol::read(path)?, command.clone())),
        _ => None,
    };
    if protocol.is_none() && a.duration_s.is_none() {
        println!("filming until Ctrl-C (no --protocol, no --duration-s); log the regulator on the clock capture.json describes");
    }
    let options = CaptureOptions {
        sources: [a.left.clone(), a.right.clone()],
        width: a.width,
        height: a.height,
        fps: a.fps,
        protocol,
        duration_s: a.duration_s,
    };
    let bar = ProgressBar::new_spinner()
        .with_style(ProgressStyle::with_template("{spinner} {elapsed} {msg}").expect("template"));
    let steps = options.protocol.as_ref().map_or(0, |(s, _)| s.len());
    let live = |s: &Stats| {
        bar.set_message(line(s, steps));
        bar.tick();
    };
    let summary = capture::capture(&a.out, &options, &live, super::interrupt_flag())?;
    bar.finish_and_clear();
    for (side, refused) in ["left", "right"].iter().zip(&summary.refused) {
        if !refused.is_empty() {
            println!("{side} camera: the backend refused {}", refused.join(", "));
        }
    }
    println!("{}", line(&summary.stats, steps));
    println!(
        "wrote {out}/frames/ ({} left, {} right frames), {out}/frames/frames.csv{}, {out}/capture.json",
        summary.stats.frames[0],
        summary.stats.frames[1],
        if steps > 0 { format!(", {out}/pressures.csv", out = a.out.display()) } else { String::new() },
        out = a.out.display()
    );
    let kept = "every frame before it is kept and listed";
    match &summary.ending {
        Ending::ProtocolDone | Ending::Duration => Ok(()),
        Ending::Interrupted => {
            Err(super::Interrupted(format!("interrupted: {kept} in {}", a.out.display())).into())
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
    }
}

/// The live line: frames, rates, drops, skew, steps.
fn line(s: &Stats, steps: usize) -> String {
    let progress = if steps > 0 {
        format!(", step {}/{steps}", s.steps_done)
    } else {
        String::new()
    };
    format!(
        "left {} frames {:.1} fps, right {} frames {:.1} fps, drops {}/{}, left/right skew {:.1} ms (median){progress}",
        s.frames[0], s.fps[0], s.frames[1], s.fps[1], s.drops[0], s.drops[1], s.skew_ms
    )
}
