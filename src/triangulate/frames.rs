//! The frames of a capture: `frames.csv` (`frame,camera,time_s`) and the images it names,
//! `left_NNNNN.png` / `right_NNNNN.png` (or `.jpg`), as `synth` and `capture` write them; or,
//! instead of images, one video per camera, `left.<avi|mkv|mp4|mov>` and `right.<…>`, where a
//! frame's number is its position in its camera's video ([`crate::video`]).

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use opencv::core::Vector;
use opencv::imgcodecs;
use opencv::prelude::*;

use super::marker::RgbImage;
use super::subpixel::ChromaSampling;
use super::TriangulateError;
use crate::data::Table;
use crate::stereo::Side;

/// One row of `frames.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRecord {
    pub camera: Side,
    pub index: usize,
    /// The capture computer's timestamp (s, the pressure log's clock).
    pub time_s: f64,
    /// Line of `frames.csv`, for messages.
    pub line: u64,
    /// How late the frame was stamped, at least (s), when it was stamped late: it waited in a
    /// queue ([`crate::frame_times::late`], set by [`FrameList::read`]). Not paired.
    pub late_s: Option<f64>,
}

/// Reads `dir/frames.csv`.
///
/// # Errors
/// [`DataError::Input`](crate::data::DataError::Input) naming the file and line: unreadable file, missing column, a
/// camera other than `left`/`right`, a bad number, a frame listed twice.
pub fn read_frame_list(dir: &Path) -> Result<Vec<FrameRecord>, TriangulateError> {
    let mut table = Table::open(&dir.join("frames.csv"), "frame,camera,time_s")?;
    let (c_frame, c_camera, c_time) = (
        table.column("frame")?,
        table.column("camera")?,
        table.column("time_s")?,
    );
    let mut out = Vec::new();
    let mut seen = HashSet::new();
    for (line, record) in table.records()? {
        let camera = match &record[c_camera] {
            "left" => Side::Left,
            "right" => Side::Right,
            other => return table.fail(line, format!("camera {other:?}: use left or right")),
        };
        let index: usize = record[c_frame].parse().map_err(|_| {
            table.bad(
                line,
                format!("frame {:?} is not a frame number", &record[c_frame]),
            )
        })?;
        let time_s: f64 = record[c_time]
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite())
            .ok_or_else(|| {
                table.bad(
                    line,
                    format!("time_s {:?} is not a number", &record[c_time]),
                )
            })?;
        if !seen.insert((camera, index)) {
            return table.fail(
                line,
                format!("{} frame {index} is listed twice", camera.name()),
            );
        }
        out.push(FrameRecord {
            camera,
            index,
            time_s,
            line,
            late_s: None,
        });
    }
    if out.is_empty() {
        return table.fail(1, "no frames listed".into());
    }
    Ok(out)
}

/// Sets each record's [`FrameRecord::late_s`] from its camera's times.
fn mark_late(records: &mut [FrameRecord]) {
    for side in [Side::Left, Side::Right] {
        let mut order: Vec<usize> = (0..records.len())
            .filter(|&i| records[i].camera == side)
            .collect();
        order.sort_by(|&a, &b| records[a].time_s.total_cmp(&records[b].time_s));
        let times: Vec<f64> = order.iter().map(|&i| records[i].time_s).collect();
        for (i, late_s) in order.into_iter().zip(crate::frame_times::late(&times)) {
            records[i].late_s = late_s;
        }
    }
}

/// The image file of a frame: `{camera}_{index:05}` with a PNG or JPEG extension.
pub fn frame_path(dir: &Path, f: &FrameRecord) -> Option<PathBuf> {
    ["png", "jpg", "jpeg"]
        .iter()
        .map(|ext| dir.join(format!("{}_{:05}.{ext}", f.camera.name(), f.index)))
        .find(|p| p.is_file())
}

/// A session's frames: the records of `frames.csv` and where each one's image is, read once
/// for the output check and the run.
#[derive(Clone, Debug)]
pub struct FrameList {
    pub records: Vec<FrameRecord>,
    /// Each record's image file (`None` when there is none); all `None` for videos.
    pub paths: Vec<Option<PathBuf>>,
    /// The left and right camera's videos, when the frames are in videos.
    pub videos: Option<[PathBuf; 2]>,
}

