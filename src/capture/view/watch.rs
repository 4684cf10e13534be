//! The page's examiner: each frame handed over decoded and searched for the bead, and with a
//! calibration the tip's track, from the frames of the last seconds as `triangulate
//! --per-frame` locates them (the cameras' clock offset told by the motion in them, or the
//! last one told while the finger rests), every half second: a left frame's tip is taken once
//! the right camera has filmed past its instant, and revised while its frames are in view.

use std::collections::BTreeMap;
use std::time::Duration;

use nalgebra::{Rotation3, Vector3};
use serde::Serialize;

use super::trust::{Trust, Watching};
use super::{Arrived, View};
use crate::calib::file::CalibrationFile;
use crate::image::RgbImage;
use crate::session::frames::FrameRecord;
use crate::stereo::Side;
use crate::triangulate::marker::{find_markers, MAX_CANDIDATES};
use crate::triangulate::per_frame::{tips_as_they_come, LiveClock, LiveTip};
use crate::triangulate::scene::{self, FirstFrames, Thumbnail};
use crate::triangulate::TriangulateOptions;

/// The track's points the page gets: the last 30 s at 30 fps.
const TRACK_POINTS: usize = 900;
/// How often the track is located again (s of the session's frames).
const EVERY_S: f64 = 0.5;
/// Frames kept before the newest tip taken, for the tracks' splines and the clock (s).
const KEEP_S: f64 = 4.0;
/// A left frame's tip is taken once the right camera has filmed this far past its instant (s,
/// on the right camera's clock): the spline through the right frames has its frame after.
const SETTLED_S: f64 = 0.1;
/// The origin is the median of this many tips at rest, at least.
const ORIGIN_TIPS: usize = 10;

/// The track on the page.
#[derive(Clone, Debug, Default, Serialize)]
pub(super) struct TrackPage {
    /// Why there are no points yet, while there are none.
    waiting: Option<String>,
    /// The newest tips: frame, x, y, z (mm, hand frame).
    points: Vec<[f64; 4]>,
    /// Left frames located, with a tip, and the others per flag.
    rows: usize,
    tips: usize,
    flagged: BTreeMap<&'static str, usize>,
    /// The right camera's stamps ahead of the left's (ms), from the motion, once measured.
    clock_offset_ms: Option<f64>,
}

/// The examiner's priority: beside a thread of the session (nice 0) wanting a core, it gets
/// about a tenth of one (the kernel weighs nice 10 at 110 against 1024).
const NICE: libc::c_int = 10;

/// Lowers the calling thread's priority to [`NICE`].
fn nice() {
    crate::priority::set_thread_nice(NICE);
}

/// Examines the frames `view` is handed until the session ends; with `calibration`, tracks
/// the tip, and with `watching` too, watches it against the model: the monitor, once the
/// session's frames are done.
pub(super) fn examine(
    view: &View,
    calibration: Option<CalibrationFile>,
    watching: Option<Watching>,
) -> Option<Trust> {
    nice();
    // Whatever runs in parallel (the decoding, the triangulation) runs on a thread of the same
    // low priority.
    let Ok(pool) = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .start_handler(|_| nice())
        .build()
    else {
        return None;
    };
    pool.install(|| watch(view, calibration, watching))
}

