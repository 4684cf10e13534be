//! The images a capture renders, in a fixed order, and where they go: each board pair and
//! finger frame rendered, encoded and written on its own (in parallel), or the finger's frames
//! as one video per camera.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use nalgebra::Point3;
use rayon::prelude::*;

use super::boards::Sighted;
use super::timing::{finger_poses, occluder, Filmed};
use super::{io_err, CaptureConfig, Realism, SynthError};
use crate::fsio;
use crate::synth::camera::{Camera, Rig};
use crate::synth::clutter;
use crate::synth::dynamics::Motion;
use crate::synth::faults::Timeline;
use crate::synth::image_format::ImageFormat;
use crate::synth::plant::Plant;
use crate::synth::render::{Lighting, Surroundings, View};
use crate::synth::scene::Finger;

/// One image to render and write.
enum Shot {
    Board {
        /// The camera's place in the rig.
        camera: usize,
        name: String,
        board: usize,
    },
    Frame {
        camera: usize,
        index: usize,
        /// Middle of the exposure.
        exposure_s: f64,
    },
}

/// A shot rendered as the camera delivers it (8-bit RGB), and where its image file goes.
struct Rendered {
    path: PathBuf,
    size: [u32; 2],
    rgb: Vec<u8>,
}

/// What every shot is rendered from: the cameras' names and views of the scene, the boards
/// (the reference last), and the finger's motion through the protocol.
pub(super) struct Studio<'a> {
    pub dir: &'a Path,
    pub seed: u64,
    pub config: &'a CaptureConfig,
    pub timeline: &'a Timeline,
    pub motion: &'a Motion,
    pub boards: Vec<&'a Sighted>,
    pub names: Vec<String>,
    pub views: Vec<View>,
    /// The second camera's view once a fault knocked it, and from when.
    pub knocked: Option<Knocked>,
}

/// The cameras' views of the scene; with clutter, the wall keeps clear of where the finger's
/// `tips` and base are seen. The red things stand in the second camera's view.
pub(crate) fn views(
    rig: &Rig,
    seed: u64,
    realism: &Realism,
    plant: &Plant,
    tips: &[[f64; 3]],
) -> Vec<View> {
    let view = |(place, camera): (usize, &Camera)| {
        let wall = wall(place, camera, seed, realism, plant, tips);
        view_of(place, camera, seed, realism, wall)
    };
    rig.cameras.iter().enumerate().map(view).collect()
}

/// Camera `camera`'s view at place `place` in front of `wall`.
fn view_of(
    place: usize,
    camera: &Camera,
    seed: u64,
    realism: &Realism,
    wall: Option<Vec<f64>>,
) -> View {
    let lighting = Lighting::from_seed(seed ^ place as u64);
    let surroundings = Surroundings {
        wall,
        specular: realism.specular,
    };
    View::new(camera.clone(), lighting, surroundings)
}

/// The wall camera `camera` at place `place` sees, with clutter; it keeps clear of where the
/// finger's `tips` and base are seen, and holds the red things in the second camera's view.
fn wall(
    place: usize,
    camera: &Camera,
    seed: u64,
    realism: &Realism,
    plant: &Plant,
    tips: &[[f64; 3]],
) -> Option<Vec<f64>> {
    realism.clutter.then(|| {
        let base = plant.centre_line([0.0; 3]).map(|line| line[0]);
        let keep = workspace_box(camera, tips.iter().chain(base.as_ref().ok()));
        let red = realism.red_distractors && place == 1;
        clutter::wall(
            camera.width as usize,
            camera.height as usize,
            seed ^ (place as u64 + 1) << 8,
            red,
            keep,
        )
    })
}

/// The second camera's view once a fault knocked it, and from when.
pub(crate) type Knocked = (f64, View);

