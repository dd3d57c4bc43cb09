//! A generated FK gait for the limbs (the source walk cycle drives arms and legs with IK
//! controls that the rig lacks). Angles follow typical walking kinematics:
//! hip flexion 10° ± 20° (+30° at heel strike, −10° at toe off), knee 5° + up to 55° in swing,
//! ankle ±8°, arm swing ±20° opposite to the leg on the same side, elbow 15°–25°; the two
//! sides half a period apart.

use glam::Quat;

/// Frame (in a 40-frame cycle) at mid-swing of the left leg; the right leg is half a period
/// away. Chosen to match the source clip, whose left foot swings in frames 25–40 and right
/// foot in frames 5–20.
const LEFT_MID_SWING: f32 = 32.5;

/// Per-bone local rotations (canonical axes) of the limbs at `frame` of a `period`-frame cycle.
pub fn limb_rotations(frame: f32, period: f32) -> Vec<(String, Quat)> {
    let mut out = Vec::with_capacity(10);
    for (side, offset) in [("L", 0.0f32), ("R", 0.5)] {
        // Swing phase: φ = 0 at mid-swing, φ = ±π/2 at toe off / heel strike.
        let phase = std::f32::consts::TAU * ((frame - LEFT_MID_SWING) / period - offset);
        let (s, c) = phase.sin_cos();
        let hip = 10.0 + 20.0 * s;
        let knee = 5.0 + 55.0 * c.max(0.0).powi(2);
        let ankle = 8.0 * s;
        let arm = -20.0 * s;
        let elbow = 20.0 - 5.0 * s;
        // Flexion that moves a hanging segment forward (+Z) is a negative rotation about +X.
        let about_x = |deg: f32| Quat::from_rotation_x(deg.to_radians());
        out.push((format!("upperleg01.{side}"), about_x(-hip)));
        out.push((format!("lowerleg01.{side}"), about_x(knee)));
        out.push((format!("foot.{side}"), about_x(-ankle)));
        out.push((format!("upperarm01.{side}"), about_x(-arm)));
        out.push((format!("lowerarm01.{side}"), about_x(-elbow)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn angle_deg(rotations: &[(String, Quat)], bone: &str) -> f32 {
        let (axis, angle) = rotations
            .iter()
            .find(|(b, _)| b == bone)
            .unwrap()
            .1
            .to_axis_angle();
        angle.to_degrees() * axis.x.signum()
    }

    #[test]
    fn hips_swing_between_minus_ten_and_thirty_degrees_half_a_period_apart() {
        let (mut lo, mut hi) = (f32::MAX, f32::MIN);
        for f in 0..40 {
            let r = limb_rotations(f as f32, 40.0);
            let flex = -angle_deg(&r, "upperleg01.L");
            lo = lo.min(flex);
            hi = hi.max(flex);
            let other = -angle_deg(&limb_rotations(f as f32 + 20.0, 40.0), "upperleg01.R");
            assert!((flex - other).abs() < 1e-3);
        }
        assert!(
            (hi - 30.0).abs() < 0.5 && (lo + 10.0).abs() < 0.5,
            "{lo} {hi}"
        );
    }

    #[test]
    fn knee_bends_most_in_swing() {
        let swing = angle_deg(&limb_rotations(LEFT_MID_SWING, 40.0), "lowerleg01.L");
        let stance = angle_deg(&limb_rotations(LEFT_MID_SWING + 20.0, 40.0), "lowerleg01.L");
        assert!(
            (swing - 60.0).abs() < 0.5 && stance < 10.0,
            "{swing} {stance}"
        );
    }
}
