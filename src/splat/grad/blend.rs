//! Backward through the blend: per pixel, the samples the forward added, walked back to front
//! (3DGS's backward), giving each splat's gradient with respect to its 2D mean, conic,
//! opacity and colour.

use super::FrameGrads;
use crate::splat::camera::Camera;
use crate::splat::render::bin::{TileBins, TileGrid};
use crate::splat::render::blend::fast_exp;
use crate::splat::render::project::{Splat2D, MIN_ALPHA};
use crate::splat::render::{RenderOptions, TILE};
use rayon::prelude::*;

/// Transmittance below which the forward finishes a pixel (as the blend stage).
const MIN_TRANSMITTANCE: f32 = 1e-4;
/// Highest alpha of one sample (as the blend stage).
const MAX_ALPHA: f32 = 0.99;
/// Pixels a row's reach is widened by beyond the α ≥ 1/255 ellipse's chord (rounding).
const CHORD_MARGIN: f32 = 0.05;

/// One splat's gradients in screen space.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct SplatGrad {
    /// `∂L/∂mean` (pixels).
    pub mean: [f32; 2],
    /// `∂L/∂conic` `(a, b, c)`.
    pub conic: [f32; 3],
    /// `∂L/∂opacity` (of the splat's capped opacity).
    pub opacity: f32,
    /// `∂L/∂rgb`.
    pub rgb: [f32; 3],
}

impl SplatGrad {
    fn add(&mut self, o: &SplatGrad) {
        for k in 0..2 {
            self.mean[k] += o.mean[k];
        }
        for k in 0..3 {
            self.conic[k] += o.conic[k];
            self.rgb[k] += o.rgb[k];
        }
        self.opacity += o.opacity;
    }
}

/// A sample of splat `g` at the pixel `d = mean − pixel` away: its Gaussian falloff
/// `e^power`, alpha and whether the forward blends it (before the transmittance test).
#[inline(always)]
fn sample(g: &Splat2D, dx: f32, dy: f32) -> (f32, f32, bool) {
    let [ca, cb, cc] = g.conic;
    let power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy;
    if !(power <= 0.0 && power >= g.min_power) {
        return (0.0, 0.0, false);
    }
    let gauss = fast_exp(power);
    let alpha = MAX_ALPHA.min(g.opacity * gauss);
    (gauss, alpha, alpha >= MIN_ALPHA)
}

/// Per splat (indexed like `splats`), the gradients of the loss whose frame gradients are
/// `frame`.
pub(super) fn backward(
    splats: &[Option<Splat2D>],
    bins: &TileBins,
    camera: &Camera,
    options: &RenderOptions,
    frame: FrameGrads<'_>,
) -> Vec<SplatGrad> {
    let (width, height) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    let grid = TileGrid::new(camera.intrinsics.width, camera.intrinsics.height);
    let bg = options.background.to_array();
    let per_tile: Vec<Vec<SplatGrad>> = (0..grid.cols * grid.rows)
        .into_par_iter()
        .map(|t| {
            let (col, row) = (t % grid.cols, t / grid.cols);
            tile_backward(splats, bins.tile(t), col, row, width, height, bg, frame)
        })
        .collect();
    let mut grads = vec![SplatGrad::default(); splats.len()];
    for (t, acc) in per_tile.iter().enumerate() {
        for (&i, g) in bins.tile(t).iter().zip(acc) {
            grads[i as usize].add(g);
        }
    }
    grads
}

/// One sample the forward blended at a pixel: the splat's place in the tile list, its offset
/// from the pixel, its falloff there and its alpha.
#[derive(Debug, Clone, Copy)]
struct Sample {
    k: u32,
    dx: f32,
    dy: f32,
    /// `e^power`, the splat's falloff at the pixel.
    gauss: f32,
    alpha: f32,
}

