//! Submanifold sparse 3×3×3 convolution on the active voxels of one level (spconv `SubMConv3d`).
//!
//! Weight layout as spconv 2.x stores it (KRSC): `[out, kx, ky, kz, in]`, kernel axes in the
//! `grid_coord` column order. `out[p] = b + Σ_{o ∈ {-1,0,1}³, p+o active} W[:, o+1, :] · in[p+o]`
//! (cross-correlation, as a dense conv3d). The neighbour pairs of a level are found once
//! ([`NeighbourMap::new`]) and reused by every block of that level (the official `indice_key`).

use std::collections::HashMap;

use candle_core::{DType, Device, IndexOp, Result, Tensor};
use candle_nn::VarBuilder;
use rayon::prelude::*;

use super::grid::pack_cell;
use crate::kernels::bf16::gathered::{GatheredProducts, OffsetPairs};
use crate::kernels::bf16::pack::Strided;
use crate::kernels::bf16::PackedRhs;

/// Index of the kernel offset `(dx, dy, dz)` ∈ {-1,0,1}³ in the flattened 27-entry kernel.
pub fn kernel_index(dx: i32, dy: i32, dz: i32) -> usize {
    ((dx + 1) * 9 + (dy + 1) * 3 + (dz + 1)) as usize
}

/// The centre offset (0, 0, 0).
const CENTRE: usize = 13;

/// Neighbour pairs of one level for the 26 non-centre kernel offsets, as device index tensors.
#[derive(Debug, Clone)]
pub struct NeighbourMap {
    /// For kernel offset k: the input rows (neighbours `p + o`); `None` when no pair exists.
    inputs: Vec<Option<Tensor>>,
    /// For all offsets concatenated in kernel order: the output rows `p`.
    outputs: Option<Tensor>,
    /// The same pairs on the host for the bf16 CPU kernel: the 26 non-centre offsets in
    /// kernel order (empty where no pair exists).
    host_pairs: Vec<OffsetPairs>,
    /// Number of active voxels.
    len: usize,
}

impl NeighbourMap {
    /// Find, for every active voxel and offset, the active neighbour (hash map of packed cells).
    pub fn new(grid: &[[u32; 3]], device: &Device) -> Result<Self> {
        let index: HashMap<u64, u32> = grid
            .iter()
            .enumerate()
            .map(|(i, &g)| (pack_cell(g), i as u32))
            .collect();
        let lookup = |g: [u32; 3], k: usize| -> Option<u32> {
            let o = [
                (k / 9) as i64 - 1,
                ((k / 3) % 3) as i64 - 1,
                (k % 3) as i64 - 1,
            ];
            let mut n = [0u32; 3];
            for d in 0..3 {
                let v = i64::from(g[d]) + o[d];
                if !(0..(1 << 21)).contains(&v) {
                    return None;
                }
                n[d] = v as u32;
            }
            index.get(&pack_cell(n)).copied()
        };
        let per_offset: Vec<(Vec<u32>, Vec<u32>)> = (0..27)
            .into_par_iter()
            .map(|k| {
                if k == CENTRE {
                    return (Vec::new(), Vec::new());
                }
                let mut ins = Vec::new();
                let mut outs = Vec::new();
                for (p, &g) in grid.iter().enumerate() {
                    if let Some(q) = lookup(g, k) {
                        ins.push(q);
                        outs.push(p as u32);
                    }
                }
                (ins, outs)
            })
            .collect();
        let mut inputs = Vec::with_capacity(27);
        let mut all_outputs = Vec::new();
        let mut host_pairs = Vec::with_capacity(26);
        for (k, (ins, outs)) in per_offset.into_iter().enumerate() {
            if ins.is_empty() {
                inputs.push(None);
            } else {
                let n = ins.len();
                inputs.push(Some(Tensor::from_slice(&ins, n, device)?));
                all_outputs.extend_from_slice(&outs);
            }
            if k != CENTRE {
                host_pairs.push(OffsetPairs {
                    inputs: ins,
                    outputs: outs,
                });
            }
        }
        let outputs = if all_outputs.is_empty() {
            None
        } else {
            let n = all_outputs.len();
            Some(Tensor::from_vec(all_outputs, n, device)?)
        };
        Ok(Self {
            inputs,
            outputs,
            host_pairs,
            len: grid.len(),
        })
    }

    /// Number of active voxels.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the level has no voxels.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Number of (output, input) pairs over the 26 non-centre offsets.
    pub fn pair_count(&self) -> usize {
        self.outputs.as_ref().map_or(0, |t| t.dim(0).unwrap_or(0))
    }
}

