//! Stage 4, blend: front-to-back alpha compositing of each tile's sorted splats
//! (3DGS reference semantics).
//!
//! Per pixel `p` and splat `i` in depth order: `power = -½ dᵀ Σ⁻¹ d` with `d` = centre − pixel;
//! `α = min(0.99, opacity · e^power)`; samples with `power > 0` or `α < 1/255` are skipped; if
//! `T · (1 − α) < 1e-4` the pixel is finished and this sample is *not* added; otherwise
//! `colour += α T c_i`, `T ← T (1 − α)`. A tile stops once all its pixels are finished. The
//! final pixel is `colour + T · background`.
//!
//! One call handles one 16×16 tile, like one CUDA block. The tile's accumulators are held as
//! structs of arrays, and each splat is applied to the half rows (8 pixels) of its `α ≥ 1/255`
//! box with branch-free loops over fixed-size arrays that the compiler turns into SIMD
//! (compiled for AVX-512 and AVX2 as well as the baseline, chosen at run time). Every pixel's
//! arithmetic is the same fixed sequence on every path (no fused multiply-adds), so the image
//! does not depend on the instruction set or on how tiles are spread over threads.

use super::bin::{TileBins, TileGrid};
use super::project::{Splat2D, MIN_ALPHA};
use super::{RenderOptions, TILE};
use crate::splat::gaussians::Gaussians;

/// Transmittance below which a pixel is finished (3DGS: 1e-4).
const MIN_TRANSMITTANCE: f32 = 1e-4;
/// Highest alpha of one sample (3DGS: 0.99).
const MAX_ALPHA: f32 = 0.99;
/// Pixels in one SIMD step: half a tile row.
const LANES: usize = 8;
/// Half rows per tile row.
const HALVES: usize = TILE / LANES;
/// Pixels added on each side of a row's exact chord (guards against rounding).
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
    /// Projected splats, one per Gaussian (`None` = culled; never binned).
    pub splats: &'a [Option<Splat2D>],
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

/// One tile row's accumulators, `TILE` pixels each.
type Row = [f32; TILE];

/// Bit of half row `h` of tile row `ly` in a [`TileScratch::live_halves`]-style mask: bits
/// `0..16` are the left halves of rows `0..16`, bits `16..32` the right halves.
#[inline(always)]
fn half_bit(ly: usize, h: usize) -> u32 {
    1 << (h * TILE + ly)
}

/// Per-tile accumulators (structs of arrays, `[row][x]`), reused from tile to tile.
struct TileScratch {
    transmittance: [Row; TILE],
    /// 1 while a pixel is still blending, 0 once finished (or outside the image).
    live: [[u32; TILE]; TILE],
    /// Live pixels per half row.
    half_live: [[u32; HALVES]; TILE],
    /// Half rows that still have a live pixel (see [`half_bit`]).
    live_halves: u32,
    r: [Row; TILE],
    g: [Row; TILE],
    b: [Row; TILE],
    depth: [Row; TILE],
    /// Features, pixel-major (`[row][x][channel]`), so that one pixel's channels are
    /// contiguous (vectorised over channels; copied straight into the output).
    features: Vec<f32>,
    /// Feature channels.
    channels: usize,
}

/// How many splats ahead of the one being blended to prefetch.
const PREFETCH_AHEAD: usize = 8;

impl TileScratch {
    fn new(channels: usize) -> Self {
        Self {
            transmittance: [[1.0; TILE]; TILE],
            live: [[1; TILE]; TILE],
            half_live: [[LANES as u32; HALVES]; TILE],
            live_halves: u32::MAX,
            r: [[0.0; TILE]; TILE],
            g: [[0.0; TILE]; TILE],
            b: [[0.0; TILE]; TILE],
            depth: [[0.0; TILE]; TILE],
            features: vec![0.0; TILE * TILE * channels],
            channels,
        }
    }

