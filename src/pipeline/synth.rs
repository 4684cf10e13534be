//! The synth stage: the datasets and, with a capture configuration, the rendered capture.

use std::fmt;
use std::path::{Path, PathBuf};

use super::{io_error, PipelineError, Session, Task};
use crate::synth::capture::{self, CaptureConfig, CaptureSummary};
use crate::synth::{self as plant_data, SynthConfig};

/// What the stage wrote.
pub struct Synthesized {
    pub out: PathBuf,
    pub datasets: Vec<PathBuf>,
    /// The capture, when one was rendered; `interrupted` says it is incomplete.
    pub capture: Option<CaptureSummary>,
    pub seconds: f64,
}

/// Writes the datasets into `out` and, with `capture_config`, the rendered capture and the
/// manifest. Ctrl-C stops rendering between images: the images written are complete, and the
/// summary says `interrupted`.
///
/// # Errors
/// [`PipelineError::Request`] for settings that do not fit together; [`PipelineError::Camera`]
/// (a synth error) for bad settings or a file that cannot be written.
pub fn run(
    out: &Path,
    config: &SynthConfig,
    capture_config: Option<&CaptureConfig>,
    session: &Session,
) -> Result<Synthesized, PipelineError> {
    check(config, capture_config)?;
    let started = std::time::Instant::now();
    let provenance = session.provenance(Some(config.seed));
    // A dynamic session's dataset is its per-frame truth; the settled grid is the steps'.
    let datasets = if capture_config.is_some_and(|c| c.dynamic.is_some()) {
        std::fs::create_dir_all(out).map_err(io_error(out))?;
        Vec::new()
    } else {
        plant_data::write_datasets(out, config, &provenance)?
    };
    let Some(capture_config) = capture_config else {
        return Ok(Synthesized {
            out: out.to_path_buf(),
            datasets,
            capture: None,
            seconds: started.elapsed().as_secs_f64(),
        });
    };
    let result = capture::write_capture(
        out,
        config,
        capture_config,
        &provenance,
        &session.counter(Task::Render),
        session.interrupt,
    );
    session.emit(super::Event::Finished(Task::Render));
    let mut summary = result?;
    summary.interrupted |= session.interrupted();
    plant_data::write_manifest(
        out,
        config,
        &datasets,
        Some((capture_config, &summary)),
        &provenance,
    )?;
    Ok(Synthesized {
        out: out.to_path_buf(),
        datasets,
        capture: Some(summary),
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// Refuses a hysteresis on rendered steps (their settled map has none) and a rig the finger
/// would not be seen from.
fn check(config: &SynthConfig, capture: Option<&CaptureConfig>) -> Result<(), PipelineError> {
    let refuse = |why: &str| Err(PipelineError::Request(why.to_string()));
    let Some(capture) = capture else {
        return Ok(());
    };
    if capture.dynamic.is_none() && config.plant.hysteresis_kpa != 0.0 {
        return refuse("hysteresis_kpa= applies to the datasets and dynamic sessions only: add no_images=true or dynamic=true, or drop it to render images");
    }
    let rig = &capture.rig;
    if !(rig.baseline_mm > 0.0 && (80.0..=400.0).contains(&rig.distance_mm)) {
        return refuse("baseline_mm= must be positive and distance_mm= lie in 80-400 mm");
    }
    if !((160..=8192).contains(&rig.width) && (120..=8192).contains(&rig.height)) {
        return refuse("width= must lie in 160-8192 px and height= in 120-8192 px");
    }
    if !(20.0..=150.0).contains(&rig.fov_diag_deg) {
        return refuse("fov_deg= must lie in 20-150 degrees");
    }
    Ok(())
}

impl fmt::Display for Synthesized {
    /// The files written, and with a capture how many frames over how many steps.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        for path in &self.datasets {
            writeln!(f, "wrote {}", path.display())?;
        }
        let Some(c) = &self.capture else {
            return Ok(());
        };
        let out = self.out.display();
        let (boards, reference) = if c.cameras.len() == 2 {
            ("board pairs", "the reference pair")
        } else {
            ("board poses", "the reference")
        };
        if c.boards > 0 {
            write!(
                f,
                "wrote {out}/calib/ ({} {boards} + {reference}), {out}/frames/",
                c.boards
            )?;
        } else {
            write!(f, "wrote {out}/frames/")?;
        }
        let frames: Vec<String> = c
            .cameras
            .iter()
            .zip(&c.frames)
            .map(|(name, n)| format!("{n} {name}"))
            .collect();
        writeln!(
            f,
            " ({} frames over {} pressure steps), pressures.csv, truth/ in {:.1} s",
            frames.join(", "),
            c.steps,
            self.seconds
        )
    }
}
