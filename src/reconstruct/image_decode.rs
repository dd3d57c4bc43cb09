//! Decoding of `sensor_msgs/Image` and `sensor_msgs/CompressedImage` payloads into RGB8 images.
//!
//! Raw images: encodings `rgb8`, `bgr8`, `rgba8`, `bgra8` and `mono8`, honouring the row `step`
//! (rows may be padded). Compressed images: JPEG and PNG, with the format string as ROS
//! `image_transport` writes it (`"jpeg"`, `"png"`, `"rgb8; jpeg compressed bgr8"`, ...).
//! Every error names the topic and the encoding or format it was decoding.

use image::{GrayImage, ImageFormat, RgbImage};

/// Why a frame could not be decoded. Each variant names the topic it came from.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Width or height is zero.
    #[error("topic {topic}: empty image ({width}x{height}, encoding {encoding})")]
    Empty {
        /// Topic of the message.
        topic: String,
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
        /// Declared encoding.
        encoding: String,
    },
    /// A side exceeds the configured limit.
    #[error("topic {topic}: image {width}x{height} exceeds the size limit of {max_side} pixels per side")]
    TooLarge {
        /// Topic of the message.
        topic: String,
        /// Declared or decoded width.
        width: u32,
        /// Declared or decoded height.
        height: u32,
        /// Configured limit (`inputs.max_image_side`).
        max_side: u32,
    },
    /// Decoding would allocate more than the image decoder's memory limit (512 MiB).
    #[error("topic {topic}: compressed image declares {width}x{height} pixels, more than the decoder's 512 MiB allocation limit allows")]
    DecodeLimit {
        /// Topic of the message.
        topic: String,
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
    },
    /// The encoding is not one this node reads.
    #[error("topic {topic}: unsupported encoding `{encoding}` (expected rgb8, bgr8, rgba8, bgra8 or mono8)")]
    UnsupportedEncoding {
        /// Topic of the message.
        topic: String,
        /// Declared encoding.
        encoding: String,
    },
    /// A person mask that is not one channel.
    #[error("topic {topic}: mask encoding `{encoding}` is not mono8 (masks are mono8 or 8UC1)")]
    MaskEncoding {
        /// Topic of the message.
        topic: String,
        /// Declared encoding.
        encoding: String,
    },
    /// `step` is shorter than one row of pixels.
    #[error("topic {topic}: step {step} is smaller than width {width} x {bytes_per_pixel} bytes (encoding {encoding})")]
    StepTooSmall {
        /// Topic of the message.
        topic: String,
        /// Declared encoding.
        encoding: String,
        /// Declared row stride in bytes.
        step: u32,
        /// Declared width.
        width: u32,
        /// Bytes per pixel of the encoding.
        bytes_per_pixel: u32,
    },
    /// `data` length disagrees with `step * height`.
    #[error("topic {topic}: data has {actual} bytes but step {step} x height {height} = {expected} (encoding {encoding})")]
    SizeMismatch {
        /// Topic of the message.
        topic: String,
        /// Declared encoding.
        encoding: String,
        /// Declared row stride.
        step: u32,
        /// Declared height.
        height: u32,
        /// `step * height`.
        expected: u64,
        /// Bytes received.
        actual: usize,
    },
    /// The compressed format string names neither JPEG nor PNG.
    #[error("topic {topic}: unsupported compressed format `{format}` (expected jpeg or png)")]
    UnsupportedFormat {
        /// Topic of the message.
        topic: String,
        /// Format string of the message.
        format: String,
    },
    /// The compressed bytes could not be decoded.
    #[error("topic {topic}: corrupt {format} data: {reason}")]
    Corrupt {
        /// Topic of the message.
        topic: String,
        /// Format string of the message.
        format: String,
        /// The decoder's message.
        reason: String,
    },
}

/// The fields of a `sensor_msgs/Image` that decoding needs, borrowed from the message.
#[derive(Debug, Clone, Copy)]
pub struct RawImage<'a> {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// ROS encoding string (`rgb8`, `bgr8`, ...).
    pub encoding: &'a str,
    /// Bytes per row including padding.
    pub step: u32,
    /// Pixel bytes, `step * height` of them.
    pub data: &'a [u8],
}

impl<'a> From<&'a crate::msgs::Image> for RawImage<'a> {
    fn from(msg: &'a crate::msgs::Image) -> Self {
        Self {
            width: msg.width,
            height: msg.height,
            encoding: &msg.encoding,
            step: msg.step,
            data: &msg.data,
        }
    }
}

