//! How rendered images are stored: PNG, or JPEG as webcams stream it.

/// How images are stored.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageFormat {
    /// Lossless.
    Png,
    /// Baseline JPEG at a quality of 1-100, as webcams stream MJPEG.
    Jpeg { quality: u8, chroma: Chroma },
}

/// Resolution of a JPEG's colour planes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
pub enum Chroma {
    /// 4:2:0, half the resolution both ways: what USB webcams' MJPEG streams and most cameras
    /// write (OpenCV's encoder, libjpeg-turbo).
    #[serde(rename = "4:2:0")]
    #[value(name = "420")]
    Half,
    /// 4:4:4, full resolution (the `image` crate's encoder).
    #[serde(rename = "4:4:4")]
    #[value(name = "444")]
    Full,
}

impl ImageFormat {
    /// What a webcam streams: MJPEG 4:2:0 at quality 85.
    pub const WEBCAM: ImageFormat = ImageFormat::Jpeg {
        quality: 85,
        chroma: Chroma::Half,
    };

    /// File extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Jpeg { .. } => "jpg",
        }
    }

    /// Encodes an 8-bit RGB image.
    pub fn encode(self, width: u32, height: u32, rgb: &[u8]) -> Vec<u8> {
        match self {
            ImageFormat::Png => encode_png(width, height, rgb),
            ImageFormat::Jpeg {
                quality,
                chroma: Chroma::Half,
            } => crate::cv::encode_jpeg(height, rgb, quality.clamp(1, 100))
                .expect("OpenCV encodes an in-memory RGB image"),
            ImageFormat::Jpeg {
                quality,
                chroma: Chroma::Full,
            } => {
                let mut out = Vec::new();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100))
                    .encode(rgb, width, height, image::ColorType::Rgb8)
                    .expect("in-memory JPEG of the stated size");
                out
            }
        }
    }
}

/// PNG bytes of an 8-bit RGB image: fast deflate (noisy images gain little from harder
/// compression) and the "up" filter (as small as Paeth on these frames, half the decoding time:
/// 5.9 against 11.4 ms for a 1280 × 720 frame).
pub fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::Fast);
    encoder.set_filter(png::FilterType::Up);
    let mut writer = encoder.write_header().expect("in-memory PNG header");
    writer
        .write_image_data(rgb)
        .expect("in-memory PNG data of the stated size");
    writer.finish().expect("in-memory PNG end");
    out
}