    /// Resets for a tile whose in-image part is `tw × th` pixels; returns that pixel count.
    fn reset(&mut self, tw: usize, th: usize) -> usize {
        self.live_halves = 0;
        for y in 0..TILE {
            for x in 0..TILE {
                self.live[y][x] = (x < tw && y < th) as u32;
            }
            for h in 0..HALVES {
                let n = self.live[y][h * LANES..(h + 1) * LANES].iter().sum();
                self.half_live[y][h] = n;
                if n > 0 {
                    self.live_halves |= half_bit(y, h);
                }
            }
        }
        self.transmittance = [[1.0; TILE]; TILE];
        self.r = [[0.0; TILE]; TILE];
        self.g = [[0.0; TILE]; TILE];
        self.b = [[0.0; TILE]; TILE];
        self.depth = [[0.0; TILE]; TILE];
        self.features.fill(0.0);
        tw * th
    }
}

/// The instruction set [`blend_band`] uses on this CPU (unless told to stay portable).
pub(crate) fn instruction_set() -> &'static str {
    crate::simd::Isa::widest(false).name()
}

/// Blends every tile of band `row` (tile row index) into `out`, with the widest SIMD the CPU
/// has unless `portable` (the baseline build; same result bit for bit).
pub(crate) fn blend_band(row: usize, input: &BlendInput, out: BandOut, portable: bool) {
    if portable {
        blend_band_portable(row, input, out)
    } else {
        blend_band_simd(row, input, out)
    }
}

crate::simd::simd_dispatch! {
    avx2;
    /// [`blend_band_portable`] compiled for the widest of AVX-512F and AVX2 the CPU has.
    fn blend_band_simd[](row: usize, input: &BlendInput, out: BandOut) = blend_band_portable;
}

