//! Stage 4, blend: front-to-back alpha compositing of each tile's sorted splats
//! (3DGS reference semantics).
//!
//! Per pixel `p` and splat `i` in depth order: `power = -½ dᵀ Σ⁻¹ d` with `d` = centre − pixel;
//! `α = min(0.99, opacity · e^power)`; samples with `α < 1/255` are skipped; if
//! `T · (1 − α) < 1e-4` the pixel is finished and this sample is *not* added; otherwise
//! `colour += α T c_i`, `T ← T (1 − α)`. A tile stops once all its pixels are finished. The
//! final pixel is `colour + T · background`. Each splat only visits the pixels of its
//! `α ≥ 1/255` box, which skips exactly the samples the reference would skip.
//!
//! One call handles one 16×16 tile, like one CUDA block; every pixel's arithmetic is a fixed
//! sequence, so the result does not depend on how tiles are spread over threads.

use super::bin::{TileBins, TileGrid};
use super::project::{Splat2D, MIN_ALPHA};
use super::{RenderOptions, TILE};
use crate::splat::gaussians::Gaussians;

/// Transmittance below which a pixel is finished (3DGS: 1e-4).
const MIN_TRANSMITTANCE: f32 = 1e-4;
/// Highest alpha of one sample (3DGS: 0.99).
const MAX_ALPHA: f32 = 0.99;
const PIXELS: usize = TILE * TILE;
/// Pixels added on each side of a row's exact span (guards against rounding).
const SPAN_MARGIN: f32 = 0.01;

/// The output rows of one band of tiles (`TILE` image rows, fewer at the bottom edge).
pub(crate) struct BandOut<'a> {
    /// RGB, `rows × width × 3`.
    pub rgb: &'a mut [f32],
    /// Alpha, `rows × width`.
    pub alpha: &'a mut [f32],
    /// Expected depth, `rows × width`.
    pub depth: &'a mut [f32],
    /// Features, `rows × width × C` (empty without features).
    pub features: &'a mut [f32],
}

/// Everything the blend reads, shared by all bands.
pub(crate) struct BlendInput<'a> {
    pub splats: &'a [Splat2D],
    pub bins: &'a TileBins,
    pub grid: TileGrid,
    pub gaussians: &'a Gaussians,
    pub options: &'a RenderOptions,
    pub width: usize,
    pub height: usize,
    /// Feature channels rendered (0 = none).
    pub channels: usize,
    /// Background features (`channels` values).
    pub background_features: &'a [f32],
}

/// Per-tile accumulators, reused from tile to tile.
struct TileScratch {
    transmittance: [f32; PIXELS],
    /// Per tile row, bit `x` set when pixel `x` of that row is finished.
    row_done: [u16; TILE],
    rgb: [[f32; 3]; PIXELS],
    depth: [f32; PIXELS],
    features: Vec<f32>,
}

/// Blends every tile of band `row` (tile row index) into `out`.
pub(crate) fn blend_band(row: usize, input: &BlendInput, out: BandOut) {
    let mut scratch = TileScratch {
        transmittance: [1.0; PIXELS],
        row_done: [0; TILE],
        rgb: [[0.0; 3]; PIXELS],
        depth: [0.0; PIXELS],
        features: vec![0.0; PIXELS * input.channels],
    };
    let BandOut {
        rgb,
        alpha,
        depth,
        features,
    } = out;
    for col in 0..input.grid.cols {
        blend_tile(col, row, input, &mut scratch);
        write_tile(col, row, input, &scratch, rgb, alpha, depth, features);
    }
}

