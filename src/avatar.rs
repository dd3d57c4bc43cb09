//! Animatable avatar: canonical Gaussians bound to a skeleton by per-Gaussian skinning weights,
//! posed by linear blend skinning (LBS).
//!
//! Posing moves each centre by its blended bone transform and turns its orientation by the
//! rotation part (polar decomposition) of that transform; scales, opacities and colours are
//! unchanged, as in LHM++ (`q_posed = quat(R_lbs) ⊗ q_cano`). Higher-order SH coefficients
//! are not rotated (LHM++ only uses RGB).

use crate::body::{SkinWeights, MAX_INFLUENCES};
use crate::splat::{GaussianError, Gaussians};
use glam::{Mat3, Mat4, Quat, Vec3};
use rayon::prelude::*;
use thiserror::Error;

/// Why an avatar cannot be built or posed.
#[derive(Debug, Error, PartialEq)]
pub enum AvatarError {
    /// The canonical Gaussians are malformed.
    #[error("avatar Gaussians: {0}")]
    Gaussians(#[from] GaussianError),
    /// Skinning weights do not have one row per Gaussian.
    #[error("avatar skin has {skin} weight rows for {gaussians} Gaussians")]
    SkinRows {
        /// Weight rows.
        skin: usize,
        /// Gaussians.
        gaussians: usize,
    },
    /// A skinning weight row is negative, non-finite or sums to zero.
    #[error("avatar skin row {row} has invalid weights {weights:?}")]
    BadWeights {
        /// Row (Gaussian) index.
        row: usize,
        /// The offending weights.
        weights: [f32; MAX_INFLUENCES],
    },
    /// Fewer skinning matrices than the bones the skin refers to.
    #[error("avatar skin uses bone {bone} but only {matrices} skinning matrices were given")]
    MissingBone {
        /// Highest bone index used.
        bone: usize,
        /// Matrices given.
        matrices: usize,
    },
}

/// Canonical Gaussians + skinning weights + the body model they are bound to.
#[derive(Debug, Clone, PartialEq)]
pub struct Avatar {
    /// Gaussians in the canonical (rest) pose.
    pub canonical: Gaussians,
    /// One skinning-weight row per Gaussian.
    pub skin: SkinWeights,
    /// Identifier of the body model whose bones the weights index (e.g. `makehuman-cc0`).
    pub body_model: String,
    /// Highest bone index any non-zero weight uses (+1), i.e. matrices needed to pose.
    bones_needed: usize,
}

impl Avatar {
    /// Binds canonical Gaussians to a skin, checking shapes and weights.
    pub fn new(
        canonical: Gaussians,
        skin: SkinWeights,
        body_model: impl Into<String>,
    ) -> Result<Self, AvatarError> {
        canonical.validate()?;
        if skin.len() != canonical.len() || skin.weights.len() != skin.bones.len() {
            return Err(AvatarError::SkinRows {
                skin: skin.weights.len().min(skin.bones.len()),
                gaussians: canonical.len(),
            });
        }
        let mut bones_needed = 0;
        for (row, (w, b)) in skin.weights.iter().zip(&skin.bones).enumerate() {
            let sum: f32 = w.iter().sum();
            if sum.is_nan()
                || sum <= 0.0
                || !sum.is_finite()
                || w.iter().any(|v| v.is_nan() || *v < 0.0)
            {
                return Err(AvatarError::BadWeights { row, weights: *w });
            }
            for (&bone, &weight) in b.iter().zip(w) {
                if weight > 0.0 {
                    bones_needed = bones_needed.max(bone as usize + 1);
                }
            }
        }
        Ok(Self {
            canonical,
            skin,
            body_model: body_model.into(),
            bones_needed,
        })
    }

    /// Writes the canonical Gaussians as a 3DGS PLY with the skinning weights and body model id
    /// in the lhmpp extension properties (see [`crate::splat::write_ply`]).
    pub fn save_ply(&self, path: &std::path::Path) -> Result<(), crate::splat::PlyError> {
        crate::splat::write_ply(
            path,
            &self.canonical,
            Some(&self.skin),
            Some(&self.body_model),
        )
    }

    /// Number of skinning matrices [`Avatar::animate`] needs.
    pub fn bones_needed(&self) -> usize {
        self.bones_needed
    }

    /// Checks that `skinning_matrices` covers every bone the skin uses.
    pub fn check_matrices(&self, skinning_matrices: &[Mat4]) -> Result<(), AvatarError> {
        if skinning_matrices.len() < self.bones_needed {
            return Err(AvatarError::MissingBone {
                bone: self.bones_needed - 1,
                matrices: skinning_matrices.len(),
            });
        }
        Ok(())
    }

