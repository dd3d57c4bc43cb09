//! PTv3 point backbone configuration (placeholder owned by `model-points`).
//!
//! This file only carries the agreed `PointBackboneConfig` interface so that the image side
//! compiles before the point backbone is merged; on merge, `model-points`' version wins.

use serde::{Deserialize, Serialize};

/// Space-filling-curve orders used to serialize the point cloud.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SerializationOrder {
    /// Morton (z-order) curve on (x, y, z).
    Z,
    /// Morton curve on (y, x, z).
    ZTrans,
    /// Hilbert curve on (x, y, z).
    Hilbert,
    /// Hilbert curve on (y, x, z).
    HilbertTrans,
}

/// Mirrors the official `point_backbone` config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointBackboneConfig {
    /// Input channels: 6 = xyz + normal.
    pub in_channels: usize,
    /// GridSample voxel size in metres.
    pub grid_size: f32,
    /// Serialization orders.
    pub order: Vec<SerializationOrder>,
    /// Pooling stride of enc1..encN.
    pub stride: Vec<usize>,
    /// PTv3 blocks per encoder level.
    pub enc_depths: Vec<usize>,
    /// Channels per encoder level.
    pub enc_channels: Vec<usize>,
    /// Attention heads per encoder level.
    pub enc_num_head: Vec<usize>,
    /// Patch size per encoder level.
    pub enc_patch_size: Vec<usize>,
    /// PTv3 blocks per decoder level.
    pub dec_depths: Vec<usize>,
    /// Channels per decoder level.
    pub dec_channels: Vec<usize>,
    /// Attention heads per decoder level.
    pub dec_num_head: Vec<usize>,
    /// Patch size per decoder level.
    pub dec_patch_size: Vec<usize>,
    /// MLP hidden ratio.
    pub mlp_ratio: f64,
}

fn orders() -> Vec<SerializationOrder> {
    use SerializationOrder::*;
    vec![Z, ZTrans, Hilbert, HilbertTrans]
}

impl PointBackboneConfig {
    /// The official LHMPP-700M point backbone.
    pub fn lhmpp_700m() -> Self {
        Self {
            in_channels: 6,
            grid_size: 0.01,
            order: orders(),
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

    /// A tiny backbone for tests.
    pub fn tiny() -> Self {
        Self {
            in_channels: 6,
            grid_size: 0.01,
            order: orders(),
            stride: vec![1, 2, 2],
            enc_depths: vec![1, 1, 1, 1],
            enc_channels: vec![16, 32, 64, 64],
            enc_num_head: vec![1, 2, 4, 4],
            enc_patch_size: vec![1024, 1024, 512, 256],
            dec_depths: vec![1, 1, 1],
            dec_channels: vec![32, 64, 64],
            dec_num_head: vec![2, 4, 4],
            dec_patch_size: vec![1024, 1024, 512],
            mlp_ratio: 4.0,
        }
    }

    /// The S backbone (two encoder–decoder PIT levels).
    pub fn small() -> Self {
        Self {
            stride: vec![1, 2],
            enc_depths: vec![4, 4, 4],
            enc_channels: vec![64, 128, 256],
            enc_num_head: vec![4, 8, 16],
            enc_patch_size: vec![4096, 4096, 2048],
            dec_depths: vec![4, 4],
            dec_channels: vec![128, 256],
            dec_num_head: vec![16, 16],
            dec_patch_size: vec![4096, 4096],
            ..Self::lhmpp_700m()
        }
    }

    /// The L backbone (four encoder–decoder PIT levels).
    pub fn large() -> Self {
        Self {
            stride: vec![1, 2, 2, 2],
            enc_depths: vec![4, 4, 4, 4, 4],
            enc_channels: vec![64, 128, 256, 512, 512],
            enc_num_head: vec![4, 8, 16, 16, 16],
            enc_patch_size: vec![4096, 4096, 2048, 1024, 1024],
            dec_depths: vec![4, 4, 4, 4],
            dec_channels: vec![128, 256, 512, 512],
            dec_num_head: vec![16, 16, 16, 16],
            dec_patch_size: vec![4096, 4096, 2048, 1024],
            ..Self::lhmpp_700m()
        }
    }
}
