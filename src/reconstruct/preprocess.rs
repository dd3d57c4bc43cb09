//! Turns a decoded camera frame into the encoder's input: crop around the person, pad to the
//! encoder's aspect ratio with white, resize to H×W and lay out as f32 CHW in [0, 1].
//!
//! Follows the official pipeline (`PadRatioWithScale`: pad with 1.0 to H/W = 5/3, no ImageNet
//! normalisation). The person is located by a mask (its bounding box; pixels outside the mask
//! are blended to white), else by a given box, else the whole frame is used.

use image::{imageops::FilterType, GrayImage, Rgb, RgbImage};

/// Why a frame could not be preprocessed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PreprocessError {
    /// The mask's size differs from the image's.
    #[error("mask is {mask_w}x{mask_h} but the image is {image_w}x{image_h}")]
    MaskSize {
        /// Mask width.
        mask_w: u32,
        /// Mask height.
        mask_h: u32,
        /// Image width.
        image_w: u32,
        /// Image height.
        image_h: u32,
    },
    /// The mask has no pixel at or above the threshold.
    #[error("mask has no person pixel (threshold {threshold})")]
    EmptyMask {
        /// Threshold used.
        threshold: u8,
    },
    /// The given box is empty or lies outside the image.
    #[error("box {bbox:?} does not overlap the {image_w}x{image_h} image")]
    BoxOutside {
        /// Box given.
        bbox: BBox,
        /// Image width.
        image_w: u32,
        /// Image height.
        image_h: u32,
    },
    /// Output size is zero.
    #[error("output size {width}x{height} is empty")]
    EmptyOutput {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
    },
}

/// An axis-aligned pixel box, `x0..x1` × `y0..y1` (end exclusive).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BBox {
    /// Left column.
    pub x0: i64,
    /// Top row.
    pub y0: i64,
    /// One past the right column.
    pub x1: i64,
    /// One past the bottom row.
    pub y1: i64,
}

impl BBox {
    /// Box width in pixels.
    pub fn width(&self) -> i64 {
        self.x1 - self.x0
    }

    /// Box height in pixels.
    pub fn height(&self) -> i64 {
        self.y1 - self.y0
    }

    fn intersect(&self, w: u32, h: u32) -> Option<BBox> {
        let b = BBox {
            x0: self.x0.max(0),
            y0: self.y0.max(0),
            x1: self.x1.min(i64::from(w)),
            y1: self.y1.min(i64::from(h)),
        };
        (b.width() > 0 && b.height() > 0).then_some(b)
    }
}

/// Where the person is in the frame.
#[derive(Debug, Clone, Copy)]
pub enum Subject<'a> {
    /// A person mask (same size as the image; 0 = background, 255 = person).
    Mask(&'a GrayImage),
    /// A bounding box from a detector.
    BBox(BBox),
    /// No localisation: use the whole frame.
    FullFrame,
}

/// Preprocessing parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct PreprocessConfig {
    /// Encoder input height (the official model uses 840).
    pub out_height: u32,
    /// Encoder input width (the official model uses 504).
    pub out_width: u32,
    /// Margin added around the person box on each side, as a fraction of its larger side.
    pub margin: f32,
    /// Mask values at or above this count as person when computing the box.
    pub mask_threshold: u8,
    /// Blend pixels to white by the mask (`rgb·m + 1·(1−m)`) when a mask is given.
    pub whiten_background: bool,
}

impl Default for PreprocessConfig {
    fn default() -> Self {
        Self {
            out_height: 840,
            out_width: 504,
            margin: 0.05,
            mask_threshold: 128,
            whiten_background: true,
        }
    }
}

/// An encoder-ready view: f32 CHW in [0, 1] and the source region it shows.
#[derive(Debug, Clone, PartialEq)]
pub struct Preprocessed {
    /// Output height.
    pub height: u32,
    /// Output width.
    pub width: u32,
    /// `3 * height * width` values, channel-major (R plane, G plane, B plane).
    pub chw: Vec<f32>,
    /// Source-image region that was resized into the output (may extend past the image,
    /// where it was filled with white).
    pub region: BBox,
}

impl Preprocessed {
    /// Bytes held by the pixel buffer.
    pub fn byte_size(&self) -> usize {
        self.chw.len() * std::mem::size_of::<f32>()
    }
}

/// Bounding box of the mask pixels at or above `threshold`, if any.
pub fn mask_bbox(mask: &GrayImage, threshold: u8) -> Option<BBox> {
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0u32, 0u32);
    for (x, y, p) in mask.enumerate_pixels() {
        if p.0[0] >= threshold {
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x + 1);
            y1 = y1.max(y + 1);
        }
    }
    (x1 > 0).then_some(BBox {
        x0: x0.into(),
        y0: y0.into(),
        x1: x1.into(),
        y1: y1.into(),
    })
}

