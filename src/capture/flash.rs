//! Each camera's latency measured from a flash: `--flash COMMAND` switches a light in view of
//! both cameras on (an LED the regulator's board drives, a lamp on a relay; the command
//! returns once it is on). One second into the session, before any protocol step, capture runs
//! it and watches both cameras' frames: a camera's latency is how long after the command ended
//! its frames show the light coming on (half-way up, interpolated between the frames either
//! side). That is the camera's delay from exposure to timestamp, on the session's clock,
//! within half a frame period; `triangulate` takes it from `capture.json` instead of measuring
//! the delays from the tip's motion.

use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::motion::{blocks, Blocks};
use super::regulator::{run_command, CommandEnd};
use super::{Clock, COMMAND_TIMEOUT_S};
use crate::stereo::Side;

/// When the flash is fired (s into the session): the frames before it are the dark reference.
pub const FIRE_AT_S: f64 = 1.0;
/// Frames up to this long before the command are kept as the dark reference (s).
const DARK_S: f64 = 0.5;
/// How long after the command the light is looked for (s): the largest latency measured.
pub const WATCH_S: f64 = 1.5;
/// A block (8 × 8 pixels) is lit when it brightens by at least this many grey levels.
const RISE: f64 = 30.0;
/// The light must light at least this many blocks (a 16-pixel LED, at least).
const MIN_LIT: usize = 4;

/// The flash command's start and end on the session's clock (s).
pub type Fired = [f64; 2];

/// What the flash measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlashLatency {
    /// The command's start and end on the session's clock (s).
    pub command_s: [f64; 2],
    /// Per camera (left, right): from the command's end to its frames showing the light
    /// half-way on (ms), when seen.
    pub latency_ms: [Option<f64>; 2],
    /// Per camera: half the frame interval where the light came on (ms), the measure's
    /// resolution.
    pub within_ms: [Option<f64>; 2],
    /// Why a camera's latency was not measured, one line each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unmeasured: Vec<String>,
}

impl FlashLatency {
    /// Both cameras' latencies (ms), when both were seen.
    pub fn both_ms(&self) -> Option<[f64; 2]> {
        match self.latency_ms {
            [Some(l), Some(r)] => Some([l, r]),
            _ => None,
        }
    }
}

impl fmt::Display for FlashLatency {
    /// What the flash measured, one line.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let one = |k: usize| match (self.latency_ms[k], self.within_ms[k]) {
            (Some(ms), Some(within)) => format!("{ms:.0} ms (± {within:.0})"),
            _ => "not seen".into(),
        };
        let mut line = format!(
            "camera latency from the flash: left {}, right {}",
            one(0),
            one(1)
        );
        if self.both_ms().is_some() {
            line += "; triangulate takes them from capture.json";
        }
        for why in &self.unmeasured {
            line += &format!("; {why}");
        }
        f.write_str(&line)
    }
}

/// Where the flash stands.
#[derive(Clone, Debug, Default)]
pub(super) enum FlashState {
    #[default]
    Waiting,
    Fired(Fired),
    /// Why the command failed.
    Failed(String),
}

