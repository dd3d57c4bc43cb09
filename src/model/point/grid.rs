//! Voxel grids of the point tokenizer: CenterShift, GridSample (1 cm, one point per voxel),
//! and the index side of GridPooling / GridUnpooling (voxel clustering by `grid // stride`).
//!
//! Index work is done on plain vectors with rayon; the learned parts (projections, LayerNorm,
//! max-reduce, scatter back) are in [`crate::model::point::pooling`].

use rayon::prelude::*;

/// Pack a non-negative grid cell (each axis < 2^21) into one sortable key, x most significant.
pub fn pack_cell(g: [u32; 3]) -> u64 {
    (u64::from(g[0]) << 42) | (u64::from(g[1]) << 21) | u64::from(g[2])
}

/// CenterShift(apply_z=True): x and y centred on the bounding-box centre, minimum z moved to 0.
pub fn center_shift(coords: &[[f32; 3]]) -> Vec<[f32; 3]> {
    if coords.is_empty() {
        return Vec::new();
    }
    let (lo, hi) = coords.iter().fold(
        ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]),
        |(mut lo, mut hi), c| {
            for d in 0..3 {
                lo[d] = lo[d].min(c[d]);
                hi[d] = hi[d].max(c[d]);
            }
            (lo, hi)
        },
    );
    let shift = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]];
    coords
        .iter()
        .map(|c| [c[0] - shift[0], c[1] - shift[1], c[2] - shift[2]])
        .collect()
}

/// Result of GridSample: one representative point per occupied voxel.
#[derive(Debug, Clone)]
pub struct GridSample {
    /// Voxel coordinates (relative to the minimum cell), one per voxel, sorted lexicographically.
    pub grid: Vec<[u32; 3]>,
    /// Index of the representative input point of each voxel (the first point that fell in it).
    pub keep: Vec<u32>,
    /// Input point → voxel index (`inverse` of the official transform).
    pub inverse: Vec<u32>,
}

/// GridSample at `grid_size`: `grid = floor(coord / grid_size) − min`, one voxel per occupied cell,
/// the lowest-index point of each cell kept (the official "train" mode picks a random one).
pub fn grid_sample(coords: &[[f32; 3]], grid_size: f32) -> GridSample {
    let cells: Vec<[i64; 3]> = coords
        .par_iter()
        .map(|c| {
            [
                (c[0] / grid_size).floor() as i64,
                (c[1] / grid_size).floor() as i64,
                (c[2] / grid_size).floor() as i64,
            ]
        })
        .collect();
    let mut min = [i64::MAX; 3];
    for c in &cells {
        for d in 0..3 {
            min[d] = min[d].min(c[d]);
        }
    }
    let grid_all: Vec<[u32; 3]> = cells
        .par_iter()
        .map(|c| {
            [
                (c[0] - min[0]) as u32,
                (c[1] - min[1]) as u32,
                (c[2] - min[2]) as u32,
            ]
        })
        .collect();
    let clusters = cluster_cells(&grid_all);
    let keep = clusters.heads.clone();
    GridSample {
        grid: clusters.cells,
        keep,
        inverse: clusters.cluster,
    }
}

/// Unique cells of a list, sorted lexicographically, with the member → cell map.
#[derive(Debug, Clone)]
pub struct Clusters {
    /// The unique cells.
    pub cells: Vec<[u32; 3]>,
    /// Member index → cell index.
    pub cluster: Vec<u32>,
    /// Lowest member index of each cell.
    pub heads: Vec<u32>,
    /// Members grouped by cell (cell-major, ascending member index inside a cell).
    pub members: Vec<u32>,
    /// `members[ptr[c]..ptr[c + 1]]` are the members of cell c.
    pub ptr: Vec<u32>,
}

impl Clusters {
    /// Largest number of members in one cell.
    pub fn max_count(&self) -> usize {
        self.ptr
            .windows(2)
            .map(|w| (w[1] - w[0]) as usize)
            .max()
            .unwrap_or(0)
    }
}

