//! The PTv3 point backbone of LHM++ (`transformer.point_backbone.*`, Sonata's
//! `PointTransformerV3`): point tokenisation (CenterShift, 1 cm GridSample, stem, serialization),
//! encoder levels (GridPooling + PTv3 blocks) and decoder levels (GridUnpooling + PTv3 blocks).
//!
//! The stages are exposed one by one because the Point-Image Transformer interleaves them with
//! its multi-modal blocks, which replace the point features between stages ([`PointState::with_feat`]).

pub mod block;
pub mod grid;
pub mod pooling;
pub mod serialization;
pub mod sparse_conv;
pub mod synthetic;

use candle_core::{DType, Device, Result, Tensor};
use candle_nn::{Module, VarBuilder};

use crate::kernels::gelu::gelu_erf;
use crate::kernels::layer_norm::{layer_norm, LayerNorm};
use crate::kernels::linear::{linear, Linear};

use block::{PtBlock, LN_EPS};
use grid::{center_shift, grid_sample, pool_cells};
use pooling::{GridPooling, GridUnpooling, PoolingIndex};
pub use serialization::SerializationOrder;
use serialization::{serialize_all, Serialized};
use sparse_conv::NeighbourMap;

/// Misuse of the staged backbone API (stages called out of order, wrong shapes).
#[derive(Debug, thiserror::Error)]
pub enum PointError {
    /// A stage was called for a level the state is not at.
    #[error("point backbone: {stage} stage {level} called on a state at level {at}")]
    WrongLevel {
        /// `encoder` or `decoder`.
        stage: &'static str,
        /// Level asked for.
        level: usize,
        /// Level of the state.
        at: usize,
    },
    /// The level does not exist in this configuration.
    #[error("point backbone: no {stage} level {level} (config has {levels} levels)")]
    NoSuchLevel {
        /// `encoder` or `decoder`.
        stage: &'static str,
        /// Level asked for.
        level: usize,
        /// Number of encoder levels.
        levels: usize,
    },
    /// Inputs with mismatched shapes.
    #[error("point backbone: {what}")]
    Shape {
        /// What was wrong.
        what: String,
    },
}

fn fail(e: PointError) -> candle_core::Error {
    candle_core::Error::wrap(e)
}

/// Configuration of the point backbone; names mirror the official `point_backbone` config.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PointBackboneConfig {
    /// Input feature size: 6 = xyz + normal.
    pub in_channels: usize,
    /// GridSample voxel size in metres (0.01).
    pub grid_size: f32,
    /// Serialization orders; block i of a level attends in `order[i % len]`.
    pub order: Vec<SerializationOrder>,
    /// Pooling stride of encoder levels 1.. (one entry per pooling).
    pub stride: Vec<usize>,
    /// PTv3 blocks per encoder level.
    pub enc_depths: Vec<usize>,
    /// Channels per encoder level.
    pub enc_channels: Vec<usize>,
    /// Attention heads per encoder level.
    pub enc_num_head: Vec<usize>,
    /// Attention patch size per encoder level.
    pub enc_patch_size: Vec<usize>,
    /// PTv3 blocks per decoder level (index = level).
    pub dec_depths: Vec<usize>,
    /// Channels per decoder level.
    pub dec_channels: Vec<usize>,
    /// Attention heads per decoder level.
    pub dec_num_head: Vec<usize>,
    /// Attention patch size per decoder level.
    pub dec_patch_size: Vec<usize>,
    /// MLP hidden size / channels.
    pub mlp_ratio: f64,
}

impl PointBackboneConfig {
    /// The released LHMPP-700M backbone (= the paper's M; `configs/train/LHMPP-any-view.yaml`).
    pub fn lhmpp_700m() -> Self {
        Self {
            in_channels: 6,
            grid_size: 0.01,
            order: SerializationOrder::official(),
            stride: vec![1, 2, 2],
            enc_depths: vec![4, 4, 4, 4],
            enc_channels: vec![64, 128, 256, 512],
            enc_num_head: vec![4, 8, 16, 16],
            enc_patch_size: vec![4096, 4096, 2048, 1024],
            dec_depths: vec![4, 4, 4],
            dec_channels: vec![128, 256, 512],
            dec_num_head: vec![16, 16, 16],
            dec_patch_size: vec![4096, 4096, 2048],
            mlp_ratio: 4.0,
        }
    }

