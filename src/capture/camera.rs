//! The cameras: opening a device, file or stream with the settings asked for (what the backend
//! refuses is said), and filming one on its own thread, each frame kept as the bytes it came as
//! and stamped as near its exposure as the source tells: a V4L2 device's frames by the
//! driver's buffer timestamp (taken as the frame arrived from the camera, on the same
//! monotonic clock), anything else at grab time.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use opencv::core::{Mat, Vector};
use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};

use super::motion::Meter;
use super::url::{self, redact};
use super::{CaptureError, CaptureOptions, Clock, STALL_S, STREAM_OPEN_S};
use crate::stereo::Side;

/// An opened camera.
pub(super) struct Camera {
    capture: VideoCapture,
    /// A file's frame period: frames are handed out at its rate, as a camera would.
    pace_s: Option<f64>,
    /// A V4L2 device: its driver stamps each frame ([`driver_time`]).
    driver_stamps: bool,
    pub refused: Vec<String>,
}

/// The most a driver's stamp may precede the grab (s): older, it is not this frame's.
const DRIVER_STAMP_MAX_AGE_S: f64 = 1.0;

/// A V4L2 driver's buffer timestamp (`CAP_PROP_POS_MSEC`: ms on the host's monotonic clock)
/// as monotonic seconds, when it can be this frame's: not after the grab at `grab_s`, and at
/// most [`DRIVER_STAMP_MAX_AGE_S`] before it (0 before the first frame, another clock, a
/// backend that means something else by it: the grab time is used instead).
pub fn driver_time(pos_msec: f64, grab_s: f64) -> Option<f64> {
    let t = pos_msec / 1e3;
    (pos_msec > 0.0 && t <= grab_s && grab_s - t <= DRIVER_STAMP_MAX_AGE_S).then_some(t)
}

