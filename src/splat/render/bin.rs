//! Stages 2–3, bin and sort: order the splats front to back, then assign each to the 16×16
//! tiles its 3σ square touches (less those its α ≥ 1/255 box misses), so that every tile's
//! list comes out already in depth order.
//!
//! The depth order is one stable LSD radix sort of the splats' depth bits (depth is positive,
//! so its IEEE bits sort like the value; equal depths keep splat order, which makes the order,
//! and the image, independent of threading). Binning is then a count pass, an exclusive
//! prefix sum and a fill pass in depth order (a counting sort by tile, stable, so no per-tile
//! sort is needed). Count and fill run in parallel over groups of tile rows. The GPU version
//! is the same with a radix sort on `tile << 32 | depth` keys.

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

/// Tiles `[x0, x1) × [y0, y1)` touched by one splat.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct TileRect {
    pub x0: u16,
    pub x1: u16,
    pub y0: u16,
    pub y1: u16,
}

impl TileGrid {
    /// The grid covering `width × height` pixels.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            cols: (width as usize).div_ceil(TILE),
            rows: (height as usize).div_ceil(TILE),
        }
    }

    /// Tile rectangle touched by a splat's `3σ` square (3DGS), in tile units.
    #[cfg(test)]
    pub fn rect(&self, s: &Splat2D) -> TileRect {
        self.rect_within(s, [s.radius; 2])
    }

    /// The tiles of [`TileGrid::rect`] that hold a pixel with alpha ≥ 1/255: the `3σ` square
    /// cut down to the splat's `α ≥ 1/255` box (narrower for elongated splats); the other
    /// tiles would only skip every sample.
    pub fn contributing_rect(&self, s: &Splat2D) -> TileRect {
        self.rect_within(s, [s.radius.min(s.extent[0]), s.radius.min(s.extent[1])])
    }

    fn rect_within(&self, s: &Splat2D, half: [f32; 2]) -> TileRect {
        let t = TILE as f32;
        let clamp = |v: f32, hi: usize| v.clamp(0.0, hi as f32) as u16;
        TileRect {
            x0: clamp(((s.mean[0] - half[0]) / t).floor(), self.cols),
            x1: clamp(((s.mean[0] + half[0]) / t).floor() + 1.0, self.cols),
            y0: clamp(((s.mean[1] - half[1]) / t).floor(), self.rows),
            y1: clamp(((s.mean[1] + half[1]) / t).floor() + 1.0, self.rows),
        }
    }
}

/// Per-tile, depth-sorted lists of splat indices, and the buffers that build them (kept
/// between frames so that binning does not allocate once warm).
#[derive(Debug, Clone, Default)]
pub(crate) struct TileBins {
    /// `offsets[t]..offsets[t + 1]` is tile `t`'s range in `indices`.
    offsets: Vec<usize>,
    /// Splat indices, front to back within each tile.
    indices: Vec<u32>,
    /// Splat indices in depth order (front first).
    order: Vec<u32>,
    /// Radix-sort keys `depth_bits << 32 | splat` and their scratch copy.
    keys: Vec<u64>,
    scratch: Vec<u64>,
    /// Tile rectangle of every splat (empty for culled ones).
    rects: Vec<TileRect>,
    /// Rectangles and splat indices in depth order.
    sorted_rects: Vec<(TileRect, u32)>,
}

