//! Space-filling-curve serialization of voxel grid coordinates (PTv3 / Sonata).
//!
//! Four orders, as in the official `point_backbone.order` list: Z-order (Morton), Z-order with x and y
//! swapped, Hilbert (Skilling's transform) and Hilbert with x and y swapped. Each order is a
//! permutation of the points (sorted by code) together with its inverse.

use rayon::prelude::*;

/// One serialization order of the official config (`z`, `z-trans`, `hilbert`, `hilbert-trans`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum SerializationOrder {
    /// Morton code, x most significant.
    Z,
    /// Morton code of (y, x, z).
    ZTrans,
    /// Hilbert code (Skilling), x most significant.
    Hilbert,
    /// Hilbert code of (y, x, z).
    HilbertTrans,
}

impl SerializationOrder {
    /// The four orders of the official config, in its order.
    pub fn official() -> Vec<Self> {
        vec![Self::Z, Self::ZTrans, Self::Hilbert, Self::HilbertTrans]
    }
}

/// Serialization depth as PTv3 computes it: `bit_length(max(grid) + 1)`.
pub fn serialization_depth(grid: &[[u32; 3]]) -> u32 {
    let max = grid
        .par_iter()
        .map(|g| g[0].max(g[1]).max(g[2]))
        .max()
        .unwrap_or(0);
    u32::BITS - (max + 1).leading_zeros()
}

/// Spread the low 21 bits of `v` so that bit i lands on bit 3i.
fn spread_bits(v: u32) -> u64 {
    let mut x = u64::from(v) & 0x1f_ffff;
    x = (x | (x << 32)) & 0x1f00000000ffff;
    x = (x | (x << 16)) & 0x1f0000ff0000ff;
    x = (x | (x << 8)) & 0x100f00f00f00f00f;
    x = (x | (x << 4)) & 0x10c30c30c30c30c3;
    x = (x | (x << 2)) & 0x1249249249249249;
    x
}

/// Morton code of one cell: bit i of x goes to bit 3i+2, of y to 3i+1, of z to 3i.
pub fn morton_code(x: u32, y: u32, z: u32) -> u64 {
    (spread_bits(x) << 2) | (spread_bits(y) << 1) | spread_bits(z)
}

/// Hilbert code of one cell on a cube of side `2^depth` (Skilling's transform, as PTv3's
/// `hilbert.encode` with `num_dims = 3`): axes transform, interleave (dim 0 most significant),
/// then Gray decode.
pub fn hilbert_code(x: u32, y: u32, z: u32, depth: u32) -> u64 {
    let mut c = [x, y, z];
    for s in (0..depth).rev() {
        let lower = (1u32 << s) - 1;
        for d in 0..3 {
            if (c[d] >> s) & 1 == 1 {
                c[0] ^= lower;
            } else {
                let t = (c[0] ^ c[d]) & lower;
                c[d] ^= t;
                c[0] ^= t;
            }
        }
    }
    let mut b = morton_code(c[0], c[1], c[2]);
    let mut shift = 1;
    while shift < 64 {
        b ^= b >> shift;
        shift <<= 1;
    }
    b
}

/// The code of one cell under one order.
pub fn encode(order: SerializationOrder, g: [u32; 3], depth: u32) -> u64 {
    match order {
        SerializationOrder::Z => morton_code(g[0], g[1], g[2]),
        SerializationOrder::ZTrans => morton_code(g[1], g[0], g[2]),
        SerializationOrder::Hilbert => hilbert_code(g[0], g[1], g[2], depth),
        SerializationOrder::HilbertTrans => hilbert_code(g[1], g[0], g[2], depth),
    }
}

/// One order as a permutation (`order[k]` = point at sequence position k) and its inverse.
#[derive(Debug, Clone)]
pub struct Serialized {
    /// Which curve.
    pub kind: SerializationOrder,
    /// Sequence position → point index.
    pub order: Vec<u32>,
    /// Point index → sequence position.
    pub inverse: Vec<u32>,
}

/// Sort the points by their code under `kind` (ties, which unique grid cells never have, by index).
pub fn serialize(grid: &[[u32; 3]], kind: SerializationOrder, depth: u32) -> Serialized {
    let mut keyed: Vec<(u64, u32)> = grid
        .par_iter()
        .enumerate()
        .map(|(i, &g)| (encode(kind, g, depth), i as u32))
        .collect();
    keyed.par_sort_unstable();
    let order: Vec<u32> = keyed.into_iter().map(|(_, i)| i).collect();
    let inverse = invert_permutation(&order);
    Serialized {
        kind,
        order,
        inverse,
    }
}

