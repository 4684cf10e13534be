//! Conversions between OpenCV matrices and plain arrays (row-major `f64`).

use opencv::core::{self, Mat, Point2f, TermCriteria, Vector};
use opencv::prelude::*;

/// Every value of `m`, row-major, channels interleaved, as `f64`.
pub(crate) fn values(m: &Mat) -> opencv::Result<Vec<f64>> {
    let mut m64 = Mat::default();
    m.convert_to(&mut m64, core::CV_64F, 1.0, 0.0)?;
    // One channel, continuous, so the values read row-major (channels interleaved).
    let flat = m64.try_clone()?.reshape(1, 0)?.try_clone()?;
    Ok(flat.data_typed::<f64>()?.to_vec())
}

/// Exactly `N` values of `m`.
pub(crate) fn fixed<const N: usize>(m: &Mat) -> opencv::Result<[f64; N]> {
    let v = values(m)?;
    v.try_into().map_err(|v: Vec<f64>| {
        opencv::Error::new(
            core::StsBadSize,
            format!("expected {N} values, got {}", v.len()),
        )
    })
}

/// A `rows`-row `CV_64F` matrix of `values` (row-major).
pub(crate) fn mat(rows: i32, values: &[f64]) -> opencv::Result<Mat> {
    Mat::from_slice(values)?.reshape(1, rows)?.try_clone()
}

/// Image points as OpenCV takes them.
pub(crate) fn points(c: &[[f32; 2]]) -> Vector<Point2f> {
    c.iter().map(|p| Point2f::new(p[0], p[1])).collect()
}

/// Points as an N × 1 two-channel `CV_64F` matrix (what the point functions take in `f64`).
pub(crate) fn points64(p: &[[f64; 2]]) -> opencv::Result<Mat> {
    let flat: Vec<f64> = p.iter().flat_map(|q| [q[0], q[1]]).collect();
    Mat::from_slice(&flat)?
        .reshape(2, p.len() as i32)?
        .try_clone()
}

/// Pairs of values back from a two-channel (or N × 2) matrix.
pub(crate) fn pairs(m: &Mat) -> opencv::Result<Vec<[f64; 2]>> {
    Ok(values(m)?.chunks(2).map(|p| [p[0], p[1]]).collect())
}

/// Iterations for OpenCV's solvers: at most `count`, or until the change is below `eps`.
pub(crate) fn criteria(count: i32, eps: f64) -> opencv::Result<TermCriteria> {
    TermCriteria::new(
        core::TermCriteria_COUNT + core::TermCriteria_EPS,
        count,
        eps,
    )
}

/// JPEG bytes of an 8-bit RGB image (`rows` rows) by OpenCV's encoder: libjpeg-turbo with its
/// defaults, baseline with 4:2:0 chroma (what a webcam's MJPEG stream holds), at `quality`.
pub(crate) fn encode_jpeg(rows: u32, rgb: &[u8], quality: u8) -> opencv::Result<Vec<u8>> {
    let flat = Mat::from_slice(rgb)?;
    let image = flat.reshape(3, rows as i32)?;
    let mut bgr = Mat::default();
    opencv::imgproc::cvt_color_def(&image, &mut bgr, opencv::imgproc::COLOR_RGB2BGR)?;
    let mut out = Vector::<u8>::new();
    let params = Vector::from_slice(&[opencv::imgcodecs::IMWRITE_JPEG_QUALITY, i32::from(quality)]);
    opencv::imgcodecs::imencode(".jpg", &bgr, &mut out, &params)?;
    Ok(out.to_vec())
}

/// Decodes an image file's bytes, copied into an OpenCV buffer by the caller, with `flags`
/// `IMREAD_COLOR` or `IMREAD_GRAYSCALE`. A JPEG cut short (no end-of-image marker after its
/// last scan: a copy or a capture that stopped mid-file) is refused, where libjpeg would
/// decode it silently with grey rows.
///
/// # Errors
/// A message saying why the bytes are not a whole image.
pub(crate) fn decode_image(bytes: &Vector<u8>, flags: i32) -> Result<Mat, String> {
    let mut image = Mat::default();
    decode_image_into(bytes, flags, &mut image)?;
    Ok(image)
}

/// [`decode_image`] into `image`, whose buffer is reused when it has the size already: a
/// caller that decodes frame after frame keeps it (fresh 2.7 MB buffers for 720p frames
/// cost page faults every time).
///
/// # Errors
/// As [`decode_image`].
pub(crate) fn decode_image_into(
    bytes: &Vector<u8>,
    flags: i32,
    image: &mut Mat,
) -> Result<(), String> {
    if is_truncated_jpeg(bytes.as_slice()) {
        return Err("a truncated JPEG (no end-of-image marker)".into());
    }
    let unreadable = || "not an image OpenCV can read".to_string();
    opencv::imgcodecs::imdecode_to(bytes, flags, image).map_err(|_| unreadable())?;
    if image.empty() {
        return Err(unreadable());
    }
    Ok(())
}

/// A JPEG whose last scan (`FF DA`) has no end-of-image marker (`FF D9`) after it. Inside a
/// scan every `FF` byte is stuffed (`FF 00`), so `FF D9` there can only be the end.
pub(crate) fn is_truncated_jpeg(bytes: &[u8]) -> bool {
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return false;
    }
    // Searched from the ends that find them at once (the end marker is last, the first scan
    // follows the headers), not the whole frame: this runs on every frame.
    let is_scan = |w: &[u8]| w == [0xFF, 0xDA];
    let Some(end) = bytes.windows(2).rposition(|w| w == [0xFF, 0xD9]) else {
        return true;
    };
    let scan_after_end = bytes[end..].windows(2).any(is_scan);
    let any_scan = bytes.windows(2).any(is_scan);
    scan_after_end || !any_scan
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_jpeg_cut_short_is_truncated_and_a_whole_one_is_not() {
        let whole = [0xFF, 0xD8, 0xFF, 0xDA, 1, 2, 0xFF, 0x00, 3, 0xFF, 0xD9];
        assert!(!super::is_truncated_jpeg(&whole));
        assert!(super::is_truncated_jpeg(&whole[..8]));
        // Trailing bytes after the end marker are fine; a PNG is not a JPEG.
        assert!(!super::is_truncated_jpeg(&[&whole[..], &[0, 0]].concat()));
        assert!(!super::is_truncated_jpeg(b"\x89PNG"));
    }
}
