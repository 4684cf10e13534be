//! Time in the virtual session: the cameras' free-running clocks, the frames they keep, the
//! muscles' pressures and the finger's pose at any moment.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{CaptureConfig, SynthError};
use crate::synth::camera::Camera;
use crate::synth::dynamics::Motion;
use crate::synth::faults::Timeline;
use crate::synth::scene::Finger;

/// One camera frame kept by the capture computer.
pub(super) struct Filmed {
    /// The camera's place in the rig.
    pub camera: usize,
    pub index: usize,
    pub exposure_s: f64,
    pub stamp_s: f64,
    pub step: usize,
}

/// A camera's free-running clock.
struct Clock {
    phase_s: f64,
    period_s: f64,
    offset_s: f64,
}

/// The frames each camera keeps: those stamped inside a step's window (every frame of a dynamic
/// session). `starts` are the steps' command times, `end` when the last ends (s).
pub(super) fn camera_frames(
    c: &CaptureConfig,
    starts: &[f64],
    end: f64,
    rng: &mut ChaCha8Rng,
) -> Vec<Filmed> {
    let clocks: Vec<Clock> = (0..c.rig.cameras)
        .map(|_| Clock {
            phase_s: rng.random_range(0.0..1.0 / c.fps),
            period_s: 1.0 / (c.fps * (1.0 + rng.random_range(-50e-6..50e-6))),
            offset_s: rng.random_range(-0.005..0.005),
        })
        .collect();
    let mut out = Vec::new();
    for (camera, clock) in clocks.iter().enumerate() {
        let mut index = 0;
        let mut n = 0u64;
        loop {
            let exposure_s = clock.phase_s + n as f64 * clock.period_s;
            n += 1;
            if exposure_s >= end {
                break;
            }
            let drift = if camera == 1 {
                c.clock_drift_s * exposure_s / end
            } else {
                0.0
            };
            let stamp_s = exposure_s
                + c.latency(camera)
                + clock.offset_s
                + rng.random_range(-0.002..0.002)
                + drift;
            let Some(step) = starts.partition_point(|&t| t <= stamp_s).checked_sub(1) else {
                continue;
            };
            if stamp_s >= end {
                continue;
            }
            let into = stamp_s - starts[step];
            if c.dynamic.is_some() || (into >= c.window_s[0] && into < c.window_s[1]) {
                out.push(Filmed {
                    camera,
                    index,
                    exposure_s,
                    stamp_s,
                    step,
                });
                index += 1;
            }
        }
    }
    out
}

/// The finger during the exposure centred on `t`: one pose when its tip moves less than
/// [`BLUR_STEP_PX`] in the image meanwhile (the smear's centre is the middle pose's), else up
/// to four, evenly spread over the exposure, one per [`BLUR_STEP_PX`] of motion (motion blur).
pub(crate) fn finger_poses(
    c: &CaptureConfig,
    timeline: &Timeline,
    motion: &Motion,
    camera: &Camera,
    t: f64,
) -> Result<Vec<Finger>, SynthError> {
    let pose = |t: f64| -> Result<Finger, SynthError> {
        let line = timeline.centre_line(motion, t)?;
        Ok(Finger::from_centre_line(&line, AXIS_STRIDE))
    };
    let exposure = c.realism.exposure_s;
    let tip = |t: f64| timeline.tip(motion, t).map(|p| camera.project(&p.into()));
    let moved = match (tip(t - exposure / 2.0)?, tip(t + exposure / 2.0)?) {
        (Some(a), Some(b)) => (a[0] - b[0]).hypot(a[1] - b[1]),
        _ => 0.0,
    };
    let n = ((moved / BLUR_STEP_PX).ceil() as usize).clamp(1, 4);
    (0..n)
        .map(|k| pose(t + exposure * ((k as f64 + 0.5) / n as f64 - 0.5)))
        .collect()
}

/// The image motion of the tip (px) each further blur pose stands for.
const BLUR_STEP_PX: f64 = 0.5;

/// Points of the centre line per capsule of the rendered finger: 25 capsules of 1.9 mm, whose
/// chord strays from the bent line by under 0.01 mm.
const AXIS_STRIDE: usize = 8;

/// The angle of the rod hiding the bead in this frame, for a share `realism.occluded` of the
/// frames (drawn from the seed, the camera and the frame).
pub(super) fn occluder(seed: u64, c: &CaptureConfig, camera: usize, index: usize) -> Option<f64> {
    let key = seed ^ 0x4f43_434c ^ (camera as u64) << 40 ^ index as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(key);
    (rng.random::<f64>() < c.realism.occluded).then(|| rng.random_range(0.0..std::f64::consts::TAU))
}