/// [`examine`]'s loop, on its pool.
fn watch(
    view: &View,
    calibration: Option<CalibrationFile>,
    watching: Option<Watching>,
) -> Option<Trust> {
    let mut tracker = calibration.map(|c| Tracker::new(c, watching.map(Trust::new)));
    if tracker.is_some() {
        view.lock().page.track = Some(TrackPage {
            waiting: Some("no frames yet".into()),
            ..TrackPage::default()
        });
    }
    let mut image = RgbImage::default();
    let mut bgr = opencv::core::Mat::default();
    let mut first = FirstFrames::default();
    while let Some(frame) = next(view) {
        let found = crate::image::decode_bytes(&frame.bytes, &mut image, &mut bgr)
            .map(|()| find_markers(&image, &TriangulateOptions::default().marker));
        let size = [image.width, image.height];
        let centres = shown(view, &frame, size, found, tracker.as_ref());
        let Some(tracker) = tracker.as_mut() else {
            continue;
        };
        // The still scene, for the monitor: one frame in scene::EVERY, of the calibration's size.
        let measured = frame.index.is_multiple_of(scene::EVERY) && centres != Err("no_image");
        let scene_px = (tracker.trust.is_some() && measured)
            .then(|| Thumbnail::of(&image).ok())
            .flatten()
            .and_then(|thumbnail| {
                first.offer(frame.side as usize, &thumbnail);
                first.shift(frame.side as usize, &thumbnail)
            });
        tracker.add(&frame, centres, scene_px);
        if tracker.due() {
            let (rest_until_s, protocol) = {
                let mut s = view.lock();
                tracker.take_commands(&mut s.commands);
                (s.rest_until_s, s.page.steps[1] > 0)
            };
            let page = tracker.locate(rest_until_s, protocol);
            let mut s = view.lock();
            s.page.track = Some(page);
            s.page.trust = tracker.trust.as_ref().map(Trust::page);
            s.said.append(&mut tracker.said);
        }
    }
    tracker.and_then(|t| t.trust)
}

/// The next frame to examine; `None` once the session has ended and every frame is done.
fn next(view: &View) -> Option<Arrived> {
    let mut s = view.lock();
    loop {
        if let Some(frame) = s.queue.pop_front() {
            return Some(frame);
        }
        if s.ended {
            return None;
        }
        s = view
            .arrived
            .wait_timeout(s, Duration::from_millis(200))
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .0;
    }
}

/// The frame's camera on the page: the bead found, or why not; the candidates for the track.
fn shown(
    view: &View,
    frame: &Arrived,
    size: [usize; 2],
    found: Result<crate::triangulate::marker::Markers, String>,
    tracker: Option<&Tracker>,
) -> Result<Vec<[f64; 2]>, &'static str> {
    let mut s = view.lock();
    let camera = &mut s.page.cameras[frame.side as usize];
    camera.examined = Some(frame.index);
    camera.size = Some(size);
    camera.bead_px = None;
    let calibrated = tracker.map(|t| t.size);
    let (why, centres) = match found {
        Err(why) => (Some(format!("unreadable: {why}")), Err("no_image")),
        Ok(_) if calibrated.is_some_and(|c| c != size) => {
            let [w, h] = calibrated.unwrap_or_default();
            let why = format!(
                "{}x{} px, the calibration's {w}x{h}: no track",
                size[0], size[1]
            );
            (Some(why), Err("no_image"))
        }
        Ok(markers) => {
            let centres: Vec<[f64; 2]> = markers
                .blobs
                .iter()
                .take(MAX_CANDIDATES)
                .map(|b| b.centre_px)
                .collect();
            camera.bead_px = centres.first().copied();
            let why = match (centres.len(), markers.discarded) {
                (0, 0) => Some("no red region".to_string()),
                (0, n) => Some(format!(
                    "no bead: {n} red regions too small, large, long or at the border"
                )),
                (1, _) => None,
                (n, _) => Some(format!("{n} candidates: the reddest marked")),
            };
            (why, Ok(centres))
        }
    };
    camera.why = why;
    centres
}

/// The tip's track from the frames examined.
struct Tracker {
    calibration: CalibrationFile,
    r_hand: Option<Rotation3<f64>>,
    size: [usize; 2],
    options: TriangulateOptions,
    /// The frames of the last seconds, with their candidates or why none.
    records: Vec<FrameRecord>,
    centres: Vec<Result<Vec<[f64; 2]>, &'static str>>,
    /// How far each frame's view of the still scene lies from its camera's first (px), where
    /// measured.
    scene: Vec<Option<f64>>,
    /// The newest left frame taken, and its time (s).
    taken: Option<usize>,
    taken_until_s: f64,
    located_at_s: f64,
    /// The last clock offset the motion told.
    clock: Option<LiveClock>,
    /// Tips taken: frame, time (s), left camera (mm).
    tips: Vec<(usize, f64, Vector3<f64>)>,
    origin: Option<Vector3<f64>>,
    page: TrackPage,
    /// The commands sent (time (s), kPa), from the one in force at the newest tip taken.
    commands: Vec<(f64, [f64; 3])>,
    /// The monitor, and the alarms it raised not yet said.
    trust: Option<Trust>,
    said: Vec<String>,
}

