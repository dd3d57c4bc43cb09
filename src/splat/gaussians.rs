//! The Gaussian set: a struct of arrays (positions, scales, rotations, opacities, SH colours,
//! optional feature channels) with validation that names the disagreeing dimension.

use glam::{Quat, Vec3};
use thiserror::Error;

/// Highest spherical-harmonics degree supported (3DGS uses 3).
pub const MAX_SH_DEGREE: usize = 3;

/// Zeroth-order SH basis constant: `rgb = 0.5 + SH_C0 · dc` (3DGS convention).
pub const SH_C0: f32 = 0.282_094_8;

/// Number of SH coefficients per colour channel for a degree: `(degree + 1)²`.
pub const fn sh_coeff_count(degree: usize) -> usize {
    (degree + 1) * (degree + 1)
}

/// Why a Gaussian set is malformed.
#[derive(Debug, Error, PartialEq)]
pub enum GaussianError {
    /// An attribute array does not have one entry per Gaussian (`N`).
    #[error("`{name}` has {actual} entries, expected {expected} (N = {n} Gaussians × {per} per Gaussian)")]
    Length {
        /// Attribute name (`scales`, `sh`, `features`, ...).
        name: &'static str,
        /// Entries found.
        actual: usize,
        /// Entries expected.
        expected: usize,
        /// Number of Gaussians.
        n: usize,
        /// Entries per Gaussian.
        per: usize,
    },
    /// The SH degree is above [`MAX_SH_DEGREE`].
    #[error("sh_degree {0} is above the supported maximum {MAX_SH_DEGREE}")]
    ShDegree(usize),
}

/// A set of 3D Gaussians, stored as one array per attribute (struct of arrays).
///
/// Colours are spherical-harmonics coefficients: Gaussian `i` owns
/// `sh[i * K .. (i + 1) * K]` with `K = (sh_degree + 1)²`, coefficient 0 being the DC term
/// (`rgb = 0.5 + SH_C0 · dc` when viewed from any direction at degree 0).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Gaussians {
    /// Centres (metres).
    pub positions: Vec<Vec3>,
    /// Standard deviations along the local axes (linear, metres).
    pub scales: Vec<Vec3>,
    /// Orientations (unit quaternions, glam xyzw).
    pub rotations: Vec<Quat>,
    /// Opacities in `[0, 1]`.
    pub opacities: Vec<f32>,
    /// SH degree of the colours, `0..=3`.
    pub sh_degree: usize,
    /// SH coefficients, `(sh_degree + 1)²` RGB triples per Gaussian.
    pub sh: Vec<[f32; 3]>,
    /// Feature channels per Gaussian (`C`; 0 when there are no features).
    pub feature_channels: usize,
    /// Features, `N × C` row-major (empty when `C = 0`).
    pub features: Vec<f32>,
}

impl Gaussians {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when the set holds no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// SH coefficients per Gaussian for the current degree.
    pub fn sh_per_gaussian(&self) -> usize {
        sh_coeff_count(self.sh_degree)
    }

    /// The SH coefficients of Gaussian `i`.
    pub fn sh_of(&self, i: usize) -> &[[f32; 3]] {
        let k = self.sh_per_gaussian();
        &self.sh[i * k..(i + 1) * k]
    }

    /// The feature row of Gaussian `i` (empty without features).
    pub fn features_of(&self, i: usize) -> &[f32] {
        let c = self.feature_channels;
        &self.features[i * c..(i + 1) * c]
    }

    /// Builds a degree-0 set from plain RGB colours in `[0, 1]`.
    pub fn from_rgb(
        positions: Vec<Vec3>,
        scales: Vec<Vec3>,
        rotations: Vec<Quat>,
        opacities: Vec<f32>,
        rgb: &[Vec3],
    ) -> Result<Self, GaussianError> {
        let sh = rgb.iter().map(|c| rgb_to_sh_dc(*c)).collect();
        let g = Self {
            positions,
            scales,
            rotations,
            opacities,
            sh_degree: 0,
            sh,
            feature_channels: 0,
            features: Vec::new(),
        };
        g.validate()?;
        Ok(g)
    }

    /// Attaches `channels` feature channels (`N × C` row-major).
    pub fn with_features(
        mut self,
        channels: usize,
        features: Vec<f32>,
    ) -> Result<Self, GaussianError> {
        self.feature_channels = channels;
        self.features = features;
        self.validate()?;
        Ok(self)
    }

    /// Checks that every attribute has one entry (or one row) per Gaussian.
    pub fn validate(&self) -> Result<(), GaussianError> {
        if self.sh_degree > MAX_SH_DEGREE {
            return Err(GaussianError::ShDegree(self.sh_degree));
        }
        let n = self.len();
        let check = |name: &'static str, actual: usize, per: usize| {
            if actual == n * per {
                Ok(())
            } else {
                Err(GaussianError::Length {
                    name,
                    actual,
                    expected: n * per,
                    n,
                    per,
                })
            }
        };
        check("scales", self.scales.len(), 1)?;
        check("rotations", self.rotations.len(), 1)?;
        check("opacities", self.opacities.len(), 1)?;
        check("sh", self.sh.len(), self.sh_per_gaussian())?;
        check("features", self.features.len(), self.feature_channels)
    }
}

/// The SH DC coefficient that shows colour `rgb` (inverse of `0.5 + SH_C0 · dc`).
pub fn rgb_to_sh_dc(rgb: Vec3) -> [f32; 3] {
    ((rgb - Vec3::splat(0.5)) / SH_C0).to_array()
}

/// The colour shown by a DC coefficient: `0.5 + SH_C0 · dc`.
pub fn sh_dc_to_rgb(dc: [f32; 3]) -> Vec3 {
    Vec3::splat(0.5) + Vec3::from_array(dc) * SH_C0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mismatched_scales_name_the_attribute() {
        let err = Gaussians::from_rgb(
            vec![Vec3::ZERO; 2],
            vec![Vec3::ONE; 1],
            vec![Quat::IDENTITY; 2],
            vec![1.0; 2],
            &[Vec3::ONE; 2],
        )
        .unwrap_err();
        assert!(
            err.to_string()
                .contains("`scales` has 1 entries, expected 2"),
            "{err}"
        );
    }

    #[test]
    fn feature_rows_must_match_channel_count() {
        let g = Gaussians::from_rgb(
            vec![Vec3::ZERO; 2],
            vec![Vec3::ONE; 2],
            vec![Quat::IDENTITY; 2],
            vec![1.0; 2],
            &[Vec3::ONE; 2],
        )
        .unwrap();
        let err = g.with_features(3, vec![0.0; 5]).unwrap_err();
        assert!(matches!(
            err,
            GaussianError::Length {
                name: "features",
                ..
            }
        ));
    }

    #[test]
    fn rgb_survives_the_sh_dc_round_trip() {
        let c = Vec3::new(0.1, 0.5, 0.9);
        assert!((sh_dc_to_rgb(rgb_to_sh_dc(c)) - c).abs().max_element() < 1e-6);
    }
}
