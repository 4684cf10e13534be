//! Videos through OpenCV's `videoio`: a camera's frames read one after the other from a file
//! (or a device, or a stream), and written as Motion-JPEG.
//!
//! A webcam's MJPEG frame is a JPEG, and so is every frame of a Motion-JPEG video; read raw
//! (`CAP_PROP_FORMAT = -1`, FFmpeg's demuxer: each packet is one frame's bytes), the frame
//! reaches the marker's fit exactly as an image file would, with its chroma sampling and
//! quantisation tables. Frames of other codecs (H.264 from OBS or a phone) are decoded by
//! OpenCV.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture, VideoWriter};

/// Extensions of the video files handcap looks for (`left.avi`, `right.mp4`, …).
pub const EXTENSIONS: [&str; 4] = ["avi", "mkv", "mp4", "mov"];

/// `dir/{stem}.<ext>` for the one of [`EXTENSIONS`] that exists.
///
/// # Errors
/// A message naming the files when more than one exists: which camera's video is meant cannot
/// be told.
pub fn find(dir: &Path, stem: &str) -> Result<Option<PathBuf>, String> {
    let found: Vec<PathBuf> = EXTENSIONS
        .iter()
        .map(|ext| dir.join(format!("{stem}.{ext}")))
        .filter(|p| p.is_file())
        .collect();
    match found.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some(one.clone())),
        many => Err(format!(
            "{} are all videos of the {stem} camera; keep the one to use",
            many.iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(" and ")
        )),
    }
}

/// Has a Motion-JPEG file (FFmpeg's reader) hand out each frame's JPEG bytes undecoded;
/// `false` for other codecs, whose frames OpenCV decodes.
pub fn read_raw_if_jpeg(capture: &mut VideoCapture) -> bool {
    matches!(
        codec(capture).as_str(),
        "MJPG" | "mjpg" | "MJPA" | "AVRn" | "jpeg" | "mjpe"
    ) && capture.set(videoio::CAP_PROP_FORMAT, -1.0).unwrap_or(false)
}

/// The codec's four-character code, as FFmpeg names it (`H264`, `MJPG`, …).
pub(crate) fn codec(capture: &VideoCapture) -> String {
    let fourcc = capture.get(videoio::CAP_PROP_FOURCC).unwrap_or(0.0) as u32;
    fourcc
        .to_le_bytes()
        .iter()
        .map(|&b| b as char)
        .filter(|c| !c.is_control())
        .collect()
}

/// One frame as it came out of the video.
pub enum Frame {
    /// An encoded frame (a JPEG for Motion-JPEG).
    Encoded(Vec<u8>),
    /// A frame OpenCV decoded (BGR).
    Decoded(Mat),
}

/// A video's frames in order.
pub struct VideoReader {
    capture: VideoCapture,
    /// Whether frames come as their JPEG bytes (Motion-JPEG) rather than decoded by OpenCV.
    pub raw: bool,
    /// The codec's four-character code.
    pub codec: String,
    /// Frames read so far.
    pub position: usize,
    /// What the container says it holds (0 when it does not say).
    pub frame_count: usize,
    pub fps: f64,
}

impl VideoReader {
    /// Opens a video file (or anything FFmpeg reads), raw when its frames are JPEGs.
    ///
    /// # Errors
    /// A message saying why it cannot be read.
    pub fn open(path: &Path) -> Result<Self, String> {
        let open = || -> opencv::Result<VideoCapture> {
            VideoCapture::from_file(path.to_string_lossy().as_ref(), videoio::CAP_FFMPEG)
        };
        let mut capture = open().map_err(|e| e.message)?;
        if !capture.is_opened().unwrap_or(false) {
            return Err("not a video FFmpeg can read".into());
        }
        let get = |c: &VideoCapture, prop| c.get(prop).unwrap_or(0.0);
        let raw = read_raw_if_jpeg(&mut capture);
        Ok(VideoReader {
            codec: codec(&capture),
            frame_count: get(&capture, videoio::CAP_PROP_FRAME_COUNT).max(0.0) as usize,
            fps: get(&capture, videoio::CAP_PROP_FPS),
            capture,
            raw,
            position: 0,
        })
    }

