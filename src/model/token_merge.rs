//! ToMe-SD bipartite soft matching of image tokens with stride-sampled destinations.
//!
//! The tokens are seen as an `h × w` grid (LHM++ passes `w = W_patches · V`, `h = H_patches`
//! although the memory order is view-major: we reproduce that index-for-index). One destination
//! is chosen per `sy × sx = 2 × 2` cell: by default the top-left token of each cell (the
//! reference's `no_rand` option); [`TokenMerge::with_destinations`] replays the official random
//! draw (`torch.randint(4, (h/2, w/2, 1))`, see [`super::draws`]). Rows and columns left over by
//! the integer division stay sources. The `r` sources with the
//! highest cosine similarity (on the metric) to their best destination are merged into it by
//! mean; unmerge copies each destination's value back to its merged sources.

use candle_core::{DType, Device, Result, Tensor, D};

/// Destination stride along x and y.
pub const STRIDE: usize = 2;

/// A merge plan for one token set (batch size 1, tokens on dim 0).
#[derive(Debug, Clone)]
pub struct TokenMerge {
    n: usize,
    identity: bool,
    /// Rows of the kept (unmerged) sources, in output order.
    unm_rows: Tensor,
    /// Rows of the destinations, in output order.
    dst_rows: Tensor,
    /// Rows of the merged sources.
    src_rows: Tensor,
    /// For each merged source: its destination's index among the destinations.
    src_to_dst: Tensor,
    /// `1 / (1 + merged sources)` per destination, `[Nb, 1]`.
    dst_inv_count: Tensor,
    /// For every original token: its row in the merged output.
    unmerge_rows: Tensor,
    merged_len: usize,
}

/// Destination (b) and source (a) indices of an `h×w` grid, in the reference's sort order;
/// `draw[cell]` (row-major over the `h/2 × w/2` cells) is the destination's index `dy·2 + dx`
/// inside its cell, top-left (0) when `None`.
fn split_grid(h: usize, w: usize, draw: Option<&[u8]>) -> (Vec<usize>, Vec<usize>) {
    let (hsy, wsx) = (h / STRIDE, w / STRIDE);
    let mut dst = Vec::with_capacity(hsy * wsx);
    let mut src = Vec::with_capacity(h * w - hsy * wsx);
    // Stable argsort of the buffer (−1 at destinations, 0 elsewhere) in row-major order.
    for y in 0..h {
        for x in 0..w {
            let idx = y * w + x;
            let in_cells = y < hsy * STRIDE && x < wsx * STRIDE;
            let is_dst = in_cells && {
                let k = draw.map_or(0, |d| d[(y / STRIDE) * wsx + x / STRIDE] as usize);
                y % STRIDE == k / STRIDE && x % STRIDE == k % STRIDE
            };
            if is_dst {
                dst.push(idx);
            } else {
                src.push(idx);
            }
        }
    }
    (dst, src)
}

fn index(v: &[usize], dev: &Device) -> Result<Tensor> {
    Tensor::from_vec(
        v.iter().map(|&i| i as u32).collect::<Vec<_>>(),
        v.len(),
        dev,
    )
}

impl TokenMerge {
    /// Plans the merge of `r` tokens from `metric [N, C]` seen as an `h × w` grid (`N = h·w`),
    /// destinations at the top-left of each cell.
    pub fn new(metric: &Tensor, h: usize, w: usize, r: usize) -> Result<Self> {
        Self::with_destinations(metric, h, w, r, None)
    }