/// The second camera's view once a fault knocked it ([`Timeline::knocked`]), and from when.
pub(crate) fn knocked_view(
    rig: &Rig,
    seed: u64,
    realism: &Realism,
    timeline: &Timeline,
    tips: &[[f64; 3]],
) -> Option<Knocked> {
    timeline.knocked().map(|(at, knocked)| {
        let before = rig.right();
        let wall = wall(1, before, seed, realism, timeline.plant(), tips)
            .map(|wall| clutter::turned(&wall, before, knocked));
        (*at, view_of(1, knocked, seed, realism, wall))
    })
}

impl Studio<'_> {
    /// Renders shot `id` (its number in the fixed order seeds its sensor noise).
    fn render(&self, id: usize, shot: &Shot) -> Result<Rendered, SynthError> {
        let (c, ext) = (self.config, self.config.format.extension());
        // The view that draws the shot takes its canvas back: a knocked camera's backdrop is
        // not its view before the knock's.
        let (camera, path, mut canvas, time, view) = match shot {
            Shot::Board {
                camera,
                name,
                board,
            } => {
                let view = &self.views[*camera];
                let path = self
                    .dir
                    .join(format!("calib/{}_{name}.{ext}", self.names[*camera]));
                let board = view.board(&self.boards[*board].board);
                (*camera, path, board, 0.0, view)
            }
            Shot::Frame {
                camera,
                index,
                exposure_s,
            } => {
                let view = match (&self.knocked, camera) {
                    (Some((at, knocked)), 1) if exposure_s >= at => knocked,
                    _ => &self.views[*camera],
                };
                let (timeline, motion) = (self.timeline, self.motion);
                let poses = finger_poses(c, timeline, motion, &view.camera, *exposure_s)?;
                let tip = timeline.tip(motion, *exposure_s)?;
                let canvas = finger_frame(view, c, self.seed, (*camera, *index), &poses, tip);
                let path = self
                    .dir
                    .join(format!("frames/{}_{index:05}.{ext}", self.names[*camera]));
                (*camera, path, canvas, *exposure_s, view)
            }
        };
        let gain = exposure_gain(c, camera, time);
        let size = [canvas.width as u32, canvas.height as u32];
        let rgb = canvas.develop(gain, self.seed, id as u64);
        view.recycle(canvas);
        Ok(Rendered { path, size, rgb })
    }
}

/// Camera `camera`'s frame `index` of the finger in its `poses` over the exposure, and what
/// passes in front of the bead (at `tip`) in this frame.
pub(crate) fn finger_frame(
    view: &View,
    c: &CaptureConfig,
    seed: u64,
    (camera, index): (usize, usize),
    poses: &[Finger],
    tip: [f64; 3],
) -> crate::synth::canvas::Canvas {
    let mut canvas = view.finger(poses);
    if let Some(angle) = occluder(seed, c, camera, index) {
        if let Some(through) = view.camera.project(&Point3::from(tip)) {
            view.occlude(&mut canvas, through, angle);
        }
    }
    canvas
}

/// The exposure's gain at `time_s`: a slow drift of the auto-exposure and the lights' 100 Hz
/// flicker, each camera (its place in the rig) on its own phase.
pub(crate) fn exposure_gain(c: &CaptureConfig, camera: usize, time_s: f64) -> f64 {
    let phase = camera as f64;
    (1.0 + c.exposure_drift * (std::f64::consts::TAU * time_s / 20.0 + phase).sin())
        * (1.0 + c.realism.flicker * (std::f64::consts::TAU * 100.0 * time_s + phase).sin())
}