/// Waits until [`FIRE_AT_S`], runs `command` (its times or failure go to `state`), then waits
/// [`WATCH_S`] for the cameras to show it.
pub(super) fn fire(
    command: &str,
    clock: &Clock,
    stop: &AtomicBool,
    state: &std::sync::Mutex<FlashState>,
) {
    let wait_until = |t: f64| {
        while clock.now_s() < t && !stop.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    wait_until(FIRE_AT_S);
    if stop.load(Ordering::SeqCst) {
        return;
    }
    let start = clock.now_s();
    let failed = match run_command(command, stop, COMMAND_TIMEOUT_S) {
        Ok(CommandEnd::Done) => None,
        Ok(CommandEnd::Stopped) => return,
        Ok(CommandEnd::Failed(why)) => Some(format!("the flash `{command}` {why}")),
        Err(e) => Some(format!("the flash `{command}` could not run: {e}")),
    };
    let end = clock.now_s();
    *state.lock().expect("flash") = match failed {
        Some(why) => FlashState::Failed(why),
        None => FlashState::Fired([start, end]),
    };
    wait_until(end + WATCH_S);
}

/// Both cameras' frames around the flash: kept from [`DARK_S`] before it was fired until
/// [`WATCH_S`] after it ended, decoded only when measured.
#[derive(Default)]
pub(super) struct Watch {
    frames: [Vec<(f64, Vec<u8>)>; 2],
}

impl Watch {
    /// Keeps a frame of `side` stamped `time_s` when it may matter, given the command's times
    /// so far.
    pub fn add(&mut self, side: Side, time_s: f64, bytes: &[u8], fired: Option<Fired>) {
        let frames = &mut self.frames[side as usize];
        match fired {
            None => {
                frames.push((time_s, bytes.to_vec()));
                let old = frames.partition_point(|f| f.0 < time_s - 2.0 * DARK_S);
                frames.drain(..old);
            }
            Some([_, end]) if time_s <= end + WATCH_S => frames.push((time_s, bytes.to_vec())),
            Some(_) => {}
        }
    }

    /// Measures both cameras' latencies from the frames kept.
    pub fn measure(&self, [start, end]: Fired) -> FlashLatency {
        let mut out = FlashLatency {
            command_s: [start, end],
            latency_ms: [None; 2],
            within_ms: [None; 2],
            unmeasured: Vec::new(),
        };
        for side in [Side::Left, Side::Right] {
            let frames: Vec<(f64, Blocks)> = self.frames[side as usize]
                .iter()
                .filter(|f| f.0 >= start - DARK_S)
                .filter_map(|(t, bytes)| Some((*t, blocks(bytes)?)))
                .collect();
            match onset(&frames, start) {
                Ok((t, within_s)) => {
                    out.latency_ms[side as usize] = Some(1e3 * (t - end));
                    out.within_ms[side as usize] = Some(1e3 * within_s);
                }
                Err(why) => out.unmeasured.push(format!("{}: {why}", side.name())),
            }
        }
        out
    }
}

/// When a camera's `frames` (time, blocks; in time order) show the light coming on after the
/// command started at `start`: the time its lit blocks are half-way up, interpolated between
/// the frames either side, and half that frame interval.
fn onset(frames: &[(f64, Blocks)], start: f64) -> Result<(f64, f64), String> {
    let first_after = frames.partition_point(|f| f.0 < start);
    let Some((_, dark)) = frames[..first_after].last() else {
        return Err("no frame before the flash to compare with".into());
    };
    let after = &frames[first_after..];
    let rise = |b: &Blocks| -> Option<Vec<f64>> {
        (b.size == dark.size).then(|| {
            b.means
                .iter()
                .zip(&dark.means)
                .map(|(a, d)| a - d)
                .collect()
        })
    };
    let rises: Vec<Vec<f64>> = after.iter().filter_map(|f| rise(&f.1)).collect();
    if rises.len() < after.len() {
        return Err("its frames changed size".into());
    }
    let lit_count = |r: &Vec<f64>| r.iter().filter(|&&x| x >= RISE).count();
    let Some(brightest) = rises.iter().max_by_key(|r| lit_count(r)) else {
        return Err(format!("no frame within {WATCH_S} s of the flash"));
    };
    let lit: Vec<usize> = (0..brightest.len())
        .filter(|&b| brightest[b] >= RISE)
        .collect();
    if lit.len() < MIN_LIT {
        return Err(format!(
            "no light came on in its view within {WATCH_S} s of the flash (is the light in view, and off before it?)"
        ));
    }
    // How far up the light is in each frame: the lit blocks' mean rise (the dark frame: 0).
    let level = |r: &[f64]| lit.iter().map(|&b| r[b]).sum::<f64>() / lit.len() as f64;
    let levels: Vec<f64> = rises.iter().map(|r| level(r)).collect();
    let full = levels.iter().copied().fold(f64::MIN, f64::max);
    let k = levels
        .iter()
        .position(|&l| l >= full / 2.0)
        .expect("the brightest frame is at least half-way");
    let (t0, l0) = match k {
        0 => (frames[first_after - 1].0, 0.0),
        _ => (after[k - 1].0, levels[k - 1]),
    };
    let (t1, l1) = (after[k].0, levels[k]);
    let t = t0 + (full / 2.0 - l0) / (l1 - l0).max(f64::EPSILON) * (t1 - t0);
    Ok((t, (t1 - t0) / 2.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 16 × 9 block frame at grey 50 with `light` added to its first 6 blocks.
    fn frame(t: f64, light: f64) -> (f64, Blocks) {
        let mut means = vec![50.0; 16 * 9];
        for m in &mut means[..6] {
            *m += light;
        }
        (
            t,
            Blocks {
                size: [16, 9],
                means,
            },
        )
    }

    #[test]
    fn the_light_is_placed_half_way_up_between_frames() {
        let period = 1.0 / 30.0;
        // Dark until 1.2 s; the frame at 1.2 + 2 periods sees it a quarter on (its exposure
        // straddled the onset), the next fully.
        let levels = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 25.0, 100.0, 100.0, 100.0];
        let frames: Vec<(f64, Blocks)> = levels
            .iter()
            .enumerate()
            .map(|(k, &l)| frame(1.0 + k as f64 * period, l))
            .collect();
        let (t, within) = onset(&frames, 1.1).unwrap();
        // Half-way (50) lies a third of the way from 25 to 100.
        let expected = 1.0 + 6.0 * period + period / 3.0;
        assert!((t - expected).abs() < 1e-9, "{t} {expected}");
        assert!((within - period / 2.0).abs() < 1e-9);
        // No light, or no frame before the command: said, not guessed.
        let dark: Vec<(f64, Blocks)> = (0..10)
            .map(|k| frame(1.0 + k as f64 * period, 0.0))
            .collect();
        assert!(onset(&dark, 1.1).unwrap_err().contains("no light came on"));
        assert!(onset(&frames, 0.5).unwrap_err().contains("no frame before"));
    }
}