/// `SubMConv3d(c_in, c_out, kernel 3, bias)` (`cpe.0` of a PTv3 block).
#[derive(Debug, Clone)]
pub struct SubMConv3d {
    /// Per kernel offset, the weight as `[in, out]` (ready for `x · W`).
    weights: Vec<Tensor>,
    bias: Tensor,
    /// For a bf16 layer on the CPU: the centre weight, the 26 others in kernel order, packed
    /// for the bf16 kernel, and the bias in f32.
    packed: Option<std::sync::Arc<PackedBf16>>,
}

/// A layer's weights packed for [`GatheredProducts`].
#[derive(Debug)]
struct PackedBf16 {
    centre: PackedRhs,
    others: Vec<PackedRhs>,
    bias: Vec<f32>,
}

impl PackedBf16 {
    /// Packs `w [out, 27, in]` (bf16, CPU) and the bias.
    fn new(w: &Tensor, bias: &Tensor) -> Result<Self> {
        let (c_out, _, c_in) = w.dims3()?;
        let values = w.flatten_all()?.to_vec1::<half::bf16>()?;
        // Offset k's weight `[out, in]`: row o from `(o·27 + k)·in`.
        let offset = |k: usize| -> Result<PackedRhs> {
            let rows = Strided {
                data: &values[k * c_in..],
                col_stride: 27 * c_in,
                k_stride: 1,
            };
            PackedRhs::pack(rows, c_out, c_in)
        };
        Ok(Self {
            centre: offset(CENTRE)?,
            others: (0..27)
                .filter(|&k| k != CENTRE)
                .map(offset)
                .collect::<Result<_>>()?,
            bias: bias.to_dtype(DType::F32)?.to_vec1()?,
        })
    }
}

