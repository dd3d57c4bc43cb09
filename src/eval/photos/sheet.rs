//! The contact sheet of `lhmpp eval-photos --picture`: one row per scored photo, the photo
//! cropped to its person with the regions drawn (tinted, outlined in their colour,
//! [`Region::tint`](super::regions::Region::tint)), the render with its regions the same way, then one swatch row per
//! region in table order (torso, upper arms, thighs, shins, feet, head): the region's tint,
//! the photo's median colour, the render's; a grey swatch crossed out where the region was
//! not shown (both) or not rendered (the render's). An uncovered region's render swatch has a
//! crossed-out corner.

use super::regions::RegionMap;
use super::{RegionScore, RegionStatus, ViewPicture};
use crate::reconstruct::preprocess::mask_bbox;
use image::imageops::{resize, FilterType};
use image::{GrayImage, Rgb, RgbImage};

/// Height of a row, pixels.
pub const ROW: u32 = 300;
const GAP: u32 = 6;
const BACKGROUND: Rgb<u8> = Rgb([70, 70, 70]);

/// `image` with its regions tinted and outlined.
pub fn draw_regions(image: &RgbImage, map: &RegionMap) -> RgbImage {
    let mut out = image.clone();
    let (w, h) = (map.width.min(image.width()), map.height.min(image.height()));
    for y in 0..h {
        for x in 0..w {
            let Some(region) = map.at(x, y) else {
                continue;
            };
            let tint = region.tint();
            let edge = [
                (x.wrapping_sub(1), y),
                (x + 1, y),
                (x, y.wrapping_sub(1)),
                (x, y + 1),
            ]
            .iter()
            .any(|&(u, v)| u >= w || v >= h || map.at(u, v) != Some(region));
            let a = if edge { 1.0 } else { 0.35 };
            let p = out.get_pixel_mut(x, y);
            for (c, t) in p.0.iter_mut().zip(tint) {
                *c = (f32::from(*c) * (1.0 - a) + f32::from(t) * a).round() as u8;
            }
        }
    }
    out
}

/// The box around the person (mask ≥ 128) grown by 8 % (the whole image for an empty mask).
fn person_box(mask: &GrayImage) -> (u32, u32, u32, u32) {
    let Some(b) = mask_bbox(mask, 128) else {
        return (0, 0, mask.width(), mask.height());
    };
    let (w, h) = (i64::from(mask.width()), i64::from(mask.height()));
    let pad = (b.width().max(b.height()) * 8 / 100).max(4);
    let (x0, y0) = ((b.x0 - pad).max(0), (b.y0 - pad).max(0));
    let (x1, y1) = ((b.x1 + pad).min(w), (b.y1 + pad).min(h));
    (x0 as u32, y0 as u32, (x1 - x0) as u32, (y1 - y0) as u32)
}

/// `image` around its person, regions drawn, scaled to [`ROW`] pixels high (at most twice as
/// wide).
fn tile(image: &RgbImage, mask: &GrayImage, map: &RegionMap) -> RgbImage {
    let (x, y, w, h) = person_box(mask);
    let drawn = draw_regions(image, map);
    let crop = image::imageops::crop_imm(&drawn, x, y, w.max(1), h.max(1)).to_image();
    let width = (u64::from(crop.width()) * u64::from(ROW) / u64::from(crop.height().max(1)))
        .clamp(1, 2 * u64::from(ROW)) as u32;
    resize(&crop, width, ROW, FilterType::Triangle)
}

fn fill(sheet: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, colour: Rgb<u8>) {
    for v in y..(y + h).min(sheet.height()) {
        for u in x..(x + w).min(sheet.width()) {
            sheet.put_pixel(u, v, colour);
        }
    }
}

/// A grey square crossed out.
fn crossed(sheet: &mut RgbImage, x: u32, y: u32, side: u32) {
    fill(sheet, x, y, side, side, Rgb([140, 140, 140]));
    for i in 0..side {
        for (u, v) in [(x + i, y + i), (x + side - 1 - i, y + i)] {
            if u < sheet.width() && v < sheet.height() {
                sheet.put_pixel(u, v, Rgb([30, 30, 30]));
            }
        }
    }
}

/// Width of the swatch column.
const SWATCHES: u32 = 12 + 2 * (ROW / 6);