impl Tracker {
    fn new(calibration: CalibrationFile, trust: Option<Trust>) -> Tracker {
        let [w, h] = calibration.rig.image_size;
        Tracker {
            r_hand: calibration.r_hand,
            size: [w as usize, h as usize],
            calibration,
            options: TriangulateOptions::default(),
            records: Vec::new(),
            centres: Vec::new(),
            scene: Vec::new(),
            taken: None,
            taken_until_s: f64::NEG_INFINITY,
            located_at_s: f64::NEG_INFINITY,
            clock: None,
            tips: Vec::new(),
            origin: None,
            page: TrackPage::default(),
            commands: Vec::new(),
            trust,
            said: Vec::new(),
        }
    }

    fn add(
        &mut self,
        frame: &Arrived,
        centres: Result<Vec<[f64; 2]>, &'static str>,
        scene_px: Option<f64>,
    ) {
        self.records.push(FrameRecord {
            camera: frame.side,
            index: frame.index,
            time_s: frame.time_s,
            line: 0,
            late_s: None,
        });
        self.centres.push(centres);
        self.scene.push(scene_px);
    }

    /// The commands sent since last taken; the first may be the newest one taken, measured
    /// since.
    fn take_commands(&mut self, sent: &mut Vec<(f64, [f64; 3])>) {
        if let (Some(last), Some(first)) = (self.commands.last(), sent.first()) {
            if last.0 == first.0 {
                self.commands.pop();
            }
        }
        self.commands.append(sent);
    }

    /// Whether the newest frames are [`EVERY_S`] past the last location.
    fn due(&self) -> bool {
        self.newest(Side::Left) - self.located_at_s >= EVERY_S
    }

