//! Growth: more Gaussians where the views ask for more than the body template gives.
//!
//! As in 3DGS's densification, the Gaussians whose screen-space position gradient stays large
//! over the views that see them (the silhouette pulls them out towards a skirt's hem or a
//! strand of hair; a colour edge pulls at them) are copied: a small one is cloned in place, a
//! large one is split in two smaller ones placed within it. A copy keeps its parent's skin
//! row, so it moves with the same bones, and its anchor is where it began.

use super::params::{Adam, Params};
use glam::{Quat, Vec3};

/// Steps between growths.
const EVERY: usize = 20;
/// Growth stops after this share of the steps, to let the grown Gaussians settle.
const UNTIL: f32 = 0.6;
/// Share of the Gaussians seen that may be copied at one growth.
const SHARE: f32 = 0.05;
/// Least mean screen-space gradient norm (per view) of a Gaussian copied.
const MIN_GRAD: f32 = 2e-6;
/// Largest scale (metres) of a Gaussian cloned rather than split.
const CLONE_BELOW: f32 = 0.01;

/// Whether step `iteration`, `progress` (0–1) through the steps, grows.
pub(crate) fn due(iteration: usize, progress: f32) -> bool {
    iteration % EVERY == 0 && progress < UNTIL
}

/// Copies the Gaussians with the largest mean gradient (`grad_2d / seen`); returns the
/// `(parent, child)` index pairs added.
pub(crate) fn densify(
    params: &mut Params,
    adam: &mut Adam,
    grad_2d: &[f32],
    seen: &[u32],
    max_gaussians: usize,
) -> Vec<(usize, usize)> {
    let _ = adam;
    let n = params.len();
    let room = max_gaussians.saturating_sub(n);
    if room == 0 {
        return Vec::new();
    }
    let mut candidates: Vec<(f32, usize)> = (0..n)
        .filter(|&i| seen[i] > 0)
        .map(|i| (grad_2d[i] / seen[i] as f32, i))
        .filter(|(g, _)| *g >= MIN_GRAD)
        .collect();
    let seen_count = seen.iter().filter(|s| **s > 0).count();
    let take = ((seen_count as f32 * SHARE) as usize).min(room);
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    candidates.truncate(take);
    let mut added = Vec::with_capacity(candidates.len());
    for (_, i) in candidates {
        let scale = params.log_scale[i].exp();
        let child = params.len();
        if scale.max_element() <= CLONE_BELOW {
            params.push_copy(
                i,
                params.position[i],
                params.log_scale[i],
                params.opacity_logit[i],
            );
        } else {
            // Split: two Gaussians 1.6× smaller, one on each side along the longest axis.
            let q = Quat::from_vec4(params.rotation[i]).normalize();
            let axis = longest_axis(scale);
            let offset = q * (axis * scale);
            let smaller = params.log_scale[i] - Vec3::splat(1.6f32.ln());
            params.push_copy(
                i,
                params.position[i] + offset,
                smaller,
                params.opacity_logit[i],
            );
            params.position[i] -= offset;
            params.log_scale[i] = smaller;
        }
        added.push((i, child));
    }
    added
}

/// The unit local axis of the largest scale.
fn longest_axis(scale: Vec3) -> Vec3 {
    if scale.x >= scale.y && scale.x >= scale.z {
        Vec3::X
    } else if scale.y >= scale.z {
        Vec3::Y
    } else {
        Vec3::Z
    }
}
