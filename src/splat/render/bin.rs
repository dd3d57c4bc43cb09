//! Stages 2–3, bin and sort: assign each splat to the 16×16 tiles its 3σ square touches,
//! then order every tile's list front to back.
//!
//! Binning is a count pass, an exclusive prefix sum and a fill pass (the GPU version is the
//! same with an atomic or a radix sort on `tile << 32 | depth` keys). Within a tile, keys are
//! `depth_bits << 32 | splat`: depth is positive, so its IEEE bits sort like the value, and the
//! splat index breaks ties, which makes the order (and the image) independent of threading.

use super::project::Splat2D;
use super::TILE;
use rayon::prelude::*;

/// Tile grid of an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct TileGrid {
    /// Tiles per row.
    pub cols: usize,
    /// Tile rows.
    pub rows: usize,
}

impl TileGrid {
    /// The grid covering `width × height` pixels.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            cols: (width as usize).div_ceil(TILE),
            rows: (height as usize).div_ceil(TILE),
        }
    }

    /// Tile rectangle `[x0, x1) × [y0, y1)` touched by a splat, in tile units.
    pub fn rect(&self, s: &Splat2D) -> (usize, usize, usize, usize) {
        let t = TILE as f32;
        let clamp = |v: f32, hi: usize| v.clamp(0.0, hi as f32) as usize;
        let x0 = clamp(((s.mean[0] - s.radius) / t).floor(), self.cols);
        let x1 = clamp(((s.mean[0] + s.radius) / t).floor() + 1.0, self.cols);
        let y0 = clamp(((s.mean[1] - s.radius) / t).floor(), self.rows);
        let y1 = clamp(((s.mean[1] + s.radius) / t).floor() + 1.0, self.rows);
        (x0, x1, y0, y1)
    }
}

/// Per-tile, depth-sorted lists of splat indices.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct TileBins {
    /// `offsets[t]..offsets[t + 1]` is tile `t`'s range in `keys`.
    pub offsets: Vec<usize>,
    /// Sort keys `depth_bits << 32 | splat index`, front to back within each tile.
    pub keys: Vec<u64>,
}

impl TileBins {
    /// The splat indices of tile `t`, front to back.
    pub fn tile(&self, t: usize) -> impl Iterator<Item = usize> + '_ {
        self.keys[self.offsets[t]..self.offsets[t + 1]]
            .iter()
            .map(|k| (*k & 0xffff_ffff) as usize)
    }
}

/// Bins the splats into tiles and sorts each tile by depth.
pub(crate) fn bin_and_sort(splats: &[Splat2D], grid: TileGrid) -> TileBins {
    let n_tiles = grid.cols * grid.rows;
    let rects: Vec<_> = {
        let _span = tracing::trace_span!("bin", splats = splats.len(), tiles = n_tiles).entered();
        splats.par_iter().map(|s| grid.rect(s)).collect()
    };
    let mut offsets = vec![0usize; n_tiles + 1];
    let mut keys;
    {
        let _span = tracing::trace_span!("bin_fill").entered();
        for &(x0, x1, y0, y1) in &rects {
            for ty in y0..y1 {
                for c in &mut offsets[ty * grid.cols + x0 + 1..ty * grid.cols + x1 + 1] {
                    *c += 1;
                }
            }
        }
        let mut running = 0;
        for o in offsets.iter_mut() {
            running += *o;
            *o = running;
        }
        let mut cursor = offsets.clone();
        keys = vec![0u64; offsets[n_tiles]];
        for (i, (s, &(x0, x1, y0, y1))) in splats.iter().zip(&rects).enumerate() {
            let key = ((s.depth.to_bits() as u64) << 32) | i as u64;
            for ty in y0..y1 {
                for tx in x0..x1 {
                    let t = ty * grid.cols + tx;
                    keys[cursor[t]] = key;
                    cursor[t] += 1;
                }
            }
        }
    }
    {
        let _span = tracing::trace_span!("sort", pairs = keys.len()).entered();
        let mut slices = Vec::with_capacity(n_tiles);
        let mut rest = keys.as_mut_slice();
        for range in offsets.windows(2) {
            let (head, tail) = rest.split_at_mut(range[1] - range[0]);
            slices.push(head);
            rest = tail;
        }
        slices.into_par_iter().for_each(|s| s.sort_unstable());
    }
    TileBins { offsets, keys }
}
