//! The frame description and flat Gaussian arrays handed to the CUDA rasteriser
//! (`rasterize.cu`), laid out exactly as its C interface (`rasterize.h`) expects.

use crate::splat::camera::Camera;
use crate::splat::gaussians::Gaussians;
use crate::splat::render::RenderOptions;
use bytemuck::{Pod, Zeroable};

/// `LhmppSplatParams` of `rasterize.h`: camera, image size and options of one frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct SplatParams {
    /// World → optical frame, 3×4 row-major `[R | t]`.
    pub view: [f32; 12],
    /// Camera centre in the world.
    pub center: [f32; 3],
    /// Focal lengths and principal point (pixels).
    pub fx: f32,
    /// See `fx`.
    pub fy: f32,
    /// See `fx`.
    pub cx: f32,
    /// See `fx`.
    pub cy: f32,
    /// Image width (pixels).
    pub width: i32,
    /// Image height (pixels).
    pub height: i32,
    /// Near plane (metres).
    pub near_plane: f32,
    /// Far plane (metres).
    pub far_plane: f32,
    /// Screen-space low-pass (pixels²).
    pub low_pass: f32,
    /// Background colour.
    pub background: [f32; 3],
    /// SH degree of the colours.
    pub sh_degree: i32,
    /// Feature channels rendered (0 = none).
    pub channels: i32,
    /// Number of Gaussians.
    pub num_gaussians: i32,
}

impl SplatParams {
    /// The parameters of rendering `gaussians` from `camera` with `options` (features are
    /// rendered when the options ask for them and the Gaussians have some).
    pub fn new(gaussians: &Gaussians, camera: &Camera, options: &RenderOptions) -> Self {
        Self::for_scene(
            camera,
            options,
            gaussians.len(),
            gaussians.sh_degree,
            gaussians.feature_channels,
        )
    }

    /// The parameters of rendering `num_gaussians` Gaussians with SH colours of `sh_degree`
    /// and `feature_channels` feature channels from `camera` with `options`.
    pub fn for_scene(
        camera: &Camera,
        options: &RenderOptions,
        num_gaussians: usize,
        sh_degree: usize,
        feature_channels: usize,
    ) -> Self {
        let view = camera.camera_from_world();
        let m = view.matrix3;
        let t = view.translation;
        let rows = [m.row(0), m.row(1), m.row(2)];
        let mut v = [0.0; 12];
        for (r, row) in rows.iter().enumerate() {
            v[4 * r..4 * r + 3].copy_from_slice(&row.to_array());
            v[4 * r + 3] = t[r];
        }
        let k = camera.intrinsics;
        Self {
            view: v,
            center: camera.center().to_array(),
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            width: k.width as i32,
            height: k.height as i32,
            near_plane: options.near,
            far_plane: options.far,
            low_pass: options.low_pass,
            background: options.background.to_array(),
            sh_degree: sh_degree as i32,
            channels: options.rendered_channels(feature_channels) as i32,
            num_gaussians: num_gaussians as i32,
        }
    }
}

/// The Gaussians as the flat `f32` arrays of `LhmppSplatScene` (struct of arrays).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FlatScene {
    /// `N × 3`.
    pub positions: Vec<f32>,
    /// `N × 3`.
    pub scales: Vec<f32>,
    /// `N × 4`, `x y z w`.
    pub rotations: Vec<f32>,
    /// `N`.
    pub opacities: Vec<f32>,
    /// `N × (degree + 1)² × 3`.
    pub sh: Vec<f32>,
    /// `N × C` (empty when no features are rendered).
    pub features: Vec<f32>,
    /// `C` background features.
    pub background_features: Vec<f32>,
}

impl FlatScene {
    /// Flattens `gaussians` for a render with `options`.
    pub fn new(gaussians: &Gaussians, options: &RenderOptions) -> Self {
        let channels = options.rendered_channels(gaussians.feature_channels);
        Self {
            positions: bytemuck::cast_slice(&gaussians.positions).to_vec(),
            scales: bytemuck::cast_slice(&gaussians.scales).to_vec(),
            rotations: bytemuck::cast_slice(&gaussians.rotations).to_vec(),
            opacities: gaussians.opacities.clone(),
            sh: bytemuck::cast_slice(&gaussians.sh).to_vec(),
            features: if channels > 0 {
                gaussians.features.clone()
            } else {
                Vec::new()
            },
            background_features: options.background_features_for(channels),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splat::camera::Intrinsics;
    use glam::Vec3;

    #[test]
    fn params_match_the_c_layout_and_carry_the_view_transform() {
        // 12 + 3 + 4 floats, 2 ints, 3 floats, 3 floats, 3 ints.
        assert_eq!(std::mem::size_of::<SplatParams>(), 30 * 4);
        let camera = Camera::look_at(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            Intrinsics::from_fov_y(64, 48, 0.8),
        );
        let p = SplatParams::new(&Gaussians::default(), &camera, &RenderOptions::default());
        let world = Vec3::new(0.3, 1.2, -0.4);
        let want = camera.camera_from_world().transform_point3(world);
        let v = p.view;
        let got = Vec3::new(
            v[0] * world.x + v[1] * world.y + v[2] * world.z + v[3],
            v[4] * world.x + v[5] * world.y + v[6] * world.z + v[7],
            v[8] * world.x + v[9] * world.y + v[10] * world.z + v[11],
        );
        assert!((got - want).length() < 1e-6, "{got} vs {want}");
        assert_eq!(p.center, [0.0, 1.0, 3.0]);
        assert_eq!((p.width, p.height, p.channels), (64, 48, 0));
    }
}
