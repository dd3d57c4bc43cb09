//! Compact avatars for the wire and for files: an [`Avatar`]'s canonical Gaussians quantised
//! as SPZ (Niantic's compressed splat format, [`crate::splat::SpzQuantised`]) in a layout that
//! compresses further ([`gaussians`]), and its skinning as a second blob of quantised bone
//! indices and weights ([`skin`]); both gzip, the Gaussians of both in one spatial (Morton)
//! order so that neighbours sit side by side. [`CompactAvatar::to_spz`] gives the Gaussians
//! as a standard SPZ file.
//!
//! What is kept ([`CompactOptions`]): positions in `1/2^fractional_bits` m steps, opacities
//! and colours in 8 bits, scales in 1/16 steps of ln σ, rotations as SPZ's smallest-three
//! components rounded to `rotation_bits`, weights in `1/weight_levels` steps. What is not: the
//! Gaussians' order and their latent feature channels (which `GaussianAvatar` leaves out too).
//! The skeleton travels beside the blobs, in the message (`CompactAvatar.msg`).

pub mod fidelity;
mod gaussians;
mod order;
mod skin;

pub use order::morton_order;

use crate::avatar::{Avatar, AvatarError};
use crate::splat::{Gaussians, SpzError, SpzQuantised};
use thiserror::Error;

/// Why a compact avatar cannot be made or read.
#[derive(Debug, Error)]
pub enum CompactError {
    /// Quantising or writing SPZ.
    #[error("compact avatar: {0}")]
    Spz(#[from] SpzError),
    /// A blob's gzip stream (the blob named).
    #[error("compact avatar {0}: gzip stream: {1}")]
    Gzip(&'static str, std::io::Error),
    /// The Gaussians blob does not hold what its header says.
    #[error("compact avatar Gaussians: {0}")]
    Gaussians(String),
    /// The skin blob does not hold what its header says.
    #[error("compact avatar skin: {0}")]
    Skin(String),
    /// The decoded Gaussians and skin do not make an avatar.
    #[error("compact avatar: {0}")]
    Avatar(#[from] AvatarError),
}

/// How finely a compact avatar keeps each attribute.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CompactOptions {
    /// Position fraction bits: steps of `1/2^bits` metres.
    pub fractional_bits: u8,
    /// Bits kept of SPZ's 9-bit rotation components (1 to 9).
    pub rotation_bits: u8,
    /// Skinning weights in `1/levels` steps (1 to 255).
    pub weight_levels: u8,
}

impl Default for CompactOptions {
    /// 1/1024 m positions, 6-bit rotation components, weights in 1/31 steps: on the embedded
    /// network's avatar of the demo bag 53 dB PSNR of the full avatar's renders (512², at rest
    /// and walking) at an eighth of its message size, on the 700M layout's 56 dB at a
    /// thirteenth (`lhmpp bench compact`; docs/status.md).
    fn default() -> Self {
        Self {
            fractional_bits: 10,
            rotation_bits: 6,
            weight_levels: 31,
        }
    }
}

/// The two blobs of a compact avatar.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct CompactAvatar {
    /// The Gaussians (gzip, `LHCA`: SPZ's quantisation, delta-coded positions).
    pub gaussians: Vec<u8>,
    /// The skin (gzip, `LHSK`), one row per Gaussian in the Gaussians blob's order.
    pub skin: Vec<u8>,
}

impl CompactAvatar {
    /// Encodes `avatar` with the default options.
    pub fn encode(avatar: &Avatar) -> Result<Self, CompactError> {
        Self::encode_with(avatar, CompactOptions::default())
    }

    /// Encodes `avatar` with `options`.
    pub fn encode_with(avatar: &Avatar, options: CompactOptions) -> Result<Self, CompactError> {
        if !(1..=9).contains(&options.rotation_bits) {
            return Err(CompactError::Gaussians(format!(
                "{} rotation bits (1 to 9)",
                options.rotation_bits
            )));
        }
        let order = morton_order(&avatar.canonical.positions);
        let sorted = reorder(&avatar.canonical, &order);
        let quantised = SpzQuantised::from_gaussians(&sorted, options.fractional_bits)?;
        Ok(Self {
            gaussians: gaussians::encode(&quantised, options.rotation_bits)?,
            skin: skin::encode(&avatar.skin, &order, options.weight_levels)?,
        })
    }

    /// The avatar these blobs hold, bound to `body_model` (its Gaussians in the blobs' order).
    pub fn decode(&self, body_model: &str) -> Result<Avatar, CompactError> {
        let canonical = gaussians::decode(&self.gaussians)?.to_gaussians()?;
        let skin = skin::decode(&self.skin, canonical.len())?;
        Ok(Avatar::new(canonical, skin, body_model)?)
    }

    /// The Gaussians as a standard SPZ v3 file (gzip), the values unchanged.
    pub fn to_spz(&self) -> Result<Vec<u8>, CompactError> {
        Ok(gaussians::decode(&self.gaussians)?.to_spz()?)
    }

    /// Bytes of both blobs.
    pub fn len(&self) -> usize {
        self.gaussians.len() + self.skin.len()
    }

    /// True when both blobs are empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The Gaussians of `g` in `order` (features dropped).
fn reorder(g: &Gaussians, order: &[u32]) -> Gaussians {
    let at = |i: &u32| *i as usize;
    Gaussians {
        positions: order.iter().map(|i| g.positions[at(i)]).collect(),
        scales: order.iter().map(|i| g.scales[at(i)]).collect(),
        rotations: order.iter().map(|i| g.rotations[at(i)]).collect(),
        opacities: order.iter().map(|i| g.opacities[at(i)]).collect(),
        sh_degree: g.sh_degree,
        sh: order
            .iter()
            .flat_map(|i| g.sh_of(at(i)).iter().copied())
            .collect(),
        feature_channels: 0,
        features: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::SkinWeights;
    use crate::splat::read_spz;
    use glam::{Quat, Vec3};

    #[test]
    fn the_spz_of_a_compact_avatar_holds_its_decoded_gaussians() {
        let n = 64;
        let g = Gaussians::from_rgb(
            (0..n)
                .map(|i| Vec3::new(i as f32 * 0.01, (i % 7) as f32 * 0.1, 0.0))
                .collect(),
            vec![Vec3::new(0.01, 0.02, 0.03); n],
            (0..n)
                .map(|i| Quat::from_rotation_y(i as f32 * 0.1))
                .collect(),
            vec![0.8; n],
            &vec![Vec3::new(0.2, 0.5, 0.9); n],
        )
        .unwrap();
        let skin = SkinWeights {
            bones: vec![[0, 1, 0, 0]; n],
            weights: vec![[0.75, 0.25, 0.0, 0.0]; n],
        };
        let avatar = Avatar::new(g, skin, "test").unwrap();
        let compact = CompactAvatar::encode(&avatar).unwrap();
        let decoded = compact.decode("test").unwrap();
        let spz = read_spz(&compact.to_spz().unwrap()).unwrap();
        assert_eq!(spz.positions, decoded.canonical.positions);
        assert_eq!(spz.sh, decoded.canonical.sh);
        let levels = CompactOptions::default().weight_levels as f32;
        assert_eq!(
            decoded.skin.weights[0],
            [0.75f32, 0.25, 0.0, 0.0].map(|w| (w * levels).round() / levels)
        );
        let e = CompactAvatar::encode_with(
            &avatar,
            CompactOptions {
                rotation_bits: 0,
                ..Default::default()
            },
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("rotation bits"), "{e}");
    }
}
