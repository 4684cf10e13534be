//! `handcap lab`: the virtual micro-hand in real time ([`crate::lab`]): cameras as Motion-JPEG
//! streams, the regulator board on a pseudo-terminal, the truth in `OUT/truth/`.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;

use crate::lab::{self, LabConfig};
use crate::synth::image_format::ImageFormat;

#[derive(clap::Args)]
pub struct Args {
    /// Folder for the lab's truth (OUT/truth/: the rig, every line the board received, every
    /// frame's exposure and tip, lab.json)
    #[arg(long)]
    out: PathBuf,
    /// Seed of the finger, the rig and the clocks (the rig is the one `handcap synth` of the
    /// same seed calibrates)
    #[arg(long, default_value_t = crate::DEFAULT_SEED)]
    seed: u64,
    /// Each camera's delay from exposure to sending (ms): left=45,right=80, LEFT,RIGHT or one
    /// for both
    #[arg(long, default_value = "left=45,right=80")]
    delay_ms: String,
    /// How much each frame's sending varies, either way (ms)
    #[arg(long, default_value_t = 2.0, value_parser = super::finite)]
    jitter_ms: f64,
    /// Share of frames each camera loses (0-0.5)
    #[arg(long, default_value_t = 0.0, value_parser = super::finite)]
    drop: f64,
    /// Both cameras stall at AT s for LENGTH s (AT,LENGTH): the frames exposed meanwhile are
    /// sent at once when it ends
    #[arg(long, value_delimiter = ',', value_parser = super::finite)]
    stall: Vec<f64>,
    /// Frames per second of each camera
    #[arg(long, default_value_t = 30.0, value_parser = super::finite)]
    fps: f64,
    /// The cameras' image size (px)
    #[arg(long, default_value_t = 1280)]
    width: u32,
    #[arg(long, default_value_t = 720)]
    height: u32,
    /// Ideal frames (plain backdrop, matte bead, steady light, no blur or occlusion), still
    /// Motion-JPEG
    #[arg(long)]
    clean: bool,
    /// JPEG quality of the streams
    #[arg(long, default_value_t = 85, value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: u8,
    /// Stop after this many seconds (default: at Ctrl-C or SIGTERM)
    #[arg(long, value_parser = super::finite)]
    duration_s: Option<f64>,
    /// First TCP port on 127.0.0.1 (left, then right); 0: any free ones
    #[arg(long, default_value_t = 0)]
    port: u16,
    /// A fault at a time of the lab's clock, KIND@T=AMOUNT (repeatable), as synth takes it
    #[arg(long = "fault", value_name = "KIND@T=AMOUNT")]
    faults: Vec<crate::synth::faults::Fault>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let mut config = LabConfig::new(a.seed);
    config.delay_s = lab::delays(&a.delay_ms).map_err(|why| anyhow::anyhow!("--delay-ms {why}"))?;
    config.jitter_s = a.jitter_ms / 1e3;
    config.drop = a.drop;
    config.stall = match a.stall[..] {
        [] => None,
        [at, length] => Some([at, length]),
        _ => super::usage!("--stall takes AT,LENGTH (s)"),
    };
    config.duration_s = a.duration_s;
    config.capture.faults = a.faults;
    config.port = a.port;
    config.capture.fps = a.fps;
    config.capture.rig.width = a.width;
    config.capture.rig.height = a.height;
    if a.clean {
        config.capture.realism = crate::synth::capture::Realism::CLEAN;
    }
    if let ImageFormat::Jpeg { quality, .. } = &mut config.capture.format {
        *quality = a.jpeg_quality;
    }
    let announce = |ready: &lab::Ready| {
        let mut out = std::io::stdout().lock();
        for (name, url) in &ready.cameras {
            let _ = writeln!(out, "camera {name} {url}");
        }
        let _ = writeln!(out, "regulator {}", ready.regulator.display());
        let _ = out.flush();
        if !ready.hardware_priority {
            eprintln!("lab: the cameras run at the machine's normal priority (a higher one needs root or CAP_SYS_NICE): on a busy machine their frames go out late");
        }
    };
    let summary = super::with_session(|s| {
        lab::run(
            &a.out,
            &config,
            &s.provenance(Some(a.seed)),
            announce,
            s.interrupt,
        )
    })
    .with_context(|| format!("lab into {}", a.out.display()))?;
    println!("{summary}; truth in {}", a.out.join("truth").display());
    Ok(())
}