impl TileBins {
    /// The splat indices of tile `t`, front to back.
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.indices[self.offsets[t]..self.offsets[t + 1]]
    }

    /// Total (tile, splat) pairs.
    pub fn pairs(&self) -> usize {
        self.indices.len()
    }

    /// Splats that survived culling (after [`TileBins::build`]).
    pub fn visible(&self) -> usize {
        self.order.len()
    }

    /// Bins the projected splats (`None` = culled) into the tiles of `grid`, each tile's list
    /// front to back; the lists hold indices into `splats`.
    pub fn build(&mut self, splats: &[Option<Splat2D>], grid: TileGrid) {
        let n_tiles = grid.cols * grid.rows;
        {
            let _span = tracing::trace_span!("sort", splats = splats.len()).entered();
            self.keys.clear();
            self.keys
                .extend(splats.iter().enumerate().filter_map(|(i, s)| {
                    s.as_ref()
                        .map(|s| ((s.depth.to_bits() as u64) << 32) | i as u64)
                }));
            radix_sort_high_half(&mut self.keys, &mut self.scratch);
            self.order.clear();
            self.order
                .extend(self.keys.iter().map(|k| (k & 0xffff_ffff) as u32));
        }
        let _span = tracing::trace_span!("bin", splats = splats.len(), tiles = n_tiles).entered();
        self.rects.clear();
        splats
            .par_iter()
            .with_min_len(1024)
            .map(|s| {
                s.as_ref()
                    .map(|s| grid.contributing_rect(s))
                    .unwrap_or_default()
            })
            .collect_into_vec(&mut self.rects);
        // Groups of whole tile rows, so each group owns one contiguous range of tiles.
        let groups = (rayon::current_num_threads() * 2).clamp(1, grid.rows.max(1));
        let rows_per_group = grid.rows.div_ceil(groups).max(1);
        self.sorted_rects.clear();
        self.sorted_rects
            .extend(self.order.iter().map(|&i| (self.rects[i as usize], i)));
        let rects = &self.rects;
        let sorted_rects = &self.sorted_rects;
        self.offsets.clear();
        self.offsets.resize(n_tiles + 1, 0);
        self.offsets[1..]
            .par_chunks_mut((rows_per_group * grid.cols).max(1))
            .enumerate()
            .for_each(|(g, counts)| {
                let (ty0, ty1) = (g * rows_per_group, (g + 1) * rows_per_group);
                for r in rects {
                    for ty in (r.y0 as usize).max(ty0)..(r.y1 as usize).min(ty1) {
                        let row = (ty - ty0) * grid.cols;
                        for c in &mut counts[row + r.x0 as usize..row + r.x1 as usize] {
                            *c += 1;
                        }
                    }
                }
            });
        let mut running = 0;
        for o in self.offsets.iter_mut() {
            running += *o;
            *o = running;
        }
        self.indices.clear();
        self.indices.resize(self.offsets[n_tiles], 0);
        // Split `indices` at the first tile of every group.
        let mut slices = Vec::with_capacity(groups);
        let mut rest = self.indices.as_mut_slice();
        let mut start = 0;
        for ty0 in (0..grid.rows).step_by(rows_per_group) {
            let end = self.offsets[((ty0 + rows_per_group).min(grid.rows)) * grid.cols];
            let (head, tail) = rest.split_at_mut(end - start);
            slices.push((ty0, head));
            rest = tail;
            start = end;
        }
        let offsets = &self.offsets;
        slices.into_par_iter().for_each(|(ty0, out)| {
            let ty1 = (ty0 + rows_per_group).min(grid.rows);
            let base = offsets[ty0 * grid.cols];
            let mut cursor: Vec<usize> = offsets[ty0 * grid.cols..ty1 * grid.cols]
                .iter()
                .map(|o| o - base)
                .collect();
            for &(r, i) in sorted_rects {
                for ty in (r.y0 as usize).max(ty0)..(r.y1 as usize).min(ty1) {
                    let row = (ty - ty0) * grid.cols;
                    for c in &mut cursor[row + r.x0 as usize..row + r.x1 as usize] {
                        out[*c] = i;
                        *c += 1;
                    }
                }
            }
        });
    }
}

/// Stable LSD radix sort of `keys` by their upper 32 bits (8 bits per pass; passes in which
/// every key has the same byte are skipped).
fn radix_sort_high_half(keys: &mut Vec<u64>, scratch: &mut Vec<u64>) {
    scratch.clear();
    scratch.resize(keys.len(), 0);
    for shift in [32u32, 40, 48, 56] {
        let mut counts = [0usize; 256];
        for k in keys.iter() {
            counts[((k >> shift) & 0xff) as usize] += 1;
        }
        if counts.contains(&keys.len()) {
            continue;
        }
        let mut running = 0;
        for c in counts.iter_mut() {
            let n = *c;
            *c = running;
            running += n;
        }
        for &k in keys.iter() {
            let b = ((k >> shift) & 0xff) as usize;
            scratch[counts[b]] = k;
            counts[b] += 1;
        }
        std::mem::swap(keys, scratch);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radix_sort_orders_by_the_high_half_and_keeps_ties_in_input_order() {
        let mut keys: Vec<u64> = (0..5000u64)
            .map(|i| (((i * 7919) % 613) << 32) | (i << 3))
            .collect();
        let mut want = keys.clone();
        want.sort_by_key(|k| k >> 32); // stable
        radix_sort_high_half(&mut keys, &mut Vec::new());
        assert_eq!(keys, want);
    }
}
