//! Compact avatars for the wire and for files: an [`Avatar`]'s canonical Gaussians as SPZ
//! (Niantic's compressed splat format, [`crate::splat::write_spz`]) and its skinning as a
//! second gzip blob of quantised bone indices and weights ([`skin`]), the Gaussians of both in
//! one spatial (Morton) order so that neighbours sit side by side and compress.
//!
//! What is kept: positions to 1/4096 m, opacities and colours to 8 bits, scales to 1/16 in
//! ln σ, rotations to SPZ's smallest-three 9-bit components, weights to 1/255. What is not:
//! the Gaussians' order and their latent feature channels (as `GaussianAvatar` leaves them
//! out too). The skeleton travels beside the blobs, in the message (`CompactAvatar.msg`).

pub mod fidelity;
mod order;
mod skin;

pub use order::morton_order;

use crate::avatar::{Avatar, AvatarError};
use crate::splat::{read_spz, write_spz, Gaussians, SpzError, DEFAULT_FRACTIONAL_BITS};
use thiserror::Error;

/// Why a compact avatar cannot be made or read.
#[derive(Debug, Error)]
pub enum CompactError {
    /// The SPZ part.
    #[error("compact avatar: {0}")]
    Spz(#[from] SpzError),
    /// The skin blob's gzip stream.
    #[error("compact avatar skin: gzip stream: {0}")]
    Gzip(std::io::Error),
    /// The skin blob does not hold what its header says.
    #[error("compact avatar skin: {0}")]
    Skin(String),
    /// The decoded Gaussians and skin do not make an avatar.
    #[error("compact avatar: {0}")]
    Avatar(#[from] AvatarError),
}

/// The two blobs of a compact avatar.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct CompactAvatar {
    /// SPZ v3 bytes (gzip) of the canonical Gaussians.
    pub spz: Vec<u8>,
    /// The skin blob (gzip, `LHSK`), one row per Gaussian in the SPZ's order.
    pub skin: Vec<u8>,
}

impl CompactAvatar {
    /// Encodes `avatar` with positions at SPZ's default 12 fraction bits.
    pub fn encode(avatar: &Avatar) -> Result<Self, CompactError> {
        Self::encode_with(avatar, DEFAULT_FRACTIONAL_BITS)
    }

    /// Encodes `avatar` with positions at `fractional_bits` fraction bits.
    pub fn encode_with(avatar: &Avatar, fractional_bits: u8) -> Result<Self, CompactError> {
        let order = morton_order(&avatar.canonical.positions);
        let sorted = reorder(&avatar.canonical, &order);
        Ok(Self {
            spz: write_spz(&sorted, fractional_bits)?,
            skin: skin::encode(&avatar.skin, &order)?,
        })
    }

    /// The avatar these blobs hold, bound to `body_model` (its Gaussians in the blobs' order).
    pub fn decode(&self, body_model: &str) -> Result<Avatar, CompactError> {
        let canonical = read_spz(&self.spz)?;
        let skin = skin::decode(&self.skin, canonical.len())?;
        Ok(Avatar::new(canonical, skin, body_model)?)
    }

    /// Bytes of both blobs.
    pub fn len(&self) -> usize {
        self.spz.len() + self.skin.len()
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