impl SubMConv3d {
    /// Load `weight [out, 3, 3, 3, in]` and `bias [out]`.
    pub fn new(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Self> {
        let w = vb.get_with_hints(
            (c_out, 3, 3, 3, c_in),
            "weight",
            candle_nn::init::DEFAULT_KAIMING_NORMAL,
        )?;
        let bias = vb.get_with_hints(c_out, "bias", candle_nn::Init::Const(0.0))?;
        Self::from_weights(&w, bias)
    }

    /// Build from a weight tensor `[out, 3, 3, 3, in]` and a bias `[out]`.
    pub fn from_weights(w: &Tensor, bias: Tensor) -> Result<Self> {
        let (c_out, _, _, _, c_in) = w.dims5()?;
        let w = w.reshape((c_out, 27, c_in))?;
        let weights = (0..27)
            .map(|k| w.i((.., k, ..))?.t()?.contiguous())
            .collect::<Result<Vec<_>>>()?;
        let packed = if w.device().is_cpu() && w.dtype() == DType::BF16 {
            Some(std::sync::Arc::new(PackedBf16::new(&w, &bias)?))
        } else {
            None
        };
        Ok(Self {
            weights,
            bias,
            packed,
        })
    }

    /// Convolve the features `[M, c_in]` of the voxels of `map` → `[M, c_out]`.
    /// A bf16 layer on the CPU runs the bf16 gathered-product kernel (f32 sums, one rounding);
    /// other layers run candle's products and `index_add`.
    pub fn forward(&self, x: &Tensor, map: &NeighbourMap) -> Result<Tensor> {
        if let (Some(p), true) = (&self.packed, x.device().is_cpu()) {
            let op = GatheredProducts {
                centre: &p.centre,
                weights: &p.others,
                pairs: &map.host_pairs,
                bias: &p.bias,
            };
            return x.contiguous()?.apply_op1_no_bwd(&op);
        }
        let mut out = x.matmul(&self.weights[CENTRE])?;
        if let Some(outputs) = &map.outputs {
            let mut parts = Vec::with_capacity(26);
            for (k, ins) in map.inputs.iter().enumerate() {
                if let Some(ins) = ins {
                    parts.push(x.index_select(ins, 0)?.matmul(&self.weights[k])?);
                }
            }
            let contributions = Tensor::cat(&parts, 0)?;
            out = out.index_add(outputs, &contributions, 0)?;
        }
        out.broadcast_add(&self.bias)
    }
}

/// Dense reference (tests only): `[M, c_in]` on a grid, by explicit loops.
#[cfg(test)]
fn dense_reference(
    grid: &[[u32; 3]],
    x: &[Vec<f32>],
    w: &[f32],
    b: &[f32],
    c_in: usize,
) -> Vec<Vec<f32>> {
    let c_out = b.len();
    let n = grid.iter().map(|g| g[0].max(g[1]).max(g[2])).max().unwrap() as usize + 3;
    let mut dense = vec![vec![0f32; c_in]; n * n * n];
    let at = |g: [i64; 3]| ((g[0] * n as i64 + g[1]) * n as i64 + g[2]) as usize;
    for (p, g) in grid.iter().enumerate() {
        dense[at([g[0] as i64 + 1, g[1] as i64 + 1, g[2] as i64 + 1])] = x[p].clone();
    }
    grid.iter()
        .map(|g| {
            let mut o = b.to_vec();
            for dx in -1..=1i64 {
                for dy in -1..=1i64 {
                    for dz in -1..=1i64 {
                        let v = &dense[at([
                            g[0] as i64 + 1 + dx,
                            g[1] as i64 + 1 + dy,
                            g[2] as i64 + 1 + dz,
                        ])];
                        let k = kernel_index(dx as i32, dy as i32, dz as i32);
                        for (co, oc) in o.iter_mut().enumerate().take(c_out) {
                            for (ci, vi) in v.iter().enumerate() {
                                *oc += w[(co * 27 + k) * c_in + ci] * vi;
                            }
                        }
                    }
                }
            }
            o
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn sparse_conv_matches_a_dense_3d_convolution_on_active_voxels() -> Result<()> {
        let dev = Device::Cpu;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut grid = Vec::new();
        for x in 0..6u32 {
            for y in 0..5u32 {
                for z in 0..4u32 {
                    if rng.gen::<f32>() < 0.45 {
                        grid.push([x, y, z]);
                    }
                }
            }
        }
        let (c_in, c_out) = (5, 7);
        // bf16-valued inputs and weights, so that the bf16 layer differs from the reference
        // by its f32 sums and one rounding of the output only.
        let round = |v: f32| half::bf16::from_f32(v).to_f32();
        let x: Vec<Vec<f32>> = (0..grid.len())
            .map(|_| (0..c_in).map(|_| round(rng.gen_range(-1.0..1.0))).collect())
            .collect();
        let w: Vec<f32> = (0..c_out * 27 * c_in)
            .map(|_| round(rng.gen_range(-1.0..1.0)))
            .collect();
        let b: Vec<f32> = (0..c_out)
            .map(|_| round(rng.gen_range(-1.0..1.0)))
            .collect();
        let map = NeighbourMap::new(&grid, &dev)?;
        assert!(map.pair_count() > 0);
        let want = dense_reference(&grid, &x, &w, &b, c_in);
        for (dtype, tol) in [(DType::F32, 1e-5f32), (DType::BF16, 0.06)] {
            let conv = SubMConv3d::from_weights(
                &Tensor::from_vec(w.clone(), (c_out, 3, 3, 3, c_in), &dev)?.to_dtype(dtype)?,
                Tensor::from_vec(b.clone(), c_out, &dev)?.to_dtype(dtype)?,
            )?;
            assert_eq!(conv.packed.is_some(), dtype == DType::BF16);
            let xt = Tensor::from_vec(x.concat(), (grid.len(), c_in), &dev)?.to_dtype(dtype)?;
            let y = conv.forward(&xt, &map)?;
            assert_eq!(y.dtype(), dtype);
            let got = y.to_dtype(DType::F32)?.to_vec2::<f32>()?;
            let mut max_diff = 0f32;
            for (g, w) in got.iter().zip(&want) {
                for (a, b) in g.iter().zip(w) {
                    max_diff = max_diff.max((a - b).abs());
                }
            }
            // bf16: outputs of up to ~10 are rounded to 8 bits of mantissa (≤ 0.03).
            assert!(max_diff < tol, "{dtype:?}: max abs diff {max_diff}");
        }
        Ok(())
    }

    #[test]
    fn an_isolated_voxel_sees_only_the_kernel_centre() -> Result<()> {
        let dev = Device::Cpu;
        let grid = vec![[0, 0, 0], [5, 5, 5]];
        let map = NeighbourMap::new(&grid, &dev)?;
        assert_eq!(map.pair_count(), 0);
        let w = Tensor::ones((1, 3, 3, 3, 1), candle_core::DType::F32, &dev)?;
        let conv = SubMConv3d::from_weights(&w, Tensor::zeros(1, candle_core::DType::F32, &dev)?)?;
        let y = conv.forward(&Tensor::new(&[[2f32], [3.0]], &dev)?, &map)?;
        assert_eq!(y.to_vec2::<f32>()?, vec![vec![2.0], vec![3.0]]);
        Ok(())
    }
}
