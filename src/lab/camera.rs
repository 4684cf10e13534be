//! A virtual webcam of the lab: it exposes on its own free-running clock, renders what it
//! sees then (the finger where the muscles hold it, the lamp as lit during the exposure),
//! encodes it as the webcam's Motion-JPEG, and sends it its delay later, with the jitter, the
//! lost frames and the stall it was given.

use std::sync::{mpsc, Arc};

use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::stream::Stream;
use super::{LabConfig, Shared};
use crate::stereo::Side;
use crate::synth::canvas::Canvas;
use crate::synth::capture::{exposure_gain, finger_frame, finger_poses};
use crate::synth::render::View;
use crate::synth::scene::Finger;

/// The lamp's radius in the image (px): a 5 mm diffused LED, lighting a few 8 × 8 blocks.
const LAMP_RADIUS_PX: f64 = 10.0;

/// What the truth keeps of one exposure.
#[derive(Clone, Debug)]
pub struct Exposed {
    pub camera: Side,
    /// Middle of the exposure (lab clock, s).
    pub exposure_s: f64,
    /// The tip then (hand frame, mm) and where the camera sees it (px).
    pub tip_mm: [f64; 3],
    pub tip_px: Option<[f64; 2]>,
    /// Share of the exposure the lamp was lit.
    pub lamp: f64,
    /// When it was sent (lab clock, s) and its number in the camera's stream; `None` when lost.
    pub sent: Option<(f64, u64)>,
    /// How late the frame was rendered against when it was due to be sent (s; 0 when on time).
    pub late_s: f64,
}

/// Films camera `side` until `stop` through `view`, or `knocked`'s from its time on (a
/// fault): renders on this thread, sends on another.
pub fn film(
    side: Side,
    (view, knocked): (&View, Option<&crate::synth::capture::Knocked>),
    config: &LabConfig,
    shared: &Shared,
    stream: &Arc<Stream>,
) {
    let as_filmed = view;
    let c = &config.capture;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed ^ 0x4c41_4243 ^ (side as u64) << 32);
    let period = 1.0 / (c.fps * (1.0 + rng.random_range(-50e-6..50e-6)));
    let phase = rng.random_range(0.0..period);
    let delay = config.delay_s[side as usize];
    let half = c.realism.exposure_s / 2.0;
    let (to_send, sending) = mpsc::channel::<(f64, Option<Vec<u8>>, Exposed)>();
    std::thread::scope(|scope| {
        scope.spawn(|| send(sending, stream, shared));
        for n in 0usize.. {
            let exposure_s = phase + n as f64 * period;
            // Rendered once every command that moves the finger during the exposure is in.
            shared.sleep_until(exposure_s + half + crate::synth::dynamics::Motion::AHEAD_S + 2e-3);
            if shared.stopped() {
                break;
            }
            let view = match knocked {
                Some((at, knocked)) if exposure_s >= *at => knocked,
                _ => as_filmed,
            };
            let lamp_at = view.camera.project(&Point3::from(super::LAMP_MM));
            // The finger's poses under the lock; the drawing after, the board answering meanwhile.
            let posed = shared.frame(|motion, timeline, lamps| {
                let poses = finger_poses(c, timeline, motion, &view.camera, exposure_s)?;
                let tip = timeline.tip(motion, exposure_s)?;
                Ok::<_, crate::synth::SynthError>((poses, tip, lamps.lit(exposure_s, half)))
            });
            let (poses, tip_mm, lamp) = match posed {
                Ok(posed) => posed,
                Err(e) => {
                    shared.fail(format!("camera {}: {e}", side.name()));
                    break;
                }
            };
            let shot = Shot {
                side,
                n,
                exposure_s,
                lamp: lamp_at.filter(|_| lamp > 0.0).map(|at| (at, lamp)),
            };
            let jpeg = picture(view, config, &shot, &poses, tip_mm);
            let mut due = exposure_s + delay + rng.random_range(-1.0..1.0) * config.jitter_s;
            if let Some([at, length]) = config.stall {
                if (at..at + length).contains(&exposure_s) {
                    due = due.max(at + length);
                }
            }
            let lost = rng.random::<f64>() < config.drop;
            let exposed = Exposed {
                camera: side,
                exposure_s,
                tip_mm,
                tip_px: view.camera.project(&Point3::from(tip_mm)),
                lamp,
                sent: None,
                late_s: (shared.now_s() - due).max(0.0),
            };
            if to_send
                .send((due, (!lost).then_some(jpeg), exposed))
                .is_err()
            {
                break;
            }
        }
        // The sender ends once it has sent what is left.
        drop(to_send);
    });
}

/// One exposure of a camera: its number, its middle (lab clock, s), and the lamp where the
/// camera sees it with the share of the exposure it was lit.
struct Shot {
    side: Side,
    n: usize,
    exposure_s: f64,
    lamp: Option<([f64; 2], f64)>,
}

/// The webcam's JPEG of `shot`: the finger in `poses` (its tip at `tip_mm`) drawn, the lamp
/// lit, developed with the exposure's gain, encoded.
fn picture(
    view: &View,
    config: &LabConfig,
    shot: &Shot,
    poses: &[Finger],
    tip_mm: [f64; 3],
) -> Vec<u8> {
    let (c, side, n) = (&config.capture, shot.side, shot.n);
    let mut canvas = finger_frame(view, c, config.seed, (side as usize, n), poses, tip_mm);
    if let Some((at, share)) = shot.lamp {
        light(&mut canvas, at, share);
    }
    let gain = exposure_gain(c, side as usize, shot.exposure_s);
    let size = [canvas.width as u32, canvas.height as u32];
    let rgb = canvas.develop(gain, config.seed, (n as u64) << 1 | side as u64);
    view.recycle(canvas);
    c.format.encode(size[0], size[1], &rgb)
}