    /// [`Self::new`] with the destination of each 2×2 cell drawn: `draw` holds
    /// `(h/2)·(w/2)` values `dy·2 + dx` in `0..4`, row-major over the cells (`None`: top-left).
    pub fn with_destinations(
        metric: &Tensor,
        h: usize,
        w: usize,
        r: usize,
        draw: Option<&[u8]>,
    ) -> Result<Self> {
        let (n, _) = metric.dims2()?;
        let dev = metric.device();
        if n != h * w {
            candle_core::bail!("token merge: {n} tokens do not form a {h}x{w} grid");
        }
        if let Some(d) = draw {
            let cells = (h / STRIDE) * (w / STRIDE);
            if d.len() != cells || d.iter().any(|&k| k as usize >= STRIDE * STRIDE) {
                candle_core::bail!(
                    "token merge: a destination draw needs {cells} values in 0..4, got {}",
                    d.len()
                );
            }
        }
        let (b_idx, a_idx) = split_grid(h, w, draw);
        let r = r.min(a_idx.len());
        if r == 0 || b_idx.is_empty() {
            let all: Vec<usize> = (0..n).collect();
            let empty = index(&[], dev)?;
            return Ok(Self {
                n,
                identity: true,
                unm_rows: index(&all, dev)?,
                dst_rows: empty.clone(),
                src_rows: empty.clone(),
                src_to_dst: empty,
                dst_inv_count: Tensor::zeros((0, 1), DType::F32, dev)?,
                unmerge_rows: index(&all, dev)?,
                merged_len: n,
            });
        }
        let m = metric.to_dtype(DType::F32)?;
        let m = m.broadcast_div(&m.sqr()?.sum_keepdim(D::Minus1)?.sqrt()?)?;
        let a = m.index_select(&index(&a_idx, dev)?, 0)?;
        let b = m.index_select(&index(&b_idx, dev)?, 0)?;
        let scores = a.matmul(&b.t()?)?; // [Na, Nb]
        let node_max = scores.max(D::Minus1)?.to_vec1::<f32>()?;
        let node_idx = scores.argmax(D::Minus1)?.to_vec1::<u32>()?;
        let mut edge: Vec<usize> = (0..a_idx.len()).collect();
        edge.sort_by(|&i, &j| node_max[j].total_cmp(&node_max[i]));
        let (src_e, unm_e) = edge.split_at(r);
        let unm: Vec<usize> = unm_e.iter().map(|&e| a_idx[e]).collect();
        let src: Vec<usize> = src_e.iter().map(|&e| a_idx[e]).collect();
        let src_to_dst: Vec<usize> = src_e.iter().map(|&e| node_idx[e] as usize).collect();
        let mut counts = vec![1f32; b_idx.len()];
        for &d in &src_to_dst {
            counts[d] += 1.0;
        }
        let mut unmerge = vec![0usize; n];
        for (i, &row) in unm.iter().enumerate() {
            unmerge[row] = i;
        }
        for (j, &row) in b_idx.iter().enumerate() {
            unmerge[row] = unm.len() + j;
        }
        for (&row, &d) in src.iter().zip(&src_to_dst) {
            unmerge[row] = unm.len() + d;
        }
        let nb = b_idx.len();
        Ok(Self {
            n,
            identity: false,
            unm_rows: index(&unm, dev)?,
            dst_rows: index(&b_idx, dev)?,
            src_rows: index(&src, dev)?,
            src_to_dst: index(&src_to_dst, dev)?,
            dst_inv_count: Tensor::from_vec(
                counts.iter().map(|c| 1.0 / c).collect::<Vec<_>>(),
                (nb, 1),
                dev,
            )?,
            unmerge_rows: index(&unmerge, dev)?,
            merged_len: n - r,
        })
    }

    /// Tokens before merging.
    pub fn original_len(&self) -> usize {
        self.n
    }

    /// Tokens after merging (`N − r`).
    pub fn merged_len(&self) -> usize {
        self.merged_len
    }

    /// `x [N, C]` → `[N − r, C]`: unmerged sources first, then the (mean-merged) destinations.
    pub fn merge(&self, x: &Tensor) -> Result<Tensor> {
        if self.identity {
            return Ok(x.clone());
        }
        let unm = x.index_select(&self.unm_rows, 0)?;
        let dst = x.index_select(&self.dst_rows, 0)?;
        let src = x.index_select(&self.src_rows, 0)?;
        let sum = dst.index_add(&self.src_to_dst, &src, 0)?;
        let dst = sum.broadcast_mul(&self.dst_inv_count.to_dtype(x.dtype())?)?;
        Tensor::cat(&[unm, dst], 0)
    }

