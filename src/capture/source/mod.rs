//! Where a camera's frames come from: a `FrameSource` hands out each frame as the file bytes
//! it came as (a camera's or a Motion-JPEG file's or stream's JPEG as it came, anything else
//! decoded and stored as PNG), stamped as near its exposure as the source tells. One file per
//! kind of source: a device on this machine ([`device`]), a video file standing in for a
//! camera ([`file`]), a network stream (`stream`). `film` runs one on its own thread.

pub mod device;
mod file;
mod stream;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;

use opencv::core::{Mat, Vector};
use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};

use super::motion::Meter;
use super::url::redact;
use super::{CaptureError, CaptureOptions, Clock};
use crate::stereo::Side;

/// A frame as its source delivered it.
pub(super) struct Frame {
    /// On the session's clock (s).
    pub time_s: f64,
    /// Stamped by the camera's driver, not when it was read.
    pub by_driver: bool,
    pub bytes: Vec<u8>,
    /// The bytes' file extension: `jpg` or `png`.
    pub extension: &'static str,
}

/// A camera's frames, one at a time.
pub(super) trait FrameSource: Send {
    /// The settings asked for that the source refused.
    fn refused(&self) -> Vec<String>;
    /// Waits for the next frame and stamps it on `clock`; `None` when none came: the source
    /// ended, failed, or stalled past its read timeout.
    fn next(&mut self, clock: &Clock) -> Option<Frame>;
    /// Whether its frames come from outside in real time (a camera, a stream), so that a
    /// silence is a stall. A video file is read here when its frames are due: on a busy
    /// machine they come late, never lost, and the file ends rather than stalls.
    fn live(&self) -> bool {
        true
    }
}

/// Opens camera `name`'s `source` as the kind of source it names.
pub(super) fn open(
    name: &str,
    source: &str,
    o: &CaptureOptions,
) -> Result<Box<dyn FrameSource>, CaptureError> {
    let not_opened = |why: String, hint: String| CaptureError::NotOpened {
        name: name.to_string(),
        camera: redact(source),
        why,
        hint,
    };
    if device::is_device(source) {
        let hint = || format!("cameras found: {}", device::devices());
        return Ok(Box::new(
            device::Device::open(source, o).map_err(|why| not_opened(why, hint()))?,
        ));
    }
    if let Some(hint) = super::url::credentials_hint(source) {
        return Err(not_opened(
            "its password holds a character that ends a URL's host part".into(),
            hint.into(),
        ));
    }
    if stream::is_stream(source) {
        let hint = "check that the stream plays (e.g. `ffplay URL`) and that the address, port and credentials are right";
        return Ok(Box::new(
            stream::Stream::open(source).map_err(|why| not_opened(why, hint.into()))?,
        ));
    }
    let hint = || {
        "give a device index (0), a device path (/dev/video0), a video file or a stream URL".into()
    };
    if Path::new(source).is_file() {
        return Ok(Box::new(
            file::VideoFile::open(source, o).map_err(|why| not_opened(why, hint()))?,
        ));
    }
    // Anything else OpenCV opens by name (a GStreamer pipeline) is a camera.
    Ok(Box::new(
        device::Device::open(source, o).map_err(|why| not_opened(why, hint()))?,
    ))
}

/// What the OpenCV sources share: grabbing a frame, stamping it, then retrieving its bytes.
struct OpenCvReader {
    capture: VideoCapture,
    mat: Mat,
    /// A V4L2 device: its driver stamps each frame ([`device::driver_time`]).
    driver_stamps: bool,
}

impl OpenCvReader {
    fn new(capture: VideoCapture, driver_stamps: bool) -> Self {
        OpenCvReader {
            capture,
            mat: Mat::default(),
            driver_stamps,
        }
    }

    /// Waits for the next frame and stamps it on `clock`: by the driver's stamp when it has
    /// one for this frame, else when it came. `None` when none came.
    fn read(&mut self, clock: &Clock) -> Option<Frame> {
        let grabbed = self.capture.grab().unwrap_or(false);
        let grab_s = clock.now_s();
        let driver_s = self
            .driver_stamps
            .then(|| self.capture.get(videoio::CAP_PROP_POS_MSEC).ok())
            .flatten()
            .and_then(|ms| device::driver_time(ms, clock.start_monotonic_s + grab_s))
            .map(|t| t - clock.start_monotonic_s);
        let (bytes, extension) = grabbed.then(|| self.retrieve()).flatten()?;
        Some(Frame {
            time_s: driver_s.unwrap_or(grab_s),
            by_driver: driver_s.is_some(),
            bytes,
            extension,
        })
    }

