//! How the cameras stored their frames' colour: a JPEG's chroma sampling and the quality its
//! chroma table is written at, read from each camera's first frame (an image file, or the
//! first frame of its Motion-JPEG video). At a coarse quality the chroma's rounding, not the
//! fit, limits the tip in motion, so a lab is told before it models.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use crate::image::ChromaSampling;
use crate::session::frames::{image_path, FRAME_EXTENSIONS};
use crate::video::{Frame, VideoReader};

/// Below this JPEG quality (libjpeg's scale) the chroma's rounding, not the fit, limits the
/// tip in motion ([`COARSE_JPEG_ADVICE`]; `scripts/bench_per_frame_seeds.py`, docs/motion.md).
const COARSE_JPEG_QUALITY: u8 = 90;

/// What a coarser quality costs, measured on ten rendered sessions of the demo's design: the
/// per-frame tip 0.040-0.086 mm RMS at quality 85, 0.020-0.051 at 95.
const COARSE_JPEG_ADVICE: &str = "the chroma's rounding holds the tip in motion to about 0.04-0.09 mm RMS (0.02-0.05 at quality 95, docs/motion.md): raise the cameras' MJPEG quality where they let it be set";

/// How each of `cameras` stored its frames' colour in `frames`: from its first frame's file
/// (`<camera>_NNNNN.jpg`, the smallest number) when it is a JPEG, or where it has no image
/// files, the first frame of its Motion-JPEG video (`<camera>.avi`, …), as the session is
/// read: the chroma's sampling and the quality its table is written at; one line, with advice
/// when a camera's is below [`COARSE_JPEG_QUALITY`]. `None` when no camera's frames are JPEGs
/// (PNG frames, videos of other codecs).
pub fn stored_colour(frames: &Path, cameras: &[&str]) -> Option<String> {
    let first = first_frame_numbers(frames, cameras);
    let mut lowest = 100;
    let stored: Vec<String> = cameras
        .iter()
        .filter_map(|&camera| {
            let (source, bytes) = match first.get(camera) {
                Some(&index) => {
                    let path = image_path(frames, camera, index)?;
                    if !is_jpeg(&path) {
                        return None;
                    }
                    let bytes = std::fs::read(&path).ok();
                    (path, bytes)
                }
                None => {
                    let video = crate::video::find(frames, camera).ok()??;
                    let bytes = first_video_jpeg(&video)?;
                    (video, Some(bytes))
                }
            };
            let told = bytes.map(|b| ChromaSampling::of_jpeg(&b));
            Some(match told.as_ref().map(|s| (s.block, s.quality())) {
                Some((block, Some(quality))) => {
                    lowest = lowest.min(quality);
                    format!("{camera} {} at quality {quality}", sampling_name(block))
                }
                _ => format!("{camera} unknown ({} unread)", source.display()),
            })
        })
        .collect();
    if stored.is_empty() {
        return None;
    }
    let advice = if lowest < COARSE_JPEG_QUALITY {
        format!("; below {COARSE_JPEG_QUALITY} {COARSE_JPEG_ADVICE}")
    } else {
        String::new()
    };
    Some(format!(
        "colour: JPEG, {} (libjpeg's scale, read from the chroma tables){advice}",
        stored.join(", ")
    ))
}

/// Writes `colour` ([`stored_colour`]) as a line, when there is one.
pub(in crate::pipeline) fn write_colour(
    f: &mut fmt::Formatter,
    colour: Option<&String>,
) -> fmt::Result {
    colour.map_or(Ok(()), |c| writeln!(f, "{c}"))
}

/// Each of `cameras`' first frame number in `frames` (of its files `<camera>_NNNNN.<ext>`,
/// `ext` one of [`FRAME_EXTENSIONS`]): one listing of the directory for all of them. The
/// frame's file is then the one the session reads ([`image_path`]).
fn first_frame_numbers<'a>(frames: &Path, cameras: &[&'a str]) -> BTreeMap<&'a str, usize> {
    let mut first: BTreeMap<&str, usize> = BTreeMap::new();
    let Ok(entries) = std::fs::read_dir(frames) else {
        return first;
    };
    for path in entries.flatten().map(|e| e.path()) {
        let extension = path.extension().map(|e| e.to_string_lossy());
        if !extension.is_some_and(|e| FRAME_EXTENSIONS.contains(&&*e)) {
            continue;
        }
        let Some(stem) = path.file_stem().map(|s| s.to_string_lossy()) else {
            continue;
        };
        let Some((name, number)) = stem.rsplit_once('_') else {
            continue;
        };
        let Some(&camera) = cameras.iter().find(|&&c| c == name) else {
            continue;
        };
        if !number.bytes().all(|b| b.is_ascii_digit()) {
            continue;
        }
        let Ok(index) = number.parse::<usize>() else {
            continue;
        };
        let kept = first.entry(camera).or_insert(index);
        *kept = (*kept).min(index);
    }
    first
}

