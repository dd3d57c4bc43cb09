//! The official diffused skinning volume (`voxel_grid/cano_1_volume.npz`, FITE's
//! `CanoBlendWeightVolume`): `diff_weight_volume` `[X, Y, Z, J]` dense weights over the box
//! `volume_bounds` `[[min x, y, z], [max x, y, z]]` (SMPL-X model frame, neutral pose).
//!
//! Lookup follows `F.grid_sample(..., align_corners=True, padding_mode="border")`: a point is
//! normalised by the bounds, node `i` of an axis sits at `i / (res − 1)`, points outside are
//! clamped to the border, and the 8 surrounding nodes are blended trilinearly. The dense
//! weights are then reduced to the strongest [`MAX_INFLUENCES`] joints, renormalised.

use std::path::Path;

use candle_core::{npy::NpzTensors, DType};
use glam::Vec3;

use crate::body::{BodyError, MAX_INFLUENCES};

/// A dense skinning-weight volume.
#[derive(Debug, Clone, PartialEq)]
pub struct BlendWeightVolume {
    /// Nodes along x, y, z.
    pub dims: [usize; 3],
    /// Joints (weights per node).
    pub joints: usize,
    /// Lower corner (first node).
    pub lo: Vec3,
    /// Upper corner (last node).
    pub hi: Vec3,
    /// `[x][y][z][joint]`, row-major.
    data: Vec<f32>,
}

impl BlendWeightVolume {
    /// A volume from dense data laid out `[x][y][z][joint]`; `origin` names the source in
    /// errors.
    pub fn from_dense(
        dims: [usize; 3],
        joints: usize,
        lo: Vec3,
        hi: Vec3,
        data: Vec<f32>,
        origin: &str,
    ) -> Result<Self, BodyError> {
        let n = dims.iter().product::<usize>() * joints;
        if data.len() != n || n == 0 {
            return Err(BodyError::format(
                origin,
                format!(
                    "`diff_weight_volume` holds {} values, {dims:?}×{joints} expected",
                    data.len()
                ),
            ));
        }
        if !(hi - lo).cmpgt(Vec3::ZERO).all() || dims.iter().any(|&d| d < 2) {
            return Err(BodyError::format(
                origin,
                format!("`volume_bounds` {lo}..{hi} or grid {dims:?} is degenerate"),
            ));
        }
        Ok(Self {
            dims,
            joints,
            lo,
            hi,
            data,
        })
    }