/// Channel order of a supported raw encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Layout {
    Rgb,
    Bgr,
    Rgba,
    Bgra,
    Mono,
}

impl Layout {
    fn parse(encoding: &str) -> Option<Self> {
        match encoding {
            "rgb8" => Some(Self::Rgb),
            "bgr8" => Some(Self::Bgr),
            "rgba8" => Some(Self::Rgba),
            "bgra8" => Some(Self::Bgra),
            "mono8" | "8UC1" => Some(Self::Mono),
            _ => None,
        }
    }

    fn bytes_per_pixel(self) -> u32 {
        match self {
            Self::Rgb | Self::Bgr => 3,
            Self::Rgba | Self::Bgra => 4,
            Self::Mono => 1,
        }
    }

    fn to_rgb(self, px: &[u8]) -> [u8; 3] {
        match self {
            Self::Rgb | Self::Rgba => [px[0], px[1], px[2]],
            Self::Bgr | Self::Bgra => [px[2], px[1], px[0]],
            Self::Mono => [px[0], px[0], px[0]],
        }
    }
}

/// Checks sizes and step of a raw image; returns its layout.
fn check_raw(topic: &str, img: &RawImage<'_>, max_side: u32) -> Result<Layout, DecodeError> {
    if img.width == 0 || img.height == 0 {
        return Err(DecodeError::Empty {
            topic: topic.into(),
            width: img.width,
            height: img.height,
            encoding: img.encoding.into(),
        });
    }
    if img.width > max_side || img.height > max_side {
        return Err(DecodeError::TooLarge {
            topic: topic.into(),
            width: img.width,
            height: img.height,
            max_side,
        });
    }
    let layout = Layout::parse(img.encoding).ok_or_else(|| DecodeError::UnsupportedEncoding {
        topic: topic.into(),
        encoding: img.encoding.into(),
    })?;
    let bpp = layout.bytes_per_pixel();
    if u64::from(img.step) < u64::from(img.width) * u64::from(bpp) {
        return Err(DecodeError::StepTooSmall {
            topic: topic.into(),
            encoding: img.encoding.into(),
            step: img.step,
            width: img.width,
            bytes_per_pixel: bpp,
        });
    }
    let expected = u64::from(img.step) * u64::from(img.height);
    if img.data.len() as u64 != expected {
        return Err(DecodeError::SizeMismatch {
            topic: topic.into(),
            encoding: img.encoding.into(),
            step: img.step,
            height: img.height,
            expected,
            actual: img.data.len(),
        });
    }
    Ok(layout)
}

/// Decodes a raw `sensor_msgs/Image` into RGB8, rejecting frames with a side over `max_side`.
pub fn decode_raw(topic: &str, img: &RawImage<'_>, max_side: u32) -> Result<RgbImage, DecodeError> {
    let layout = check_raw(topic, img, max_side)?;
    let bpp = layout.bytes_per_pixel() as usize;
    let (w, h) = (img.width as usize, img.height as usize);
    let mut out = Vec::with_capacity(w * h * 3);
    for row in img.data.chunks_exact(img.step as usize) {
        for px in row[..w * bpp].chunks_exact(bpp) {
            out.extend_from_slice(&layout.to_rgb(px));
        }
    }
    Ok(RgbImage::from_raw(img.width, img.height, out).expect("buffer sized width*height*3"))
}

/// Decodes a raw mono8 `sensor_msgs/Image` (a person mask) into a grey image.
pub fn decode_mask(
    topic: &str,
    img: &RawImage<'_>,
    max_side: u32,
) -> Result<GrayImage, DecodeError> {
    let layout = check_raw(topic, img, max_side)?;
    if layout != Layout::Mono {
        return Err(DecodeError::MaskEncoding {
            topic: topic.into(),
            encoding: img.encoding.into(),
        });
    }
    let w = img.width as usize;
    let mut out = Vec::with_capacity(w * img.height as usize);
    for row in img.data.chunks_exact(img.step as usize) {
        out.extend_from_slice(&row[..w]);
    }
    Ok(GrayImage::from_raw(img.width, img.height, out).expect("buffer sized width*height"))
}

