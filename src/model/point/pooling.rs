//! The learned halves of Sonata's GridPooling (`down`: Linear → max over each cluster →
//! LayerNorm → GELU) and GridUnpooling (`up`: `GELU(LN(proj_skip(parent)))` plus
//! `GELU(LN(proj(child)))` scattered back by cluster index).

use candle_core::{Device, Result, Tensor};
use candle_nn::{Module, VarBuilder};

use crate::kernels::gelu::gelu_erf;
use crate::kernels::layer_norm::{layer_norm, LayerNorm};
use crate::kernels::linear::{linear, Linear};

use super::block::LN_EPS;
use super::grid::Clusters;

/// Row indices `[clusters, max_count]` for a padded segment reduce: each cluster's members,
/// padded by repeating its first member (max is unchanged by repeats).
pub fn segment_table(clusters: &Clusters) -> (Vec<u32>, usize) {
    let width = clusters.max_count().max(1);
    let mut table = Vec::with_capacity(clusters.cells.len() * width);
    for w in clusters.ptr.windows(2) {
        let members = &clusters.members[w[0] as usize..w[1] as usize];
        for j in 0..width {
            table.push(members[j.min(members.len() - 1)]);
        }
    }
    (table, width)
}

/// Index tensors of one pooling step, on the device.
#[derive(Debug, Clone)]
pub struct PoolingIndex {
    /// Padded member table, flattened `[clusters * width]`.
    table: Tensor,
    width: usize,
    clusters: usize,
    /// Parent point → cluster (the official `pooling_inverse`).
    pub cluster: Tensor,
}

impl PoolingIndex {
    /// Upload the index side of a pooling step.
    pub fn new(c: &Clusters, device: &Device) -> Result<Self> {
        let (table, width) = segment_table(c);
        let n = table.len();
        Ok(Self {
            table: Tensor::from_vec(table, n, device)?,
            width,
            clusters: c.cells.len(),
            cluster: Tensor::from_slice(&c.cluster, c.cluster.len(), device)?,
        })
    }

    /// Max of the rows of `x [M, C]` over each cluster → `[clusters, C]`.
    pub fn segment_max(&self, x: &Tensor) -> Result<Tensor> {
        let c = x.dim(1)?;
        let g = x.index_select(&self.table, 0)?;
        if self.width == 1 {
            return Ok(g);
        }
        g.reshape((self.clusters, self.width, c))?.max(1)
    }
}

/// `enc.enc{l}.down`: `proj` (Linear) and `norm.0` (LayerNorm), then GELU.
#[derive(Debug, Clone)]
pub struct GridPooling {
    proj: Linear,
    norm: LayerNorm,
}

impl GridPooling {
    /// Load `proj` (c_in → c_out) and `norm.0`.
    pub fn new(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            proj: linear(c_in, c_out, vb.pp("proj"))?,
            norm: layer_norm(c_out, LN_EPS, vb.pp("norm").pp("0"))?,
        })
    }

    /// Parent features `[M, c_in]` → cluster features `[clusters, c_out]`.
    pub fn forward(&self, x: &Tensor, index: &PoolingIndex) -> Result<Tensor> {
        let pooled = index.segment_max(&self.proj.forward(x)?)?;
        gelu_erf(&self.norm.forward(&pooled)?)
    }
}

/// `dec.dec{l}.up`: `proj.{0,1}` on the child, `proj_skip.{0,1}` on the parent (Linear + LN + GELU each).
#[derive(Debug, Clone)]
pub struct GridUnpooling {
    proj: Linear,
    proj_norm: LayerNorm,
    skip: Linear,
    skip_norm: LayerNorm,
}

impl GridUnpooling {
    /// Load `proj.0` (c_in → c_out), `proj.1`, `proj_skip.0` (c_skip → c_out), `proj_skip.1`.
    pub fn new(c_in: usize, c_skip: usize, c_out: usize, vb: VarBuilder) -> Result<Self> {
        let p = vb.pp("proj");
        let s = vb.pp("proj_skip");
        Ok(Self {
            proj: linear(c_in, c_out, p.pp("0"))?,
            proj_norm: layer_norm(c_out, LN_EPS, p.pp("1"))?,
            skip: linear(c_skip, c_out, s.pp("0"))?,
            skip_norm: layer_norm(c_out, LN_EPS, s.pp("1"))?,
        })
    }

    /// Child features `[clusters, c_in]` and parent features `[M, c_skip]` → `[M, c_out]`.
    pub fn forward(&self, child: &Tensor, parent: &Tensor, cluster: &Tensor) -> Result<Tensor> {
        let skip = gelu_erf(&self.skip_norm.forward(&self.skip.forward(parent)?)?)?;
        let up = gelu_erf(&self.proj_norm.forward(&self.proj.forward(child)?)?)?;
        skip + up.index_select(cluster, 0)?
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::point::grid::pool_cells;

    #[test]
    fn segment_max_takes_the_largest_member_per_cluster() -> Result<()> {
        let dev = Device::Cpu;
        let grid = vec![[0, 0, 0], [1, 1, 1], [2, 0, 0], [3, 1, 0], [0, 1, 0]];
        let c = pool_cells(&grid, 2);
        assert_eq!(c.cells, vec![[0, 0, 0], [1, 0, 0]]);
        let idx = PoolingIndex::new(&c, &dev)?;
        let x = Tensor::new(
            &[
                [1f32, -5.0],
                [4.0, 0.0],
                [2.0, 2.0],
                [-1.0, 7.0],
                [0.0, 3.0],
            ],
            &dev,
        )?;
        assert_eq!(
            idx.segment_max(&x)?.to_vec2::<f32>()?,
            vec![vec![4.0, 3.0], vec![2.0, 7.0]]
        );
        Ok(())
    }
}