/// One tile's gradients, one entry per entry of its splat list `list`.
#[allow(clippy::too_many_arguments)]
fn tile_backward(
    splats: &[Option<Splat2D>],
    list: &[u32],
    col: usize,
    row: usize,
    width: usize,
    height: usize,
    bg: [f32; 3],
    frame: FrameGrads<'_>,
) -> Vec<SplatGrad> {
    let mut acc = vec![SplatGrad::default(); list.len()];
    if list.is_empty() {
        return acc;
    }
    let (x0, y0) = (col * TILE, row * TILE);
    let (tw, th) = (TILE.min(width - x0), TILE.min(height - y0));
    let reach = PixelLists::new(splats, list, x0, y0, tw, th);
    // The tile's splats in list order, so that the per-pixel sweeps read them in place.
    let local: Vec<Option<Splat2D>> = list.iter().map(|&i| splats[i as usize]).collect();
    let mut samples = Vec::new();
    for ly in 0..th {
        for lx in 0..tw {
            let o = (y0 + ly) * width + x0 + lx;
            let d_rgb = [frame.rgb[3 * o], frame.rgb[3 * o + 1], frame.rgb[3 * o + 2]];
            let d_alpha = frame.alpha[o];
            if d_rgb == [0.0; 3] && d_alpha == 0.0 {
                continue;
            }
            let (px, py) = ((x0 + lx) as f32, (y0 + ly) as f32);
            let t_final = pixel_samples(&local, reach.of(ly * TILE + lx), px, py, &mut samples);
            pixel_backward(&local, &samples, t_final, bg, d_rgb, d_alpha, &mut acc);
        }
    }
    acc
}

/// For each pixel of a tile, the places in the tile's list of the splats whose α ≥ 1/255 box
/// holds it, front to back (what the forward's row spans visit).
struct PixelLists {
    /// `offsets[p]..offsets[p + 1]` is pixel `p`'s range of `entries` (`p = y · TILE + x`).
    offsets: Vec<u32>,
    entries: Vec<u32>,
}

impl PixelLists {
    fn new(
        splats: &[Option<Splat2D>],
        list: &[u32],
        x0: usize,
        y0: usize,
        tw: usize,
        th: usize,
    ) -> Self {
        // Each splat's rows within the tile, each with the pixel range of its α ≥ 1/255
        // ellipse's chord (widened a little against rounding, as the forward's row spans).
        let mut spans: Vec<(u32, u8, u8, u8)> = Vec::new();
        for (k, &i) in list.iter().enumerate() {
            let Some(g) = splats[i as usize].as_ref() else {
                continue;
            };
            let range = |centre: f32, extent: f32, origin: usize, len: usize| {
                let lo = (centre - extent - origin as f32).ceil().max(0.0);
                let hi = (centre + extent - origin as f32)
                    .floor()
                    .min(len as f32 - 1.0);
                (lo <= hi).then_some((lo as usize, hi as usize))
            };
            let (Some((xa, xb)), Some((ya, yb))) = (
                range(g.mean[0], g.extent[0], x0, tw),
                range(g.mean[1], g.extent[1], y0, th),
            ) else {
                continue;
            };
            let [ca, cb, cc] = g.conic;
            let (inv_a, k0, k1) = (1.0 / ca, -2.0 * ca * g.min_power, ca * cc - cb * cb);
            for y in ya..=yb {
                let dy = g.mean[1] - (y0 + y) as f32;
                let disc = k0 - k1 * dy * dy;
                let (mut lo, mut hi) = (xa, xb);
                if disc.is_finite() && inv_a.is_finite() && ca > 0.0 {
                    if disc < 0.0 {
                        continue;
                    }
                    let half_chord = disc.sqrt() * inv_a;
                    let centre = g.mean[0] + cb * dy * inv_a - x0 as f32;
                    let a = (centre - half_chord - CHORD_MARGIN).ceil();
                    let b = (centre + half_chord + CHORD_MARGIN).floor();
                    if b < xa as f32 || a > xb as f32 {
                        continue;
                    }
                    lo = lo.max(a.max(0.0) as usize);
                    hi = hi.min(b as usize);
                }
                spans.push((k as u32, y as u8, lo as u8, hi as u8));
            }
        }
        let mut offsets = vec![0u32; TILE * TILE + 1];
        for &(_, y, xa, xb) in &spans {
            for x in xa..=xb {
                offsets[y as usize * TILE + x as usize + 1] += 1;
            }
        }
        for p in 0..TILE * TILE {
            offsets[p + 1] += offsets[p];
        }
        let mut fill = offsets.clone();
        let mut entries = vec![0u32; offsets[TILE * TILE] as usize];
        for &(k, y, xa, xb) in &spans {
            for x in xa..=xb {
                let p = y as usize * TILE + x as usize;
                entries[fill[p] as usize] = k;
                fill[p] += 1;
            }
        }
        Self { offsets, entries }
    }

