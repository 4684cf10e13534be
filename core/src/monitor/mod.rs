//! Trust as it runs: a session's rows replayed in time order against a fitted model, an online
//! band around its predictions that holds its coverage on any session, and two alarms, each
//! naming its channel.
//!
//! # The band
//! The band's radius starts at the model file's calibrated radius r₀ at the level asked and
//! follows the errors seen by quantile tracking (the P part of conformal PID control,
//! Angelopoulos, Candès & Tibshirani 2023, which is adaptive conformal inference on the
//! radius itself): after each row, r ← r + η (1[e > r] − α), α = 1 − level, η a step times
//! the larger of r₀ and the largest of the last 100 errors (conformal PID scales its step so,
//! by the scores seen). Whatever the errors do, such a tracker's radius stays within
//! [−η, max e + η], so over T rows the share it missed comes to α, within about
//! (max e + 2η) / (η T): its level holds on any session, drift or none.
//!
//! Which step? A small one gives a steady radius and follows a change slowly; a large one
//! follows a change within a few rows and the errors' every swing. The band runs six
//! trackers, `gain` × ¼, ½, 1, 2, 4, 8, and its radius is their mean weighted by how well
//! each has tracked the quantile lately (dynamically-tuned adaptive conformal inference,
//! Gibbs & Candès 2024: exponential weights on each tracker's pinball loss, scaled as the
//! step is, with a fixed share that lets a tracker left behind come back; the learning rate
//! and the share from the paper's interval of [`INTERVAL_ROWS`] rows). On calm rows the
//! weights follow the errors' swings from region to region; after a change they move to the
//! quick trackers within a few rows (measured in `band.rs`). The weighted mean carries each
//! tracker's guarantee only approximately (the paper bounds its coverage error by terms of the
//! learning rate and the share that do not vanish); measured, it held 0.903-0.906 of the rows
//! of 65 h of virtual sessions at 0.9.
//!
//! # The alarms
//! A band that follows the errors never says they changed; the alarms do. Each is a Bernoulli
//! CUSUM (Page 1954) on one look every `look_s` (rows of a time series a frame apart are not
//! independent; a second apart nearly are): the look counts as a miss when its value exceeds a
//! fixed reference, a miss having probability p₀ while nothing changed, and the alarm asks
//! whether the rate rose to p₁ = 5 p₀. Its statistic is the largest log-likelihood ratio of
//! the looks since any time, S ← max(0, S + log(p₁/p₀) on a miss, log((1−p₁)/(1−p₀))
//! otherwise), the alarm S ≥ h. With h = log(N), the mean number of looks before a false
//! alarm is at least N (Lorden 1971): h comes from `false_alarm_hours`. The change is dated
//! at the last look where S was 0 before the alarm. Each channel alarms once: what follows a
//! change is the changed finger or rig, which only a refit or a new calibration ends.
//!
//! - **The finger changed** (model channel): the look's error against the lesser of r₀ and
//!   the `level` quantile of the errors of the session's first `baseline_s`, p₀ = α. The model
//!   file's radius was calibrated on held-out runs to be exceeded that often, and is often
//!   wider than a new session of the finger it was fitted on needs (whole runs held out, a
//!   model fitted on fewer rows); the session's own start then says what "unchanged" looks
//!   like. A model already worse than its radius says is caught against r₀; a leak, an aged
//!   muscle or a payload during the session, against the start.
//! - **A camera moved** (geometry channel): the look's reprojection residual (px: how far the
//!   triangulated tip reprojects from the beads found, model-free) against the 90th
//!   percentile of the session's first `baseline_s`, p₀ = 0.1. A camera that turned no longer
//!   agrees with the calibration; the tip it gives is wrong however good the model. And, per
//!   camera where the rows have it, how far its view of the still scene moved since the
//!   session's first frame (px, `triangulate --per-frame`'s `scene_<camera>_px`) against the
//!   same quantile, at least [`SCENE_FLOOR_PX`]: it sees a turn the residual cannot (a pan of
//!   one camera of a side-by-side pair moves its beads along their epipolar lines) and names
//!   the camera that turned.
//!
//! A baseline's quantile is a sample's: in about half the sessions it falls below the
//! errors' own, and the rest of such a session misses more often than p₀. Each reference is
//! therefore a 95 % upper confidence bound of that quantile over the baseline's looks
//! ([`crate::stats::quantile_upper_bound`], for independent looks; a baseline of too few
//! looks for one, 29 for the 0.9 quantile, gives the quantile of all its values). On virtual
//! sessions with nothing changed it cut the finger channel's false alarms 2.5-7 fold
//! (docs/monitor.md).
//!
//! - **The finger responds otherwise** (model channel too, when the rows' outputs are known):
//!   each look's least-squares scale of the errors on the prediction's displacement from rest,
//!   s = Σ e·d / Σ |d|² over the look's rows (e the measured minus the predicted outputs, d the
//!   prediction less the model's at rest; looks whose rows lie within r₀ of rest on average say
//!   nothing). A finger 10 % softer gives s ≈ +0.11 wherever it goes; a stiffer one, a leak or
//!   a payload, s < 0; the model's own bias moves s by about ±0.015 from minute to minute. A
//!   two-sided CUSUM on s less the baseline's median, allowance k = 0.05 (half a change of
//!   [`RESPONSE_SHIFT`]) and threshold [`RESPONSE_THRESHOLD`] (scaled with h from
//!   `false_alarm_hours`), catches a change of a tenth in tens of seconds where the exceedances
//!   need minutes. Its threshold is measured, not a bound: looks a second apart along a path
//!   are correlated, and on 144 virtual sessions with nothing changed (24.9 h, two models,
//!   single long runs and trials) it raised none.
//!
//! Both alarms look from the end of the baseline on. The false-alarm bound holds for looks
//! whose misses are independent at rate p₀; a session's errors are not quite that (the model
//! errs more in some regions than others, and a finger creeps over minutes): on ten-minute
//! virtual sessions with nothing changed, a minute's miss rate against the first two
//! minutes' quantile ran 0.08-0.2. Watching for p₁ = 5 p₀, not less, is why such drift does
//! not alarm: the statistic grows only when misses run above 0.27 (where the two
//! log-likelihood steps balance), which a stiffness change of 15 % or a tilted camera passes
//! within seconds.
//!
//! # As the rows come
//! [`Monitor`] takes a session's rows one at a time, each row's residual before its error,
//! and says an alarm on the row it fires (`capture --model`, live); [`watch`] replays a
//! recorded session through it.

