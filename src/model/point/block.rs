//! The PTv3 block (Sonata `Block`, pre-norm): conditional positional encoding
//! (`cpe` = SubMConv3d → Linear → LayerNorm, residual), serialized patch attention (`norm1`,
//! `attn.qkv`, `attn.proj`, residual) and an MLP (`norm2`, `mlp.0.fc1`, GELU, `mlp.0.fc2`, residual).

use candle_core::{DType, Result, Tensor};
use candle_nn::{Module, VarBuilder};

use crate::kernels::layer_norm::{layer_norm, LayerNorm};
use crate::kernels::linear::{linear, Linear};

use super::serialization::Serialized;
use super::sparse_conv::{NeighbourMap, SubMConv3d};
use crate::model::attention::attention;

/// LayerNorm epsilon of the official model (PyTorch default).
pub const LN_EPS: f64 = 1e-5;

/// Patch padding of PTv3's `get_padding_and_inverse` for one cloud of `n` points and patch `k`:
/// sequence slot → position in the serialized order. When `n > k` and `n` is not a multiple of
/// `k`, the tail of the last patch repeats the slots of the previous patch; when `n ≤ k` there is
/// one patch of `n`.
pub fn patch_padding(n: usize, k: usize) -> Vec<u32> {
    let n_pad = if n <= k { n } else { n.div_ceil(k) * k };
    let mut pad: Vec<u32> = (0..n_pad as u32).collect();
    if n_pad != n {
        let r = n % k;
        for s in (n_pad - k + r)..n_pad {
            pad[s] = pad[s - k];
        }
    }
    pad
}

/// `SerializedAttention` with patch attention (no RPE, no shuffling).
#[derive(Debug, Clone)]
pub struct SerializedAttention {
    qkv: Linear,
    proj: Linear,
    num_heads: usize,
    patch_size: usize,
}

impl SerializedAttention {
    /// `attn.qkv` (C → 3C, bias) and `attn.proj` (C → C).
    pub fn new(
        channels: usize,
        num_heads: usize,
        patch_size: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        Ok(Self {
            qkv: linear(channels, 3 * channels, vb.pp("qkv"))?,
            proj: linear(channels, channels, vb.pp("proj"))?,
            num_heads,
            patch_size,
        })
    }

    /// Attention inside patches of `patch_size` consecutive points of `order`; `x [M, C]`.
    pub fn forward(&self, x: &Tensor, order: &Serialized) -> Result<Tensor> {
        let out = self.attend(x, order)?;
        self.proj.forward(&out)
    }

    /// `residual + proj(attention(x))`, the add fused into the projection.
    pub fn forward_residual(
        &self,
        x: &Tensor,
        order: &Serialized,
        residual: &Tensor,
    ) -> Result<Tensor> {
        let out = self.attend(x, order)?;
        self.proj.forward_residual(&out, residual, None)
    }

    /// Patch attention before the output projection, back in input order `[M, C]`.
    fn attend(&self, x: &Tensor, order: &Serialized) -> Result<Tensor> {
        let (m, c) = x.dims2()?;
        let k = self.patch_size.min(m).max(1);
        let pad = patch_padding(m, self.patch_size);
        let n_pad = pad.len();
        let gather: Vec<u32> = pad.iter().map(|&s| order.order[s as usize]).collect();
        let device = x.device();
        let gather = Tensor::from_vec(gather, n_pad, device)?;
        let inverse = Tensor::from_slice(&order.inverse, m, device)?;
        let h = self.num_heads;
        let d = c / h;
        let patches = n_pad / k;
        let qkv = self
            .qkv
            .forward(x)?
            .index_select(&gather, 0)?
            .reshape((patches, k, 3, h, d))?
            .permute((2, 0, 3, 1, 4))?
            .contiguous()?;
        attention(&qkv.get(0)?, &qkv.get(1)?, &qkv.get(2)?, None)?
            .permute((0, 2, 1, 3))?
            .reshape((n_pad, c))?
            .index_select(&inverse, 0)
    }
}

/// One PTv3 block; `order_index` picks the serialization it attends in (block i uses order i % 4).
#[derive(Debug, Clone)]
pub struct PtBlock {
    cpe_conv: SubMConv3d,
    cpe_linear: Linear,
    cpe_norm: LayerNorm,
    norm1: LayerNorm,
    attn: SerializedAttention,
    norm2: LayerNorm,
    fc1: Linear,
    fc2: Linear,
    order_index: usize,
}

