//! A synthetic person: the body template with seeded shape variation, dressed by an [`Outfit`],
//! as canonical Gaussians on anchor points (the ground-truth avatar).

use super::outfit::Outfit;
use crate::avatar::Avatar;
use crate::body::{BodyError, BodyTemplate, MakeHumanShape, MAKEHUMAN_MODEL_ID};
use crate::splat::Gaussians;
use glam::{Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One synthetic person and its ground-truth avatar.
#[derive(Debug, Clone)]
pub struct SyntheticPerson {
    /// The template after shape variation (vertices and joints scaled).
    pub template: BodyTemplate,
    /// Clothing colours.
    pub outfit: Outfit,
    /// Ground-truth canonical Gaussians with their skinning.
    pub avatar: Avatar,
    /// Height scale applied to the template.
    pub height_scale: f32,
    /// Girth scale (x and z) applied to the template.
    pub girth_scale: f32,
}

/// Errors while making a synthetic person.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// The body template failed to load.
    #[error(transparent)]
    Body(#[from] BodyError),
    /// The avatar could not be built.
    #[error(transparent)]
    Avatar(#[from] crate::avatar::AvatarError),
    /// The Gaussians are inconsistent.
    #[error(transparent)]
    Gaussians(#[from] crate::splat::GaussianError),
    /// Writing the bag failed.
    #[error(transparent)]
    Bag(#[from] crate::bag::BagError),
    /// A pose refers to unknown bones.
    #[error("pose: {0}")]
    Pose(String),
    /// A training sample could not be made or written.
    #[error("dataset: {0}")]
    Dataset(String),
    /// The garment library could not be loaded or prepared.
    #[error("garments: {0}")]
    Dressing(String),
}

impl SyntheticPerson {
    /// Makes the person for `seed` with `points` Gaussians on the body surface.
    pub fn new(seed: u64, points: usize) -> Result<Self, SynthError> {
        Self::wearing(seed, points, Outfit::random(seed))
    }

    /// [`Self::new`] in `outfit` instead of the seed's own.
    pub fn wearing(seed: u64, points: usize, outfit: Outfit) -> Result<Self, SynthError> {
        let (height_scale, girth_scale) = Self::shape_of(seed);
        let mut template = BodyTemplate::load_default()?;
        MakeHumanShape {
            height_scale,
            girth_scale,
        }
        .apply(&mut template);
        let anchors = template.sample_anchors(points, seed);
        let height = template.height();
        let area: f32 = template
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| template.vertices[i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum();
        // Disc-like splats whose footprints overlap enough to close the surface.
        let radius = 0.9 * (area / points as f32).sqrt();
        let colors: Vec<Vec3> = anchors
            .positions
            .iter()
            .zip(&anchors.part_labels)
            .map(|(p, label)| {
                let part = template.part_names[*label as usize].as_str();
                Vec3::from(outfit.color(part, *p, height))
            })
            .collect();
        let rotations: Vec<Quat> = anchors
            .normals
            .iter()
            .map(|n| Quat::from_rotation_arc(Vec3::Z, n.normalize_or(Vec3::Z)))
            .collect();
        let n = anchors.len();
        let gaussians = Gaussians::from_rgb(
            anchors.positions.clone(),
            vec![Vec3::new(radius, radius, 0.2 * radius); n],
            rotations,
            vec![0.98; n],
            &colors,
        )?;
        let avatar = Avatar::new(gaussians, anchors.skin, MAKEHUMAN_MODEL_ID)?;
        Ok(Self {
            template,
            outfit,
            avatar,
            height_scale,
            girth_scale,
        })
    }
}

impl SyntheticPerson {
    /// The seeded body shape of person `seed`: height scale in 0.92..1.08 and girth scale in
    /// 0.9..1.12.
    pub fn shape_of(seed: u64) -> (f32, f32) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7065_7273_6f6e);
        let height_scale = rng.gen_range(0.92..1.08);
        let girth_scale = rng.gen_range(0.9..1.12);
        (height_scale, girth_scale)
    }

    /// The shape applied to the template, as a `BodyShape` message carries it.
    pub fn shape(&self) -> MakeHumanShape {
        MakeHumanShape {
            height_scale: self.height_scale,
            girth_scale: self.girth_scale,
        }
    }
}