    /// The next frame; `None` at the end.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn next_frame(&mut self) -> opencv::Result<Option<Frame>> {
        let mut mat = Mat::default();
        if !self.capture.read(&mut mat)? || mat.empty() {
            return Ok(None);
        }
        self.position += 1;
        Ok(Some(if self.raw {
            Frame::Encoded(mat.data_bytes()?.to_vec())
        } else {
            Frame::Decoded(mat)
        }))
    }

    /// Frame `index`, skipping the frames before it undecoded; `None` past the end. Frames
    /// come front to back: an index already passed is not read again.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn frame(&mut self, index: usize) -> opencv::Result<Option<Frame>> {
        while self.position < index {
            if !self.skip()? {
                return Ok(None);
            }
        }
        self.next_frame()
    }

    /// Skips the next frame without decoding it; `false` at the end.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn skip(&mut self) -> opencv::Result<bool> {
        let more = self.capture.grab()?;
        if more {
            self.position += 1;
        }
        Ok(more)
    }
}

/// Each frame's timestamp in a video (s from its start: the container's presentation times,
/// or the frame number over the rate where it keeps none).
///
/// # Errors
/// A message saying why the video cannot be read.
pub fn timestamps(path: &Path) -> Result<Vec<f64>, String> {
    let open = || VideoCapture::from_file(path.to_string_lossy().as_ref(), videoio::CAP_FFMPEG);
    let mut capture = open().map_err(|e| e.message)?;
    if !capture.is_opened().unwrap_or(false) {
        return Err("not a video FFmpeg can read".into());
    }
    let mut times = Vec::new();
    while capture.grab().map_err(|e| e.message)? {
        times.push(
            capture
                .get(videoio::CAP_PROP_POS_MSEC)
                .map_err(|e| e.message)?
                / 1e3,
        );
    }
    Ok(times)
}

/// Writes frames (8-bit RGB, one size) as a Motion-JPEG AVI, OpenCV's own writer (no FFmpeg
/// needed), 4:2:0 at a JPEG `quality` (1-100, libjpeg's meaning; see [`opencv_mjpeg_quality`]);
/// into a temporary file renamed when finished, so that an
/// interrupted write leaves no half a video under the name.
pub struct MjpegWriter {
    writer: VideoWriter,
    size: Size,
    bgr: Vec<u8>,
    partial: PathBuf,
    path: PathBuf,
}

impl MjpegWriter {
    /// # Errors
    /// A message saying why the file cannot be written.
    pub fn create(path: &Path, fps: f64, size: [u32; 2], quality: u8) -> Result<Self, String> {
        let size = Size::new(size[0] as i32, size[1] as i32);
        let partial = path.with_extension("partial.avi");
        let create = || -> opencv::Result<VideoWriter> {
            let fourcc = VideoWriter::fourcc('M', 'J', 'P', 'G')?;
            let mut writer = VideoWriter::new_with_backend(
                partial.to_string_lossy().as_ref(),
                videoio::CAP_OPENCV_MJPEG,
                fourcc,
                fps,
                size,
                true,
            )?;
            writer.set(
                videoio::VIDEOWRITER_PROP_QUALITY,
                opencv_mjpeg_quality(quality),
            )?;
            Ok(writer)
        };
        let writer = create().map_err(|e| e.message)?;
        if !writer.is_opened().unwrap_or(false) {
            return Err("OpenCV cannot write a video there".into());
        }
        Ok(MjpegWriter {
            writer,
            size,
            bgr: Vec::new(),
            partial,
            path: path.to_path_buf(),
        })
    }

    /// Appends one frame.
    ///
    /// # Errors
    /// An OpenCV failure.
    pub fn write(&mut self, rgb: &[u8]) -> opencv::Result<()> {
        self.bgr.clear();
        self.bgr
            .extend(rgb.chunks_exact(3).flat_map(|p| [p[2], p[1], p[0]]));
        let flat = Mat::from_slice(&self.bgr)?;
        let image = flat.reshape(3, self.size.height)?;
        self.writer.write(&image)
    }

    /// Finishes the file (its index) and gives it its name.
    ///
    /// # Errors
    /// A message saying what failed.
    pub fn finish(mut self) -> Result<(), String> {
        self.writer.release().map_err(|e| e.message)?;
        std::fs::rename(&self.partial, &self.path).map_err(|e| e.to_string())
    }
}

/// OpenCV's Motion-JPEG writer divides the standard quantisation tables by 12 × quality / 100;
/// libjpeg (and webcams, and `imencode`) scale them by 50 / quality below 50 and by
/// 2 − quality / 50 above. The writer's quality that gives libjpeg's tables at `quality`.
pub fn opencv_mjpeg_quality(quality: u8) -> f64 {
    let q = f64::from(quality.clamp(1, 100));
    let scale = if q < 50.0 { 50.0 / q } else { 2.0 - q / 50.0 };
    100.0 / (12.0 * scale.max(1e-3))
}

impl Drop for MjpegWriter {
    fn drop(&mut self) {
        // Unfinished (an error or an interruption on the way): no partial file stays.
        let _ = std::fs::remove_file(&self.partial);
    }
}