    fn of(&self, pixel: usize) -> &[u32] {
        &self.entries[self.offsets[pixel] as usize..self.offsets[pixel + 1] as usize]
    }
}

/// The samples the forward blended at pixel `(px, py)` among the tile's splats `local` at the
/// places `reach`
/// (front to back), into `samples`; returns the final transmittance.
#[inline]
fn pixel_samples(
    local: &[Option<Splat2D>],
    reach: &[u32],
    px: f32,
    py: f32,
    samples: &mut Vec<Sample>,
) -> f32 {
    samples.clear();
    let mut t = 1.0f32;
    for &k in reach {
        let Some(g) = &local[k as usize] else {
            continue;
        };
        let (dx, dy) = (g.mean[0] - px, g.mean[1] - py);
        let (gauss, alpha, sampled) = sample(g, dx, dy);
        if !sampled {
            continue;
        }
        let next = t * (1.0 - alpha);
        if next < MIN_TRANSMITTANCE {
            break;
        }
        t = next;
        samples.push(Sample {
            k,
            dx,
            dy,
            gauss,
            alpha,
        });
    }
    t
}

/// Adds one pixel's contribution to the gradients of the tile's splats, walking its
/// `samples` back to front from the final transmittance `t_final`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn pixel_backward(
    local: &[Option<Splat2D>],
    samples: &[Sample],
    t_final: f32,
    bg: [f32; 3],
    d_rgb: [f32; 3],
    d_alpha: f32,
    acc: &mut [SplatGrad],
) {
    let mut t = t_final;
    // `behind` is the colour the samples behind the current one added.
    let mut behind = [0.0f32; 3];
    let bg_dot: f32 = (0..3).map(|c| bg[c] * d_rgb[c]).sum();
    for s in samples.iter().rev() {
        let g = local[s.k as usize]
            .as_ref()
            .expect("a sampled splat is visible");
        let (dx, dy, alpha) = (s.dx, s.dy, s.alpha);
        let inv_one_minus = 1.0 / (1.0 - alpha);
        t *= inv_one_minus;
        let weight = alpha * t;
        let mut d_a = (d_alpha - bg_dot) * t_final * inv_one_minus;
        for c in 0..3 {
            d_a += d_rgb[c] * (g.rgb[c] * t - behind[c] * inv_one_minus);
        }
        let grad = &mut acc[s.k as usize];
        for c in 0..3 {
            grad.rgb[c] += weight * d_rgb[c];
            behind[c] += g.rgb[c] * weight;
        }
        // α = min(0.99, opacity · e^power): no gradient where the cap holds.
        let gauss = s.gauss;
        if g.opacity * gauss >= MAX_ALPHA {
            continue;
        }
        grad.opacity += d_a * gauss;
        let d_power = d_a * alpha;
        let [ca, cb, cc] = g.conic;
        grad.mean[0] -= d_power * (ca * dx + cb * dy);
        grad.mean[1] -= d_power * (cc * dy + cb * dx);
        grad.conic[0] -= 0.5 * d_power * dx * dx;
        grad.conic[1] -= d_power * dx * dy;
        grad.conic[2] -= 0.5 * d_power * dy * dy;
    }
}