    fn newest(&self, side: Side) -> f64 {
        self.records
            .iter()
            .filter(|r| r.camera == side)
            .map(|r| r.time_s)
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Locates the left frames of the last seconds, takes those the right camera has filmed
    /// past, sets the origin from the tips at rest (before `rest_until_s`, or the first tips
    /// without a protocol), and forgets the frames no longer needed.
    fn locate(&mut self, rest_until_s: Option<f64>, protocol: bool) -> TrackPage {
        let now = self.newest(Side::Left);
        self.located_at_s = now;
        // The clock offset from the motion of the frames in view; at rest, the last one.
        let locate = |clock| {
            let rig = &self.calibration.rig;
            let (records, centres) = (&self.records, &self.centres);
            tips_as_they_come(rig, &self.options, records, centres, &self.scene, clock)
        };
        let mut located = locate(None);
        if let (Ok((_, clock)), Some(last)) = (&located, self.clock) {
            if clock.offset_ms().1 == 0 {
                located = locate(Some(last));
            }
        }
        let (tips, clock) = match located {
            Ok(located) => located,
            Err(e) => {
                self.page.waiting = Some(e.to_string());
                return self.page.clone();
            }
        };
        if clock.offset_ms().1 > 0 {
            self.clock = Some(clock);
            self.page.clock_offset_ms = Some(clock.offset_ms().0);
        }
        let settled = self.newest(Side::Right) - SETTLED_S;
        for LiveTip {
            frame,
            time_s: t,
            tip,
            scene_px: scene,
        } in tips
        {
            if self.taken.is_some_and(|k| frame <= k) {
                // A tip taken and still in view is revised: the clock is now told by more of
                // the motion around it.
                if let Ok((p, _)) = tip {
                    if let Ok(k) = self.tips.binary_search_by_key(&frame, |tip| tip.0) {
                        self.tips[k].2 = Vector3::from(p);
                    }
                }
                continue;
            }
            if clock.right_instant(t) > settled {
                continue;
            }
            (self.taken, self.taken_until_s) = (Some(frame), t);
            self.page.rows += 1;
            let command = self.commands.iter().rev().find(|c| c.0 <= t);
            if let (Some(trust), Some(&(_, command))) = (self.trust.as_mut(), command) {
                trust.take((t, command, tip.map(|(p, px)| (Vector3::from(p), px)), scene));
            }
            match tip {
                Ok((p, _)) => {
                    self.page.tips += 1;
                    self.tips.push((frame, t, Vector3::from(p)));
                }
                Err(flag) => *self.page.flagged.entry(flag).or_default() += 1,
            }
        }
        self.forget();
        self.origin = self
            .origin
            .or_else(|| self.rest_origin(rest_until_s, protocol));
        if let Some(trust) = self.trust.as_mut() {
            let hand = self.r_hand.zip(self.origin);
            self.said.extend(trust.watch(hand));
        }
        self.page.waiting = self.waiting(protocol);
        if let (Some(origin), Some(r)) = (self.origin, self.r_hand) {
            let from = self.tips.len().saturating_sub(TRACK_POINTS);
            self.page.points = self.tips[from..]
                .iter()
                .map(|(frame, _, p)| {
                    let q = r * (p - origin);
                    [*frame as f64, q.x, q.y, q.z]
                })
                .collect();
        }
        self.page.clone()
    }

    /// Drops the frames more than [`KEEP_S`] before the newest tip taken.
    fn forget(&mut self) {
        let keep_from = self.taken_until_s - KEEP_S;
        let keep: Vec<bool> = self.records.iter().map(|r| r.time_s >= keep_from).collect();
        retain_kept(&mut self.records, &keep);
        retain_kept(&mut self.centres, &keep);
        retain_kept(&mut self.scene, &keep);
        let in_force = self.commands.partition_point(|c| c.0 <= self.taken_until_s);
        self.commands.drain(..in_force.saturating_sub(1));
        if self.tips.len() > 2 * TRACK_POINTS && self.origin.is_some() {
            self.tips.drain(..TRACK_POINTS);
        }
    }

    /// The median tip at rest: the tips before the first command with pressure, once it came;
    /// without a protocol, the first [`ORIGIN_TIPS`] tips.
    fn rest_origin(&self, rest_until_s: Option<f64>, protocol: bool) -> Option<Vector3<f64>> {
        let rest: Vec<Vector3<f64>> = match (protocol, rest_until_s) {
            (true, None) => return None,
            (true, Some(until)) => self
                .tips
                .iter()
                .filter(|(_, t, _)| *t < until)
                .map(|(_, _, p)| *p)
                .collect(),
            (false, _) => self
                .tips
                .iter()
                .take(ORIGIN_TIPS)
                .map(|(_, _, p)| *p)
                .collect(),
        };
        (rest.len() >= ORIGIN_TIPS).then(|| crate::stats::median_point(&rest))
    }

    /// Why the page shows no track, if it shows none.
    fn waiting(&self, protocol: bool) -> Option<String> {
        if self.r_hand.is_none() {
            Some(
                "the calibration has no hand axes (R_hand): run calibrate with the reference board"
                    .into(),
            )
        } else if self.origin.is_some() {
            None
        } else if protocol {
            Some(format!(
                "{} tips; the origin is the tip at rest before the protocol's first pressure",
                self.tips.len()
            ))
        } else {
            Some(format!(
                "{} tips; the origin is the median of the first {ORIGIN_TIPS}",
                self.tips.len()
            ))
        }
    }
}

/// The items of `items` whose place in `keep` is true (those past its end kept).
fn retain_kept<T>(items: &mut Vec<T>, keep: &[bool]) {
    let mut k = keep.iter();
    items.retain(|_| *k.next().unwrap_or(&true));
}