    /// The posed Gaussians for per-bone skinning matrices (canonical → posed, world units).
    ///
    /// Panics if fewer matrices than [`Avatar::bones_needed`] are given
    /// (see [`Avatar::check_matrices`]).
    pub fn animate(&self, skinning_matrices: &[Mat4]) -> Gaussians {
        let mut posed = self.canonical.clone();
        self.animate_into(skinning_matrices, &mut posed);
        posed
    }

    /// Like [`Avatar::animate`] but writes only positions and rotations into `posed`, which must
    /// be a clone of the canonical set (or an earlier pose of it): no allocation per frame.
    pub fn animate_into(&self, skinning_matrices: &[Mat4], posed: &mut Gaussians) {
        if let Err(e) = self.check_matrices(skinning_matrices) {
            panic!("Avatar::animate: {e}");
        }
        assert_eq!(
            posed.len(),
            self.canonical.len(),
            "posed set must have the avatar's Gaussian count"
        );
        let _span = tracing::trace_span!("animate", n = self.canonical.len()).entered();
        let c = &self.canonical;
        posed
            .positions
            .par_iter_mut()
            .zip(posed.rotations.par_iter_mut())
            .enumerate()
            .with_min_len(4096)
            .for_each(|(i, (pos, rot))| {
                let m = blend(&self.skin, i, skinning_matrices);
                *pos = m.transform_point3(c.positions[i]);
                let r = rotation_part(Mat3::from_mat4(m));
                // An unrotated Gaussian keeps its quaternion bit for bit.
                *rot = if r == Quat::IDENTITY {
                    c.rotations[i]
                } else {
                    (r * c.rotations[i]).normalize()
                };
            });
    }
}

/// Weighted mean of the bone matrices of row `i` (weights renormalised to sum to 1, so that
/// identity matrices give exactly the identity).
#[inline]
fn blend(skin: &SkinWeights, i: usize, matrices: &[Mat4]) -> Mat4 {
    let (b, w) = (&skin.bones[i], &skin.weights[i]);
    let mut m = matrices[b[0] as usize] * w[0];
    let mut sum = w[0];
    for (&bone, &weight) in b.iter().zip(w).skip(1) {
        if weight != 0.0 {
            m += matrices[bone as usize] * weight;
            sum += weight;
        }
    }
    if sum == 1.0 {
        m
    } else {
        m * (1.0 / sum)
    }
}

/// The rotation closest to `m` (the orthogonal polar factor), by Björck–Bowie iteration
/// `R ← R (3I − RᵀR) / 2` after scaling `m` to unit mean squared singular value; exact (one
/// check, no iteration) for matrices that already are rotations. Returns the identity for
/// singular or reflecting input.
pub fn rotation_part(m: Mat3) -> Quat {
    let norm = frobenius(m);
    let det = m.determinant();
    if norm.is_nan() || norm <= 0.0 || !norm.is_finite() || det.is_nan() || det <= 0.0 {
        return Quat::IDENTITY;
    }
    let mut r = m;
    for k in 0..12 {
        let gram = r.transpose() * r;
        if frobenius(gram - Mat3::IDENTITY) < 1e-6 {
            break;
        }
        if k == 0 {
            r *= 3f32.sqrt() / norm;
            continue;
        }
        r *= Mat3::IDENTITY * 1.5 - gram * 0.5;
    }
    Quat::from_mat3(&r).normalize()
}

fn frobenius(m: Mat3) -> f32 {
    let c = [m.x_axis, m.y_axis, m.z_axis];
    c.iter()
        .map(|v: &Vec3| v.length_squared())
        .sum::<f32>()
        .sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polar_part_of_a_scaled_rotation_is_the_rotation() {
        let q = Quat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 0.7);
        let m = Mat3::from_quat(q) * Mat3::from_diagonal(Vec3::new(0.6, 0.9, 1.4));
        // A non-uniform scale *after* the rotation is not a pure polar factor; use a uniform one.
        let r = rotation_part(Mat3::from_quat(q) * 0.7);
        assert!(r.dot(q).abs() > 1.0 - 1e-6, "{r} vs {q}");
        assert!(rotation_part(m).is_normalized());
    }

    #[test]
    fn halfway_blend_of_two_rotations_gives_the_halfway_rotation() {
        let a = Mat3::from_rotation_z(0.0);
        let b = Mat3::from_rotation_z(1.2);
        let r = rotation_part((a + b) * 0.5);
        let expected = Quat::from_rotation_z(0.6);
        assert!(r.dot(expected).abs() > 1.0 - 1e-6, "{r}");
    }
}