    /// The frame just grabbed, as file bytes: JPEG as it came, else PNG.
    fn retrieve(&mut self) -> Option<(Vec<u8>, &'static str)> {
        self.capture.retrieve(&mut self.mat, 0).ok()?;
        let bytes = self.mat.data_bytes().ok()?;
        if self.mat.rows() == 1 && bytes.starts_with(&[0xff, 0xd8]) {
            return Some((bytes.to_vec(), "jpg"));
        }
        let mut png = Vector::<u8>::new();
        opencv::imgcodecs::imencode(".png", &self.mat, &mut png, &Vector::new()).ok()?;
        Some((png.to_vec(), "png"))
    }
}

/// A frame as grabbed: its camera (its place in the session's), number, time, and file bytes
/// with their extension.
pub(super) struct Grabbed {
    pub camera: usize,
    pub index: usize,
    pub frame: Frame,
    /// Its change from the camera's previous frame, when measured ([`super::motion::Meter`]).
    pub change: Option<f64>,
}

impl Grabbed {
    /// The pair's camera that grabbed it (for what a pair alone does: the flash, the LED, a
    /// calibration capture, the page).
    pub fn side(&self) -> Side {
        Side::of_index(self.camera)
    }
}

/// Why a camera's thread ended.
pub(super) enum CameraEnd {
    Stopped,
    Failed { time_s: f64, frames: usize },
}

/// Films `source` until `stop`, sending each frame on `tx`; with `meter`, each frame's motion
/// is measured too.
pub(super) fn film(
    camera: usize,
    mut source: Box<dyn FrameSource>,
    clock: &Clock,
    tx: &mpsc::Sender<Grabbed>,
    stop: &AtomicBool,
    mut meter: Option<Meter>,
) -> CameraEnd {
    let mut index = 0;
    while !stop.load(Ordering::SeqCst) {
        let Some(frame) = source.next(clock) else {
            return CameraEnd::Failed {
                time_s: clock.now_s(),
                frames: index,
            };
        };
        let change = meter.as_mut().and_then(|m| m.change(&frame.bytes));
        let sent = tx.send(Grabbed {
            camera,
            index,
            frame,
            change,
        });
        if sent.is_err() {
            break;
        }
        index += 1;
    }
    CameraEnd::Stopped
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A source that hands out `times` and then ends, as a new kind of source would.
    struct Scripted {
        times: std::vec::IntoIter<f64>,
    }

    impl FrameSource for Scripted {
        fn refused(&self) -> Vec<String> {
            Vec::new()
        }

        fn next(&mut self, _clock: &Clock) -> Option<Frame> {
            let time_s = self.times.next()?;
            Some(Frame {
                time_s,
                by_driver: true,
                bytes: time_s.to_le_bytes().to_vec(),
                extension: "png",
            })
        }
    }

    #[test]
    fn filming_numbers_every_frame_a_source_delivers_and_says_when_it_ended() {
        let clock = Clock {
            start: std::time::Instant::now(),
            start_monotonic_s: 0.0,
        };
        let (tx, rx) = mpsc::channel();
        let source = Box::new(Scripted {
            times: vec![0.1, 0.2, 0.35].into_iter(),
        });
        let end = film(2, source, &clock, &tx, &AtomicBool::new(false), None);
        assert!(matches!(end, CameraEnd::Failed { frames: 3, .. }));
        let got: Vec<Grabbed> = rx.try_iter().collect();
        assert_eq!(got.len(), 3);
        for (k, (g, t)) in got.iter().zip([0.1, 0.2, 0.35]).enumerate() {
            assert_eq!((g.camera, g.index, g.frame.time_s), (2, k, t));
            assert_eq!(g.frame.bytes, t.to_le_bytes());
            assert!(g.frame.by_driver && g.change.is_none());
        }
        // Stopped before the first frame: nothing is read.
        let source = Box::new(Scripted {
            times: vec![0.1].into_iter(),
        });
        let end = film(0, source, &clock, &tx, &AtomicBool::new(true), None);
        assert!(matches!(end, CameraEnd::Stopped));
        assert_eq!(rx.try_iter().count(), 0);
    }
}