use serde::Serialize;

mod band;
mod cusum;
mod replay;
mod response;
pub use band::{Band, INTERVAL_ROWS, STEP_WINDOW};
pub use cusum::Cusum;
use cusum::Watcher;
pub use replay::{watch, Outputs, Scene};
use response::Response;

/// How the monitor watches.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    /// The band's coverage (e.g. 0.9).
    pub level: f64,
    /// The band's middle tracker's step per row, a share of the errors' scale (its trackers
    /// step ¼ … 8 times this).
    pub gain: f64,
    /// One look for the alarms every this many seconds.
    pub look_s: f64,
    /// The mean time between false alarms, at least (hours of looks).
    pub false_alarm_hours: f64,
    /// The geometry's reference: the session's first this many seconds.
    pub baseline_s: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            level: 0.9,
            gain: 0.05,
            look_s: 1.0,
            false_alarm_hours: 24.0,
            baseline_s: 120.0,
        }
    }
}

impl Settings {
    /// Every rule, named.
    ///
    /// # Errors
    /// The first setting out of its range, with the range.
    pub fn check(&self) -> Result<(), String> {
        let rules = [
            (
                self.level > 0.0 && self.level < 1.0,
                "level must lie strictly between 0 and 1",
            ),
            (
                self.gain > 0.0 && self.gain <= 1.0,
                "gain must lie in (0, 1]",
            ),
            (
                self.look_s > 0.0 && self.look_s.is_finite(),
                "look_s must be a positive number of seconds",
            ),
            (
                self.false_alarm_hours > 0.0 && self.false_alarm_hours.is_finite(),
                "false_alarm_hours must be a positive number of hours",
            ),
            (
                self.baseline_s > 0.0 && self.baseline_s.is_finite(),
                "baseline_s must be a positive number of seconds",
            ),
        ];
        rules
            .into_iter()
            .find(|(ok, _)| !ok)
            .map_or(Ok(()), |(_, rule)| Err(rule.to_string()))
    }