/// Whether `path` names a JPEG file (by its extension).
fn is_jpeg(path: &Path) -> bool {
    (path.extension()).is_some_and(|e| e != "png")
}

/// The first frame's bytes of a Motion-JPEG `video`; `None` for other codecs or an unreadable
/// file.
fn first_video_jpeg(video: &Path) -> Option<Vec<u8>> {
    let mut reader = VideoReader::open(video).ok()?;
    match reader.next_frame() {
        Ok(Some(Frame::Encoded(bytes))) if reader.raw => Some(bytes),
        _ => None,
    }
}

/// A chroma block's size in luma pixels, as the trade names it.
fn sampling_name(block: [usize; 2]) -> String {
    match block {
        [1, 1] => "4:4:4".to_string(),
        [2, 1] => "4:2:2".to_string(),
        [2, 2] => "4:2:0".to_string(),
        [h, v] => format!("chroma {h} × {v} pixels"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::image_format::{Chroma, ImageFormat};

    /// A 64 × 48 grey frame stored as `format`.
    fn frame(format: ImageFormat) -> Vec<u8> {
        format.encode(64, 48, &vec![128; 64 * 48 * 3])
    }

    fn jpeg(quality: u8) -> ImageFormat {
        ImageFormat::Jpeg {
            quality,
            chroma: Chroma::Half,
        }
    }

    #[test]
    fn each_named_camera_is_read_from_its_first_frame_or_its_video_and_no_other() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // cam1's first frame (the smallest number) is at 92, a later one at 50.
        std::fs::write(d.join("cam1_00002.jpg"), frame(jpeg(50))).unwrap();
        std::fs::write(d.join("cam1_00001.jpeg"), frame(jpeg(92))).unwrap();
        // Not a frame, though it sorts first: no number after the name.
        std::fs::write(d.join("cam1_.jpg"), frame(jpeg(20))).unwrap();
        // cam2 filmed to a Motion-JPEG video at 70.
        let video = |name: &str, quality| {
            let path = d.join(name);
            let mut video = crate::video::MjpegWriter::create(&path, 30.0, [64, 48], quality);
            video.as_mut().unwrap().write(&[128; 64 * 48 * 3]).unwrap();
            video.unwrap().finish().unwrap();
        };
        video("cam2.avi", 70);
        // cam3 is not among the cameras asked for (not calibrated); cam4's frames are PNG, which
        // the session reads before the video beside them.
        std::fs::write(d.join("cam3_00001.jpg"), frame(jpeg(30))).unwrap();
        std::fs::write(d.join("cam4_00001.png"), frame(ImageFormat::Png)).unwrap();
        video("cam4.avi", 40);

        let line = stored_colour(d, &["cam1", "cam2", "cam4"]).unwrap();
        assert!(
            line.starts_with(
                "colour: JPEG, cam1 4:2:0 at quality 92, cam2 4:2:0 at quality 70 (libjpeg's"
            ),
            "{line}"
        );
        assert!(line.contains("; below 90 the chroma's rounding"), "{line}");
        assert!(!line.contains("cam3") && !line.contains("cam4"), "{line}");

        // At 90 and above, no advice; PNG frames alone, no line.
        assert!(!stored_colour(d, &["cam1"]).unwrap().contains("below"));
        assert_eq!(stored_colour(d, &["cam4"]), None);
        // A frame that is not a JPEG inside is named unread.
        std::fs::write(d.join("cam5_00001.jpg"), b"not a jpeg").unwrap();
        let unread = stored_colour(d, &["cam5"]).unwrap();
        assert!(unread.contains("cam5 unknown ("), "{unread}");
        // A frame kept as PNG and JPEG alike is read as the session reads it: the PNG.
        std::fs::write(d.join("cam6_00001.png"), frame(ImageFormat::Png)).unwrap();
        std::fs::write(d.join("cam6_00001.jpg"), frame(jpeg(60))).unwrap();
        assert_eq!(stored_colour(d, &["cam6"]), None);
    }
}
