//! Sparse skinning weights and linear blend skinning of points.

use glam::{Mat4, Vec3};

/// Most bones that influence one vertex or point (top-k, renormalised).
pub const MAX_INFLUENCES: usize = 4;

/// Per-element sparse skinning weights: `bones[i][k]` with weight `weights[i][k]`; unused
/// slots have weight 0; each row's weights sum to 1.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SkinWeights {
    /// Bone indices per element.
    pub bones: Vec<[u16; MAX_INFLUENCES]>,
    /// Weights per element, non-negative, summing to 1.
    pub weights: Vec<[f32; MAX_INFLUENCES]>,
}

impl SkinWeights {
    /// Number of skinned elements.
    pub fn len(&self) -> usize {
        self.bones.len()
    }

    /// True when no element is skinned.
    pub fn is_empty(&self) -> bool {
        self.bones.is_empty()
    }

    /// The blended skinning matrix of element `i` given per-bone skinning matrices.
    #[inline]
    pub fn blended(&self, i: usize, matrices: &[Mat4]) -> Mat4 {
        // Σ w_k M_k written as M_0 + Σ w_k (M_k − M_0) (equal since Σ w_k = 1): bones that
        // share one matrix (e.g. all at rest) give exactly that matrix, not a rounded blend.
        let (b, w) = (&self.bones[i], &self.weights[i]);
        let m0 = matrices[b[0] as usize];
        let mut m = m0;
        for k in 1..MAX_INFLUENCES {
            if w[k] != 0.0 {
                let mk = matrices[b[k] as usize];
                if mk != m0 {
                    m += (mk - m0) * w[k];
                }
            }
        }
        m
    }

    /// Moves canonical points by linear blend skinning.
    pub fn skin_points(&self, points: &[Vec3], matrices: &[Mat4]) -> Vec<Vec3> {
        assert_eq!(points.len(), self.len(), "one weight row per point");
        points
            .iter()
            .enumerate()
            .map(|(i, p)| self.blended(i, matrices).transform_point3(*p))
            .collect()
    }
}
