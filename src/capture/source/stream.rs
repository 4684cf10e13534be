//! A network stream (`http://…` Motion-JPEG as IP cameras, mjpg-streamer and ESP32-CAMs serve
//! it, `rtsp://…`), read by FFmpeg with the server's settings. Its Motion-JPEG frames are kept
//! as the bytes that came: no decoding and re-encoding on the grab thread (23.5 ms of CPU for a
//! 720p frame, which a busy computer cannot spare at 30 fps); other codecs are decoded. FFmpeg's
//! own waits are 30 s; a stream gives up within [`STREAM_OPEN_S`] to open and [`STALL_S`] to
//! read instead, so a stopped server ends the session promptly and Ctrl-C is never kept
//! waiting. When it does not open, its server is asked what it answers ([`url::answer`]).

use std::time::Instant;

use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};

use super::{Frame, FrameSource, OpenCvReader};
use crate::capture::url;
use crate::capture::{Clock, STALL_S, STREAM_OPEN_S};

/// Whether `source` is a stream's URL.
pub(super) fn is_stream(source: &str) -> bool {
    source.contains("://")
}

pub(super) struct Stream {
    reader: OpenCvReader,
    refused: Vec<String>,
}

impl Stream {
    /// Opens the stream at `source` (`Err`: why not, with the server's answer).
    pub fn open(source: &str) -> Result<Self, String> {
        let ms = |s: f64| (1e3 * s).round() as i32;
        let params = opencv::core::Vector::<i32>::from_slice(&[
            videoio::CAP_PROP_OPEN_TIMEOUT_MSEC,
            ms(STREAM_OPEN_S),
            videoio::CAP_PROP_READ_TIMEOUT_MSEC,
            ms(STALL_S),
        ]);
        let opening = Instant::now();
        let mut capture = VideoCapture::from_file_with_params(source, videoio::CAP_FFMPEG, &params)
            .map_err(|e| e.message)?;
        if !capture.is_opened().unwrap_or(false) {
            let waited = opening.elapsed().as_secs_f64() >= STREAM_OPEN_S - 0.5;
            let answer = url::answer(source).map_or(String::new(), |a| format!("; {a}"));
            return Err(if waited {
                format!("it did not open and send a frame within {STREAM_OPEN_S} s{answer}")
            } else {
                format!("it did not open{answer}")
            });
        }
        let mut refused = Vec::new();
        if !crate::video::read_raw_if_jpeg(&mut capture) {
            refused.push(format!(
                "raw frames (codec {:?}, not Motion-JPEG: frames decoded, stored as PNG)",
                crate::video::codec(&capture)
            ));
        }
        Ok(Stream {
            reader: OpenCvReader::new(capture, false),
            refused,
        })
    }
}

impl FrameSource for Stream {
    fn refused(&self) -> Vec<String> {
        self.refused.clone()
    }

    fn next(&mut self, clock: &Clock) -> Option<Frame> {
        self.reader.read(clock)
    }
}