/// The band loop, inlined into each instruction-set variant.
#[inline(always)]
fn blend_band_portable(row: usize, input: &BlendInput, out: BandOut) {
    let mut scratch = TileScratch::new(input.channels);
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

/// Image coordinates of one tile's pixel columns and rows, as floats.
struct TileFrame {
    xs: Row,
    ys: Row,
}

#[inline(always)]
fn blend_tile(col: usize, row: usize, input: &BlendInput, s: &mut TileScratch) {
    let (x0, y0) = (col * TILE, row * TILE);
    let tw = TILE.min(input.width - x0);
    let th = TILE.min(input.height - y0);
    let mut remaining = s.reset(tw, th);
    let frame = TileFrame {
        xs: std::array::from_fn(|x| (x0 + x) as f32),
        ys: std::array::from_fn(|y| (y0 + y) as f32),
    };
    let list = input.bins.tile(row * input.grid.cols + col);
    for (k, &i) in list.iter().enumerate() {
        // Fetch a splat a few iterations before it is blended.
        if let Some(&ahead) = list.get(k + PREFETCH_AHEAD) {
            prefetch(&input.splats[ahead as usize]);
        }
        let Some(g) = &input.splats[i as usize] else {
            continue;
        };
        remaining -= blend_splat(g, &frame, input, s);
        if remaining == 0 {
            break;
        }
    }
}

/// Hints the CPU to load `value` into the cache (no effect where there is no such hint).
#[inline(always)]
fn prefetch<T>(value: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let start = value as *const T as *const i8;
        // SAFETY: prefetching never faults and reads nothing architecturally; both addresses
        // lie within `value`.
        unsafe {
            _mm_prefetch(start, _MM_HINT_T0);
            _mm_prefetch(
                start.wrapping_add(std::mem::size_of::<T>() - 1),
                _MM_HINT_T0,
            );
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = value;
}

/// The half rows of the tile that splat `g` can reach (a [`half_bit`] mask): rows within its
/// `α ≥ 1/255` box whose chord of the `α ≥ 1/255` ellipse, widened a little against rounding,
/// overlaps the half. Computed for all 16 rows at once; NaN comparisons keep a half, so that
/// this only ever skips work.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(a < b)` is deliberately true for NaN.
#[inline(always)]
fn reachable_halves(g: &Splat2D, f: &TileFrame) -> u32 {
    let [ca, cb, cc] = g.conic;
    let [mx, my] = g.mean;
    // Row `dy` holds the pixels with power ≥ min_power, i.e. a dx² + 2 b dy dx + c dy² +
    // 2 min_power ≤ 0: dx = (−b dy ± √(k0 − k1 dy²)) / a.
    let inv_a = 1.0 / ca;
    let k0 = -2.0 * ca * g.min_power;
    let k1 = ca * cc - cb * cb;
    let (box_lo, box_hi) = (mx - g.extent[0], mx + g.extent[0]);
    let x0 = f.xs[0];
    let mut left = 0u32;
    let mut right = 0u32;
    for (ly, &py) in f.ys.iter().enumerate() {
        let dy = my - py;
        let disc = k0 - k1 * dy * dy;
        let half_chord = disc.max(0.0).sqrt() * inv_a;
        let centre = mx + cb * dy * inv_a;
        let lo = (centre - half_chord - SPAN_MARGIN).max(box_lo);
        let hi = (centre + half_chord + SPAN_MARGIN).min(box_hi);
        let row = !(disc < 0.0) & !(dy.abs() > g.extent[1]) & !(lo > hi);
        left |= ((row & !(lo > x0 + 7.0) & !(hi < x0)) as u32) << ly;
        right |= ((row & !(lo > x0 + 15.0) & !(hi < x0 + 8.0)) as u32) << ly;
    }
    left | right << TILE
}

/// Applies one splat to the tile; returns how many pixels it finished.
#[inline(always)]
fn blend_splat(g: &Splat2D, f: &TileFrame, input: &BlendInput, s: &mut TileScratch) -> usize {
    let mut todo = reachable_halves(g, f) & s.live_halves;
    if todo == 0 {
        return 0;
    }
    let feats = if input.channels > 0 {
        input.gaussians.features_of(g.index as usize)
    } else {
        &[]
    };
    let mut finished = 0;
    while todo != 0 {
        let bit = todo.trailing_zeros() as usize;
        todo &= todo - 1;
        let (h, ly) = (bit / TILE, bit % TILE);
        let dy = g.mean[1] - f.ys[ly];
        let lanes = h * LANES..(h + 1) * LANES;
        let mut w = [0.0f32; LANES];
        let done = blend_half_row(
            g,
            dy,
            lanes_of(&f.xs, h),
            lanes_of_mut(&mut s.transmittance[ly], h),
            lanes_of_mut_u32(&mut s.live[ly], h),
            &mut w,
        );
        if done > 0 {
            s.half_live[ly][h] -= done;
            if s.half_live[ly][h] == 0 {
                s.live_halves &= !half_bit(ly, h);
            }
            finished += done as usize;
        }
        accumulate(&mut s.r[ly][lanes.clone()], g.rgb[0], &w);
        accumulate(&mut s.g[ly][lanes.clone()], g.rgb[1], &w);
        accumulate(&mut s.b[ly][lanes.clone()], g.rgb[2], &w);
        accumulate(&mut s.depth[ly][lanes.clone()], g.depth, &w);
        if s.channels > 0 {
            let c = s.channels;
            let first = (ly * TILE + h * LANES) * c;
            accumulate_features(&mut s.features[first..first + LANES * c], feats, &w);
        }
    }
    finished
}

#[inline(always)]
fn lanes_of(row: &Row, h: usize) -> &[f32; LANES] {
    (&row[h * LANES..(h + 1) * LANES])
        .try_into()
        .expect("a half row has LANES pixels")
}

#[inline(always)]
fn lanes_of_mut(row: &mut Row, h: usize) -> &mut [f32; LANES] {
    (&mut row[h * LANES..(h + 1) * LANES])
        .try_into()
        .expect("a half row has LANES pixels")
}

#[inline(always)]
fn lanes_of_mut_u32(row: &mut [u32; TILE], h: usize) -> &mut [u32; LANES] {
    (&mut row[h * LANES..(h + 1) * LANES])
        .try_into()
        .expect("a half row has LANES pixels")
}

/// Applies splat `g` to the 8 pixels at columns `xs` of the image row `dy` above its centre:
/// updates their transmittance and live flags, writes each pixel's blend weight `α T` (0 where
/// nothing is added) to `w` and returns how many pixels finished.
#[inline(always)]
fn blend_half_row(
    g: &Splat2D,
    dy: f32,
    xs: &[f32; LANES],
    transmittance: &mut [f32; LANES],
    live: &mut [u32; LANES],
    w: &mut [f32; LANES],
) -> u32 {
    let [ca, cb, cc] = g.conic;
    let (mx, opacity, min_power) = (g.mean[0], g.opacity, g.min_power);
    let cc_dy2 = cc * dy * dy;
    let mut finished = 0;
    for l in 0..LANES {
        let dx = mx - xs[l];
        let power = -0.5 * (ca * dx * dx + cc_dy2) - cb * dx * dy;
        let alpha = MAX_ALPHA.min(opacity * fast_exp(power));
        // `power < min_power` ⇔ alpha < 1/255; both are tested so rounding matches 3DGS.
        let sampled = (live[l] != 0) & (power <= 0.0) & (power >= min_power) & (alpha >= MIN_ALPHA);
        let t = transmittance[l];
        let next_t = t * (1.0 - alpha);
        let ends = next_t < MIN_TRANSMITTANCE;
        let adds = sampled & !ends;
        let done = sampled & ends;
        w[l] = if adds { alpha * t } else { 0.0 };
        transmittance[l] = if adds { next_t } else { t };
        live[l] = if done { 0 } else { live[l] };
        finished += done as u32;
    }
    finished
}

/// `acc[pixel][channel] += features[channel] · w[pixel]` for the 8 pixels of a half row
/// (pixels with a zero weight are skipped: adding `± 0` would leave them unchanged anyway).
#[inline(always)]
fn accumulate_features(acc: &mut [f32], features: &[f32], w: &[f32; LANES]) {
    let c = features.len();
    for (pixel, &wl) in acc.chunks_exact_mut(c).zip(w) {
        if wl != 0.0 {
            for (a, f) in pixel.iter_mut().zip(features) {
                *a += f * wl;
            }
        }
    }
}

/// `acc += value · w` lane by lane (a zero weight leaves `acc` bit for bit unchanged).
#[inline(always)]
fn accumulate(acc: &mut [f32], value: f32, w: &[f32; LANES]) {
    for (a, w) in acc.iter_mut().zip(w) {
        *a += value * w;
    }
}

/// `e^x` for `x` in `[-87, 0]`, relative error below 3e-7: `x = n ln2 + r` with `|r| ≤ ln2/2`,
/// a degree-6 Taylor polynomial for `e^r`, and `2^n` built in the exponent bits. Branch-free
/// and inlinable, so that the blend loop vectorises.
#[inline(always)]
pub(crate) fn fast_exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    const ROUND: f32 = 12_582_912.0; // 1.5 · 2^23: adding and subtracting it rounds to an integer.
    const ROUND_BITS: i32 = 0x4B40_0000; // bits of ROUND: `t`'s low mantissa bits hold `n`.
    let x = x.max(-87.0);
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    // `2^n` from the integer in `t`'s bits (no float → int conversion, which would not
    // vectorise).
    let exponent = (t.to_bits() as i32).wrapping_sub(ROUND_BITS) + 127;
    p * f32::from_bits((exponent << 23) as u32)
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
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
            let o = ly * input.width + x0 + lx;
            let t = s.transmittance[ly][lx];
            rgb[o * 3] = s.r[ly][lx] + t * bg.x;
            rgb[o * 3 + 1] = s.g[ly][lx] + t * bg.y;
            rgb[o * 3 + 2] = s.b[ly][lx] + t * bg.z;
            let a = 1.0 - t;
            alpha[o] = a;
            depth[o] = if a > 0.0 { s.depth[ly][lx] / a } else { 0.0 };
            if c > 0 {
                let dst = &mut features[o * c..(o + 1) * c];
                let p = (ly * TILE + lx) * c;
                for ((d, acc), b) in dst
                    .iter_mut()
                    .zip(&s.features[p..p + c])
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
}
