//! The light a view saw, put back on the avatar: per Gaussian, the factor that turns its
//! de-lit colour (as [`super::photo_colours`] leaves it) into the colour the view shows, so a
//! fit against the lit views ([`crate::refine`]) keeps the avatar's colours de-lit.

use super::delight::KeyLight;
use super::photo_colours::{canonical_normals, in_shadow, occupied_cells};
use crate::avatar::Avatar;
use crate::body::BodyTemplate;
use glam::{Mat4, Vec3};

/// Per Gaussian of `avatar`, the factor `e^exposure / gain` that `light` (fitted to the views
/// sharing one world frame, [`KeyLight`]) applies in a view where the person stands as
/// `skinning` poses them and the view's exposure offset is `exposure`: the key light's
/// shading of the Gaussian's posed normal, zero key light in the avatar's own cast shadow.
pub fn view_shading(
    avatar: &Avatar,
    template: &BodyTemplate,
    light: &KeyLight,
    skinning: &[Mat4],
    exposure: f32,
) -> Vec<Vec3> {
    let (normals, _) = canonical_normals(avatar, template);
    let transforms = avatar.blend_transforms(skinning);
    let posed: Vec<Vec3> = avatar
        .canonical
        .positions
        .iter()
        .zip(&transforms)
        .map(|(p, (a, _))| a.transform_point3(*p))
        .collect();
    let dir = light.key.normalize_or_zero();
    let cells = (dir != Vec3::ZERO).then(|| occupied_cells(&posed));
    let scale = exposure.exp();
    normals
        .iter()
        .zip(&transforms)
        .zip(&posed)
        .map(|((n, (_, r)), p)| {
            let n = (*r * *n).normalize_or_zero();
            let lit = match &cells {
                Some(c) if in_shadow(c, *p + n * 0.02, dir) => 0.0,
                _ => 1.0,
            };
            scale / light.gain_lit(n, lit)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::BodyTemplate;

    /// Without a light nothing changes; with one, Gaussians facing it come out brighter than
    /// those facing away, and the exposure scales everything.
    #[test]
    fn the_light_brightens_what_faces_it() {
        let template = BodyTemplate::load_default().unwrap();
        let anchors = template.sample_anchors(2000, 1);
        let n = anchors.len();
        let g = crate::splat::Gaussians::from_rgb(
            anchors.positions.clone(),
            vec![Vec3::splat(0.01); n],
            vec![glam::Quat::IDENTITY; n],
            vec![1.0; n],
            &vec![Vec3::splat(0.5); n],
        )
        .unwrap();
        let avatar = Avatar::new(g, anchors.skin, "test").unwrap();
        let pose = template
            .skeleton
            .skinning_matrices(&crate::body::Pose::default());
        let none = view_shading(&avatar, &template, &KeyLight::none(), &pose, 0.0);
        assert!(none
            .iter()
            .all(|s| (*s - Vec3::ONE).abs().max_element() < 1e-6));
        let light = KeyLight {
            key: Vec3::Z * 1.5,
            strength: Vec3::splat(1.5),
            ..KeyLight::none()
        };
        let lit = view_shading(&avatar, &template, &light, &pose, 0.0);
        let (front, back): (Vec<_>, Vec<_>) = avatar
            .canonical
            .positions
            .iter()
            .zip(&lit)
            .filter(|(p, _)| p.y > 1.0 && p.y < 1.4)
            .partition(|(p, _)| p.z > 0.05);
        let mean = |v: &[(&Vec3, &Vec3)]| v.iter().map(|(_, s)| s.x).sum::<f32>() / v.len() as f32;
        assert!(
            mean(&front) > 1.3 * mean(&back),
            "{} {}",
            mean(&front),
            mean(&back)
        );
        let brighter = view_shading(&avatar, &template, &light, &pose, 0.5);
        assert!((brighter[0].x / lit[0].x - 0.5f32.exp()).abs() < 1e-4);
    }
}
