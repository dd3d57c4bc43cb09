//! The kinematic tree: bone names, parents, rest joints, rest bone orientations and forward
//! kinematics producing linear-blend-skinning matrices.

use super::{BodyError, Pose};
use glam::{Mat3, Mat4, Quat, Vec3};

/// A skeleton in the canonical rest pose. Bones are ordered so that every parent precedes
/// its children.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Skeleton {
    /// Bone names (MakeHuman rig names, or SMPL-X joint names).
    pub bone_names: Vec<String>,
    /// Parent bone index per bone; `None` for a root.
    pub parents: Vec<Option<usize>>,
    /// Rest position of each bone's joint (its head), canonical frame, metres.
    pub joints: Vec<Vec3>,
    /// Rest orientation of each bone: columns are the bone's local X, Y (head → tail) and Z
    /// axes in canonical coordinates (Blender's bone matrix with its roll); identity for
    /// SMPL-X. Used to convert bone-space rotations (Blender keyframes) into [`Pose`] rotations.
    pub rest_orientations: Vec<Mat3>,
}

impl Skeleton {
    /// Number of bones.
    pub fn len(&self) -> usize {
        self.bone_names.len()
    }

    /// True when the skeleton has no bones.
    pub fn is_empty(&self) -> bool {
        self.bone_names.is_empty()
    }

    /// Index of the bone called `name`.
    pub fn bone_index(&self, name: &str) -> Option<usize> {
        self.bone_names.iter().position(|b| b == name)
    }

