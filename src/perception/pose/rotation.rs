//! Small rotation helpers: frames from two vectors, shortest arcs, swing–twist splits.

use glam::{Mat3, Quat, Vec3};

/// Vectors shorter than this are treated as undefined directions.
const TINY: f32 = 1e-6;

/// Orthonormal frame whose first axis is `primary` and whose second lies in the plane of
/// `primary` and `secondary`, on `secondary`'s side; `None` when they are (nearly) parallel.
pub(crate) fn triad(primary: Vec3, secondary: Vec3) -> Option<Mat3> {
    let x = primary.try_normalize()?;
    let z = x.cross(secondary);
    if z.length() < 1e-4 * secondary.length().max(TINY) {
        return None;
    }
    let z = z.normalize();
    Some(Mat3::from_cols(x, z.cross(x), z))
}

/// The rotation taking the frame of (`rest_primary`, `rest_secondary`) onto that of
/// (`primary`, `secondary`): the primaries align exactly, the secondaries as far as the
/// primaries allow.
pub(crate) fn align(
    rest_primary: Vec3,
    rest_secondary: Vec3,
    primary: Vec3,
    secondary: Vec3,
) -> Option<Quat> {
    let rest = triad(rest_primary, rest_secondary)?;
    let seen = triad(primary, secondary)?;
    Some(Quat::from_mat3(&(seen * rest.transpose())).normalize())
}

/// The shortest rotation taking direction `from` onto direction `to`; `None` when either is
/// zero.
pub(crate) fn arc(from: Vec3, to: Vec3) -> Option<Quat> {
    Some(Quat::from_rotation_arc(
        from.try_normalize()?,
        to.try_normalize()?,
    ))
}

/// Angle in (−π, π].
pub(crate) fn wrap(angle: f32) -> f32 {
    let a = angle.rem_euclid(std::f32::consts::TAU);
    if a > std::f32::consts::PI {
        a - std::f32::consts::TAU
    } else {
        a
    }
}

/// Signed angle about unit `axis` from `from` to `to`, both projected onto the plane normal
/// to `axis`; `None` when a projection vanishes.
pub(crate) fn angle_about(axis: Vec3, from: Vec3, to: Vec3) -> Option<f32> {
    let u = (from - axis * from.dot(axis)).try_normalize()?;
    let v = (to - axis * to.dot(axis)).try_normalize()?;
    Some(axis.dot(u.cross(v)).atan2(u.dot(v)))
}

/// The twist angle of `q` about unit `axis` (swing–twist split `q = swing · twist`, the
/// twist about `axis`, the swing about an axis normal to it), in (−π, π].
pub(crate) fn twist_angle(q: Quat, axis: Vec3) -> f32 {
    let along = Vec3::new(q.x, q.y, q.z).dot(axis);
    if along.abs() < TINY && q.w.abs() < TINY {
        return 0.0;
    }
    wrap(2.0 * along.atan2(q.w))
}

/// Splits `q` into `(swing, twist angle)` with `q = swing · R(axis, twist)`.
pub(crate) fn swing_twist(q: Quat, axis: Vec3) -> (Quat, f32) {
    let twist = twist_angle(q, axis);
    let swing = (q * Quat::from_axis_angle(axis, -twist)).normalize();
    (swing, twist)
}

/// Rotation angle of `q` in [0, π].
pub(crate) fn angle_of(q: Quat) -> f32 {
    2.0 * q.w.abs().min(1.0).acos()
}

/// `q` scaled down to at most `max` radians about its own axis.
pub(crate) fn limit_angle(q: Quat, max: f32) -> Quat {
    let angle = angle_of(q);
    if angle <= max || angle < TINY {
        q
    } else {
        Quat::IDENTITY.slerp(q, max / angle).normalize()
    }
}

/// Cubic ease from 0 (at or below `t = 0`) to 1 (at or above `t = 1`).
pub(crate) fn smoothstep(t: f32) -> f32 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn align_maps_both_rest_vectors_onto_the_seen_ones() {
        let q0 = Quat::from_euler(glam::EulerRot::ZYX, 0.3, -1.1, 2.0);
        let (p, s) = (Vec3::new(0.2, -1.0, 0.1), Vec3::new(1.0, 0.3, 0.5));
        let q = align(p, s, q0 * p, q0 * s).unwrap();
        assert!(
            q.abs_diff_eq(q0, 1e-5) || q.abs_diff_eq(-q0, 1e-5),
            "{q} {q0}"
        );
        assert!(align(p, p * 2.0, p, s).is_none());
    }

    #[test]
    fn swing_twist_recomposes_and_isolates_the_twist() {
        let axis = Vec3::new(1.0, 2.0, -0.5).normalize();
        let swing = Quat::from_axis_angle(axis.any_orthonormal_vector(), 0.7);
        let q = swing * Quat::from_axis_angle(axis, -2.5);
        let (s, t) = swing_twist(q, axis);
        assert!((t + 2.5).abs() < 1e-5, "{t}");
        assert!(s.abs_diff_eq(swing, 1e-5) || s.abs_diff_eq(-swing, 1e-5));
        assert!((wrap(3.5) - (3.5 - std::f32::consts::TAU)).abs() < 1e-6);
    }

    #[test]
    fn angle_about_is_signed_and_limit_angle_shrinks() {
        let a = angle_about(Vec3::Z, Vec3::X, Vec3::Y).unwrap();
        assert!((a - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        let b = angle_about(Vec3::Z, Vec3::Y, Vec3::X + Vec3::Z).unwrap();
        assert!((b + std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        let q = limit_angle(Quat::from_rotation_y(1.0), 0.25);
        assert!((angle_of(q) - 0.25).abs() < 1e-5);
    }
}
