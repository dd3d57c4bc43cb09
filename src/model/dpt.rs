//! DPT neural renderer configuration (placeholder owned by `model-points`).
//!
//! Carries only the agreed `DptConfig` interface so the image side compiles before the
//! renderer is merged; on merge, `model-points`' version wins.

use serde::{Deserialize, Serialize};

/// Mirrors the official `neural_renderer` (patch_4dptonly) config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DptConfig {
    /// Feature channels of the splatted map (128).
    pub in_channels: usize,
    /// Patchify size (7).
    pub patch_size: usize,
    /// Token dimension after patchify (1024).
    pub embed_dim: usize,
    /// DPT fusion features (128).
    pub features: usize,
    /// DPT per-level channels.
    pub out_channels: [usize; 4],
}

impl DptConfig {
    /// The official LHMPP-700M renderer.
    pub fn lhmpp_700m() -> Self {
        Self {
            in_channels: 128,
            patch_size: 7,
            embed_dim: 1024,
            features: 128,
            out_channels: [128, 256, 512, 512],
        }
    }

    /// A tiny renderer for tests.
    pub fn tiny() -> Self {
        Self {
            in_channels: 32,
            patch_size: 7,
            embed_dim: 64,
            features: 16,
            out_channels: [16, 32, 64, 64],
        }
    }
}