    /// The response test's threshold: [`RESPONSE_THRESHOLD`] scaled with [`Settings::threshold`].
    pub fn response_threshold(&self) -> f64 {
        RESPONSE_THRESHOLD * self.threshold() / Settings::default().threshold()
    }

    /// The alarms' threshold h = log(false-alarm looks).
    pub fn threshold(&self) -> f64 {
        (self.false_alarm_hours * 3600.0 / self.look_s)
            .max(2.0)
            .ln()
    }
}

/// Which stream an alarm watched.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Channel {
    /// The model channel (its errors): the finger is no longer the finger modelled.
    Finger,
    /// The geometry channel (the cameras' agreement on the bead): a camera is no longer where
    /// it was calibrated.
    Camera,
}

impl Channel {
    /// The channel's name in files and messages (as it serialises).
    pub fn name(self) -> &'static str {
        match self {
            Channel::Finger => "finger",
            Channel::Camera => "camera",
        }
    }

    /// What the alarm says and what to do.
    pub fn advice(self) -> &'static str {
        match self {
            Channel::Finger => "the finger changed (a leak, wear, a payload): refit the model on the rows after the change",
            Channel::Camera => "a camera moved: recalibrate, then triangulate the session again",
        }
    }
}

/// The baseline's median reprojection residual (px) over which the calibration is not the
/// cameras' ([`Monitor::misfit`]): a rig as calibrated reprojects its beads within a few
/// tenths of a pixel, and the triangulation refuses views a pixel or two apart.
pub const MISFIT_PX: f64 = 2.0;

/// The triangulation's flag on a row whose views disagreed beyond its gate: the geometry
/// channel's miss (+∞), whatever the residual.
pub const DISAGREED: &str = "reprojection";

/// The change in the finger's response (a share of its displacement) the response test is
/// tuned to: its allowance is half of it.
pub const RESPONSE_SHIFT: f64 = 0.1;

/// The response test's threshold at the default `false_alarm_hours` (24 h), in shares of a
/// displacement summed over looks past the allowance ([module docs](self)).
pub const RESPONSE_THRESHOLD: f64 = 1.0;

/// The least reference of a camera's still-scene channel (px): the scene of an unmoved webcam
/// wanders from frame to frame by noise of a few tenths of a pixel (0.4 at most on the virtual
/// lab's JPEG frames, `scripts/bench_scene.py`), and a turn of 0.05° (0.8 px of a C920's
/// picture) or more is what it is to catch; a pan or a tilt of 0.1° moves the picture 1.6 px.
pub const SCENE_FLOOR_PX: f64 = 0.75;

/// A scene alarm's advice.
const SCENE_MOVED: &str =
    "its view of the still scene moved: recalibrate, then triangulate the session again";

/// How long after a finger change a camera's may be dated and still explain it (s): the
/// CUSUM dates a change to within a few looks.
const CAMERA_FIRST_S: f64 = 10.0;

/// A response alarm's advice: the finger moves further than modelled.
const FURTHER: &str = "the finger moves further than modelled (softer: wear, a muscle's braid loosened): refit the model on the rows after the change";

/// A response alarm's advice: the finger moves less than modelled.
const LESS: &str = "the finger moves less than modelled (stiffer, a leak, a payload): check the muscles and the lines, then refit the model on the rows after the change";