/// The processor time one frame of `view` takes to render and encode (s), its parallel parts
/// counted (the process's time: called before the lab's threads start): the least of three,
/// the finger moving (a step to half the pressure), the lamp lit.
pub fn frame_cost(
    view: &View,
    config: &LabConfig,
    timeline: &crate::synth::faults::Timeline,
) -> Result<f64, crate::synth::SynthError> {
    let c = &config.capture;
    let mut motion =
        crate::synth::dynamics::Motion::at_rest(&c.dynamics, config.synth.plant.hysteresis_kpa);
    motion.command(0.0, [crate::hand::MAX_PRESSURE_KPA / 2.0; 3]);
    let moving_s =
        c.dynamics.delay_s + c.dynamics.lag_s.iter().fold(0.0, |a: f64, &b| a.max(b)) / 2.0;
    motion.run_to(moving_s + 1.0);
    let poses = finger_poses(c, timeline, &motion, &view.camera, moving_s)?;
    let tip_mm = timeline.tip(&motion, moving_s)?;
    let lamp = view
        .camera
        .project(&Point3::from(super::LAMP_MM))
        .map(|at| (at, 1.0));
    let cpu_s = || {
        let mut t = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime fills the timespec it is given.
        unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
        t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
    };
    let mut least = f64::INFINITY;
    for n in 0..3 {
        let started = cpu_s();
        let shot = Shot {
            side: Side::Left,
            n,
            exposure_s: 0.0,
            lamp,
        };
        picture(view, config, &shot, &poses, tip_mm);
        least = least.min(cpu_s() - started);
    }
    Ok(least)
}

/// The processor the lab leaves to `capture` (and its page) beside it (cores).
const HOST_CORES: f64 = 0.5;

/// Whether `cores` can render both cameras' frames at `config`'s rate, each taking `cost_s` of
/// processor time, with [`HOST_CORES`] left over; else what they can.
pub fn renderable(cost_s: f64, config: &LabConfig, cores: usize) -> Result<(), String> {
    let (fps, rig) = (config.capture.fps, &config.capture.rig);
    let needed = 2.0 * fps * cost_s;
    let budget = cores as f64 - HOST_CORES;
    if needed <= budget {
        return Ok(());
    }
    let most = (budget / (2.0 * cost_s)).floor();
    Err(format!(
        "two cameras at {fps} fps need {needed:.1} cores to render ({:.0} ms a frame at {}x{}) and this machine has {cores}, half a core of them left to capture: {}",
        1e3 * cost_s,
        rig.width,
        rig.height,
        if most >= 1.0 {
            format!("at most --fps {most} here, or a smaller --width and --height")
        } else {
            "give a smaller --width and --height".to_string()
        }
    ))
}

/// Sends each frame when due (at once when rendered late), in order; a lost frame is kept in
/// the truth unsent.
fn send(frames: mpsc::Receiver<(f64, Option<Vec<u8>>, Exposed)>, stream: &Stream, shared: &Shared) {
    super::as_hardware();
    for (due, jpeg, mut exposed) in frames {
        shared.sleep_until(due);
        if let Some(jpeg) = jpeg {
            let number = stream.published();
            stream.publish(jpeg);
            exposed.sent = Some((shared.now_s(), number));
        }
        shared.exposed(exposed);
    }
}

/// The lamp lit for `share` of the exposure: a white disc at `at`, as bright as the share.
fn light(canvas: &mut Canvas, at: [f64; 2], share: f64) {
    let r = LAMP_RADIUS_PX;
    let (w, h) = (canvas.width as f64, canvas.height as f64);
    let x0 = (at[0] - r - 1.0).clamp(0.0, w - 1.0) as usize;
    let x1 = (at[0] + r + 1.0).clamp(0.0, w - 1.0) as usize;
    let y0 = (at[1] - r - 1.0).clamp(0.0, h - 1.0) as usize;
    let y1 = (at[1] + r + 1.0).clamp(0.0, h - 1.0) as usize;
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = (x as f64 - at[0]).hypot(y as f64 - at[1]);
            let cover = (r + 0.5 - d).clamp(0.0, 1.0) * share;
            if cover > 0.0 {
                let px = &mut canvas.rgb[3 * (y * canvas.width + x)..][..3];
                for v in px {
                    *v += (cover * (250.0 - f64::from(*v)).max(0.0)) as f32;
                }
            }
        }
    }
    canvas.detail = Some(match canvas.detail {
        None => (x0, y0, x1, y1),
        Some(d) => (d.0.min(x0), d.1.min(y0), d.2.max(x1), d.3.max(y1)),
    });
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_lab_renders_what_the_cores_beside_capture_can_and_says_what_they_can() {
        let config = crate::lab::LabConfig::new(1);
        // 30 fps of two cameras at 20 ms a frame: 1.2 cores.
        assert!(super::renderable(0.02, &config, 2).is_ok());
        let why = super::renderable(0.02, &config, 1).unwrap_err();
        assert!(
            why.contains("need 1.2 cores") && why.contains("at most --fps 12"),
            "{why}"
        );
        let why = super::renderable(1.0, &config, 1).unwrap_err();
        assert!(why.contains("give a smaller --width and --height"), "{why}");
    }
}
