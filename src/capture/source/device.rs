//! A camera on this machine: a device index (`0`), a device path (`/dev/video2`), or anything
//! else OpenCV opens by name (a GStreamer pipeline). It is asked for Motion-JPEG at the size
//! and rate given and for fixed exposure, white balance and focus (what it refuses is said),
//! and its JPEG bytes are kept as the camera sent them. A V4L2 device's frames are stamped by
//! the driver ([`driver_time`]), on the same monotonic clock as the session.

use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};

use super::{Frame, FrameSource, OpenCvReader};
use crate::capture::{CaptureOptions, Clock};

/// The most a driver's stamp may precede the grab (s): older, it is not this frame's.
const DRIVER_STAMP_MAX_AGE_S: f64 = 1.0;

/// A V4L2 driver's buffer timestamp (`CAP_PROP_POS_MSEC`: ms on the host's monotonic clock)
/// as monotonic seconds, when it can be this frame's: not after the grab at `grab_s`, and at
/// most `DRIVER_STAMP_MAX_AGE_S` before it (0 before the first frame, another clock, a
/// backend that means something else by it: the grab time is used instead).
pub fn driver_time(pos_msec: f64, grab_s: f64) -> Option<f64> {
    let t = pos_msec / 1e3;
    (pos_msec > 0.0 && t <= grab_s && grab_s - t <= DRIVER_STAMP_MAX_AGE_S).then_some(t)
}

/// Whether `source` names a device rather than a file or a stream.
pub(super) fn is_device(source: &str) -> bool {
    source.parse::<i32>().is_ok() || source.starts_with("/dev/")
}

/// The video devices on this machine, for the message when a camera does not open.
pub(super) fn devices() -> String {
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

pub(super) struct Device {
    reader: OpenCvReader,
    refused: Vec<String>,
}

impl Device {
    /// Opens `source` (`Err`: why not) with the settings of `o`.
    pub fn open(source: &str, o: &CaptureOptions) -> Result<Self, String> {
        let opened = match source.parse::<i32>() {
            Ok(index) => VideoCapture::new(index, videoio::CAP_ANY),
            Err(_) => VideoCapture::from_file(source, videoio::CAP_ANY),
        };
        let mut capture = opened.map_err(|e| e.message)?;
        if !capture.is_opened().unwrap_or(false) {
            return Err("OpenCV cannot open it".into());
        }
        let mjpg = f64::from(videoio::VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap_or(0));
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
        let refused = settings
            .into_iter()
            .filter(|&(_, prop, value)| !capture.set(prop, value).unwrap_or(false))
            .map(|(name, _, _)| name.to_string())
            .collect();
        let driver_stamps = capture.get_backend_name().is_ok_and(|b| b == "V4L2");
        Ok(Device {
            reader: OpenCvReader::new(capture, driver_stamps),
            refused,
        })
    }
}

impl FrameSource for Device {
    fn refused(&self) -> Vec<String> {
        self.refused.clone()
    }

    fn next(&mut self, clock: &Clock) -> Option<Frame> {
        self.reader.read(clock)
    }
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
