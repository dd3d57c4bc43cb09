//! Animatable avatar: canonical Gaussians bound to a skeleton by per-Gaussian skinning weights,
//! posed by linear blend skinning (LBS).
//!
//! Posing moves each centre by its blended bone transform and turns its orientation by the
//! rotation part (polar decomposition) of that transform; scales, opacities and colours are
//! unchanged, as in LHM++ (`q_posed = quat(R_lbs) ⊗ q_cano`). Higher-order SH coefficients
//! are not rotated (LHM++ only uses RGB).

use crate::body::{SkinWeights, MAX_INFLUENCES};
use crate::splat::{GaussianError, Gaussians};
use glam::{Affine3A, Mat3, Mat3A, Mat4, Quat, Vec3, Vec4};
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
    /// be a clone of the canonical set (or an earlier pose of it): no allocation per frame
    /// beyond one small per-bone table.
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
        let bones = BoneSet::new(skinning_matrices);
        let c = &self.canonical;
        posed
            .positions
            .par_chunks_mut(POSE_CHUNK)
            .zip(posed.rotations.par_chunks_mut(POSE_CHUNK))
            .enumerate()
            .for_each(|(chunk, (positions, rotations))| {
                let start = chunk * POSE_CHUNK;
                for (k, (pos, rot)) in positions.iter_mut().zip(rotations).enumerate() {
                    let i = start + k;
                    let (b, w) = (&self.skin.bones[i], &self.skin.weights[i]);
                    *pos = bones.blend_affine(b, w).transform_point3(c.positions[i]);
                    let r = bones.blend_rotation(b, w);
                    // An unrotated Gaussian keeps its quaternion bit for bit.
                    *rot = if r == Quat::IDENTITY {
                        c.rotations[i]
                    } else {
                        (r * c.rotations[i]).normalize()
                    };
                }
            });
    }
}

impl Avatar {
    /// Each Gaussian's blended bone transform and the rotation part [`Avatar::animate`] turns
    /// its orientation by, for `skinning_matrices` (the posed centre is `transform ·
    /// canonical`, the posed quaternion `rotation ⊗ canonical`, normalised): what a fit of the
    /// canonical Gaussians through posing needs ([`crate::refine`]).
    ///
    /// Panics if fewer matrices than [`Avatar::bones_needed`] are given.
    pub fn blend_transforms(&self, skinning_matrices: &[Mat4]) -> Vec<(Affine3A, Quat)> {
        if let Err(e) = self.check_matrices(skinning_matrices) {
            panic!("Avatar::blend_transforms: {e}");
        }
        blend_rows(&self.skin, skinning_matrices)
    }
}

/// [`Avatar::blend_transforms`] for any skin rows (every bone they use must have a matrix).
pub fn blend_rows(skin: &SkinWeights, skinning_matrices: &[Mat4]) -> Vec<(Affine3A, Quat)> {
    let bones = BoneSet::new(skinning_matrices);
    (0..skin.len())
        .into_par_iter()
        .with_min_len(POSE_CHUNK)
        .map(|i| {
            let (b, w) = (&skin.bones[i], &skin.weights[i]);
            (bones.blend_affine(b, w), bones.blend_rotation(b, w))
        })
        .collect()
}

/// Gaussians posed per rayon task.
const POSE_CHUNK: usize = 4096;

/// Largest deviation `‖AᵀA/s² − I‖_F` for which a bone's linear part `A` counts as a rotation
/// scaled by `s`.
const RIGID_TOLERANCE: f32 = 1e-5;

/// Power-iteration steps at most in [`BoneSet::blend_rotation`] (the last multiplies by
/// `A^(2^(POWER_STEPS − 1))`).
const POWER_STEPS: usize = 7;

/// Per-pose bone data, prepared once for the per-Gaussian loop.
struct BoneSet {
    /// Skinning transforms (the `Mat4`s without their constant last row).
    affine: Vec<Affine3A>,
    /// Unit quaternion (as `Vec4`) and scale of every bone when each bone's linear part is a
    /// positively scaled rotation; `None` otherwise.
    rigid: Option<Vec<(Vec4, f32)>>,
}