/// The left and the right camera's video in `dir`, where there is one.
///
/// # Errors
/// [`TriangulateError::Video`] when a camera has two (`right.avi` and `right.mp4`).
pub fn videos(dir: &Path) -> Result<(Option<PathBuf>, Option<PathBuf>), TriangulateError> {
    let find = |stem| {
        crate::video::find(dir, stem).map_err(|message| TriangulateError::Video {
            path: dir.to_path_buf(),
            message,
        })
    };
    Ok((find("left")?, find("right")?))
}

impl FrameList {
    /// Reads `dir/frames.csv` and finds each frame's image, or the two videos; for two videos
    /// without `frames.csv`, their own timestamps after `video_start_s` (left, right; s on the
    /// log's clock).
    ///
    /// # Errors
    /// As [`read_frame_list`], [`TriangulateError::NoImages`] when no frame has an image
    /// and there are no videos, [`TriangulateError::Video`] for videos without `frames.csv`
    /// nor start times, or with both.
    pub fn read(dir: &Path, video_start_s: Option<[f64; 2]>) -> Result<Self, TriangulateError> {
        let listed = dir.join("frames.csv").exists();
        let videos = videos(dir)?;
        if let (Some(left), Some(right)) = videos.clone() {
            let video_error = |path: &Path, message: String| TriangulateError::Video {
                path: path.to_path_buf(),
                message,
            };
            match (listed, video_start_s) {
                (false, Some(start)) => {
                    let mut records = Vec::new();
                    // A video's own timestamps are the camera's rhythm: nothing is late.
                    for (side, path) in [(Side::Left, &left), (Side::Right, &right)] {
                        let times =
                            crate::video::timestamps(path).map_err(|why| video_error(path, why))?;
                        records.extend(times.iter().enumerate().map(|(index, t)| FrameRecord {
                            camera: side,
                            index,
                            time_s: start[side as usize] + t,
                            line: 0,
                            late_s: None,
                        }));
                    }
                    return Ok(FrameList {
                        paths: vec![None; records.len()],
                        records,
                        videos: Some([left, right]),
                    });
                }
                (false, None) => {
                    return Err(video_error(dir, "videos but no frames.csv: give --video-start-s LEFT,RIGHT (when each video's first frame was taken, on the pressure log's clock) to time the frames by the videos' own timestamps".into()));
                }
                (true, Some(_)) => {
                    return Err(video_error(dir, "--video-start-s is for videos without frames.csv, and this folder has one: drop the flag".into()));
                }
                (true, None) => {}
            }
        }
        let mut records = read_frame_list(dir)?;
        mark_late(&mut records);
        let paths: Vec<Option<PathBuf>> = records.iter().map(|f| frame_path(dir, f)).collect();
        if paths.iter().any(Option::is_some) {
            return Ok(FrameList {
                records,
                paths,
                videos: None,
            });
        }
        match videos {
            (Some(left), Some(right)) => Ok(FrameList {
                records,
                paths,
                videos: Some([left, right]),
            }),
            _ => Err(TriangulateError::NoImages(dir.to_path_buf())),
        }
    }

    /// The order to read the records in: as listed for images; for videos, each camera's
    /// frames by number (a video is read once, front to back).
    pub fn reading_order(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.records.len()).collect();
        if self.videos.is_some() {
            order.sort_by_key(|&i| (self.records[i].camera as u8, self.records[i].index));
        }
        order
    }

    /// A reader of the frames' data, in [`FrameList::reading_order`].
    ///
    /// # Errors
    /// A video that cannot be opened.
    pub fn reader(&self) -> Result<FrameReader<'_>, TriangulateError> {
        let videos = match &self.videos {
            Some([left, right]) => {
                let open = |path: &PathBuf| {
                    crate::video::VideoReader::open(path).map_err(|why| TriangulateError::Video {
                        path: path.clone(),
                        message: format!(
                            "{why}; give a video FFmpeg reads, or the frames as images"
                        ),
                    })
                };
                Some([open(left)?, open(right)?])
            }
            None => None,
        };
        Ok(FrameReader {
            list: self,
            videos,
            ended: [None, None],
        })
    }
}

/// A video that ended before the last frame `frames.csv` lists for it (a recording cut short,
/// a file copied while written): its frames are used up to its end, the rest counted missing.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct VideoEnd {
    pub path: PathBuf,
    /// Frames the video holds.
    pub frames: usize,
    /// Frames `frames.csv` lists after its end.
    pub missing: usize,
}

/// One frame's data, as [`FrameReader::read`] gives it to a worker.
pub enum FrameData<'a> {
    /// An image file to read.
    File(&'a Path),
    /// No image for this record.
    Missing,
    /// A frame out of a video.
    Video(crate::video::Frame),
}