/// Serialize under every order of the list (depth from the grid, as PTv3).
pub fn serialize_all(grid: &[[u32; 3]], orders: &[SerializationOrder]) -> Vec<Serialized> {
    let depth = serialization_depth(grid);
    orders.iter().map(|&k| serialize(grid, k, depth)).collect()
}

/// Inverse of a permutation of `0..n`.
pub fn invert_permutation(perm: &[u32]) -> Vec<u32> {
    let mut inv = vec![0u32; perm.len()];
    for (k, &i) in perm.iter().enumerate() {
        inv[i as usize] = k as u32;
    }
    inv
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{seq::SliceRandom, SeedableRng};

    fn full_cube(k: u32) -> Vec<[u32; 3]> {
        let n = 1u32 << k;
        let mut g = Vec::new();
        for x in 0..n {
            for y in 0..n {
                for z in 0..n {
                    g.push([x, y, z]);
                }
            }
        }
        g
    }

    fn mean_step(grid: &[[u32; 3]], order: &[u32]) -> f64 {
        let dist = |a: [u32; 3], b: [u32; 3]| {
            (0..3)
                .map(|d| (a[d] as f64 - b[d] as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let total: f64 = order
            .windows(2)
            .map(|w| dist(grid[w[0] as usize], grid[w[1] as usize]))
            .sum();
        total / (order.len() - 1) as f64
    }

    #[test]
    fn every_order_is_a_permutation_with_its_inverse() {
        let mut grid = full_cube(3);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        grid.shuffle(&mut rng);
        grid.truncate(300);
        for s in serialize_all(&grid, &SerializationOrder::official()) {
            let mut seen = s.order.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..grid.len() as u32).collect::<Vec<_>>());
            for (k, &i) in s.order.iter().enumerate() {
                assert_eq!(s.inverse[i as usize], k as u32);
            }
        }
    }

    #[test]
    fn hilbert_steps_are_face_neighbours_on_a_full_cube() {
        for k in 1..=4 {
            let grid = full_cube(k);
            // PTv3 takes bit_length(max + 1): one bit more than the cube needs; the cube is then
            // the first octant of the curve, still one connected Hilbert path.
            let depth = serialization_depth(&grid);
            assert_eq!(depth, k + 1);
            for kind in [
                SerializationOrder::Hilbert,
                SerializationOrder::HilbertTrans,
            ] {
                let s = serialize(&grid, kind, depth);
                for w in s.order.windows(2) {
                    let (a, b) = (grid[w[0] as usize], grid[w[1] as usize]);
                    let l1: i64 = (0..3).map(|d| (a[d] as i64 - b[d] as i64).abs()).sum();
                    assert_eq!(l1, 1, "{kind:?} k={k}: {a:?} -> {b:?}");
                }
            }
        }
    }

    #[test]
    fn z_and_hilbert_orders_keep_neighbours_close() {
        let grid = full_cube(5);
        let mut random: Vec<u32> = (0..grid.len() as u32).collect();
        random.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(1));
        let random_step = mean_step(&grid, &random);
        for s in serialize_all(&grid, &SerializationOrder::official()) {
            let step = mean_step(&grid, &s.order);
            assert!(
                step < random_step / 5.0,
                "{:?}: {step} vs random {random_step}",
                s.kind
            );
        }
    }

    #[test]
    fn morton_puts_x_on_the_most_significant_bit() {
        assert_eq!(morton_code(1, 0, 0), 0b100);
        assert_eq!(morton_code(0, 1, 0), 0b010);
        assert_eq!(morton_code(0, 0, 1), 0b001);
        assert_eq!(morton_code(2, 0, 0), 0b100_000);
        assert_eq!(encode(SerializationOrder::ZTrans, [1, 0, 0], 1), 0b010);
    }

    #[test]
    fn transposed_orders_swap_x_and_y() {
        let g = [5, 9, 3];
        assert_eq!(
            encode(SerializationOrder::HilbertTrans, g, 4),
            encode(SerializationOrder::Hilbert, [9, 5, 3], 4)
        );
    }
}