/// The video devices on this machine, for the message when a camera does not open.
fn devices() -> String {
    let mut found: Vec<String> = std::fs::read_dir("/dev")
        .map(|d| {
            d.flatten()
                .map(|e| e.path().display().to_string())
                .filter(|p| p.starts_with("/dev/video"))
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    if found.is_empty() {
        "none (no /dev/video*)".into()
    } else {
        found.join(", ")
    }
}

pub(super) fn open_camera(
    side: Side,
    source: &str,
    o: &CaptureOptions,
) -> Result<Camera, CaptureError> {
    let device = source.parse::<i32>().is_ok() || source.starts_with("/dev/");
    let not_opened = |why: String| CaptureError::NotOpened {
        side: side.name(),
        camera: redact(source),
        why,
        hint: if device {
            format!("cameras found: {}", devices())
        } else if source.contains("://") {
            "check that the stream plays (e.g. `ffplay URL`) and that the address, port and credentials are right".into()
        } else {
            "give a device index (0), a device path (/dev/video0), a video file or a stream URL"
                .into()
        },
    };
    let file = Path::new(source).is_file();
    let stream = !device && source.contains("://");
    let opening = Instant::now();
    let opened = if let Ok(index) = source.parse::<i32>() {
        VideoCapture::new(index, videoio::CAP_ANY)
    } else if stream {
        // FFmpeg's own waits are 30 s; a stream gives up within the stall's time instead, so
        // a stopped server ends the session promptly and Ctrl-C is never kept waiting.
        let ms = |s: f64| (1e3 * s).round() as i32;
        let params = opencv::core::Vector::<i32>::from_slice(&[
            videoio::CAP_PROP_OPEN_TIMEOUT_MSEC,
            ms(STREAM_OPEN_S),
            videoio::CAP_PROP_READ_TIMEOUT_MSEC,
            ms(STALL_S),
        ]);
        VideoCapture::from_file_with_params(source, videoio::CAP_FFMPEG, &params)
    } else if file {
        VideoCapture::from_file(source, videoio::CAP_FFMPEG)
    } else {
        VideoCapture::from_file(source, videoio::CAP_ANY)
    };
    let mut capture = opened.map_err(|e| not_opened(e.message))?;
    if !capture.is_opened().unwrap_or(false) {
        return Err(not_opened(if stream {
            let waited = opening.elapsed().as_secs_f64() >= STREAM_OPEN_S - 0.5;
            let answer = url::answer(source).map_or(String::new(), |a| format!("; {a}"));
            if waited {
                format!("it did not open and send a frame within {STREAM_OPEN_S} s{answer}")
            } else {
                format!("it did not open{answer}")
            }
        } else {
            "OpenCV cannot open it".into()
        }));
    }
    let mut refused = Vec::new();
    let pace_s = if file {
        // A Motion-JPEG file's frames raw, as a camera's MJPEG would come.
        crate::video::read_raw_if_jpeg(&mut capture);
        let fps = capture.get(videoio::CAP_PROP_FPS)?;
        Some(1.0 / if fps > 0.0 { fps } else { o.fps })
    } else if stream {
        // A stream's settings are the server's. Its Motion-JPEG frames are kept as the bytes
        // that came: no decoding and re-encoding on the grab thread (23.5 ms of CPU for a 720p
        // frame, which a busy computer cannot spare at 30 fps). Other codecs are decoded.
        if !crate::video::read_raw_if_jpeg(&mut capture) {
            refused.push(format!(
                "raw frames (codec {:?}, not Motion-JPEG: frames decoded, stored as PNG)",
                crate::video::codec(&capture)
            ));
        }
        None
    } else {
        let mjpg = f64::from(opencv::videoio::VideoWriter::fourcc('M', 'J', 'P', 'G')?);
        let settings = [
            ("MJPG", videoio::CAP_PROP_FOURCC, mjpg),
            ("width", videoio::CAP_PROP_FRAME_WIDTH, f64::from(o.width)),
            (
                "height",
                videoio::CAP_PROP_FRAME_HEIGHT,
                f64::from(o.height),
            ),
            ("frame rate", videoio::CAP_PROP_FPS, o.fps),
            // V4L2: 1 is manual exposure.
            ("fixed exposure", videoio::CAP_PROP_AUTO_EXPOSURE, 1.0),
            ("fixed white balance", videoio::CAP_PROP_AUTO_WB, 0.0),
            ("fixed focus", videoio::CAP_PROP_AUTOFOCUS, 0.0),
            // The MJPEG bytes as the camera sent them.
            ("raw frames", videoio::CAP_PROP_CONVERT_RGB, 0.0),
        ];
        for (name, prop, value) in settings {
            if !capture.set(prop, value).unwrap_or(false) {
                refused.push(name.to_string());
            }
        }
        None
    };
    let driver_stamps = !file && !stream && capture.get_backend_name().is_ok_and(|b| b == "V4L2");
    Ok(Camera {
        capture,
        pace_s,
        driver_stamps,
        refused,
    })
}

/// A frame as grabbed: its camera, number, time, and file bytes with their extension.
pub(super) struct Grabbed {
    pub side: Side,
    pub index: usize,
    pub time_s: f64,
    pub bytes: Vec<u8>,
    pub extension: &'static str,
    /// Stamped by the camera's driver ([`driver_time`]), not at grab time.
    pub by_driver: bool,
    /// Its change from the camera's previous frame, when measured ([`super::motion::Meter`]).
    pub change: Option<f64>,
}

/// Why a camera's thread ended.
pub(super) enum CameraEnd {
    Stopped,
    Failed { time_s: f64, frames: usize },
}

/// The frame a camera just grabbed, as file bytes: JPEG as it came, else PNG.
fn retrieve(capture: &mut VideoCapture, mat: &mut Mat) -> opencv::Result<(Vec<u8>, &'static str)> {
    capture.retrieve(mat, 0)?;
    let bytes = mat.data_bytes()?;
    if mat.rows() == 1 && bytes.starts_with(&[0xff, 0xd8]) {
        return Ok((bytes.to_vec(), "jpg"));
    }
    let mut png = Vector::<u8>::new();
    opencv::imgcodecs::imencode(".png", mat, &mut png, &Vector::new())?;
    Ok((png.to_vec(), "png"))
}

/// Films `camera` until `stop`, sending each frame on `tx`; with `meter`, each frame's motion
/// is measured too.
pub(super) fn film(
    side: Side,
    mut camera: Camera,
    clock: &Clock,
    tx: &mpsc::Sender<Grabbed>,
    stop: &AtomicBool,
    mut meter: Option<Meter>,
) -> CameraEnd {
    let mut mat = Mat::default();
    let mut index = 0;
    while !stop.load(Ordering::SeqCst) {
        if let Some(period) = camera.pace_s {
            let due = index as f64 * period;
            let wait = due - clock.now_s();
            if wait > 0.0 {
                std::thread::sleep(Duration::from_secs_f64(wait));
            }
        }
        let grabbed = camera.capture.grab().unwrap_or(false);
        let grab_s = clock.now_s();
        let driver_s = camera
            .driver_stamps
            .then(|| camera.capture.get(videoio::CAP_PROP_POS_MSEC).ok())
            .flatten()
            .and_then(|ms| driver_time(ms, clock.start_monotonic_s + grab_s))
            .map(|t| t - clock.start_monotonic_s);
        let time_s = driver_s.unwrap_or(grab_s);
        let frame = grabbed
            .then(|| retrieve(&mut camera.capture, &mut mat).ok())
            .flatten();
        let Some((bytes, extension)) = frame else {
            return CameraEnd::Failed {
                time_s,
                frames: index,
            };
        };
        let change = meter.as_mut().and_then(|m| m.change(&bytes));
        let sent = tx.send(Grabbed {
            side,
            index,
            time_s,
            bytes,
            extension,
            by_driver: driver_s.is_some(),
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
    use super::driver_time;

    #[test]
    fn a_driver_stamp_is_used_only_when_it_can_be_the_frames() {
        // 1000.2 s since boot, grabbed 30 ms later.
        assert_eq!(driver_time(1_000_200.0, 1000.23), Some(1000.2));
        // Before the first frame, after the grab, or older than a second: the grab time.
        assert_eq!(driver_time(0.0, 1000.23), None);
        assert_eq!(driver_time(1_000_300.0, 1000.23), None);
        assert_eq!(driver_time(998_000.0, 1000.23), None);
        // Wall-clock milliseconds from another backend.
        assert_eq!(driver_time(1.7e12, 1000.23), None);
    }
}
