//! The official Gaussian decoder's inference rules per body part, applied to avatars made on
//! the SMPL-X prior: hand opacities fixed, upper-body scales clamped. The values belong to
//! the network (`model::gs_head`), the part masks to the prior (`body::official`).

use glam::Vec3;

use crate::body::official::OfficialPrior;
use crate::model::gs_head::{HAND_OPACITY, UPPER_BODY_MAX_SCALE};

/// Sets the opacity of the prior's hand points to [`HAND_OPACITY`] and clamps the scales of
/// its upper-body points to [`UPPER_BODY_MAX_SCALE`] (`GSMLPDecoder` at inference).
/// Points beyond the shortest of the three lengths are left as they are.
pub fn apply_part_rules(prior: &OfficialPrior, scales: &mut [Vec3], opacities: &mut [f32]) {
    let n = prior.len().min(scales.len()).min(opacities.len());
    for i in 0..n {
        if prior.is_hand[i] {
            opacities[i] = HAND_OPACITY;
        }
        if prior.is_upper_body[i] {
            scales[i] = scales[i].min(Vec3::splat(UPPER_BODY_MAX_SCALE));
        }
    }
}