impl BoneSet {
    fn new(matrices: &[Mat4]) -> Self {
        let affine: Vec<Affine3A> = matrices.iter().map(|m| Affine3A::from_mat4(*m)).collect();
        let rigid = affine
            .iter()
            .map(|a| {
                let m = Mat3::from(a.matrix3);
                let s = m.x_axis.length();
                let det = m.determinant();
                if !(s.is_finite() && s > 0.0 && det > 0.0) {
                    return None;
                }
                let r = m * (1.0 / s);
                if frobenius(r.transpose() * r - Mat3::IDENTITY) > RIGID_TOLERANCE {
                    return None;
                }
                // An exact identity stays exact (keeps the identity pose bit for bit).
                let q = if r == Mat3::IDENTITY {
                    Quat::IDENTITY
                } else {
                    Quat::from_mat3(&r).normalize()
                };
                Some((Vec4::from(q), s))
            })
            .collect();
        Self { affine, rigid }
    }

    /// Weighted mean of the row's bone transforms (weights renormalised to sum to 1, so that
    /// identity transforms give exactly the identity).
    #[inline]
    fn blend_affine(&self, b: &[u16; MAX_INFLUENCES], w: &[f32; MAX_INFLUENCES]) -> Affine3A {
        let a0 = &self.affine[b[0] as usize];
        let mut x = a0.matrix3.x_axis * w[0];
        let mut y = a0.matrix3.y_axis * w[0];
        let mut z = a0.matrix3.z_axis * w[0];
        let mut t = a0.translation * w[0];
        let mut sum = w[0];
        for (&bone, &weight) in b.iter().zip(w).skip(1) {
            if weight != 0.0 {
                let a = &self.affine[bone as usize];
                x += a.matrix3.x_axis * weight;
                y += a.matrix3.y_axis * weight;
                z += a.matrix3.z_axis * weight;
                t += a.translation * weight;
                sum += weight;
            }
        }
        if sum != 1.0 {
            let inv = 1.0 / sum;
            (x, y, z, t) = (x * inv, y * inv, z * inv, t * inv);
        }
        Affine3A {
            matrix3: Mat3A::from_cols(x, y, z),
            translation: t,
        }
    }