fn blend_tile(col: usize, row: usize, input: &BlendInput, s: &mut TileScratch) {
    let (x0, y0) = (col * TILE, row * TILE);
    let tw = TILE.min(input.width - x0);
    let th = TILE.min(input.height - y0);
    s.transmittance.fill(1.0);
    s.row_done.fill(0);
    s.rgb.fill([0.0; 3]);
    s.depth.fill(0.0);
    s.features.fill(0.0);
    let c = input.channels;
    let mut remaining = tw * th;
    let tile = row * input.grid.cols + col;
    let (xmax, ymax) = ((x0 + tw - 1) as i32, (y0 + th - 1) as i32);
    for si in input.bins.tile(tile) {
        let g = &input.splats[si];
        let lo_x = ceil_i(g.mean[0] - g.extent[0]).max(x0 as i32);
        let hi_x = floor_i(g.mean[0] + g.extent[0]).min(xmax);
        let lo_y = ceil_i(g.mean[1] - g.extent[1]).max(y0 as i32);
        let hi_y = floor_i(g.mean[1] + g.extent[1]).min(ymax);
        if lo_x > hi_x || lo_y > hi_y {
            continue;
        }
        let [ca, cb, cc] = g.conic;
        let min_power = g.min_power;
        // Row `dy` holds the pixels with power ≥ min_power, i.e. a dx² + 2 b dy dx + c dy² +
        // 2 min_power ≤ 0: dx = (−b dy ± √(k0 − k1 dy²)) / a.
        let inv_a = 1.0 / ca;
        let k0 = -2.0 * ca * min_power;
        let k1 = ca * cc - cb * cb;
        let feats = if c > 0 {
            input.gaussians.features_of(g.index as usize)
        } else {
            &[]
        };
        for py in lo_y as usize..=hi_y as usize {
            let dy = g.mean[1] - py as f32;
            let disc = k0 - k1 * dy * dy;
            if disc.is_nan() || disc < 0.0 {
                continue;
            }
            let half = disc.sqrt() * inv_a;
            // px = mean − dx; widen by a little so rounding never drops a pixel.
            let centre = g.mean[0] + cb * dy * inv_a;
            let span_lo = ceil_i(centre - half - SPAN_MARGIN).max(lo_x);
            let span_hi = floor_i(centre + half + SPAN_MARGIN).min(hi_x);
            if span_lo > span_hi {
                continue;
            }
            // Visit only the unfinished pixels of the span (bit x = pixel x0 + x).
            let (first, last) = (span_lo as usize - x0, span_hi as usize - x0);
            let span_bits = ((1u32 << (last + 1)) - (1u32 << first)) as u16;
            let mut todo = span_bits & !s.row_done[py - y0];
            let row_base = (py - y0) * TILE;
            while todo != 0 {
                let lx = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                let px = x0 + lx;
                let p = row_base + lx;
                let dx = g.mean[0] - px as f32;
                let power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy;
                // `power < min_power` ⇔ alpha < 1/255: skip without the exponential.
                if power > 0.0 || power < min_power {
                    continue;
                }
                let alpha = MAX_ALPHA.min(g.opacity * fast_exp(power));
                if alpha < MIN_ALPHA {
                    continue;
                }
                let t = s.transmittance[p];
                let next_t = t * (1.0 - alpha);
                if next_t < MIN_TRANSMITTANCE {
                    s.row_done[py - y0] |= 1 << lx;
                    remaining -= 1;
                    continue;
                }
                let w = alpha * t;
                let acc = &mut s.rgb[p];
                acc[0] += g.rgb[0] * w;
                acc[1] += g.rgb[1] * w;
                acc[2] += g.rgb[2] * w;
                s.depth[p] += g.depth * w;
                if c > 0 {
                    for (a, f) in s.features[p * c..(p + 1) * c].iter_mut().zip(feats) {
                        *a += f * w;
                    }
                }
                s.transmittance[p] = next_t;
            }
        }
        if remaining == 0 {
            break;
        }
    }
}

/// `⌊x⌋` without a libm call, for `x` clamped to ±1e9 (NaN gives 0).
#[inline(always)]
fn floor_i(x: f32) -> i32 {
    let x = x.clamp(-1e9, 1e9);
    let i = x as i32;
    i - ((i as f32) > x) as i32
}

/// `⌈x⌉` without a libm call, for `x` clamped to ±1e9 (NaN gives 0).
#[inline(always)]
fn ceil_i(x: f32) -> i32 {
    let x = x.clamp(-1e9, 1e9);
    let i = x as i32;
    i + ((i as f32) < x) as i32
}

/// `e^x` for `x` in `[-87, 0]`, relative error below 3e-7: `x = n ln2 + r` with `|r| ≤ ln2/2`,
/// a degree-6 Taylor polynomial for `e^r`, and `2^n` built in the exponent bits. About 4×
/// faster than `f32::exp` and inlinable (the hot path of the blend).
#[inline(always)]
pub(crate) fn fast_exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    const ROUND: f32 = 12_582_912.0; // 1.5 · 2^23: adding and subtracting it rounds to an integer.
    let x = x.max(-87.0);
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    p * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

#[allow(clippy::too_many_arguments)]
fn write_tile(
    col: usize,
    row: usize,
    input: &BlendInput,
    s: &TileScratch,
    rgb: &mut [f32],
    alpha: &mut [f32],
    depth: &mut [f32],
    features: &mut [f32],
) {
    let x0 = col * TILE;
    let tw = TILE.min(input.width - x0);
    let th = TILE.min(input.height - row * TILE);
    let bg = input.options.background;
    let c = input.channels;
    for ly in 0..th {
        for lx in 0..tw {
            let p = ly * TILE + lx;
            let o = ly * input.width + x0 + lx;
            let t = s.transmittance[p];
            for ((d, acc), b) in rgb[o * 3..o * 3 + 3]
                .iter_mut()
                .zip(s.rgb[p])
                .zip(bg.to_array())
            {
                *d = acc + t * b;
            }
            let a = 1.0 - t;
            alpha[o] = a;
            depth[o] = if a > 0.0 { s.depth[p] / a } else { 0.0 };
            if c > 0 {
                let dst = &mut features[o * c..(o + 1) * c];
                for ((d, acc), b) in dst
                    .iter_mut()
                    .zip(&s.features[p * c..(p + 1) * c])
                    .zip(input.background_features)
                {
                    *d = acc + t * b;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::fast_exp;

    #[test]
    fn fast_exp_matches_std_exp_on_the_blend_range() {
        let mut worst = 0.0f64;
        for k in 0..=200_000 {
            let x = -20.0 * k as f32 / 200_000.0;
            let want = (x as f64).exp();
            worst = worst.max(((fast_exp(x) as f64) - want).abs() / want);
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
        assert_eq!(fast_exp(0.0), 1.0);
    }

    #[test]
    fn integer_floor_and_ceil_match_std() {
        for x in [-3.5f32, -3.0, -0.2, 0.0, 0.7, 2.0, 2.0001, 1e12, -1e12] {
            let x_c = x.clamp(-1e9, 1e9);
            assert_eq!(super::floor_i(x), x_c.floor() as i32, "{x}");
            assert_eq!(super::ceil_i(x), x_c.ceil() as i32, "{x}");
        }
    }
}