/// Hands out each record's frame: image files by path, video frames read in order.
pub struct FrameReader<'a> {
    list: &'a FrameList,
    videos: Option<[crate::video::VideoReader; 2]>,
    /// Per camera, where its video ended early.
    ended: [Option<VideoEnd>; 2],
}

impl<'a> FrameReader<'a> {
    /// Per camera, the codec of a video whose frames OpenCV decodes (not Motion-JPEG): the
    /// marker's fit gets them without knowing how their colour was sampled.
    pub fn decoded_codecs(&self) -> [Option<String>; 2] {
        let videos = self.videos.as_ref();
        [0, 1].map(|k| {
            videos
                .map(|v| &v[k])
                .filter(|v| !v.raw)
                .map(|v| v.codec.clone())
        })
    }

    /// Record `i`'s frame; for videos, records must come in [`FrameList::reading_order`]. A
    /// frame after its video's end is [`FrameData::Missing`] and counted ([`Self::ended`]).
    ///
    /// # Errors
    /// [`TriangulateError::Video`] when the video cannot be read.
    pub fn read(&mut self, i: usize) -> Result<FrameData<'a>, TriangulateError> {
        let list: &'a FrameList = self.list;
        let Some(videos) = &mut self.videos else {
            return Ok(list.paths[i]
                .as_deref()
                .map_or(FrameData::Missing, FrameData::File));
        };
        let record = &list.records[i];
        let side = record.camera as usize;
        let path = &list.videos.as_ref().expect("videos")[side];
        let video = &mut videos[side];
        let frame = video
            .frame(record.index)
            .map_err(|e| TriangulateError::Video {
                path: path.clone(),
                message: e.message,
            })?;
        match frame {
            Some(frame) => Ok(FrameData::Video(frame)),
            None => {
                let end = self.ended[side].get_or_insert_with(|| VideoEnd {
                    path: path.clone(),
                    frames: video.position,
                    missing: 0,
                });
                end.missing += 1;
                Ok(FrameData::Missing)
            }
        }
    }

    /// Per camera, where its video ended before the frames listed for it.
    pub fn ended(&self) -> [Option<VideoEnd>; 2] {
        self.ended.clone()
    }
}

impl FrameData<'_> {
    /// How a message names the frame.
    pub fn name(&self, list: &FrameList, i: usize) -> PathBuf {
        match (self, &list.videos) {
            (FrameData::File(path), _) => path.to_path_buf(),
            (_, Some(videos)) => PathBuf::from(format!(
                "{} frame {}",
                videos[list.records[i].camera as usize].display(),
                list.records[i].index
            )),
            _ => PathBuf::from(format!("frames.csv line {}", list.records[i].line)),
        }
    }
}

/// Decodes a PNG (with the `png` crate: the fastest decoder here) or any other format OpenCV
/// reads (JPEG through libjpeg) into 8-bit RGB.
///
/// # Errors
/// A message saying why the file is not an image.
pub fn decode(path: &Path) -> Result<RgbImage, String> {
    let mut image = RgbImage::default();
    decode_into(path, &mut image, &mut Buffers::default())?;
    Ok(image)
}

/// What decoding a frame needs besides the image itself, kept from frame to frame: a 1280 ×
/// 720 frame is 2.7 MB, and fresh buffers cost page faults every time (the file's bytes, and
/// OpenCV's decoded BGR image: reusing it halved the time of decoding a JPEG).
#[derive(Default)]
pub struct Buffers {
    file: Vec<u8>,
    bgr: opencv::core::Mat,
}

/// [`decode`] into `image`, reusing its buffer and `buffers` from frame to frame.
///
/// # Errors
/// A message saying why the file is not an image.
pub fn decode_into(path: &Path, image: &mut RgbImage, buffers: &mut Buffers) -> Result<(), String> {
    use std::io::Read;
    let file = &mut buffers.file;
    file.clear();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(file))
        .map_err(|e| e.to_string())?;
    decode_bytes(file, image, &mut buffers.bgr)
}

/// A frame's data decoded into `image`.
///
/// # Errors
/// A message saying why it is not an image.
pub fn decode_frame(
    data: &FrameData,
    image: &mut RgbImage,
    buffers: &mut Buffers,
) -> Result<(), String> {
    match data {
        FrameData::File(path) => decode_into(path, image, buffers),
        FrameData::Missing => Err("no image".into()),
        FrameData::Video(crate::video::Frame::Encoded(bytes)) => {
            decode_bytes(bytes, image, &mut buffers.bgr)
        }
        FrameData::Video(crate::video::Frame::Decoded(bgr)) => {
            image.chroma = ChromaSampling::FULL;
            bgr_to_rgb(bgr, image)
        }
    }
}