/// Group equal cells (the `torch.unique(..., sorted=True, return_inverse=True)` of the official code).
pub fn cluster_cells(grid: &[[u32; 3]]) -> Clusters {
    let mut keyed: Vec<(u64, u32)> = grid
        .par_iter()
        .enumerate()
        .map(|(i, &g)| (pack_cell(g), i as u32))
        .collect();
    keyed.par_sort_unstable();
    let mut cells = Vec::new();
    let mut heads = Vec::new();
    let mut ptr = vec![0u32];
    let mut cluster = vec![0u32; grid.len()];
    let mut members = Vec::with_capacity(grid.len());
    let mut last = None;
    for (k, &(key, i)) in keyed.iter().enumerate() {
        if last != Some(key) {
            if last.is_some() {
                ptr.push(k as u32);
            }
            last = Some(key);
            cells.push(grid[i as usize]);
            heads.push(i);
        }
        cluster[i as usize] = (cells.len() - 1) as u32;
        members.push(i);
    }
    if !keyed.is_empty() {
        ptr.push(keyed.len() as u32);
    }
    Clusters {
        cells,
        cluster,
        heads,
        members,
        ptr,
    }
}

/// GridPooling's index side: cluster the cells of one level by `grid // stride`.
pub fn pool_cells(grid: &[[u32; 3]], stride: u32) -> Clusters {
    let coarse: Vec<[u32; 3]> = grid
        .par_iter()
        .map(|g| [g[0] / stride, g[1] / stride, g[2] / stride])
        .collect();
    cluster_cells(&coarse)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::point::synthetic::body_surface_points;

    #[test]
    fn center_shift_centres_x_and_y_and_grounds_z() {
        let c = center_shift(&[[1.0, 2.0, 3.0], [3.0, 6.0, 5.0]]);
        assert_eq!(c, vec![[-1.0, -2.0, 0.0], [1.0, 2.0, 2.0]]);
    }

    #[test]
    fn grid_sample_keeps_the_first_point_of_each_voxel() {
        let pts = [
            [0.015, 0.0, 0.0],
            [0.001, 0.0, 0.0],
            [0.012, 0.001, 0.009],
            [0.0, 0.0, 0.0],
        ];
        let s = grid_sample(&pts, 0.01);
        assert_eq!(s.grid, vec![[0, 0, 0], [1, 0, 0]]);
        assert_eq!(s.keep, vec![1, 0]);
        assert_eq!(s.inverse, vec![1, 0, 1, 0]);
    }

    #[test]
    fn pooling_clusters_cover_every_cell_once() {
        let (pts, _) = body_surface_points(20_000, 3);
        let s = grid_sample(&pts, 0.01);
        let p = pool_cells(&s.grid, 2);
        let mut members = p.members.clone();
        members.sort_unstable();
        assert_eq!(members, (0..s.grid.len() as u32).collect::<Vec<_>>());
        for (i, &c) in p.cluster.iter().enumerate() {
            let g = s.grid[i];
            assert_eq!(p.cells[c as usize], [g[0] / 2, g[1] / 2, g[2] / 2]);
        }
        assert!(p.max_count() <= 8);
        assert_eq!(*p.ptr.last().unwrap() as usize, s.grid.len());
    }

    /// The paper's table (160K input): 24,377 (1 cm) → 6,441 (2 cm) → 1,686 (4 cm).
    #[test]
    fn body_cloud_token_counts_shrink_like_the_paper() {
        let (pts, _) = body_surface_points(160_000, 11);
        let shifted = center_shift(&pts);
        let s = grid_sample(&shifted, 0.01);
        let l1 = pool_cells(&s.grid, 1);
        let l2 = pool_cells(&l1.cells, 2);
        let l3 = pool_cells(&l2.cells, 2);
        let counts = [s.grid.len(), l1.cells.len(), l2.cells.len(), l3.cells.len()];
        eprintln!("token counts for 160K body points: {counts:?}");
        assert_eq!(counts[0], counts[1], "stride 1 keeps every voxel");
        assert!((15_000..=35_000).contains(&counts[0]), "{counts:?}");
        for w in counts[1..].windows(2) {
            let ratio = w[0] as f64 / w[1] as f64;
            assert!((3.0..=5.0).contains(&ratio), "{counts:?}");
        }
    }
}