    /// The rotation part (orthogonal polar factor) of the row's blended linear transform.
    ///
    /// With rigid bones (`Aₖ = sₖ Rₖ`) the polar factor of `Σ wₖ sₖ Rₖ` is the rotation `R`
    /// maximising `tr(Rᵀ Σ wₖ sₖ Rₖ) = Σ wₖ sₖ (4 (q·qₖ)² − 1)`, i.e. the top eigenvector `q`
    /// of `A = Σ wₖ sₖ qₖ qₖᵀ` (4×4), found by power iteration (with squaring) from the
    /// sign-aligned weighted mean of the `qₖ`: a few 4×4 operations instead of a 3×3 polar
    /// decomposition. Other bones
    /// fall back to [`rotation_part`].
    #[inline]
    fn blend_rotation(&self, b: &[u16; MAX_INFLUENCES], w: &[f32; MAX_INFLUENCES]) -> Quat {
        let Some(rigid) = &self.rigid else {
            let a = self.blend_affine(b, w);
            return rotation_part(Mat3::from(a.matrix3));
        };
        let mut qs = [Vec4::ZERO; MAX_INFLUENCES];
        let mut cs = [0.0f32; MAX_INFLUENCES];
        let mut n = 0;
        for (&bone, &weight) in b.iter().zip(w) {
            if weight != 0.0 {
                let (q, s) = rigid[bone as usize];
                qs[n] = q;
                cs[n] = weight * s;
                n += 1;
            }
        }
        let (qs, cs) = (&qs[..n], &cs[..n]);
        if n == 1 || qs.iter().all(|q| *q == qs[0]) {
            return Quat::from_vec4(qs[0]);
        }
        let mut x = qs
            .iter()
            .zip(cs)
            .fold(Vec4::ZERO, |acc, (q, c)| {
                acc + *q * c.copysign(q.dot(qs[0]))
            })
            .normalize();
        // Power iteration with repeated squaring: step k multiplies by A^(2^k), so the error
        // shrinks like (λ₂/λ₁)^(2^k) (blends of nearby rotations stop after a step or two).
        let mut power = qs.iter().zip(cs).fold(Mat4::ZERO, |acc, (q, c)| {
            acc + Mat4::from_cols(
                *q * (c * q.x),
                *q * (c * q.y),
                *q * (c * q.z),
                *q * (c * q.w),
            )
        });
        for step in 0..POWER_STEPS {
            let y = (power * x).normalize();
            let change = (y - x).length_squared();
            x = y;
            if change < 1e-10 || step + 1 == POWER_STEPS {
                break;
            }
            power = power * power;
            // Rescale (trace = sum of eigenvalues > 0) so that the powers neither overflow nor
            // underflow.
            let trace = power.x_axis.x + power.y_axis.y + power.z_axis.z + power.w_axis.w;
            power *= 1.0 / trace;
        }
        if !x.is_finite() {
            let a = self.blend_affine(b, w);
            return rotation_part(Mat3::from(a.matrix3));
        }
        Quat::from_vec4(x)
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
    fn quaternion_blend_of_rigid_bones_equals_the_polar_factor_of_the_blended_matrix() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let matrices: Vec<Mat4> = (0..30)
            .map(|k| {
                let axis = Vec3::new(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                );
                let q = Quat::from_scaled_axis(axis * rng.gen_range(0.0..1.5));
                // A few bones uniformly scaled, as a body-shape scale would.
                let s = if k % 5 == 0 { 1.3 } else { 1.0 };
                Mat4::from_scale_rotation_translation(Vec3::splat(s), q, Vec3::new(0.1, 0.2, 0.3))
            })
            .collect();
        let bones = BoneSet::new(&matrices);
        assert!(bones.rigid.is_some(), "rotations (scaled) are rigid bones");
        let mut worst = 0.0f32;
        for _ in 0..2000 {
            let b: [u16; 4] = std::array::from_fn(|_| rng.gen_range(0..30));
            let mut w: [f32; 4] = std::array::from_fn(|_| rng.gen_range(0.0..1.0));
            let sum: f32 = w.iter().sum();
            w.iter_mut().for_each(|v| *v /= sum);
            let fast = bones.blend_rotation(&b, &w);
            let polar = rotation_part(Mat3::from(bones.blend_affine(&b, &w).matrix3));
            // ‖q₁ ∓ q₂‖ ≈ half the angle between the rotations.
            let gap = (Vec4::from(fast) - Vec4::from(polar))
                .length()
                .min((Vec4::from(fast) + Vec4::from(polar)).length());
            worst = worst.max(2.0 * gap);
        }
        println!("worst angle between the two rotations: {worst:.2e} rad");
        assert!(
            worst < 1e-5,
            "worst angle between the two rotations {worst} rad"
        );
    }

    #[test]
    fn non_rigid_bones_fall_back_to_the_polar_factor_of_the_blended_matrix() {
        let sheared = Mat4::from_mat3(Mat3::from_cols(
            Vec3::new(1.0, 0.3, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 0.8),
        ));
        let turned = Mat4::from_rotation_y(0.9);
        let bones = BoneSet::new(&[sheared, turned]);
        assert!(bones.rigid.is_none(), "a sheared bone is not rigid");
        let (b, w) = ([0, 1, 0, 0], [0.5, 0.5, 0.0, 0.0]);
        let expected = rotation_part((Mat3::from_mat4(sheared) + Mat3::from_mat4(turned)) * 0.5);
        let got = bones.blend_rotation(&b, &w);
        assert!(got.dot(expected).abs() > 1.0 - 1e-6, "{got} vs {expected}");
        assert!(
            got.dot(Quat::IDENTITY).abs() < 1.0 - 1e-3,
            "the blend does rotate"
        );
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