impl PtBlock {
    /// Load `cpe.{0,1,2}`, `norm1.0`, `attn.{qkv,proj}`, `norm2.0`, `mlp.0.{fc1,fc2}`.
    pub fn new(
        channels: usize,
        num_heads: usize,
        patch_size: usize,
        mlp_ratio: f64,
        order_index: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        let hidden = (channels as f64 * mlp_ratio) as usize;
        let cpe = vb.pp("cpe");
        let mlp = vb.pp("mlp").pp("0");
        Ok(Self {
            cpe_conv: SubMConv3d::new(channels, channels, cpe.pp("0"))?,
            cpe_linear: linear(channels, channels, cpe.pp("1"))?,
            cpe_norm: layer_norm(channels, LN_EPS, cpe.pp("2"))?,
            norm1: layer_norm(channels, LN_EPS, vb.pp("norm1").pp("0"))?,
            attn: SerializedAttention::new(channels, num_heads, patch_size, vb.pp("attn"))?,
            norm2: layer_norm(channels, LN_EPS, vb.pp("norm2").pp("0"))?,
            fc1: linear(channels, hidden, mlp.pp("fc1"))?,
            fc2: linear(hidden, channels, mlp.pp("fc2"))?,
            order_index,
        })
    }

    /// Index of the serialization order this block attends in.
    pub fn order_index(&self) -> usize {
        self.order_index
    }

    /// `x [M, C]` → `[M, C]` on the level described by `orders` and `neighbours`.
    ///
    /// The residual stream inside the block is f32 whatever `x`'s dtype: a bf16 model rounds
    /// it once, at the block's output, instead of after each of its three residual adds.
    pub fn forward(
        &self,
        x: &Tensor,
        orders: &[Serialized],
        neighbours: &NeighbourMap,
    ) -> Result<Tensor> {
        let dtype = x.dtype();
        let cpe = self.cpe_conv.forward(x, neighbours)?;
        let cpe = self.cpe_norm.forward(&self.cpe_linear.forward(&cpe)?)?;
        let stream = (x.to_dtype(DType::F32)? + cpe.to_dtype(DType::F32)?)?;
        let order = &orders[self.order_index % orders.len()];
        let normed = self.norm1.forward(&stream)?.to_dtype(dtype)?;
        let stream = self.attn.forward_residual(&normed, order, &stream)?;
        let normed = self.norm2.forward(&stream)?.to_dtype(dtype)?;
        let hdn = self.fc1.forward_gelu(&normed)?;
        self.fc2
            .forward_residual(&hdn, &stream, None)?
            .to_dtype(dtype)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::point::serialization::{serialize_all, SerializationOrder};
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    fn small_grid() -> Vec<[u32; 3]> {
        let mut g = Vec::new();
        for x in 0..5 {
            for y in 0..4 {
                for z in 0..3 {
                    g.push([x, y, z]);
                }
            }
        }
        g
    }

    fn attn(patch: usize, vm: &VarMap) -> Result<SerializedAttention> {
        let vb = VarBuilder::from_varmap(vm, DType::F32, &Device::Cpu);
        SerializedAttention::new(8, 2, patch, vb)
    }

    #[test]
    fn one_patch_attention_does_not_depend_on_the_order() -> Result<()> {
        let grid = small_grid();
        let orders = serialize_all(&grid, &SerializationOrder::official());
        let vm = VarMap::new();
        let a = attn(4096, &vm)?;
        let x = Tensor::randn(0f32, 1.0, (grid.len(), 8), &Device::Cpu)?;
        let z = a.forward(&x, &orders[0])?;
        let h = a.forward(&x, &orders[2])?;
        let d = (z - h)?.abs()?.flatten_all()?.max(0)?.to_scalar::<f32>()?;
        assert!(d < 1e-5, "{d}");
        Ok(())
    }

    #[test]
    fn small_patches_attend_locally_along_the_order() -> Result<()> {
        let grid = small_grid();
        let orders = serialize_all(&grid, &SerializationOrder::official());
        let vm = VarMap::new();
        let a = attn(16, &vm)?;
        let x = Tensor::randn(0f32, 1.0, (grid.len(), 8), &Device::Cpu)?;
        let z = a.forward(&x, &orders[0])?;
        let h = a.forward(&x, &orders[2])?;
        let d = (&z - h)?.abs()?.flatten_all()?.max(0)?.to_scalar::<f32>()?;
        assert!(d > 1e-4, "different patches must give different outputs");
        // changing a point outside the first Z patch leaves the first patch's outputs unchanged
        let first_patch: Vec<u32> = orders[0].order[..16].to_vec();
        let outsider = orders[0].order[40] as usize;
        let mut xv = x.to_vec2::<f32>()?;
        xv[outsider] = vec![5.0; 8];
        let x2 = Tensor::new(xv, &Device::Cpu)?;
        let z2 = a.forward(&x2, &orders[0])?;
        let idx = Tensor::new(first_patch.as_slice(), &Device::Cpu)?;
        let d = (z.index_select(&idx, 0)? - z2.index_select(&idx, 0)?)?
            .abs()?
            .flatten_all()?
            .max(0)?
            .to_scalar::<f32>()?;
        assert_eq!(d, 0.0);
        Ok(())
    }

    #[test]
    fn padding_repeats_the_previous_patch_slots() {
        assert_eq!(patch_padding(3, 4), vec![0, 1, 2]);
        assert_eq!(patch_padding(8, 4), (0..8).collect::<Vec<_>>());
        // n = 10, k = 4: n_pad 12, last patch = slots 8, 9 then 6, 7 of the previous patch
        assert_eq!(
            patch_padding(10, 4),
            vec![0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 6, 7]
        );
    }
}
