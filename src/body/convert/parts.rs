//! Per-vertex body-part labels from the UV-space segmentation image and its colour palette.

use crate::body::BodyError;
use glam::Vec2;
use serde::Deserialize;

#[derive(Deserialize)]
struct PaletteFile {
    colors: serde_yaml_ng::Mapping,
}

/// Part names and their RGB colours, in the yaml file's order.
pub fn parse_palette(text: &str, origin: &str) -> Result<Vec<(String, [u8; 3])>, BodyError> {
    let file: PaletteFile =
        serde_yaml_ng::from_str(text).map_err(|e| BodyError::format(origin, e.to_string()))?;
    file.colors
        .into_iter()
        .map(|(k, v)| {
            let name = k
                .as_str()
                .ok_or_else(|| BodyError::format(origin, "part names must be strings"))?
                .to_string();
            let rgb: [u8; 3] = serde_yaml_ng::from_value(v)
                .map_err(|e| BodyError::format(origin, format!("colors.{name}: {e}")))?;
            Ok((name, rgb))
        })
        .collect()
}

/// Labels each UV by the nearest palette colour of the image pixel it falls on
/// (column = u·width, row = (1 − v)·height). Returns the labels and how many pixels were not
/// an exact palette colour.
pub fn label_uvs(
    image: &image::RgbImage,
    palette: &[(String, [u8; 3])],
    uvs: &[Vec2],
) -> (Vec<u8>, usize) {
    let (w, h) = image.dimensions();
    let mut inexact = 0;
    let labels = uvs
        .iter()
        .map(|uv| {
            let col = ((uv.x * w as f32) as i64).clamp(0, w as i64 - 1) as u32;
            let row = (((1.0 - uv.y) * h as f32) as i64).clamp(0, h as i64 - 1) as u32;
            let px = image.get_pixel(col, row).0;
            let dist =
                |c: &[u8; 3]| -> i32 { (0..3).map(|k| (px[k] as i32 - c[k] as i32).pow(2)).sum() };
            let (best, d) = palette
                .iter()
                .enumerate()
                .map(|(i, (_, c))| (i, dist(c)))
                .min_by_key(|&(i, d)| (d, i))
                .expect("palette is not empty");
            if d != 0 {
                inexact += 1;
            }
            best as u8
        })
        .collect();
    (labels, inexact)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uv_picks_the_pixel_with_v_up() {
        let mut img = image::RgbImage::new(2, 2);
        img.put_pixel(0, 0, image::Rgb([255, 0, 0])); // top-left: v near 1
        let palette = vec![
            ("body".to_string(), [0, 0, 0]),
            ("head".to_string(), [250, 0, 0]),
        ];
        let (labels, inexact) =
            label_uvs(&img, &palette, &[Vec2::new(0.1, 0.9), Vec2::new(0.1, 0.1)]);
        assert_eq!(labels, [1, 0]);
        assert_eq!(inexact, 1);
    }
}
