//! How close a decoded compact avatar renders to the avatar it was made from: both posed
//! alike and splatted by the CPU rasteriser from cameras around the body, scored by PSNR.

use crate::avatar::Avatar;
use crate::body::{Pose, Skeleton};
use crate::eval::metrics::{psnr, ImageRef};
use crate::splat::{render, Camera, Intrinsics, RenderOptions};
use glam::Vec3;

/// `views` cameras orbiting the canonical body of `avatar` at its bounding box's centre,
/// `size`² pixels, 45° vertical field of view, far enough to frame its height.
pub fn orbit_cameras(avatar: &Avatar, views: usize, size: u32) -> Vec<Camera> {
    let (lo, hi) = avatar
        .canonical
        .positions
        .iter()
        .filter(|p| p.is_finite())
        .fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
    let (lo, hi) = if lo.x > hi.x {
        (Vec3::ZERO, Vec3::ONE)
    } else {
        (lo, hi)
    };
    let fov = 45f32.to_radians();
    let radius = 0.6 * (hi - lo).max_element() / (0.5 * fov).tan() + 0.5 * (hi.z - lo.z);
    let intrinsics = Intrinsics::from_fov_y(size, size, fov);
    (0..views)
        .map(|i| Camera::orbit(i, views, radius, 0.0, 0.5 * (lo + hi), intrinsics))
        .collect()
}

/// PSNR (dB) of `decoded`'s renders against `original`'s, on a white background, for every
/// pose (skinned through `skeleton`) and every camera, pose-major. Fails when a pose names
/// bones the skeleton lacks or the skeleton has fewer bones than the skins use.
pub fn round_trip_psnr(
    original: &Avatar,
    decoded: &Avatar,
    skeleton: &Skeleton,
    poses: &[Pose],
    cameras: &[Camera],
) -> Result<Vec<f64>, String> {
    let options = RenderOptions {
        background: Vec3::ONE,
        ..Default::default()
    };
    let mut scores = Vec::with_capacity(poses.len() * cameras.len());
    for pose in poses {
        let matrices = skeleton
            .try_skinning_matrices(pose)
            .map_err(|e| e.to_string())?;
        original
            .check_matrices(&matrices)
            .map_err(|e| e.to_string())?;
        decoded
            .check_matrices(&matrices)
            .map_err(|e| e.to_string())?;
        let (a, b) = (original.animate(&matrices), decoded.animate(&matrices));
        for camera in cameras {
            let (x, y) = (render(&a, camera, &options), render(&b, camera, &options));
            let (w, h) = (x.width as usize, x.height as usize);
            let clamp = |v: &[f32]| v.iter().map(|c| c.clamp(0.0, 1.0)).collect::<Vec<f32>>();
            let (x, y) = (clamp(&x.rgb), clamp(&y.rgb));
            scores.push(psnr(ImageRef::new(&x, w, h, 3), ImageRef::new(&y, w, h, 3)));
        }
    }
    Ok(scores)
}