    /// Loads `diff_weight_volume` and `volume_bounds` from the official npz.
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let origin = path.display().to_string();
        let npz = NpzTensors::new(path).map_err(|e| BodyError::format(&origin, e.to_string()))?;
        let get = |key: &str| {
            npz.get(key)
                .map_err(|e| BodyError::format(&origin, format!("`{key}`: {e}")))?
                .ok_or_else(|| BodyError::missing(&origin, key))
        };
        let bad =
            |key: &str, e: candle_core::Error| BodyError::format(&origin, format!("`{key}`: {e}"));
        let vol = get("diff_weight_volume")?;
        let d = vol.dims().to_vec();
        if d.len() != 4 {
            return Err(BodyError::format(
                &origin,
                format!("`diff_weight_volume` is {d:?}, expected [X, Y, Z, joints]"),
            ));
        }
        let data = vol
            .to_dtype(DType::F32)
            .and_then(|t| t.flatten_all())
            .and_then(|t| t.to_vec1::<f32>())
            .map_err(|e| bad("diff_weight_volume", e))?;
        let bounds = get("volume_bounds")?
            .to_dtype(DType::F32)
            .and_then(|t| t.flatten_all())
            .and_then(|t| t.to_vec1::<f32>())
            .map_err(|e| bad("volume_bounds", e))?;
        if bounds.len() != 6 {
            return Err(BodyError::format(
                &origin,
                format!("`volume_bounds` has {} values, expected 2×3", bounds.len()),
            ));
        }
        Self::from_dense(
            [d[0], d[1], d[2]],
            d[3],
            Vec3::from_slice(&bounds[..3]),
            Vec3::from_slice(&bounds[3..]),
            data,
            &origin,
        )
    }

    /// Dense interpolated weights at `p` (model frame), one per joint.
    pub fn weights(&self, p: Vec3) -> Vec<f32> {
        let t = ((p - self.lo) / (self.hi - self.lo)).clamp(Vec3::ZERO, Vec3::ONE);
        let g = t * Vec3::new(
            (self.dims[0] - 1) as f32,
            (self.dims[1] - 1) as f32,
            (self.dims[2] - 1) as f32,
        );
        let base = g.floor();
        let f = g - base;
        let mut out = vec![0f32; self.joints];
        for corner in 0..8usize {
            let o = [corner & 1, (corner >> 1) & 1, corner >> 2];
            let mut idx = [0usize; 3];
            let mut w = 1.0;
            for a in 0..3 {
                idx[a] = (base[a] as usize + o[a]).min(self.dims[a] - 1);
                w *= if o[a] == 1 { f[a] } else { 1.0 - f[a] };
            }
            if w <= 0.0 {
                continue;
            }
            let node = ((idx[0] * self.dims[1] + idx[1]) * self.dims[2] + idx[2]) * self.joints;
            for (o, v) in out.iter_mut().zip(&self.data[node..node + self.joints]) {
                *o += w * v;
            }
        }
        out
    }

    /// The strongest [`MAX_INFLUENCES`] joints at `p`, renormalised; `None` when every weight
    /// is zero or negative.
    pub fn top_weights(&self, p: Vec3) -> Option<([u16; MAX_INFLUENCES], [f32; MAX_INFLUENCES])> {
        let dense = self.weights(p);
        let mut idx: Vec<usize> = (0..dense.len()).collect();
        idx.sort_by(|a, b| dense[*b].total_cmp(&dense[*a]).then(a.cmp(b)));
        let mut bones = [0u16; MAX_INFLUENCES];
        let mut weights = [0f32; MAX_INFLUENCES];
        let mut sum = 0.0;
        for (k, &j) in idx.iter().take(MAX_INFLUENCES).enumerate() {
            if dense[j] > 0.0 {
                bones[k] = j as u16;
                weights[k] = dense[j];
                sum += dense[j];
            }
        }
        if sum <= 0.0 {
            return None;
        }
        weights.iter_mut().for_each(|w| *w /= sum);
        Some((bones, weights))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 3×2×2 grid over [0,2]×[0,1]×[0,1], 2 joints: joint 1's weight equals x / 2.
    fn ramp() -> BlendWeightVolume {
        let mut data = Vec::new();
        for x in 0..3 {
            for _y in 0..2 {
                for _z in 0..2 {
                    let w1 = x as f32 / 2.0;
                    data.extend([1.0 - w1, w1]);
                }
            }
        }
        BlendWeightVolume::from_dense(
            [3, 2, 2],
            2,
            Vec3::ZERO,
            Vec3::new(2.0, 1.0, 1.0),
            data,
            "t",
        )
        .unwrap()
    }

    #[test]
    fn lookup_is_trilinear_inside_and_clamped_outside() {
        let v = ramp();
        let w = v.weights(Vec3::new(0.5, 0.3, 0.9));
        assert!(
            (w[1] - 0.25).abs() < 1e-6 && (w[0] - 0.75).abs() < 1e-6,
            "{w:?}"
        );
        assert_eq!(v.weights(Vec3::new(9.0, -4.0, 0.5)), vec![0.0, 1.0]);
        assert_eq!(v.weights(Vec3::new(-9.0, 0.5, 7.0)), vec![1.0, 0.0]);
    }

    #[test]
    fn top_weights_keep_the_strongest_joints_normalised() {
        let v = ramp();
        let (b, w) = v.top_weights(Vec3::new(1.5, 0.5, 0.5)).unwrap();
        assert_eq!(b[0], 1);
        assert!((w[0] - 0.75).abs() < 1e-6 && (w[1] - 0.25).abs() < 1e-6);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn wrong_sizes_are_rejected_with_the_source_named() {
        let err = BlendWeightVolume::from_dense(
            [2, 2, 2],
            2,
            Vec3::ZERO,
            Vec3::ONE,
            vec![0.0; 3],
            "vol.npz",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("vol.npz"), "{err}");
    }
}