    /// A tiny backbone with the 700M topology (4 levels, strides [1,2,2]) for tests.
    pub fn tiny() -> Self {
        Self {
            in_channels: 6,
            grid_size: 0.01,
            order: SerializationOrder::official(),
            stride: vec![1, 2, 2],
            enc_depths: vec![1, 1, 1, 1],
            enc_channels: vec![16, 32, 32, 64],
            enc_num_head: vec![2, 2, 4, 4],
            enc_patch_size: vec![256, 256, 128, 64],
            dec_depths: vec![1, 1, 1],
            dec_channels: vec![32, 32, 64],
            dec_num_head: vec![2, 2, 4],
            dec_patch_size: vec![256, 256, 128],
            mlp_ratio: 4.0,
        }
    }

    /// LHM++ S (4 PI-MT layers = 2 encoder + 2 decoder levels): the 700M backbone cut to 3 levels.
    /// Not released; our reading of the paper's "number of PI-MT layers".
    pub fn small() -> Self {
        let m = Self::lhmpp_700m();
        Self {
            stride: vec![1, 2],
            enc_depths: m.enc_depths[..3].to_vec(),
            enc_channels: m.enc_channels[..3].to_vec(),
            enc_num_head: m.enc_num_head[..3].to_vec(),
            enc_patch_size: m.enc_patch_size[..3].to_vec(),
            dec_depths: m.dec_depths[..2].to_vec(),
            dec_channels: m.dec_channels[..2].to_vec(),
            dec_num_head: m.dec_num_head[..2].to_vec(),
            dec_patch_size: m.dec_patch_size[..2].to_vec(),
            ..m
        }
    }

    /// LHM++ L (8 PI-MT layers = 4 encoder + 4 decoder levels): the 700M backbone with a fifth
    /// level (stride 2, 512 channels). Not released; our reading of the paper.
    pub fn large() -> Self {
        let m = Self::lhmpp_700m();
        Self {
            stride: vec![1, 2, 2, 2],
            enc_depths: vec![4, 4, 4, 4, 4],
            enc_channels: vec![64, 128, 256, 512, 512],
            enc_num_head: vec![4, 8, 16, 16, 16],
            enc_patch_size: vec![4096, 4096, 2048, 1024, 512],
            dec_depths: vec![4, 4, 4, 4],
            dec_channels: vec![128, 256, 512, 512],
            dec_num_head: vec![16, 16, 16, 16],
            dec_patch_size: vec![4096, 4096, 2048, 1024],
            ..m
        }
    }

    /// Number of encoder levels (4 for the 700M model).
    pub fn num_levels(&self) -> usize {
        self.enc_channels.len()
    }

    /// Channels of the decoder output (the per-point feature size, 128 for the 700M model).
    pub fn out_channels(&self) -> usize {
        self.dec_channels
            .first()
            .copied()
            .unwrap_or(self.enc_channels[0])
    }
}

/// Geometry of one level: voxel cells, serializations, neighbour pairs for the sparse conv.
#[derive(Debug, Clone)]
struct Level {
    grid: Vec<[u32; 3]>,
    orders: Vec<Serialized>,
    neighbours: NeighbourMap,
}

impl Level {
    /// `perm`: the official order shuffle after a GridPooling (`orders[k]` becomes the
    /// serialization of `order[perm[k]]`); `None` keeps the config's order.
    fn new(
        grid: Vec<[u32; 3]>,
        order: &[SerializationOrder],
        perm: Option<&[usize]>,
        device: &Device,
    ) -> Result<Self> {
        let mut orders = serialize_all(&grid, order);
        if let Some(perm) = perm {
            let mut sorted = perm.to_vec();
            sorted.sort_unstable();
            if sorted != (0..orders.len()).collect::<Vec<_>>() {
                return Err(fail(PointError::Shape {
                    what: format!(
                        "order permutation {perm:?} is not a permutation of 0..{}",
                        orders.len()
                    ),
                }));
            }
            let mut slots: Vec<Option<Serialized>> = orders.into_iter().map(Some).collect();
            orders = perm
                .iter()
                .map(|&p| slots[p].take().expect("checked permutation"))
                .collect();
        }
        let neighbours = NeighbourMap::new(&grid, device)?;
        Ok(Self {
            grid,
            orders,
            neighbours,
        })
    }
}

/// A level left behind by pooling, kept for unpooling (the official `pooling_parent`).
#[derive(Debug, Clone)]
struct Parent {
    feat: Tensor,
    level: Level,
    index: PoolingIndex,
}