/// Grows `b` by `margin` (fraction of its larger side) and then along its shorter dimension so
/// that height/width equals `out_h/out_w`, keeping the centre.
fn fit_region(b: BBox, margin: f32, out_h: u32, out_w: u32) -> BBox {
    let pad = (margin.max(0.0) as f64 * b.width().max(b.height()) as f64).round();
    let (mut w, mut h) = (b.width() as f64 + 2.0 * pad, b.height() as f64 + 2.0 * pad);
    let target = f64::from(out_h) / f64::from(out_w);
    if h / w > target {
        w = h / target;
    } else {
        h = w * target;
    }
    let cx = (b.x0 + b.x1) as f64 / 2.0;
    let cy = (b.y0 + b.y1) as f64 / 2.0;
    let x0 = (cx - w / 2.0).round() as i64;
    let y0 = (cy - h / 2.0).round() as i64;
    BBox {
        x0,
        y0,
        x1: x0 + (w.round() as i64).max(1),
        y1: y0 + (h.round() as i64).max(1),
    }
}

/// Crops, pads with white and resizes `image` into the encoder's input layout.
pub fn preprocess(
    image: &RgbImage,
    subject: Subject<'_>,
    cfg: &PreprocessConfig,
) -> Result<Preprocessed, PreprocessError> {
    let (iw, ih) = image.dimensions();
    if cfg.out_height == 0 || cfg.out_width == 0 {
        return Err(PreprocessError::EmptyOutput {
            width: cfg.out_width,
            height: cfg.out_height,
        });
    }
    let (person, mask) = match subject {
        Subject::Mask(mask) => {
            if mask.dimensions() != (iw, ih) {
                return Err(PreprocessError::MaskSize {
                    mask_w: mask.width(),
                    mask_h: mask.height(),
                    image_w: iw,
                    image_h: ih,
                });
            }
            let b = mask_bbox(mask, cfg.mask_threshold).ok_or(PreprocessError::EmptyMask {
                threshold: cfg.mask_threshold,
            })?;
            (b, cfg.whiten_background.then_some(mask))
        }
        Subject::BBox(b) => {
            let clipped = b.intersect(iw, ih).ok_or(PreprocessError::BoxOutside {
                bbox: b,
                image_w: iw,
                image_h: ih,
            })?;
            (clipped, None)
        }
        Subject::FullFrame => (
            BBox {
                x0: 0,
                y0: 0,
                x1: iw.into(),
                y1: ih.into(),
            },
            None,
        ),
    };
    let margin = if matches!(subject, Subject::FullFrame) {
        0.0
    } else {
        cfg.margin
    };
    let region = fit_region(person, margin, cfg.out_height, cfg.out_width);
    let canvas = paint_region(image, mask, region);
    let resized =
        image::imageops::resize(&canvas, cfg.out_width, cfg.out_height, FilterType::Triangle);
    Ok(Preprocessed {
        height: cfg.out_height,
        width: cfg.out_width,
        chw: to_chw(&resized),
        region,
    })
}

/// Copies `region` of the image onto a white canvas of the region's size (parts outside the
/// image stay white); with a mask, blends each pixel towards white by `1 - mask/255`.
fn paint_region(image: &RgbImage, mask: Option<&GrayImage>, region: BBox) -> RgbImage {
    let (rw, rh) = (region.width() as u32, region.height() as u32);
    let mut canvas = RgbImage::from_pixel(rw, rh, Rgb([255, 255, 255]));
    let Some(overlap) = region.intersect(image.width(), image.height()) else {
        return canvas;
    };
    for y in overlap.y0..overlap.y1 {
        for x in overlap.x0..overlap.x1 {
            let src = *image.get_pixel(x as u32, y as u32);
            let px = match mask {
                Some(m) => {
                    let a = u32::from(m.get_pixel(x as u32, y as u32).0[0]);
                    Rgb(src
                        .0
                        .map(|c| ((u32::from(c) * a + 255 * (255 - a) + 127) / 255) as u8))
                }
                None => src,
            };
            canvas.put_pixel((x - region.x0) as u32, (y - region.y0) as u32, px);
        }
    }
    canvas
}

