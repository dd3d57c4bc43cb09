//! Labels drawn into pictures (evaluation strips, contact sheets): text in an 8×8 bitmap font
//! (`font8x8`, public domain) scaled up, and rows of tiles each with a caption band above it, so
//! a picture says which panel is input, which is ground truth and which is ours.

use font8x8::legacy::BASIC_LEGACY;
use image::{Rgb, RgbImage};

/// Dark grey for captions.
pub const INK: Rgb<u8> = Rgb([25, 25, 25]);

/// Draws `text` with its top-left corner at (`x`, `y`), each font pixel `scale`×`scale`;
/// characters outside ASCII are drawn as `?`. Pixels off the image are skipped.
pub fn draw_text(image: &mut RgbImage, x: u32, y: u32, text: &str, scale: u32, colour: Rgb<u8>) {
    for (i, c) in text.chars().enumerate() {
        let glyph = BASIC_LEGACY[if c.is_ascii() {
            c as usize
        } else {
            b'?' as usize
        }];
        let left = x + i as u32 * 8 * scale;
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits >> col & 1 == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let (px, py) = (left + col * scale + dx, y + row as u32 * scale + dy);
                        if px < image.width() && py < image.height() {
                            image.put_pixel(px, py, colour);
                        }
                    }
                }
            }
        }
    }
}

/// Width in pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: u32) -> u32 {
    text.chars().count() as u32 * 8 * scale
}

/// Tiles side by side, `gap` pixels of `background` apart, each with its caption in a band of
/// `12 * scale` pixels above it (a tile narrower than its caption is centred in a wider slot).
pub fn captioned_row(
    tiles: &[(&RgbImage, &str)],
    scale: u32,
    gap: u32,
    background: Rgb<u8>,
) -> RgbImage {
    let band = 12 * scale;
    let slot =
        |(tile, caption): &(&RgbImage, &str)| tile.width().max(text_width(caption, scale) + 4);
    let width = tiles
        .iter()
        .map(|t| slot(t) + gap)
        .sum::<u32>()
        .saturating_sub(gap);
    let height = band + tiles.iter().map(|(t, _)| t.height()).max().unwrap_or(0);
    let mut out = RgbImage::from_pixel(width.max(1), height.max(1), background);
    let mut x = 0;
    for t in tiles {
        let (tile, caption) = t;
        let w = slot(t);
        draw_text(&mut out, x + 2, 2 * scale, caption, scale, INK);
        image::imageops::replace(
            &mut out,
            *tile,
            (x + (w - tile.width()) / 2) as i64,
            band as i64,
        );
        x += w + gap;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_where_asked_and_nowhere_else() {
        let mut im = RgbImage::from_pixel(40, 20, Rgb([255, 255, 255]));
        draw_text(&mut im, 4, 2, "A", 2, INK);
        let inked: Vec<(u32, u32)> = im
            .enumerate_pixels()
            .filter(|(_, _, p)| **p == INK)
            .map(|(x, y, _)| (x, y))
            .collect();
        assert!(inked.len() > 20, "an A has ink");
        assert!(inked
            .iter()
            .all(|&(x, y)| (4..20).contains(&x) && (2..18).contains(&y)));
        assert_eq!(text_width("abc", 2), 48);
    }

    #[test]
    fn captions_sit_above_their_tiles() {
        let red = RgbImage::from_pixel(30, 10, Rgb([255, 0, 0]));
        let blue = RgbImage::from_pixel(30, 10, Rgb([0, 0, 255]));
        let row = captioned_row(&[(&red, "in"), (&blue, "ours")], 1, 4, Rgb([255, 255, 255]));
        assert_eq!(row.height(), 22);
        assert_eq!(row.width(), 30 + 4 + 36);
        assert_eq!(*row.get_pixel(5, 15), Rgb([255, 0, 0]));
        assert_eq!(*row.get_pixel(34 + 18, 15), Rgb([0, 0, 255]));
        assert!((0..12).any(|y| (0..30).any(|x| *row.get_pixel(x, y) == INK)));
        assert!((0..12).any(|y| (34..70).any(|x| *row.get_pixel(x, y) == INK)));
    }
}