/// The points at the current level: features, grid, orders, the pooling stack and the map back
/// to the input points.
#[derive(Debug, Clone)]
pub struct PointState {
    feat: Tensor,
    level: Level,
    parents: Vec<Parent>,
    input_inverse: Tensor,
}

impl PointState {
    /// Features `[M, C]`.
    pub fn feat(&self) -> &Tensor {
        &self.feat
    }

    /// Replace the features (the multi-modal block does this between stages).
    pub fn with_feat(self, feat: Tensor) -> Self {
        Self { feat, ..self }
    }

    /// Hilbert-order permutation `u32 [M]` (sequence position → point), the MM block's sequence
    /// order (the official `mm_order`, taken before the order shuffle).
    pub fn hilbert_order(&self) -> Result<Tensor> {
        let device = self.feat.device();
        let hilbert = self
            .level
            .orders
            .iter()
            .find(|s| s.kind == SerializationOrder::Hilbert);
        let order = match hilbert {
            Some(s) => s.order.clone(),
            None => {
                let depth = serialization::serialization_depth(&self.level.grid);
                serialization::serialize(&self.level.grid, SerializationOrder::Hilbert, depth).order
            }
        };
        let n = order.len();
        Tensor::from_vec(order, n, device)
    }

    /// Per-voxel features `[M, C]` at level 0 → per-input-point features `[N, C]`.
    pub fn to_input_points(&self, feat: &Tensor) -> Result<Tensor> {
        let level0 = self
            .parents
            .first()
            .map_or(self.level.grid.len(), |p| p.level.grid.len());
        if feat.dim(0)? != level0 {
            return Err(fail(PointError::Shape {
                what: format!(
                    "to_input_points expects {level0} level-0 voxels, got features {:?}",
                    feat.dims()
                ),
            }));
        }
        feat.index_select(&self.input_inverse, 0)
    }

    /// Number of points at the current level.
    pub fn len(&self) -> usize {
        self.level.grid.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.level.grid.is_empty()
    }

    /// Voxel cells of the current level (in units of this level's voxel size).
    pub fn grid_coords(&self) -> &[[u32; 3]] {
        &self.level.grid
    }

    /// Number of pooling steps above the input level (the encoder level the state is at, before
    /// decoding).
    pub fn depth(&self) -> usize {
        self.parents.len()
    }
}

/// One encoder level: optional GridPooling (`down`) and PTv3 blocks.
#[derive(Debug, Clone)]
struct EncoderLevel {
    down: Option<(GridPooling, u32)>,
    blocks: Vec<PtBlock>,
}

/// One decoder level: GridUnpooling (`up`) and PTv3 blocks.
#[derive(Debug, Clone)]
struct DecoderLevel {
    up: GridUnpooling,
    blocks: Vec<PtBlock>,
}

/// The PTv3 point backbone (`transformer.point_backbone`).
#[derive(Debug, Clone)]
pub struct PointBackbone {
    cfg: PointBackboneConfig,
    stem_linear: Linear,
    stem_norm: LayerNorm,
    enc: Vec<EncoderLevel>,
    dec: Vec<DecoderLevel>,
    device: Device,
    dtype: DType,
}

fn blocks(
    depth: usize,
    channels: usize,
    heads: usize,
    patch: usize,
    cfg: &PointBackboneConfig,
    vb: &VarBuilder,
) -> Result<Vec<PtBlock>> {
    (0..depth)
        .map(|i| {
            PtBlock::new(
                channels,
                heads,
                patch,
                cfg.mlp_ratio,
                i % cfg.order.len().max(1),
                vb.pp(format!("block{i}")),
            )
        })
        .collect()
}

