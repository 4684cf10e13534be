//! Images as handcap reads them: 8-bit RGB, with how the file stored the colour (a JPEG's
//! chroma sampling and quantisation, which the marker's sub-pixel fit models), decoded from
//! PNG, JPEG or anything else OpenCV reads.

use std::path::Path;

use opencv::core::Vector;
use opencv::imgcodecs;
use opencv::prelude::*;

/// An 8-bit RGB image, row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
    /// How finely the file stored the colour (JPEG 4:2:0: one sample per 2 × 2 pixels).
    pub chroma: ChromaSampling,
}

/// How a file stored an image's colour: pixels per chroma sample across and down (1 × 1 for
/// PNG and JPEG 4:4:4, 2 × 2 for 4:2:0, 2 × 1 for 4:2:2), and for a JPEG the chroma's
/// quantisation steps (row-major 8 × 8, DC first).
#[derive(Clone, Debug, PartialEq)]
pub struct ChromaSampling {
    pub block: [usize; 2],
    pub steps: Option<[f64; 64]>,
}

impl Default for ChromaSampling {
    fn default() -> Self {
        ChromaSampling::FULL
    }
}

/// JPEG's zig-zag order: the natural (row-major) index of each stored coefficient.
const ZIGZAG: [usize; 64] = [
    0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48, 41, 34, 27, 20,
    13, 6, 7, 14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51, 58, 59,
    52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63,
];

impl ChromaSampling {
    /// Full-resolution, unquantised colour (PNG).
    pub const FULL: ChromaSampling = ChromaSampling {
        block: [1, 1],
        steps: None,
    };

    /// From a JPEG file's header: the frame header's sampling factors (luma's over the
    /// chroma's) and the quantisation table of the first chroma component, read up to the
    /// first scan. [`Self::FULL`]
    /// when the bytes are not a colour baseline or progressive JPEG.
    pub fn of_jpeg(bytes: &[u8]) -> ChromaSampling {
        Self::parse(bytes).unwrap_or(ChromaSampling::FULL)
    }

    fn parse(bytes: &[u8]) -> Option<ChromaSampling> {
        if !bytes.starts_with(&[0xff, 0xd8]) {
            return None;
        }
        let mut tables: [Option<[f64; 64]>; 4] = [None; 4];
        // The chroma's sampling and table id, from the frame header.
        let mut frame = None;
        let mut i = 2;
        loop {
            let (marker, len) = (*bytes.get(i + 1)?, bytes.get(i + 2..i + 4)?);
            if bytes[i] != 0xff {
                return None;
            }
            let len = usize::from(len[0]) << 8 | usize::from(len[1]);
            let body = bytes.get(i + 4..i + 2 + len)?;
            match marker {
                // Quantisation tables: precision and id, then 64 steps in zig-zag order.
                0xdb => {
                    let mut t = body;
                    while let Some((&pq_tq, rest)) = t.split_first() {
                        let wide = pq_tq >> 4 == 1;
                        let size = if wide { 128 } else { 64 };
                        let raw = rest.get(..size)?;
                        let mut steps = [0.0; 64];
                        for (k, &at) in ZIGZAG.iter().enumerate() {
                            steps[at] = if wide {
                                f64::from(u16::from(raw[2 * k]) << 8 | u16::from(raw[2 * k + 1]))
                            } else {
                                f64::from(raw[k])
                            };
                        }
                        *tables.get_mut(usize::from(pq_tq & 15))? = Some(steps);
                        t = &rest[size..];
                    }
                }
                0xc0..=0xc2 => {
                    // 8-bit samples only: a 12-bit file's tables are on another scale.
                    let n = usize::from(*body.get(5)?);
                    if *body.first()? != 8 {
                        return None;
                    }
                    if n < 3 {
                        return None;
                    }
                    let factor = |k: usize| -> Option<(usize, usize, usize)> {
                        let c = body.get(6 + 3 * k..9 + 3 * k)?;
                        Some((
                            usize::from(c[1] >> 4),
                            usize::from(c[1] & 15),
                            usize::from(c[2]),
                        ))
                    };
                    let ((lh, lv, _), (ch, cv, tq)) = (factor(0)?, factor(1)?);
                    if ch == 0 || cv == 0 || lh % ch != 0 || lv % cv != 0 {
                        return None;
                    }
                    frame = Some(([lh / ch, lv / cv], tq));
                }
                // The first scan: its tables came before it, before or after the frame header
                // (libjpeg writes them before, the `image` crate after).
                0xda => {
                    let (block, tq) = frame?;
                    return Some(ChromaSampling {
                        block,
                        steps: *tables.get(tq)?,
                    });
                }
                _ => {}
            }
            i += 2 + len;
        }
    }
}

/// libjpeg's (the IJG's) chroma table at quality 50 (row-major), which every quality scales.
const IJG_CHROMA: [u32; 64] = {
    let mut t = [99; 64];
    let head = [
        [17, 18, 24, 47],
        [18, 21, 26, 66],
        [24, 26, 56, 99],
        [47, 66, 99, 99],
    ];
    let mut k = 0;
    while k < 16 {
        t[(k / 4) * 8 + k % 4] = head[k / 4][k % 4];
        k += 1;
    }
    t
};

/// The chroma table libjpeg writes at `quality` (1-100) for a baseline file, in its integer
/// arithmetic (`jpeg_quality_scaling`, `jpeg_add_quant_table`).
pub(crate) fn ijg_chroma(quality: u8) -> [f64; 64] {
    let q = u32::from(quality.clamp(1, 100));
    let scale = if q < 50 { 5000 / q } else { 200 - 2 * q };
    IJG_CHROMA.map(|t| f64::from(((t * scale + 50) / 100).clamp(1, 255)))
}

impl ChromaSampling {
    /// The quality (1-100, libjpeg's scale) whose chroma table is nearest the file's (in the
    /// steps' logarithms): the file's own for a libjpeg-written JPEG, an equivalent for a
    /// camera's own tables. `None` without a quantisation table (PNG).
    pub fn quality(&self) -> Option<u8> {
        let steps = self.steps?;
        let distance = |quality: u8| -> f64 {
            let table = ijg_chroma(quality);
            steps
                .iter()
                .zip(&table)
                .map(|(s, t)| (s.max(1.0).ln() - t.ln()).abs())
                .sum()
        };
        // Equal tables (qualities 1-3 all step 255) read as the lowest: the cautious side.
        (1..=100).min_by(|&a, &b| distance(a).total_cmp(&distance(b)))
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
    pub(crate) bgr: opencv::core::Mat,
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

/// An encoded image: PNG by the `png` crate, JPEG by zune-jpeg, anything else by OpenCV.
pub fn decode_bytes(
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
pub fn bgr_to_rgb(bgr: &opencv::core::Mat, image: &mut RgbImage) -> Result<(), String> {
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
