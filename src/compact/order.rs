//! A spatial order of points: Morton (Z-order) codes of their positions on a 2¹⁰ grid over
//! their bounding box, so that points near each other in space are near in the order.

use glam::Vec3;

/// Bits per axis of the Morton grid.
const BITS: u32 = 10;

/// Spreads the low 10 bits of `v` to every third bit.
fn spread(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    (x | (x << 2)) & 0x0924_9249
}

/// Indices of `points` sorted by their Morton code (ties keep their order; non-finite
/// coordinates count as the box's low corner).
pub fn morton_order(points: &[Vec3]) -> Vec<u32> {
    let finite = || points.iter().filter(|p| p.is_finite());
    let lo = finite().fold(Vec3::splat(f32::INFINITY), |a, p| a.min(*p));
    let hi = finite().fold(Vec3::splat(f32::NEG_INFINITY), |a, p| a.max(*p));
    let cells = ((1u32 << BITS) - 1) as f32;
    let scale = (hi - lo).max(Vec3::splat(1e-9)).recip() * cells;
    let code = |p: &Vec3| {
        let c = ((*p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(cells));
        let c = if c.is_finite() { c } else { Vec3::ZERO };
        spread(c.x as u32) | (spread(c.y as u32) << 1) | (spread(c.z as u32) << 2)
    };
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    let codes: Vec<u32> = points.iter().map(code).collect();
    order.sort_by_key(|&i| codes[i as usize]);
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_order_is_a_permutation_that_walks_space_in_z_order() {
        let points = vec![
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(f32::NAN, 0.0, 0.0),
        ];
        let order = morton_order(&points);
        assert_eq!(order, vec![1, 4, 2, 3, 0]);
        assert_eq!(spread(0b11), 0b1001);
    }
}
