//! Time in the virtual session: the cameras' free-running clocks, the frames they keep, the
//! muscles' pressures and the finger's pose at any moment.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{CaptureConfig, SynthError};
use crate::stereo::Side;
use crate::synth::camera::Camera;
use crate::synth::plant::{Plant, Pressures};
use crate::synth::scene::Finger;

/// One camera frame kept by the capture computer.
pub(super) struct Filmed {
    pub camera: Side,
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

/// The frames each camera keeps: those stamped inside a step's window.
pub(super) fn camera_frames(c: &CaptureConfig, steps: usize, rng: &mut ChaCha8Rng) -> Vec<Filmed> {
    let clocks: Vec<Clock> = (0..2)
        .map(|_| Clock {
            phase_s: rng.random_range(0.0..1.0 / c.fps),
            period_s: 1.0 / (c.fps * (1.0 + rng.random_range(-50e-6..50e-6))),
            offset_s: rng.random_range(-0.005..0.005),
        })
        .collect();
    let end = steps as f64 * c.step_s;
    let mut out = Vec::new();
    for (side, clock) in [Side::Left, Side::Right].into_iter().zip(&clocks) {
        let mut index = 0;
        let mut n = 0u64;
        loop {
            let exposure_s = clock.phase_s + n as f64 * clock.period_s;
            n += 1;
            if exposure_s >= end {
                break;
            }
            let drift = if side == Side::Right {
                c.clock_drift_s * exposure_s / end
            } else {
                0.0
            };
            let stamp_s = exposure_s
                + c.latency_s[side as usize]
                + clock.offset_s
                + rng.random_range(-0.002..0.002)
                + drift;
            let step = (stamp_s / c.step_s).floor();
            if step < 0.0 || step as usize >= steps {
                continue;
            }
            let into = stamp_s - step * c.step_s;
            if into >= c.window_s[0] && into < c.window_s[1] {
                out.push(Filmed {
                    camera: side,
                    index,
                    exposure_s,
                    stamp_s,
                    step: step as usize,
                });
                index += 1;
            }
        }
    }
    out
}

/// The finger during the exposure centred on `t`: one pose when it moves less than 0.02 px
/// in the image meanwhile, else four, evenly spread over the exposure (motion blur).
pub(super) fn finger_poses(
    c: &CaptureConfig,
    plant: &Plant,
    steps: &[(&str, Pressures)],
    camera: &Camera,
    t: f64,
) -> Result<Vec<Finger>, SynthError> {
    let pose = |t: f64| -> Result<Finger, SynthError> {
        let line = plant.centre_line(pressure_at(c, steps, t))?;
        Ok(Finger::from_centre_line(&line, 4))
    };
    let half = c.realism.exposure_s / 2.0;
    let (start, end) = (pose(t - half)?, pose(t + half)?);
    let moved = match (camera.project(&start.tip), camera.project(&end.tip)) {
        (Some(a), Some(b)) => (a[0] - b[0]).hypot(a[1] - b[1]),
        _ => 0.0,
    };
    if moved < 0.02 {
        return Ok(vec![pose(t)?]);
    }
    (0..4)
        .map(|k| pose(t - half + c.realism.exposure_s * (k as f64 + 0.5) / 4.0))
        .collect()
}

/// The angle of the rod hiding the bead in this frame, for a share `realism.occluded` of the
/// frames (drawn from the seed, the camera and the frame).
pub(super) fn occluder(seed: u64, c: &CaptureConfig, camera: Side, index: usize) -> Option<f64> {
    let key = seed ^ 0x4f43_434c ^ (camera as u64) << 40 ^ index as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(key);
    (rng.random::<f64>() < c.realism.occluded).then(|| rng.random_range(0.0..std::f64::consts::TAU))
}

/// The muscles' pressures at time `t` (first-order response to each command).
pub(super) fn pressure_at(c: &CaptureConfig, steps: &[(&str, Pressures)], t: f64) -> Pressures {
    let k = ((t / c.step_s).floor().max(0.0) as usize).min(steps.len() - 1);
    let target = steps[k].1;
    let before = if k == 0 { [0.0; 3] } else { steps[k - 1].1 };
    let decay = (-(t - k as f64 * c.step_s).max(0.0) / c.settle_tau_s).exp();
    std::array::from_fn(|i| target[i] + (before[i] - target[i]) * decay)
}