fn to_chw(img: &RgbImage) -> Vec<f32> {
    let plane = (img.width() * img.height()) as usize;
    let mut out = vec![0.0f32; 3 * plane];
    for (i, px) in img.pixels().enumerate() {
        for c in 0..3 {
            out[c * plane + i] = f32::from(px.0[c]) / 255.0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const GREY: Rgb<u8> = Rgb([100, 100, 100]);
    const RED: Rgb<u8> = Rgb([220, 0, 0]);

    /// A 200x120 grey frame with a red "person" in columns 80..120, rows 20..100.
    fn scene() -> (RgbImage, GrayImage) {
        let img = RgbImage::from_fn(200, 120, |x, y| {
            if (80..120).contains(&x) && (20..100).contains(&y) {
                RED
            } else {
                GREY
            }
        });
        let mask = GrayImage::from_fn(200, 120, |x, y| {
            image::Luma([if (80..120).contains(&x) && (20..100).contains(&y) {
                255
            } else {
                0
            }])
        });
        (img, mask)
    }

    fn cfg() -> PreprocessConfig {
        PreprocessConfig {
            out_height: 50,
            out_width: 30,
            margin: 0.0,
            ..PreprocessConfig::default()
        }
    }

    fn px(p: &Preprocessed, x: u32, y: u32) -> [f32; 3] {
        let plane = (p.width * p.height) as usize;
        let i = (y * p.width + x) as usize;
        [p.chw[i], p.chw[plane + i], p.chw[2 * plane + i]]
    }

    #[test]
    fn output_is_chw_in_unit_range_with_requested_size() {
        let (img, mask) = scene();
        let p = preprocess(&img, Subject::Mask(&mask), &cfg()).unwrap();
        assert_eq!((p.height, p.width), (50, 30));
        assert_eq!(p.chw.len(), 3 * 50 * 30);
        assert!(p.chw.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn mask_crop_centres_the_person_and_pads_sides_white() {
        let (img, mask) = scene();
        let p = preprocess(&img, Subject::Mask(&mask), &cfg()).unwrap();
        // Person box 40x80 (H/W = 2) is wider than 5/3: it fills the height, white left/right.
        assert_eq!(p.region.height(), 80);
        assert_eq!(p.region.width(), 48);
        let centre = px(&p, 15, 25);
        assert!(centre[0] > 0.8 && centre[1] < 0.1, "centre {centre:?}");
        // Columns just outside the person come from grey background, whitened by the mask.
        let edge = px(&p, 0, 25);
        assert!(edge.iter().all(|c| *c > 0.95), "edge {edge:?}");
    }

    #[test]
    fn bbox_crop_keeps_real_background() {
        let (img, _) = scene();
        let b = BBox {
            x0: 80,
            y0: 20,
            x1: 120,
            y1: 100,
        };
        let p = preprocess(&img, Subject::BBox(b), &cfg()).unwrap();
        let edge = px(&p, 0, 25);
        assert!(
            edge.iter().all(|c| (c - 100.0 / 255.0).abs() < 0.02),
            "edge {edge:?}"
        );
    }

    #[test]
    fn full_frame_wider_than_target_is_padded_top_and_bottom_with_white() {
        let (img, _) = scene();
        let p = preprocess(&img, Subject::FullFrame, &cfg()).unwrap();
        // 200 wide → region 200x333: ~106 white rows above and below the 120-row frame.
        assert_eq!(p.region.width(), 200);
        assert!(px(&p, 15, 0).iter().all(|c| *c == 1.0));
        assert!(px(&p, 15, 49).iter().all(|c| *c == 1.0));
        let middle = px(&p, 2, 25);
        assert!(
            (middle[0] - 100.0 / 255.0).abs() < 0.02,
            "middle {middle:?}"
        );
    }

    #[test]
    fn person_at_the_border_is_padded_not_shifted() {
        let img = RgbImage::from_pixel(60, 60, RED);
        let b = BBox {
            x0: 0,
            y0: 0,
            x1: 20,
            y1: 60,
        };
        let p = preprocess(&img, Subject::BBox(b), &cfg()).unwrap();
        assert!(p.region.x0 < 0, "region {:?}", p.region);
        // Left of the image is white, the person is red.
        assert!(px(&p, 0, 25).iter().all(|c| *c == 1.0));
        assert!(px(&p, 15, 25)[1] < 0.1);
    }

    #[test]
    fn bad_masks_and_boxes_are_errors() {
        let (img, _) = scene();
        let small = GrayImage::new(10, 10);
        assert!(matches!(
            preprocess(&img, Subject::Mask(&small), &cfg()),
            Err(PreprocessError::MaskSize { .. })
        ));
        let empty = GrayImage::new(200, 120);
        assert!(matches!(
            preprocess(&img, Subject::Mask(&empty), &cfg()),
            Err(PreprocessError::EmptyMask { .. })
        ));
        let outside = BBox {
            x0: 300,
            y0: 0,
            x1: 400,
            y1: 10,
        };
        assert!(matches!(
            preprocess(&img, Subject::BBox(outside), &cfg()),
            Err(PreprocessError::BoxOutside { .. })
        ));
    }
}
