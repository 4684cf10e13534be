//! A video file standing in for a camera: its frames handed out at the file's own rate (or
//! `--fps` when it has none), a Motion-JPEG file's as the JPEG bytes it holds, and stamped as
//! they are handed out.

use std::time::Duration;

use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};

use super::{Frame, FrameSource, OpenCvReader};
use crate::capture::{CaptureOptions, Clock};

pub(super) struct VideoFile {
    reader: OpenCvReader,
    /// Its frame period (s).
    period_s: f64,
    /// Frames handed out.
    count: usize,
}

impl VideoFile {
    /// Opens the file at `path` (`Err`: why not).
    pub fn open(path: &str, o: &CaptureOptions) -> Result<Self, String> {
        let mut capture =
            VideoCapture::from_file(path, videoio::CAP_FFMPEG).map_err(|e| e.message)?;
        if !capture.is_opened().unwrap_or(false) {
            return Err("OpenCV cannot open it".into());
        }
        crate::video::read_raw_if_jpeg(&mut capture);
        let fps = capture.get(videoio::CAP_PROP_FPS).unwrap_or(0.0);
        Ok(VideoFile {
            reader: OpenCvReader::new(capture, false),
            period_s: 1.0 / if fps > 0.0 { fps } else { o.fps },
            count: 0,
        })
    }
}

impl FrameSource for VideoFile {
    fn refused(&self) -> Vec<String> {
        Vec::new()
    }

    fn live(&self) -> bool {
        false
    }

    fn next(&mut self, clock: &Clock) -> Option<Frame> {
        let wait = self.count as f64 * self.period_s - clock.now_s();
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait));
        }
        let frame = self.reader.read(clock)?;
        self.count += 1;
        Some(frame)
    }
}