    /// Checks the bone order (parents first) and the array lengths; `origin` names the source.
    pub fn validate(&self, origin: &str) -> Result<(), BodyError> {
        let n = self.len();
        if self.parents.len() != n || self.joints.len() != n || self.rest_orientations.len() != n {
            return Err(BodyError::format(
                origin,
                "skeleton arrays differ in length",
            ));
        }
        for (i, p) in self.parents.iter().enumerate() {
            if let Some(p) = p {
                if *p >= i {
                    return Err(BodyError::format(
                        origin,
                        format!(
                            "bone `{}` comes before its parent `{}`",
                            self.bone_names[i],
                            self.bone_names.get(*p).map_or("?", |s| s.as_str())
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Errors with the list of bone names in `pose` that this skeleton does not have.
    pub fn check_pose(&self, pose: &Pose) -> Result<(), BodyError> {
        let mut unknown: Vec<String> = pose
            .rotations
            .keys()
            .filter(|name| self.bone_index(name).is_none())
            .cloned()
            .collect();
        if unknown.is_empty() {
            return Ok(());
        }
        unknown.sort();
        Err(BodyError::UnknownBones(unknown))
    }

    /// Forward kinematics: one matrix per bone mapping a canonical rest point to its posed
    /// world position (`G_j · G_j,rest⁻¹`, the root transform applied last).
    ///
    /// Bones of `pose` that the skeleton lacks are ignored here (with a warning); validate
    /// poses from outside with [`Skeleton::check_pose`] or use
    /// [`Skeleton::try_skinning_matrices`].
    pub fn skinning_matrices(&self, pose: &Pose) -> Vec<Mat4> {
        if let Err(e) = self.check_pose(pose) {
            tracing::warn!("{e}; ignoring them");
        }
        let mut local = vec![Quat::IDENTITY; self.len()];
        for (name, q) in &pose.rotations {
            if let Some(i) = self.bone_index(name) {
                local[i] = q.normalize();
            }
        }
        self.skinning_matrices_from_locals(&local, pose.root_rotation, pose.root_translation)
    }

    /// [`Skeleton::skinning_matrices`] that first rejects poses naming unknown bones.
    pub fn try_skinning_matrices(&self, pose: &Pose) -> Result<Vec<Mat4>, BodyError> {
        self.check_pose(pose)?;
        Ok(self.skinning_matrices(pose))
    }

    /// Forward kinematics from per-bone local rotations (indexed like the bones).
    pub fn skinning_matrices_from_locals(
        &self,
        local: &[Quat],
        root_rotation: Quat,
        root_translation: Vec3,
    ) -> Vec<Mat4> {
        let n = self.len();
        let mut global: Vec<Mat4> = Vec::with_capacity(n);
        // Bones whose chain up to the root is unrotated keep exactly the identity matrix, so
        // vertices they alone weight stay bit-for-bit in place.
        let mut at_rest: Vec<bool> = Vec::with_capacity(n);
        assert_eq!(local.len(), n, "one local rotation per bone");
        for (j, &q) in local.iter().enumerate() {
            let (g, rest) = match self.parents[j] {
                Some(p) => (
                    global[p] * Mat4::from_rotation_translation(q, self.joints[j] - self.joints[p]),
                    at_rest[p] && q == Quat::IDENTITY,
                ),
                None => (
                    Mat4::from_rotation_translation(q, self.joints[j]),
                    q == Quat::IDENTITY,
                ),
            };
            global.push(g);
            at_rest.push(rest);
        }
        let pivot = self.joints.first().copied().unwrap_or(Vec3::ZERO);
        let root_rotation = root_rotation.normalize();
        let root_is_identity = root_rotation == Quat::IDENTITY && root_translation == Vec3::ZERO;
        let root = Mat4::from_translation(root_translation + pivot)
            * Mat4::from_quat(root_rotation)
            * Mat4::from_translation(-pivot);
        (0..n)
            .map(|j| match (at_rest[j], root_is_identity) {
                (true, true) => Mat4::IDENTITY,
                (true, false) => root,
                _ => root * global[j] * Mat4::from_translation(-self.joints[j]),
            })
            .collect()
    }

    /// Posed joint positions for skinning matrices from [`Skeleton::skinning_matrices`].
    pub fn posed_joints(&self, matrices: &[Mat4]) -> Vec<Vec3> {
        self.joints
            .iter()
            .zip(matrices)
            .map(|(j, m)| m.transform_point3(*j))
            .collect()
    }

    /// `mask[i]` is true when bone `i` is `bone` or one of its descendants.
    pub fn subtree_mask(&self, bone: usize) -> Vec<bool> {
        let mut mask = vec![false; self.len()];
        mask[bone] = true;
        for i in bone + 1..self.len() {
            if let Some(p) = self.parents[i] {
                mask[i] = mask[p];
            }
        }
        mask
    }

    /// Converts a rotation expressed in bone `bone`'s local (Blender rest) axes into the
    /// canonical-axes convention of [`Pose`]: `B · q · Bᵀ`.
    pub fn bone_local_to_canonical(&self, bone: usize, local: Quat) -> Quat {
        let b = Quat::from_mat3(&self.rest_orientations[bone]);
        (b * local * b.conjugate()).normalize()
    }

    /// Converts a translation in bone `bone`'s local axes into canonical axes.
    pub fn bone_local_vector_to_canonical(&self, bone: usize, v: Vec3) -> Vec3 {
        self.rest_orientations[bone] * v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain() -> Skeleton {
        Skeleton {
            bone_names: vec!["a".into(), "b".into(), "c".into()],
            parents: vec![None, Some(0), Some(1)],
            joints: vec![Vec3::ZERO, Vec3::Y, Vec3::Y * 2.0],
            rest_orientations: vec![Mat3::IDENTITY; 3],
        }
    }

    #[test]
    fn rotating_middle_bone_moves_its_child_about_its_joint() {
        let s = chain();
        let mut pose = Pose::identity();
        pose.rotations.insert(
            "b".into(),
            Quat::from_rotation_z(std::f32::consts::FRAC_PI_2),
        );
        let m = s.skinning_matrices(&pose);
        let posed = s.posed_joints(&m);
        assert!(posed[1].abs_diff_eq(Vec3::Y, 1e-6));
        assert!(posed[2].abs_diff_eq(Vec3::new(-1.0, 1.0, 0.0), 1e-6));
    }

    #[test]
    fn unknown_bones_are_listed_in_the_error() {
        let s = chain();
        let mut pose = Pose::identity();
        pose.rotations.insert("zz".into(), Quat::IDENTITY);
        pose.rotations.insert("yy".into(), Quat::IDENTITY);
        let err = s.try_skinning_matrices(&pose).unwrap_err().to_string();
        assert!(err.contains("yy, zz"), "{err}");
    }

    #[test]
    fn root_transform_is_applied_last_about_the_root_joint() {
        let s = chain();
        let pose = Pose {
            root_rotation: Quat::from_rotation_y(std::f32::consts::PI),
            root_translation: Vec3::X,
            ..Pose::identity()
        };
        let m = s.skinning_matrices(&pose);
        let p = m[2].transform_point3(Vec3::new(0.5, 2.0, 0.0));
        assert!(p.abs_diff_eq(Vec3::new(0.5, 2.0, 0.0), 1e-6), "{p}");
    }
}