/// Reads the codec from a `CompressedImage.format` string as `image_transport` writes it:
/// either just `jpeg`/`png`, or `"<raw encoding>; <codec> compressed <encoding>"`.
pub fn compressed_codec(format: &str) -> Option<ImageFormat> {
    let lower = format.to_ascii_lowercase();
    let codec_part = lower.split(';').next_back().unwrap_or("");
    let words: Vec<&str> = codec_part
        .split(|c: char| c.is_whitespace() || c == ';')
        .filter(|w| !w.is_empty())
        .collect();
    let first = words.first().copied().unwrap_or("");
    match first {
        "jpeg" | "jpg" => Some(ImageFormat::Jpeg),
        "png" => Some(ImageFormat::Png),
        _ => None,
    }
}

/// Decodes a `sensor_msgs/CompressedImage` (JPEG or PNG) into RGB8, rejecting frames with a side
/// over `max_side` before the pixels are decoded.
pub fn decode_compressed(
    topic: &str,
    format: &str,
    data: &[u8],
    max_side: u32,
) -> Result<RgbImage, DecodeError> {
    let codec = compressed_codec(format).ok_or_else(|| DecodeError::UnsupportedFormat {
        topic: topic.into(),
        format: format.into(),
    })?;
    // Decoder messages may span lines; the error is one line.
    let corrupt = |reason: String| DecodeError::Corrupt {
        topic: topic.into(),
        format: format.into(),
        reason: reason.split_whitespace().collect::<Vec<_>>().join(" "),
    };
    let reader = image::ImageReader::with_format(std::io::Cursor::new(data), codec);
    let decoder_dims = reader
        .into_dimensions()
        .map_err(|e| corrupt(e.to_string()))?;
    let (width, height) = decoder_dims;
    if width == 0 || height == 0 {
        return Err(DecodeError::Empty {
            topic: topic.into(),
            width,
            height,
            encoding: format.into(),
        });
    }
    if width > max_side || height > max_side {
        return Err(DecodeError::TooLarge {
            topic: topic.into(),
            width,
            height,
            max_side,
        });
    }
    let reader = image::ImageReader::with_format(std::io::Cursor::new(data), codec);
    let decoded = reader.decode().map_err(|e| match e {
        image::ImageError::Limits(_) => DecodeError::DecodeLimit {
            topic: topic.into(),
            width,
            height,
        },
        e => corrupt(e.to_string()),
    })?;
    Ok(decoded.into_rgb8())
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOPIC: &str = "/cam0/image_raw";

    fn raw<'a>(w: u32, h: u32, enc: &'a str, step: u32, data: &'a [u8]) -> RawImage<'a> {
        RawImage {
            width: w,
            height: h,
            encoding: enc,
            step,
            data,
        }
    }

    #[test]
    fn bgr8_with_row_padding_becomes_rgb() {
        // 2x2 bgr8 with 2 padding bytes per row (step 8).
        let data = [
            1, 2, 3, 4, 5, 6, 99, 99, //
            7, 8, 9, 10, 11, 12, 99, 99,
        ];
        let img = decode_raw(TOPIC, &raw(2, 2, "bgr8", 8, &data), 64).unwrap();
        assert_eq!(img.dimensions(), (2, 2));
        assert_eq!(img.as_raw(), &[3, 2, 1, 6, 5, 4, 9, 8, 7, 12, 11, 10]);
    }

    #[test]
    fn every_supported_encoding_gives_the_same_red_pixel() {
        let cases: [(&str, Vec<u8>); 4] = [
            ("rgb8", vec![200, 10, 20]),
            ("bgr8", vec![20, 10, 200]),
            ("rgba8", vec![200, 10, 20, 255]),
            ("bgra8", vec![20, 10, 200, 255]),
        ];
        for (enc, px) in cases {
            let img = decode_raw(TOPIC, &raw(1, 1, enc, px.len() as u32, &px), 64).unwrap();
            assert_eq!(img.as_raw(), &[200, 10, 20], "{enc}");
        }
        let grey = decode_raw(TOPIC, &raw(1, 1, "mono8", 1, &[77]), 64).unwrap();
        assert_eq!(grey.as_raw(), &[77, 77, 77]);
    }

    #[test]
    fn step_and_size_disagreements_name_topic_and_encoding() {
        let data = [0u8; 12];
        let e = decode_raw(TOPIC, &raw(2, 2, "rgb8", 5, &data), 64).unwrap_err();
        assert!(matches!(e, DecodeError::StepTooSmall { .. }), "{e}");
        let msg = e.to_string();
        assert!(msg.contains(TOPIC) && msg.contains("rgb8"), "{msg}");
        let e = decode_raw(TOPIC, &raw(2, 2, "rgb8", 6, &data[..11]), 64).unwrap_err();
        assert!(
            matches!(
                e,
                DecodeError::SizeMismatch {
                    expected: 12,
                    actual: 11,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains(TOPIC));
    }

    #[test]
    fn empty_oversized_and_unknown_encodings_are_rejected() {
        let e = decode_raw(TOPIC, &raw(0, 0, "rgb8", 0, &[]), 64).unwrap_err();
        assert!(matches!(e, DecodeError::Empty { .. }));
        let data = vec![0u8; 65 * 3];
        let e = decode_raw(TOPIC, &raw(65, 1, "rgb8", 65 * 3, &data), 64).unwrap_err();
        assert!(matches!(e, DecodeError::TooLarge { max_side: 64, .. }));
        let e = decode_raw(TOPIC, &raw(1, 1, "16UC1", 2, &[0, 0]), 64).unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains("16UC1") && msg.contains(TOPIC), "{msg}");
    }

    #[test]
    fn mask_must_be_mono8_and_drops_padding() {
        let data = [10, 20, 0, 30, 40, 0];
        let m = decode_mask("/mask", &raw(2, 2, "mono8", 3, &data), 64).unwrap();
        assert_eq!(m.as_raw(), &[10, 20, 30, 40]);
        let e = decode_mask("/mask", &raw(1, 1, "rgb8", 3, &[1, 2, 3]), 64).unwrap_err();
        assert_eq!(
            e.to_string(),
            "topic /mask: mask encoding `rgb8` is not mono8 (masks are mono8 or 8UC1)"
        );
    }

    fn gradient(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 8) as u8, (y * 8) as u8, 128]))
    }

    fn encode(img: &RgbImage, fmt: ImageFormat) -> Vec<u8> {
        let mut bytes = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut bytes), fmt)
            .unwrap();
        bytes
    }

    #[test]
    fn ros_format_strings_select_the_codec() {
        assert_eq!(compressed_codec("jpeg"), Some(ImageFormat::Jpeg));
        assert_eq!(compressed_codec("png"), Some(ImageFormat::Png));
        assert_eq!(
            compressed_codec("rgb8; jpeg compressed bgr8"),
            Some(ImageFormat::Jpeg)
        );
        assert_eq!(
            compressed_codec("bgr8; png compressed bgr8"),
            Some(ImageFormat::Png)
        );
        assert_eq!(compressed_codec("16UC1; compressedDepth"), None);
        assert_eq!(compressed_codec("theora"), None);
    }

    #[test]
    fn png_round_trips_exactly_and_jpeg_closely() {
        let img = gradient(24, 16);
        let png = decode_compressed(TOPIC, "png", &encode(&img, ImageFormat::Png), 64).unwrap();
        assert_eq!(png, img);
        let jpg = decode_compressed(
            TOPIC,
            "rgb8; jpeg compressed bgr8",
            &encode(&img, ImageFormat::Jpeg),
            64,
        )
        .unwrap();
        assert_eq!(jpg.dimensions(), (24, 16));
        let mean_err: f64 = jpg
            .as_raw()
            .iter()
            .zip(img.as_raw())
            .map(|(a, b)| (f64::from(*a) - f64::from(*b)).abs())
            .sum::<f64>()
            / img.as_raw().len() as f64;
        assert!(mean_err < 8.0, "jpeg mean abs error {mean_err}");
    }

    #[test]
    fn corrupt_or_oversized_compressed_data_is_a_clear_error() {
        let mut bytes = encode(&gradient(24, 16), ImageFormat::Png);
        bytes.truncate(bytes.len() / 2);
        let e = decode_compressed(TOPIC, "png", &bytes, 64).unwrap_err();
        assert!(matches!(e, DecodeError::Corrupt { .. }), "{e}");
        assert!(e.to_string().contains(TOPIC));
        let e = decode_compressed(TOPIC, "jpeg", b"not a jpeg at all", 64).unwrap_err();
        assert!(matches!(e, DecodeError::Corrupt { .. }), "{e}");
        let big = encode(&gradient(80, 8), ImageFormat::Png);
        let e = decode_compressed(TOPIC, "png", &big, 64).unwrap_err();
        assert!(matches!(e, DecodeError::TooLarge { width: 80, .. }), "{e}");
        let e = decode_compressed(TOPIC, "theora", &big, 64).unwrap_err();
        assert!(e.to_string().contains("theora"));
    }
}
