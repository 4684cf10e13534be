//! The frames of a capture: `frames.csv` (`frame,camera,time_s`) and the images it names,
//! `left_NNNNN.png` / `right_NNNNN.png` (or `.jpg`), as `synth` and `capture` write them; or,
//! instead of images, one video per camera, `left.<avi|mkv|mp4|mov>` and `right.<…>`, where a
//! frame's number is its position in its camera's video ([`crate::video`]). `capture` and
//! `synth` write `frames.csv` ([`frames_csv`]); `triangulate` and `calibrate` read it, and pair
//! the left and right frames by time ([`pair_frames`]).

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use super::SessionError;
use crate::data::{Csv, Table};
use crate::image::{bgr_to_rgb, decode_bytes, decode_into, Buffers, ChromaSampling, RgbImage};
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

/// Whether `name` can name a camera: lower-case letters and digits, a letter first (`left`,
/// `cam1`), as the session's files (`<camera>_NNNNN.jpg`, `<camera>_NN.png`) spell it.
pub fn is_camera_name(name: &str) -> bool {
    name.starts_with(|c: char| c.is_ascii_lowercase())
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit())
}

/// Reads `dir/frames.csv`.
///
/// # Errors
/// [`DataError::Input`](crate::data::DataError::Input) naming the file and line: unreadable file, missing column, a
/// camera other than `left`/`right`, a bad number, a frame listed twice.
pub fn read_frame_list(dir: &Path) -> Result<Vec<FrameRecord>, SessionError> {
    let rows = read_frame_rows(dir, |name| match name {
        "left" => Ok(Some(Side::Left)),
        "right" => Ok(Some(Side::Right)),
        other => Err(format!("camera {other:?}: use left or right")),
    })?;
    Ok(rows
        .into_iter()
        .map(|(camera, index, time_s, line)| FrameRecord {
            camera,
            index,
            time_s,
            line,
            late_s: None,
        })
        .collect())
}