    /// `y [N − r, C]` → `[N, C]`: every merged source receives a copy of its destination.
    pub fn unmerge(&self, y: &Tensor) -> Result<Tensor> {
        if self.identity {
            return Ok(y.clone());
        }
        y.index_select(&self.unmerge_rows, 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tokens(n: usize, c: usize) -> Tensor {
        Tensor::randn(0f32, 1.0, (n, c), &Device::Cpu).unwrap()
    }

    fn max_abs(t: Tensor) -> f32 {
        t.abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap()
    }

    #[test]
    fn zero_ratio_is_the_identity() {
        let x = tokens(24, 5);
        let plan = TokenMerge::new(&x, 4, 6, 0).unwrap();
        assert_eq!(plan.merged_len(), 24);
        assert_eq!(
            max_abs((plan.unmerge(&plan.merge(&x).unwrap()).unwrap() - &x).unwrap()),
            0.0
        );
    }

    #[test]
    fn merged_token_equals_the_mean_of_its_group() {
        let metric = tokens(6 * 8, 4);
        let x = tokens(6 * 8, 3);
        let plan = TokenMerge::new(&metric, 6, 8, 20).unwrap();
        let merged = plan.merge(&x).unwrap();
        assert_eq!(merged.dims(), &[28, 3]);
        let unmerge = plan.unmerge_rows.to_vec1::<u32>().unwrap();
        let xs = x.to_vec2::<f32>().unwrap();
        let ms = merged.to_vec2::<f32>().unwrap();
        // Each output row is the mean of all original tokens that unmerge to it.
        for (row, m) in ms.iter().enumerate() {
            let group: Vec<usize> = (0..48).filter(|&i| unmerge[i] as usize == row).collect();
            assert!(!group.is_empty());
            for c in 0..3 {
                let mean = group.iter().map(|&i| xs[i][c]).sum::<f32>() / group.len() as f32;
                assert!((m[c] - mean).abs() < 1e-5, "row {row}: {} vs {mean}", m[c]);
            }
        }
        // 20 sources were merged, so 20 tokens share a row with some other token.
        let shared = (0..48)
            .filter(|&i| (0..48).any(|j| j != i && unmerge[j] == unmerge[i]))
            .count();
        assert!(shared >= 20);
    }

    #[test]
    fn unmerge_restores_shape_and_copies_destinations() {
        let metric = tokens(5 * 7, 4);
        let plan = TokenMerge::new(&metric, 5, 7, 10).unwrap();
        let y = tokens(plan.merged_len(), 2);
        let out = plan.unmerge(&y).unwrap();
        assert_eq!(out.dims(), &[35, 2]);
        // Merging a copy-unmerged tensor gives it back (groups hold equal values).
        assert!(max_abs((plan.merge(&out).unwrap() - &y).unwrap()) < 1e-6);
    }

    #[test]
    fn drawn_destinations_pick_the_token_inside_each_cell() {
        // 4x6 grid: 2x3 cells; draw (row-major cells) 3 = bottom-right, 1 = top-right, 2 = bottom-left.
        let draw = [3u8, 1, 2, 0, 0, 3];
        let (dst, src) = split_grid(4, 6, Some(&draw));
        assert_eq!(dst, vec![3, 7, 10, 12, 14, 23]);
        assert_eq!(dst.len() + src.len(), 24);
        assert_eq!(split_grid(4, 6, Some(&[0; 6])), split_grid(4, 6, None));
        // Odd sizes: the leftover row and column stay sources.
        let (dst, _) = split_grid(5, 5, Some(&[3, 3, 3, 3]));
        assert_eq!(dst, vec![6, 8, 16, 18]);
        let metric = tokens(24, 4);
        let plan = TokenMerge::with_destinations(&metric, 4, 6, 8, Some(&draw)).unwrap();
        let rows = plan.dst_rows.to_vec1::<u32>().unwrap();
        assert_eq!(rows, vec![3, 7, 10, 12, 14, 23]);
        assert!(TokenMerge::with_destinations(&metric, 4, 6, 8, Some(&[0; 5])).is_err());
        assert!(TokenMerge::with_destinations(&metric, 4, 6, 8, Some(&[4; 6])).is_err());
    }

    #[test]
    fn identical_tokens_merge_first() {
        // Sources that duplicate a destination have cosine 1 and must be the ones merged.
        let mut rows = vec![vec![0f32; 3]; 16];
        for (i, r) in rows.iter_mut().enumerate() {
            r[0] = (i as f32).sin();
            r[1] = (i as f32 * 1.7).cos();
            r[2] = i as f32 * 0.1 - 0.5;
        }
        rows[1] = rows[0].clone(); // token 1 (source) duplicates token 0 (a destination)
        let metric = Tensor::new(rows, &Device::Cpu).unwrap();
        let plan = TokenMerge::new(&metric, 4, 4, 1).unwrap();
        let unmerge = plan.unmerge_rows.to_vec1::<u32>().unwrap();
        assert_eq!(unmerge[0], unmerge[1]);
    }
}