impl PointBackbone {
    /// Build from `vb = root.pp("transformer").pp("point_backbone")`.
    pub fn new(cfg: &PointBackboneConfig, vb: VarBuilder) -> Result<Self> {
        let levels = cfg.num_levels();
        let stem = vb.pp("embedding").pp("stem");
        let mut enc = Vec::with_capacity(levels);
        for l in 0..levels {
            let v = vb.pp("enc").pp(format!("enc{l}"));
            let c = cfg.enc_channels[l];
            let down = if l > 0 {
                let pool = GridPooling::new(cfg.enc_channels[l - 1], c, v.pp("down"))?;
                Some((pool, cfg.stride[l - 1] as u32))
            } else {
                None
            };
            let blocks = blocks(
                cfg.enc_depths[l],
                c,
                cfg.enc_num_head[l],
                cfg.enc_patch_size[l],
                cfg,
                &v,
            )?;
            enc.push(EncoderLevel { down, blocks });
        }
        let mut dec = Vec::with_capacity(levels.saturating_sub(1));
        for l in 0..levels.saturating_sub(1) {
            let v = vb.pp("dec").pp(format!("dec{l}"));
            let c_in = if l + 2 == levels {
                cfg.enc_channels[levels - 1]
            } else {
                cfg.dec_channels[l + 1]
            };
            let c = cfg.dec_channels[l];
            let up = GridUnpooling::new(c_in, cfg.enc_channels[l], c, v.pp("up"))?;
            let blocks = blocks(
                cfg.dec_depths[l],
                c,
                cfg.dec_num_head[l],
                cfg.dec_patch_size[l],
                cfg,
                &v,
            )?;
            dec.push(DecoderLevel { up, blocks });
        }
        let stem_linear = linear(cfg.in_channels, cfg.enc_channels[0], stem.pp("linear"))?;
        let dtype = stem_linear.weight().dtype();
        Ok(Self {
            cfg: cfg.clone(),
            stem_norm: layer_norm(cfg.enc_channels[0], LN_EPS, stem.pp("norm"))?,
            stem_linear,
            enc,
            dec,
            device: vb.device().clone(),
            dtype,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &PointBackboneConfig {
        &self.cfg
    }

    /// GridSample (1 cm, first point per voxel), CenterShift, stem Linear(6→C0)+LN+GELU,
    /// serialization. `coords`, `normals`: `[N, 3]` f32.
    pub fn embed(&self, coords: &Tensor, normals: &Tensor) -> Result<PointState> {
        let (n, three) = coords.dims2()?;
        if three != 3 || normals.dims() != [n, 3] {
            return Err(fail(PointError::Shape {
                what: format!(
                    "embed expects coords and normals [N, 3], got {:?} and {:?}",
                    coords.dims(),
                    normals.dims()
                ),
            }));
        }
        let to_rows = |t: &Tensor| -> Result<Vec<[f32; 3]>> {
            let flat = t.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?;
            Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        };
        let shifted = center_shift(&to_rows(coords)?);
        let normals = to_rows(normals)?;
        let sample = grid_sample(&shifted, self.cfg.grid_size);
        let m = sample.grid.len();
        let mut feat6 = Vec::with_capacity(m * 6);
        for &i in &sample.keep {
            feat6.extend_from_slice(&shifted[i as usize]);
            feat6.extend_from_slice(&normals[i as usize]);
        }
        let feat = Tensor::from_vec(feat6, (m, 6), &self.device)?.to_dtype(self.dtype)?;
        let feat = gelu_erf(&self.stem_norm.forward(&self.stem_linear.forward(&feat)?)?)?;
        let input_inverse = Tensor::from_vec(sample.inverse, n, &self.device)?;
        let level = Level::new(sample.grid, &self.cfg.order, None, &self.device)?;
        Ok(PointState {
            feat,
            level,
            parents: Vec::new(),
            input_inverse,
        })
    }

    /// Encoder level `level` (0..num_levels): GridPooling by `stride[level-1]` for level > 0
    /// (Linear+LN+GELU, max-reduce), then the PTv3 blocks; the pooled level keeps the config's
    /// order of serializations.
    pub fn encoder_stage(&self, level: usize, state: PointState) -> Result<PointState> {
        self.encoder_stage_ordered(level, state, None)
    }

    /// [`Self::encoder_stage`] with the pooled level's serializations permuted by `perm`
    /// (the official `torch.randperm` after GridPooling: block i attends in
    /// `order[perm[i % len]]`, here and in the decoder level that unpools back to this one).
    /// Ignored at level 0, which has no pooling.
    pub fn encoder_stage_ordered(
        &self,
        level: usize,
        state: PointState,
        perm: Option<&[usize]>,
    ) -> Result<PointState> {
        let stage = self.enc.get(level).ok_or_else(|| {
            fail(PointError::NoSuchLevel {
                stage: "encoder",
                level,
                levels: self.enc.len(),
            })
        })?;
        let expected_depth = level.saturating_sub(1);
        if state.parents.len() != expected_depth {
            return Err(fail(PointError::WrongLevel {
                stage: "encoder",
                level,
                at: state.parents.len(),
            }));
        }
        let mut state = state;
        if let Some((pool, stride)) = &stage.down {
            let clusters = pool_cells(&state.level.grid, *stride);
            let index = PoolingIndex::new(&clusters, &self.device)?;
            let feat = pool.forward(&state.feat, &index)?;
            let level = Level::new(clusters.cells, &self.cfg.order, perm, &self.device)?;
            state.parents.push(Parent {
                feat: state.feat,
                level: state.level,
                index,
            });
            state.feat = feat;
            state.level = level;
        }
        state.feat = run_blocks(&stage.blocks, state.feat, &state.level)?;
        Ok(state)
    }

    /// Decoder level `level` (num_levels−2 down to 0): GridUnpooling with the skip of encoder
    /// level `level` (proj + proj_skip), then the PTv3 blocks.
    pub fn decoder_stage(&self, level: usize, state: PointState) -> Result<PointState> {
        let stage = self.dec.get(level).ok_or_else(|| {
            fail(PointError::NoSuchLevel {
                stage: "decoder",
                level,
                levels: self.enc.len(),
            })
        })?;
        if state.parents.len() != level + 1 {
            return Err(fail(PointError::WrongLevel {
                stage: "decoder",
                level,
                at: state.parents.len(),
            }));
        }
        let mut state = state;
        let parent = state.parents.pop().expect("checked depth");
        let feat = stage
            .up
            .forward(&state.feat, &parent.feat, &parent.index.cluster)?;
        state.level = parent.level;
        state.feat = run_blocks(&stage.blocks, feat, &state.level)?;
        Ok(state)
    }

    /// Every stage in order: embed, encoder 0..L, decoder L−2..0 → per-voxel features `[M, C_out]`
    /// at level 0 (no multi-modal blocks; the PIT interleaves those).
    pub fn forward(&self, coords: &Tensor, normals: &Tensor) -> Result<PointState> {
        let mut s = self.embed(coords, normals)?;
        for l in 0..self.enc.len() {
            s = self.encoder_stage(l, s)?;
        }
        for l in (0..self.dec.len()).rev() {
            s = self.decoder_stage(l, s)?;
        }
        Ok(s)
    }
}

fn run_blocks(blocks: &[PtBlock], mut feat: Tensor, level: &Level) -> Result<Tensor> {
    for b in blocks {
        feat = b.forward(&feat, &level.orders, &level.neighbours)?;
    }
    Ok(feat)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::checkpoint::seeded_var_builder;
    use crate::testing::max_abs_diff;

    fn tiny_state(n: usize) -> (PointBackbone, PointState) {
        let cfg = PointBackboneConfig {
            enc_patch_size: vec![64, 64, 32, 16],
            ..PointBackboneConfig::tiny()
        };
        let vb = seeded_var_builder(5, DType::F32, &Device::Cpu);
        let bb = PointBackbone::new(&cfg, vb.pp("point_backbone")).unwrap();
        let (p, nrm) = synthetic::body_surface_points(n, 4);
        let dev = Device::Cpu;
        let coords = Tensor::from_vec(p.concat(), (n, 3), &dev).unwrap();
        let normals = Tensor::from_vec(nrm.concat(), (n, 3), &dev).unwrap();
        let s = bb.embed(&coords, &normals).unwrap();
        let s = bb.encoder_stage(0, s).unwrap();
        (bb, s)
    }

    #[test]
    fn pooling_order_permutation_picks_the_block_order_and_keeps_hilbert() {
        let (bb, s) = tiny_state(3_000);
        let plain = bb.encoder_stage(1, s.clone()).unwrap();
        let identity = bb
            .encoder_stage_ordered(1, s.clone(), Some(&[0, 1, 2, 3]))
            .unwrap();
        assert_eq!(max_abs_diff(plain.feat(), identity.feat()), 0.0);
        // Block 0 of the level attends in order perm[0]: Hilbert instead of Z changes the
        // patches (the level holds several), the MM sequence order stays Hilbert.
        let shuffled = bb
            .encoder_stage_ordered(1, s.clone(), Some(&[2, 0, 1, 3]))
            .unwrap();
        assert!(plain.len() > 2 * 64);
        assert!(max_abs_diff(plain.feat(), shuffled.feat()) > 1e-4);
        assert_eq!(
            plain.hilbert_order().unwrap().to_vec1::<u32>().unwrap(),
            shuffled.hilbert_order().unwrap().to_vec1::<u32>().unwrap()
        );
        assert!(bb.encoder_stage_ordered(1, s, Some(&[0, 0, 1, 2])).is_err());
    }
}