/// The rows of `dir/frames.csv` as (camera, frame number, time, line), each row's camera
/// named by `camera` from the row's name (`Ok(None)`: a row to leave out; `Err(message)`: the
/// row refused), its numbers checked, a camera's frame listed twice refused, and at least one
/// row kept.
///
/// # Errors
/// [`DataError::Input`](crate::data::DataError::Input) naming the file and line.
pub fn read_frame_rows<C: Copy + Eq + std::hash::Hash>(
    dir: &Path,
    camera: impl Fn(&str) -> Result<Option<C>, String>,
) -> Result<Vec<(C, usize, f64, u64)>, SessionError> {
    let table = Table::open(&dir.join("frames.csv"), "frame,camera,time_s")?;
    let (c_frame, c_camera, c_time) = (
        table.column("frame")?,
        table.column("camera")?,
        table.column("time_s")?,
    );
    let mut out = Vec::new();
    let mut seen = HashSet::new();
    for (line, record) in table.records()? {
        let name = &record[c_camera];
        let id = match camera(name) {
            Ok(Some(id)) => id,
            Ok(None) => continue,
            Err(message) => return table.fail(line, message),
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
        if !seen.insert((id, index)) {
            return table.fail(line, format!("{name} frame {index} is listed twice"));
        }
        out.push((id, index, time_s, line));
    }
    if out.is_empty() {
        return table.fail(1, "no frames listed".into());
    }
    Ok(out)
}

/// `frames.csv` of `rows` (camera, frame number, time in s), in the order given.
pub fn frames_csv<C: AsRef<str>>(rows: impl IntoIterator<Item = (C, usize, f64)>) -> String {
    let mut csv = frames_table();
    frames_rows(&mut csv, rows);
    csv.into_string()
}

/// `frames.csv` with its header and no rows yet.
pub fn frames_table() -> Csv {
    Csv::new(["frame", "camera", "time_s"])
}

/// Adds `rows` to `frames.csv`.
pub fn frames_rows<C: AsRef<str>>(csv: &mut Csv, rows: impl IntoIterator<Item = (C, usize, f64)>) {
    for (camera, index, time_s) in rows {
        csv.row([
            index.to_string(),
            camera.as_ref().to_string(),
            format!("{time_s:.6}"),
        ]);
    }
}

/// The indices of `side`'s records in time order.
pub fn in_time_order(records: &[FrameRecord], side: Side) -> Vec<usize> {
    let mut order: Vec<usize> = (0..records.len())
        .filter(|&i| records[i].camera == side)
        .collect();
    order.sort_by(|&a, &b| records[a].time_s.total_cmp(&records[b].time_s));
    order
}

/// Sets each record's [`FrameRecord::late_s`] from its camera's times.
fn mark_late(records: &mut [FrameRecord]) {
    for side in [Side::Left, Side::Right] {
        let order = in_time_order(records, side);
        let times: Vec<f64> = order.iter().map(|&i| records[i].time_s).collect();
        for (i, late_s) in order.into_iter().zip(crate::frame_times::late(
            &times,
            crate::frame_times::period(&times),
        )) {
            records[i].late_s = late_s;
        }
    }
}

/// The extensions a frame's image file may have, in the order they are looked for.
pub const FRAME_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The image file of camera `camera`'s frame `index` in `dir`: `{camera}_{index:05}` with one
/// of [`FRAME_EXTENSIONS`].
pub fn image_path(dir: &Path, camera: &str, index: usize) -> Option<PathBuf> {
    FRAME_EXTENSIONS
        .iter()
        .map(|ext| dir.join(format!("{camera}_{index:05}.{ext}")))
        .find(|p| p.is_file())
}

/// The image file of a frame of the pair ([`image_path`]).
pub fn frame_path(dir: &Path, f: &FrameRecord) -> Option<PathBuf> {
    image_path(dir, f.camera.name(), f.index)
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
/// [`SessionError::Video`] when a camera has two (`right.avi` and `right.mp4`).
pub fn videos(dir: &Path) -> Result<(Option<PathBuf>, Option<PathBuf>), SessionError> {
    let find = |stem| {
        crate::video::find(dir, stem).map_err(|message| SessionError::Video {
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
    /// As [`read_frame_list`], [`SessionError::NoImages`] when no frame has an image
    /// and there are no videos, [`SessionError::Video`] for videos without `frames.csv`
    /// nor start times, or with both.
    pub fn read(dir: &Path, video_start_s: Option<[f64; 2]>) -> Result<Self, SessionError> {
        let listed = dir.join("frames.csv").exists();
        let videos = videos(dir)?;
        if let (Some(left), Some(right)) = videos.clone() {
            let video_error = |path: &Path, message: String| SessionError::Video {
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
            _ => Err(SessionError::NoImages(dir.to_path_buf())),
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
    pub fn reader(&self) -> Result<FrameReader<'_>, SessionError> {
        let videos = match &self.videos {
            Some([left, right]) => {
                let open = |path: &PathBuf| {
                    crate::video::VideoReader::open(path).map_err(|why| SessionError::Video {
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
    /// [`SessionError::Video`] when the video cannot be read.
    pub fn read(&mut self, i: usize) -> Result<FrameData<'a>, SessionError> {
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
        let frame = video.frame(record.index).map_err(|e| SessionError::Video {
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

/// Left and right frames paired by time: indices into the frame list.
#[derive(Clone, Debug, PartialEq)]
pub struct Pairing {
    pub pairs: Vec<(usize, usize)>,
    /// Frames of each camera with no partner (left, right).
    pub unpaired: [usize; 2],
}

/// Pairs each left frame with the right frame nearest in time when that right frame's nearest
/// left frame is it, and they are at most `max_dt_s` apart; frames stamped late take no part.
/// Pairs come in time order.
pub fn pair_frames(frames: &[FrameRecord], max_dt_s: f64) -> Pairing {
    let by_time = |side: Side| {
        let mut v = in_time_order(frames, side);
        v.retain(|&i| frames[i].late_s.is_none());
        v
    };
    let (left, right) = (by_time(Side::Left), by_time(Side::Right));
    let nearest = |to: f64, among: &[usize]| -> Option<usize> {
        let k = among.partition_point(|&i| frames[i].time_s < to);
        [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter(|&j| j < among.len())
            .min_by(|&a, &b| {
                (frames[among[a]].time_s - to)
                    .abs()
                    .total_cmp(&(frames[among[b]].time_s - to).abs())
            })
    };
    let mut pairs = Vec::new();
    for &l in &left {
        let Some(r) = nearest(frames[l].time_s, &right) else {
            continue;
        };
        let r = right[r];
        let back = nearest(frames[r].time_s, &left).map(|k| left[k]);
        if back == Some(l) && (frames[l].time_s - frames[r].time_s).abs() <= max_dt_s {
            pairs.push((l, r));
        }
    }
    Pairing {
        unpaired: [left.len() - pairs.len(), right.len() - pairs.len()],
        pairs,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn frame(camera: Side, index: usize, time_s: f64) -> FrameRecord {
        FrameRecord {
            camera,
            index,
            time_s,
            line: 0,
            late_s: None,
        }
    }

    #[test]
    fn frames_pair_with_their_mutual_nearest_within_the_tolerance() {
        let f = vec![
            frame(Side::Left, 0, 0.100),
            frame(Side::Left, 1, 0.133),
            frame(Side::Left, 2, 0.166),
            frame(Side::Left, 3, 0.500), // its right partner was dropped
            frame(Side::Right, 0, 0.108),
            frame(Side::Right, 1, 0.141),
            frame(Side::Right, 2, 0.175),
            frame(Side::Right, 3, 0.540), // 40 ms from the nearest left frame
        ];
        let p = pair_frames(&f, 0.02);
        assert_eq!(p.pairs, vec![(0, 4), (1, 5), (2, 6)]);
        assert_eq!(p.unpaired, [1, 1]);
        // Two left frames near one right frame: only the nearer pairs.
        let f = vec![
            frame(Side::Left, 0, 0.100),
            frame(Side::Left, 1, 0.104),
            frame(Side::Right, 0, 0.103),
        ];
        assert_eq!(pair_frames(&f, 0.02).pairs, vec![(1, 2)]);
    }
}