/// A finger alarm's advice when a camera moved first.
const FINGER_AFTER_CAMERA: &str = "the tips moved with the camera that moved: recalibrate and triangulate again first, then watch again before refitting the model";

/// One alarm; shown as the line that says it.
#[derive(Clone, Debug, Serialize)]
pub struct Alarm {
    pub channel: Channel,
    /// When the alarm was raised (the row's time, s).
    pub time_s: f64,
    /// When the change began, as the CUSUM dates it (s).
    pub change_s: f64,
    /// The row the alarm was raised at (0-based).
    pub row: usize,
    /// The camera whose view of the still scene moved, for a scene alarm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    pub advice: &'static str,
}

impl std::fmt::Display for Alarm {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        let camera = self
            .camera
            .as_ref()
            .map_or_else(String::new, |c| format!(" ({c})"));
        write!(
            f,
            "alarm: {}{camera} at {:.1} s (the change began about {:.1} s): {}",
            self.channel.name(),
            self.time_s,
            self.change_s,
            self.advice
        )
    }
}

/// One row as the monitor saw it.
#[derive(Clone, Debug)]
pub struct Seen {
    /// The band's radius before the row was seen.
    pub band: f64,
    pub covered: bool,
    pub model_stat: f64,
    /// The response test's statistic, when the rows' outputs are watched.
    pub response_stat: Option<f64>,
    pub geometry_stat: Option<f64>,
    /// An alarm raised at this row.
    pub alarm: Option<Channel>,
}

/// A session watched.
#[derive(Clone, Debug, Serialize)]
pub struct Monitored {
    #[serde(skip)]
    pub rows: Vec<Seen>,
    pub alarms: Vec<Alarm>,
    /// The share of rows the band held.
    pub coverage: f64,
    /// The model's radius at the level, from its file (the band's start).
    pub start_radius: f64,
    /// The model alarm's reference (output units).
    pub model_reference: f64,
    /// The geometry alarm's reference (px), when the rows have residuals.
    pub geometry_reference_px: Option<f64>,
    /// The baseline's median reprojection residual (px; a row refused as disagreeing views
    /// counts as +∞), when the rows have residuals: over [`MISFIT_PX`], the calibration is not
    /// this rig's.
    pub baseline_median_px: Option<f64>,
    /// Each still-scene channel's reference (px), by camera, when the rows have it.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub scene_references_px: Vec<(String, Option<f64>)>,
    /// The alarms' threshold h.
    pub threshold: f64,
}

/// One channel's values at their times (s, rising).
#[derive(Clone, Copy, Debug)]
pub struct Series<'a> {
    pub times: &'a [f64],
    pub values: &'a [f64],
}

/// The monitor as the rows come ([`watch`] replays a whole session through it): push each
/// row's reprojection residual ([`Monitor::geometry`]) before its model error
/// ([`Monitor::error`]), in time order.
#[derive(Clone, Debug)]
pub struct Monitor {
    settings: Settings,
    radius: f64,
    band: Band,
    /// The first row's time, and the baseline's end.
    baseline_end: Option<f64>,
    finger: Watcher,
    camera: Watcher,
    /// Each camera's still-scene channel, by name, in the order they came.
    scene: Vec<(String, Watcher)>,
    /// With the rows' outputs ([`Monitor::with_rest`]).
    response: Option<Response>,
    rows: Vec<Seen>,
    alarms: Vec<Alarm>,
}

impl Monitor {
    /// A monitor of a model whose calibrated radius at `settings.level` is `radius`.
    pub fn new(radius: f64, settings: &Settings) -> Monitor {
        let h = settings.threshold();
        Monitor {
            settings: settings.clone(),
            radius,
            band: Band::new(radius, settings.level, settings.gain),
            baseline_end: None,
            finger: Watcher::new(settings.level, radius, 1.0 - settings.level, h),
            camera: Watcher::new(0.9, f64::INFINITY, 0.1, h),
            scene: Vec::new(),
            response: None,
            rows: Vec::new(),
            alarms: Vec::new(),
        }
    }