/// Renders and writes every image: the boards' views (`calib/`, the reference last), then
/// the finger's `frames` (`frames/`, images or one video per camera). `progress(done, total)`
/// is called as images are written; `interrupt` stops between images. `false` when
/// interrupted (the files written are complete).
pub(super) fn write_all(
    studio: &Studio,
    frames: &[Filmed],
    progress: &(dyn Fn(usize, usize) + Sync),
    interrupt: &AtomicBool,
) -> Result<bool, SynthError> {
    let mut shots = Vec::new();
    let last = studio.boards.len().saturating_sub(1);
    for (board, sighted) in studio.boards.iter().enumerate() {
        let name = if board == last {
            "ref".to_string()
        } else {
            format!("{board:02}")
        };
        for &camera in &sighted.by {
            shots.push(Shot::Board {
                camera,
                name: name.clone(),
                board,
            });
        }
    }
    let board_shots = shots.len();
    shots.extend(frames.iter().map(|f| Shot::Frame {
        camera: f.camera,
        index: f.index,
        exposure_s: f.exposure_s,
    }));
    let total = shots.len();
    let done = AtomicUsize::new(0);
    let counted = || progress(done.fetch_add(1, Ordering::SeqCst) + 1, total);
    // With `video`, the finger's frames go to each camera's video instead, in order.
    let images = if studio.config.video {
        board_shots
    } else {
        total
    };
    let written: Vec<Result<bool, SynthError>> = shots[..images]
        .par_iter()
        .enumerate()
        .map(|(id, shot)| {
            if interrupt.load(Ordering::SeqCst) {
                return Ok(false);
            }
            let Rendered { path, size, rgb } = studio.render(id, shot)?;
            let bytes = studio.config.format.encode(size[0], size[1], &rgb);
            fsio::write_bytes(&path, &bytes).map_err(io_err(&path))?;
            counted();
            Ok(true)
        })
        .collect();
    let mut complete = true;
    for w in written {
        complete &= w?;
    }
    if studio.config.video && complete {
        complete = write_videos(studio, &shots, images, &counted, interrupt)?;
    }
    Ok(complete)
}

/// The finger's frames (`shots[first..]`) as one video per camera, `frames/<camera>.avi`
/// (`left.avi`, `right.avi` of a pair), Motion-JPEG at the format's quality; `false` when
/// interrupted (no video is then left).
fn write_videos(
    studio: &Studio,
    shots: &[Shot],
    first: usize,
    counted: &(dyn Fn() + Sync),
    interrupt: &AtomicBool,
) -> Result<bool, SynthError> {
    let (dir, config) = (studio.dir, studio.config);
    let quality = match config.format {
        ImageFormat::Jpeg { quality, .. } => quality,
        ImageFormat::Png => 95,
    };
    let size = [config.rig.width, config.rig.height];
    for (camera, name) in studio.names.iter().enumerate() {
        let path = dir.join(format!("frames/{name}.avi"));
        let failed = |why: String| SynthError::Write {
            path: path.clone(),
            source: std::io::Error::other(why),
        };
        let mut writer =
            crate::video::MjpegWriter::create(&path, config.fps, size, quality).map_err(failed)?;
        let mine: Vec<(usize, &Shot)> = shots
            .iter()
            .enumerate()
            .skip(first)
            .filter(|(_, s)| matches!(s, Shot::Frame { camera: c, .. } if *c == camera))
            .collect();
        for chunk in mine.chunks(32) {
            if interrupt.load(Ordering::SeqCst) {
                return Ok(false);
            }
            let frames = chunk
                .par_iter()
                .map(|&(id, shot)| studio.render(id, shot).map(|r| r.rgb))
                .collect::<Result<Vec<_>, _>>()?;
            for rgb in frames {
                writer.write(&rgb).map_err(|e| failed(e.message))?;
                counted();
            }
        }
        writer.finish().map_err(failed)?;
    }
    Ok(true)
}

/// The pixel box [u0, v0, u1, v1] of the points' images.
fn workspace_box<'a>(camera: &Camera, points: impl Iterator<Item = &'a [f64; 3]>) -> [f64; 4] {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for [u, v] in points.filter_map(|p| camera.project(&Point3::from(*p))) {
        b = [b[0].min(u), b[1].min(v), b[2].max(u), b[3].max(v)];
    }
    b
}
