//! View-dependent colour from real spherical harmonics of degree 0..=3 (3DGS basis and signs).

use super::gaussians::SH_C0;
use glam::Vec3;

const SH_C1: f32 = 0.488_602_5;
const SH_C2: [f32; 5] = [
    1.092_548_4,
    -1.092_548_4,
    0.315_391_57,
    -1.092_548_4,
    0.546_274_2,
];
const SH_C3: [f32; 7] = [
    -0.590_043_6,
    2.890_611_4,
    -0.457_045_8,
    0.373_176_33,
    -0.457_045_8,
    1.445_305_7,
    -0.590_043_6,
];

/// Colour of one Gaussian seen along unit direction `dir` (camera → Gaussian):
/// `0.5 + Σ SH · basis(dir)`, clamped at 0 as in 3DGS (not clamped above).
pub fn eval_sh(degree: usize, sh: &[[f32; 3]], dir: Vec3) -> Vec3 {
    let c = |k: usize| Vec3::from_array(sh[k]);
    let mut rgb = c(0) * SH_C0;
    if degree > 0 {
        let (x, y, z) = (dir.x, dir.y, dir.z);
        rgb += -SH_C1 * y * c(1) + SH_C1 * z * c(2) - SH_C1 * x * c(3);
        if degree > 1 {
            let (xx, yy, zz) = (x * x, y * y, z * z);
            let (xy, yz, xz) = (x * y, y * z, x * z);
            rgb += SH_C2[0] * xy * c(4)
                + SH_C2[1] * yz * c(5)
                + SH_C2[2] * (2.0 * zz - xx - yy) * c(6)
                + SH_C2[3] * xz * c(7)
                + SH_C2[4] * (xx - yy) * c(8);
            if degree > 2 {
                rgb += SH_C3[0] * y * (3.0 * xx - yy) * c(9)
                    + SH_C3[1] * xy * z * c(10)
                    + SH_C3[2] * y * (4.0 * zz - xx - yy) * c(11)
                    + SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * c(12)
                    + SH_C3[4] * x * (4.0 * zz - xx - yy) * c(13)
                    + SH_C3[5] * z * (xx - yy) * c(14)
                    + SH_C3[6] * x * (xx - 3.0 * yy) * c(15);
            }
        }
    }
    (rgb + Vec3::splat(0.5)).max(Vec3::ZERO)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn degree_zero_colour_ignores_the_view_direction() {
        let sh = [[0.3, -0.2, 1.0]];
        let a = eval_sh(0, &sh, Vec3::X);
        let b = eval_sh(0, &sh, Vec3::new(0.0, -0.6, 0.8));
        assert_eq!(a, b);
        assert!((a.x - (0.5 + SH_C0 * 0.3)).abs() < 1e-7);
    }

    #[test]
    fn first_order_term_brightens_towards_its_axis() {
        // Coefficient 2 multiplies +z: looking along +z is brighter than along -z.
        let mut sh = [[0.0; 3]; 4];
        sh[2] = [2.0, 2.0, 2.0];
        let front = eval_sh(1, &sh, Vec3::Z);
        let back = eval_sh(1, &sh, -Vec3::Z);
        assert!((front.x - (0.5 + 2.0 * SH_C1)).abs() < 1e-6);
        assert_eq!(back.x, 0.0, "clamped at zero");
    }
}