fn swatches(sheet: &mut RgbImage, x: u32, y: u32, regions: &[RegionScore]) {
    let side = ROW / 6 - 4;
    for (i, r) in regions.iter().enumerate() {
        let top = y + i as u32 * (ROW / 6) + 2;
        fill(sheet, x, top, 8, side, Rgb(r.region.tint()));
        let (px, rx) = (x + 12, x + 12 + ROW / 6);
        match (r.status, r.photo, r.render) {
            (RegionStatus::NotShown, ..) => {
                crossed(sheet, px, top, side);
                crossed(sheet, rx, top, side);
            }
            (RegionStatus::NotRendered, Some(p), _) => {
                fill(sheet, px, top, side, side, Rgb(p.rgb));
                crossed(sheet, rx, top, side);
            }
            (RegionStatus::Uncovered, Some(p), Some(q)) => {
                fill(sheet, px, top, side, side, Rgb(p.rgb));
                fill(sheet, rx, top, side, side, Rgb(q.rgb));
                crossed(sheet, rx, top, side / 3);
            }
            (_, Some(p), Some(q)) => {
                fill(sheet, px, top, side, side, Rgb(p.rgb));
                fill(sheet, rx, top, side, side, Rgb(q.rgb));
            }
            _ => {
                crossed(sheet, px, top, side);
                crossed(sheet, rx, top, side);
            }
        }
    }
}

/// The contact sheet of `views`, one row each.
pub fn contact_sheet(views: &[ViewPicture]) -> RgbImage {
    let rows: Vec<(RgbImage, RgbImage)> = views
        .iter()
        .map(|v| {
            (
                tile(&v.photo, &v.photo_mask, &v.photo_map),
                tile(&v.render, &v.render_mask, &v.render_map),
            )
        })
        .collect();
    let width = rows
        .iter()
        .map(|(p, r)| p.width() + r.width() + SWATCHES + 4 * GAP)
        .max()
        .unwrap_or(1);
    let height = (rows.len() as u32 * (ROW + GAP) + GAP).max(1);
    let mut sheet = RgbImage::from_pixel(width, height, BACKGROUND);
    for (i, ((photo, render), view)) in rows.iter().zip(views).enumerate() {
        let y = GAP + i as u32 * (ROW + GAP);
        image::imageops::replace(&mut sheet, photo, i64::from(GAP), i64::from(y));
        let x = 2 * GAP + photo.width();
        image::imageops::replace(&mut sheet, render, i64::from(x), i64::from(y));
        swatches(&mut sheet, x + render.width() + GAP, y, &view.regions);
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::photos::regions::{region_map, Region, RegionConfig};
    use crate::perception::{Landmark, LandmarkId, BODY_LANDMARKS};
    use glam::Vec3;

    #[test]
    fn regions_are_drawn_in_their_tint_on_the_sheet() {
        // A torso only: shoulders and hips seen, nothing else.
        let mut l = [Landmark::default(); BODY_LANDMARKS];
        for (id, x, y) in [
            (LandmarkId::LeftShoulder, 70.0, 20.0),
            (LandmarkId::RightShoulder, 30.0, 20.0),
            (LandmarkId::LeftHip, 65.0, 80.0),
            (LandmarkId::RightHip, 35.0, 80.0),
        ] {
            l[id.index()] = Landmark {
                position: Vec3::new(x, y, 0.0),
                visibility: 1.0,
                presence: 1.0,
            };
        }
        let config = RegionConfig::default();
        let mask = image::GrayImage::from_pixel(100, 100, image::Luma([255]));
        let map = region_map(
            &l,
            &mask,
            super::super::regions::seen_parts(&l, &config),
            &config,
        );
        let image = RgbImage::from_pixel(100, 100, Rgb([255, 255, 255]));
        let drawn = draw_regions(&image, &map);
        let tint = Region::Torso.tint();
        let inside = drawn.get_pixel(50, 50).0;
        let want: Vec<u8> = tint
            .iter()
            .map(|t| (255.0 * 0.65 + f32::from(*t) * 0.35).round() as u8)
            .collect();
        assert_eq!(inside.to_vec(), want);
        assert_eq!(drawn.get_pixel(2, 2).0, [255, 255, 255]);
        let scores = super::super::compare_regions(&image, &map, &image, &map, &map, &config);
        let sheet = contact_sheet(&[ViewPicture {
            photo: image.clone(),
            photo_mask: mask.clone(),
            photo_map: map.clone(),
            render: image,
            render_mask: mask,
            render_map: map,
            regions: scores,
        }]);
        assert_eq!(sheet.height(), ROW + 2 * GAP);
        // The torso's swatch: its tint, then white (the photo's and render's median).
        let swatch_x = sheet.width() - SWATCHES - GAP;
        assert_eq!(sheet.get_pixel(swatch_x + 2, GAP + 10).0, tint);
        assert_eq!(sheet.get_pixel(swatch_x + 20, GAP + 10).0, [255, 255, 255]);
    }
}