    /// The monitor that also watches the finger's response ([`Monitor::outputs`]), `rest`
    /// the model's outputs at rest.
    pub fn with_rest(mut self, rest: Vec<f64>) -> Monitor {
        self.response = Some(Response::new(rest, self.radius, &self.settings));
        self
    }

    /// A row's predicted and measured outputs at `t`, before its [`Monitor::error`]: the
    /// finger's response (with [`Monitor::with_rest`]); the finger alarm when it fires.
    pub fn outputs(&mut self, t: f64, predicted: &[f64], measured: &[f64]) -> Option<Alarm> {
        let end = self.baseline_end(t);
        let look_s = self.settings.look_s;
        let (change_s, further) = self
            .response
            .as_mut()?
            .take(t, predicted, measured, end, look_s)?;
        self.finger_alarm(t, change_s, if further { FURTHER } else { LESS })
    }

    /// The finger alarm at `t`, the change dated `change_s`, once: with `advice` unless a
    /// camera moved first.
    fn finger_alarm(&mut self, t: f64, change_s: f64, advice: &'static str) -> Option<Alarm> {
        if self.alarms.iter().any(|a| a.channel == Channel::Finger) {
            return None;
        }
        let alarm = Alarm {
            channel: Channel::Finger,
            time_s: t,
            change_s,
            row: self.rows.len(),
            camera: None,
            advice: if camera_first(change_s, &self.alarms) {
                FINGER_AFTER_CAMERA
            } else {
                advice
            },
        };
        self.alarms.push(alarm.clone());
        Some(alarm)
    }

    fn baseline_end(&mut self, t: f64) -> f64 {
        *self
            .baseline_end
            .get_or_insert(t + self.settings.baseline_s)
    }

    /// A row's reprojection residual at `t` (px; +∞ where the views disagreed beyond the
    /// triangulation's gate); the camera alarm, when it fires.
    pub fn geometry(&mut self, t: f64, px: f64) -> Option<Alarm> {
        let end = self.baseline_end(t);
        let change_s = self.camera.take(t, px, end, self.settings.look_s)?;
        Some(self.camera_alarm(t, change_s, None, Channel::Camera.advice()))
    }

    /// How far `camera`'s view of the still scene lay at `t` from the session's first frame's
    /// (px); that camera's alarm, when it fires.
    pub fn scene(&mut self, camera: &str, t: f64, px: f64) -> Option<Alarm> {
        let end = self.baseline_end(t);
        let h = self.settings.threshold();
        let watcher = named(&mut self.scene, camera, || {
            Watcher::new(0.9, f64::INFINITY, 0.1, h).at_least(SCENE_FLOOR_PX)
        });
        let change_s = watcher.take(t, px, end, self.settings.look_s)?;
        Some(self.camera_alarm(t, change_s, Some(camera.to_string()), SCENE_MOVED))
    }

    /// A camera alarm at `t`, the change dated `change_s`, kept and returned.
    fn camera_alarm(
        &mut self,
        t: f64,
        change_s: f64,
        camera: Option<String>,
        advice: &'static str,
    ) -> Alarm {
        let alarm = Alarm {
            channel: Channel::Camera,
            time_s: t,
            change_s,
            // The next model row.
            row: self.rows.len(),
            camera,
            advice,
        };
        self.alarms.push(alarm.clone());
        alarm
    }

    /// A row's model error at `t`: the row as seen, and the finger alarm when it fires.
    pub fn error(&mut self, t: f64, e: f64) -> (Seen, Option<Alarm>) {
        let end = self.baseline_end(t);
        let change = self.finger.take(t, e, end, self.settings.look_s);
        let row = self.rows.len();
        let alarm =
            change.and_then(|change_s| self.finger_alarm(t, change_s, Channel::Finger.advice()));
        let seen = Seen {
            band: self.band.radius(),
            covered: self.band.update(e),
            model_stat: self.finger.cusum.stat(),
            response_stat: self.response.as_ref().map(Response::stat),
            geometry_stat: self.camera.seen.then(|| self.camera.cusum.stat()),
            alarm: self.alarms.iter().find(|a| a.row == row).map(|a| a.channel),
        };
        self.rows.push(seen.clone());
        (seen, alarm)
    }