/// An encoded image: PNG by the `png` crate, JPEG by zune-jpeg, anything else by OpenCV.
pub(crate) fn decode_bytes(
    bytes: &[u8],
    image: &mut RgbImage,
    bgr: &mut opencv::core::Mat,
) -> Result<(), String> {
    if bytes.starts_with(b"\x89PNG") {
        image.chroma = ChromaSampling::FULL;
        decode_png(bytes, image)
    } else if bytes.starts_with(&[0xff, 0xd8]) {
        decode_jpeg(bytes, image)?;
        image.chroma = ChromaSampling::of_jpeg(bytes);
        Ok(())
    } else {
        image.chroma = ChromaSampling::FULL;
        decode_opencv(bytes, bgr, image)
    }
}

fn decode_png(bytes: &[u8], image: &mut RgbImage) -> Result<(), String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let buf = &mut image.data;
    buf.resize(reader.output_buffer_size(), 0);
    let info = reader.next_frame(buf).map_err(|e| e.to_string())?;
    buf.truncate(info.buffer_size());
    (image.width, image.height) = (info.width as usize, info.height as usize);
    let expanded: Vec<u8> = match info.color_type {
        png::ColorType::Rgb => return Ok(()),
        png::ColorType::Rgba => buf
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        png::ColorType::Grayscale => buf.iter().flat_map(|&g| [g, g, g]).collect(),
        png::ColorType::GrayscaleAlpha => buf
            .chunks_exact(2)
            .flat_map(|p| [p[0], p[0], p[0]])
            .collect(),
        png::ColorType::Indexed => return Err("indexed PNG left unexpanded".into()),
    };
    *buf = expanded;
    Ok(())
}

/// JPEG with zune-jpeg, straight to RGB: 3 × faster than OpenCV's decoder here, which has
/// libjpeg write RGB and then swaps every pixel to BGR byte by byte (40 % of triangulating a
/// webcam capture), and us swap them back. Its colour interpolation is libjpeg's (3/4 of the
/// nearer chroma sample, 1/4 of the farther), which the sub-pixel fit models.
fn decode_jpeg(bytes: &[u8], image: &mut RgbImage) -> Result<(), String> {
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;
    if crate::cv::is_truncated_jpeg(bytes) {
        return Err("a truncated JPEG (no end-of-image marker)".into());
    }
    let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(bytes, options);
    let not_jpeg =
        |e: zune_jpeg::errors::DecodeErrors| format!("not a JPEG that can be read ({e})");
    decoder.decode_headers().map_err(not_jpeg)?;
    let info = decoder.info().ok_or("a JPEG without a frame header")?;
    (image.width, image.height) = (usize::from(info.width), usize::from(info.height));
    image.data.resize(3 * image.width * image.height, 0);
    decoder.decode_into(&mut image.data).map_err(not_jpeg)
}

fn decode_opencv(
    bytes: &[u8],
    bgr: &mut opencv::core::Mat,
    image: &mut RgbImage,
) -> Result<(), String> {
    let buf = Vector::<u8>::from_slice(bytes);
    // Camera frames carry no orientation to apply, and OpenCV's search for one (EXIF) read
    // the whole file byte by byte: a third of the decoding time of a 720p JPEG.
    let flags = imgcodecs::IMREAD_COLOR | imgcodecs::IMREAD_IGNORE_ORIENTATION;
    crate::cv::decode_image_into(&buf, flags, bgr)?;
    bgr_to_rgb(bgr, image)
}

/// An OpenCV BGR image into `image`'s RGB.
fn bgr_to_rgb(bgr: &opencv::core::Mat, image: &mut RgbImage) -> Result<(), String> {
    let not_image = |_| "not an 8-bit colour image".to_string();
    (image.width, image.height) = (bgr.cols() as usize, bgr.rows() as usize);
    let continuous;
    let bgr = if bgr.is_continuous() {
        bgr
    } else {
        continuous = bgr.try_clone().map_err(not_image)?;
        &continuous
    };
    let src = bgr.data_bytes().map_err(not_image)?;
    image.data.resize(src.len(), 0);
    for (d, s) in image.data.chunks_exact_mut(3).zip(src.chunks_exact(3)) {
        d.copy_from_slice(&[s[2], s[1], s[0]]);
    }
    Ok(())
}