    /// Once the baseline ended with its median residual over [`MISFIT_PX`]: what to say, in
    /// one line.
    pub fn misfit(&self) -> Option<String> {
        let (_, median) = self.camera.decided?;
        misfit(median, self.settings.baseline_s)
    }

    /// The share of rows the band held so far.
    pub fn coverage(&self) -> f64 {
        let held = self.rows.iter().filter(|r| r.covered).count();
        held as f64 / self.rows.len().max(1) as f64
    }

    /// The alarms so far.
    pub fn alarms(&self) -> &[Alarm] {
        &self.alarms
    }

    /// The session watched: a finger alarm's advice now knows of a camera that moved after
    /// it was raised, and a channel whose baseline had no values shows no statistic.
    pub fn finish(mut self) -> Monitored {
        let model_reference = self.finger.decide().0.unwrap_or(self.radius);
        let (geometry_reference_px, baseline_median_px) = if self.camera.seen {
            let (reference, median) = self.camera.decide();
            (reference, Some(median))
        } else {
            (None, None)
        };
        let scene_references_px = self
            .scene
            .iter_mut()
            .map(|(name, watcher)| (name.clone(), watcher.decide().0))
            .collect();
        let last = self.rows.len().saturating_sub(1);
        let alarms = self.alarms.clone();
        for alarm in &mut self.alarms {
            alarm.row = alarm.row.min(last);
            if alarm.channel == Channel::Finger && camera_first(alarm.change_s, &alarms) {
                alarm.advice = FINGER_AFTER_CAMERA;
            }
        }
        self.alarms.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
        for (k, row) in self.rows.iter_mut().enumerate() {
            row.geometry_stat = geometry_reference_px.map(|_| row.geometry_stat.unwrap_or(0.0));
            row.alarm = self.alarms.iter().find(|a| a.row == k).map(|a| a.channel);
        }
        Monitored {
            coverage: self.coverage(),
            rows: self.rows,
            alarms: self.alarms,
            start_radius: self.radius,
            model_reference,
            geometry_reference_px,
            baseline_median_px,
            scene_references_px,
            threshold: self.settings.threshold(),
        }
    }
}

/// The value named `name` in `list`, made by `new` (and kept) when it has none.
pub fn named<'a, T>(
    list: &'a mut Vec<(String, T)>,
    name: &str,
    new: impl FnOnce() -> T,
) -> &'a mut T {
    let k = match list.iter().position(|(n, _)| n == name) {
        Some(k) => k,
        None => {
            list.push((name.to_string(), new()));
            list.len() - 1
        }
    };
    &mut list[k].1
}

/// What a baseline whose median residual is `median_px` says, when it is over [`MISFIT_PX`].
pub fn misfit(median_px: f64, baseline_s: f64) -> Option<String> {
    (median_px > MISFIT_PX).then(|| {
        let median = if median_px.is_finite() {
            format!("{median_px:.2} px")
        } else {
            "refused (over half the rows: the views disagree)".into()
        };
        format!(
            "the median reprojection residual in the first {baseline_s} s is {median}, over {MISFIT_PX} px: the calibration is not these cameras' (another rig, or a camera moved before the session); calibrate this rig"
        )
    })
}

/// Whether a camera moved before a finger change dated `change_s` (or within the camera's
/// own dating of it): it moved the tips it gives, and is the first to explain.
fn camera_first(change_s: f64, alarms: &[Alarm]) -> bool {
    alarms
        .iter()
        .any(|a| a.channel == Channel::Camera && a.change_s <= change_s + CAMERA_FIRST_S)
}

#[cfg(test)]
mod tests;
