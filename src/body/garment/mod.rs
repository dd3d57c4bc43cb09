//! Garments that dress the body template: CC0 MakeHuman clothes, shoes, hats and hair fitted
//! to the template, plus garments made by offsetting body regions (long coat, skirt, dress,
//! shorts), each skinned to the template's skeleton.
//!
//! Everything is in the template's canonical frame and rest pose (see [`crate::body`]). A
//! garment follows a [`MakeHumanShape`] exactly by the same per-axis scale as the body: its
//! vertices are bound to base-mesh vertices by weights and offsets that scale with the body
//! ([`GarmentBinding`]), so refitting on the scaled base equals scaling the rest vertices.
//!
//! The library is built by `lhmpp body garments` ([`crate::body::convert::garments`]) into
//! `assets/body/garments.safetensors` (layout in `io.rs`); the runtime never reads the source
//! folders.

mod io;
pub mod report;

pub use io::{FORMAT as GARMENTS_FORMAT, GARMENTS_ASSET};

use super::raycast::TriangleBvh;
use super::{vertex_normals, BodyError, BodyTemplate, MakeHumanShape, SkinWeights};
use glam::Vec3;
use std::path::Path;

/// What a garment is; decides how garments combine and which covers which.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum GarmentKind {
    /// Shirt, jacket or top of a suit.
    Top,
    /// Trousers, shorts or skirt.
    Bottom,
    /// Top and bottom in one (overall, dress, one-piece suit).
    OnePiece,
    /// Worn over a top and bottom or a one-piece.
    Coat,
    /// A pair of shoes.
    Shoes,
    /// A hair style.
    Hair,
    /// A hat.
    Hat,
}

impl GarmentKind {
    /// Every kind.
    pub const ALL: [GarmentKind; 7] = [
        GarmentKind::Shoes,
        GarmentKind::Bottom,
        GarmentKind::Top,
        GarmentKind::OnePiece,
        GarmentKind::Coat,
        GarmentKind::Hair,
        GarmentKind::Hat,
    ];

    /// Lower-case name (`top`, `one-piece`, ...), as stored in the asset.
    pub fn name(self) -> &'static str {
        match self {
            GarmentKind::Top => "top",
            GarmentKind::Bottom => "bottom",
            GarmentKind::OnePiece => "one-piece",
            GarmentKind::Coat => "coat",
            GarmentKind::Shoes => "shoes",
            GarmentKind::Hair => "hair",
            GarmentKind::Hat => "hat",
        }
    }

    /// The kind named `name` ([`GarmentKind::name`]).
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// Whether surfaces of this kind are open sheets without a meaningful outside (hair
    /// cards): they cover whatever lies under them from either side.
    pub fn two_sided(self) -> bool {
        self == GarmentKind::Hair
    }
}

/// Part of a garment, per vertex: what procedural materials colour differently.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum GarmentRegion {
    /// Torso of a top, one-piece or coat.
    Top = 0,
    /// Sleeves (vertices mostly skinned to arm bones).
    Sleeve = 1,
    /// Trousers, skirt, the lower part of a one-piece, a coat's tails.
    Bottom = 2,
    /// Small separate parts: buttons, belts, socks, pockets.
    Detail = 3,
    /// A shoe's upper.
    Upper = 4,
    /// A shoe's sole (the lowest 2 cm).
    Sole = 5,
    /// Hair.
    Hair = 6,
    /// A hat.
    Hat = 7,
}

impl GarmentRegion {
    /// Every region, by its `u8` value.
    pub const ALL: [GarmentRegion; 8] = [
        GarmentRegion::Top,
        GarmentRegion::Sleeve,
        GarmentRegion::Bottom,
        GarmentRegion::Detail,
        GarmentRegion::Upper,
        GarmentRegion::Sole,
        GarmentRegion::Hair,
        GarmentRegion::Hat,
    ];

    /// The region stored as `value`.
    pub fn from_u8(value: u8) -> Option<Self> {
        Self::ALL.get(value as usize).copied()
    }
}

/// Skeleton region of a bone, from its MakeHuman name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BoneClass {
    /// Spine, pelvis, root, clavicles, shoulders, breasts.
    Torso,
    /// Upper arm to fingers.
    Arm,
    /// Upper leg to toes.
    Leg,
    /// Neck, head and face.
    Head,
}

impl BoneClass {
    /// The class of the bone named `name`.
    pub fn of(name: &str) -> Self {
        const ARM: [&str; 5] = ["upperarm", "lowerarm", "wrist", "finger", "metacarpal"];
        const LEG: [&str; 4] = ["upperleg", "lowerleg", "foot", "toe"];
        const TORSO: [&str; 6] = ["spine", "pelvis", "root", "clavicle", "shoulder", "breast"];
        if ARM.iter().any(|p| name.starts_with(p)) {
            BoneClass::Arm
        } else if LEG.iter().any(|p| name.starts_with(p)) {
            BoneClass::Leg
        } else if TORSO.iter().any(|p| name.starts_with(p)) {
            BoneClass::Torso
        } else {
            BoneClass::Head
        }
    }

    /// The class holding the most weight of one skinned element.
    pub fn dominant(skin: &SkinWeights, i: usize, bone_names: &[String]) -> Self {
        let mut sums = [0f32; 4];
        for (b, w) in skin.bones[i].iter().zip(&skin.weights[i]) {
            let class = bone_names
                .get(*b as usize)
                .map_or(BoneClass::Torso, |n| Self::of(n));
            sums[class as usize] += w;
        }
        let best = (0..4)
            .max_by(|a, b| sums[*a].total_cmp(&sums[*b]))
            .unwrap_or(0);
        [
            BoneClass::Torso,
            BoneClass::Arm,
            BoneClass::Leg,
            BoneClass::Head,
        ][best]
    }
}

/// How each garment vertex hangs on the base mesh: the weighted sum of three base-mesh
/// vertices plus an offset. Base-mesh indices are those of MakeHuman's `hm08` (19,158
/// vertices: the template's skin vertices first, in the template's order, then helper
/// geometry); offsets are in metres for the base the garment was fitted to, and scale with the
/// body (per axis) for another shape.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GarmentBinding {
    /// Three base-mesh vertex indices per garment vertex.
    pub vertices: Vec<[u16; 3]>,
    /// Their weights (MakeHuman's fits may hold small negative weights).
    pub weights: Vec<[f32; 3]>,
    /// Offsets (metres, canonical axes).
    pub offsets: Vec<Vec3>,
}

impl GarmentBinding {
    /// Garment vertices refitted on `base` (base-mesh positions, canonical frame) with the
    /// offsets scaled per axis by `offset_scale` (the shape's axis scale against the base the
    /// binding was made on); `None` when a reference is past `base`.
    pub fn refit(&self, base: &[Vec3], offset_scale: Vec3) -> Option<Vec<Vec3>> {
        self.vertices
            .iter()
            .zip(&self.weights)
            .zip(&self.offsets)
            .map(|((v, w), o)| {
                let mut p = *o * offset_scale;
                for k in 0..3 {
                    p += *base.get(v[k] as usize)? * w[k];
                }
                Some(p)
            })
            .collect()
    }
}

/// Unit normals of a garment's vertices for shading, coverage and occlusion: the mesh's
/// normals, or for two-sided kinds (hair cards, which have no outside) the direction away from
/// `head_centre`.
pub fn shading_normals(
    kind: GarmentKind,
    vertices: &[Vec3],
    triangles: &[[u32; 3]],
    head_centre: Vec3,
) -> Vec<Vec3> {
    if kind.two_sided() {
        vertices
            .iter()
            .map(|v| (*v - head_centre).normalize_or(Vec3::Y))
            .collect()
    } else {
        vertex_normals(vertices, triangles)
    }
}

/// Farthest a garment may stand off a surface and still cover it (metres).
pub const COVER_RANGE: f32 = 0.3;

/// Deepest a garment may sink under a surface (that pokes through it) and still cover it
/// (metres).
pub const COVER_DEPTH: f32 = 0.025;

/// Whether `garment` covers the surface point `point` with outward unit normal `normal`,
/// where `blockers` is what else may stand in the way (the body): going out along the normal,
/// the ray leaves through the garment's outside (any side of a two-sided garment) within
/// [`COVER_RANGE`] before meeting a blocker; or, where the surface pokes through the garment,
/// going in, the ray enters the garment from its outside within [`COVER_DEPTH`]. Meeting the
/// garment's outside first going out means it dresses another body part.
pub fn covered(
    garment: &TriangleBvh,
    two_sided: bool,
    blockers: &TriangleBvh,
    point: Vec3,
    normal: Vec3,
) -> bool {
    let origin = point + normal * 1e-3;
    if let Some(hit) = garment.first_hit(origin, normal, COVER_RANGE) {
        if (two_sided || hit.exits)
            && blockers
                .first_hit(origin, normal, hit.t)
                .is_none_or(|b| b.t >= hit.t)
        {
            return true;
        }
    }
    garment
        .first_hit(origin, -normal, COVER_DEPTH)
        .is_some_and(|hit| two_sided || !hit.exits)
}

/// One garment in the canonical frame and rest pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Garment {
    /// Unique name (`male_casualsuit02.top`, `bob01`, `long_coat`, ...).
    pub name: String,
    /// What it is.
    pub kind: GarmentKind,
    /// Where it comes from (source file, or how it was made).
    pub source: String,
    /// Rest vertices (metres, canonical frame, template's rest shape).
    pub vertices: Vec<Vec3>,
    /// Triangles, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Top-4 skinning weights per vertex on the template's skeleton.
    pub skin: SkinWeights,
    /// How each vertex follows the base mesh.
    pub binding: GarmentBinding,
    /// Region per vertex.
    pub regions: Vec<GarmentRegion>,
    /// Ambient occlusion per vertex in the rest pose on the template (1 open, 0 enclosed),
    /// hemisphere sampling against this garment and the body.
    pub occlusion: Vec<f32>,
    /// Per template vertex: whether this garment covers it (the ray along the skin's normal
    /// meets the garment before leaving through any other surface).
    pub covers: Vec<bool>,
}

impl Garment {
    /// Area-weighted unit vertex normals of the rest mesh.
    pub fn normals(&self) -> Vec<Vec3> {
        vertex_normals(&self.vertices, &self.triangles)
    }

    /// Rest vertices on a body of `shape` (exactly the refit on the scaled base mesh).
    pub fn shaped_vertices(&self, shape: &MakeHumanShape) -> Vec<Vec3> {
        let s = shape.axis_scale();
        self.vertices.iter().map(|v| *v * s).collect()
    }

    /// Total surface area (square metres) of the rest mesh.
    pub fn area(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Checks lengths, indices, weights and bones against a skeleton of `bones` bones and a
    /// template of `body_vertices` vertices; `origin` names the source in errors.
    pub fn validate(
        &self,
        bones: usize,
        body_vertices: usize,
        origin: &str,
    ) -> Result<(), BodyError> {
        let n = self.vertices.len();
        let bad = |m: String| {
            Err(BodyError::format(
                origin,
                format!("garment `{}`: {m}", self.name),
            ))
        };
        let lens = [
            ("skin rows", self.skin.len()),
            ("binding rows", self.binding.vertices.len()),
            ("binding weights", self.binding.weights.len()),
            ("binding offsets", self.binding.offsets.len()),
            ("regions", self.regions.len()),
            ("occlusion values", self.occlusion.len()),
        ];
        if let Some((what, len)) = lens.iter().find(|(_, l)| *l != n) {
            return bad(format!("{n} vertices but {len} {what}"));
        }
        if self.covers.len() != body_vertices {
            return bad(format!(
                "covers {} body vertices, the template has {body_vertices}",
                self.covers.len()
            ));
        }
        if n == 0 || self.triangles.is_empty() {
            return bad("no geometry".into());
        }
        if let Some(t) = self
            .triangles
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= n))
        {
            return bad(format!("triangle {t:?} indexes past {n} vertices"));
        }
        for (i, (b, w)) in self.skin.bones.iter().zip(&self.skin.weights).enumerate() {
            let sum: f32 = w.iter().sum();
            if !((sum - 1.0).abs() < 1e-3 && w.iter().all(|x| *x >= 0.0)) {
                return bad(format!(
                    "vertex {i}: skinning weights {w:?} do not sum to 1"
                ));
            }
            if let Some(bone) = b
                .iter()
                .zip(w)
                .find(|(b, w)| **w > 0.0 && **b as usize >= bones)
            {
                return bad(format!("vertex {i}: bone {} past {bones} bones", bone.0));
            }
        }
        if !self.vertices.iter().all(|v| v.is_finite()) {
            return bad("non-finite vertex".into());
        }
        Ok(())
    }
}

/// Every garment, and the template they were fitted to.
#[derive(Debug, Clone, PartialEq)]
pub struct GarmentLibrary {
    /// The garments, in asset order.
    pub garments: Vec<Garment>,
    /// Ambient occlusion of the naked template per vertex in the rest pose.
    pub body_occlusion: Vec<f32>,
}

impl GarmentLibrary {
    /// The embedded library (`assets/body/garments.safetensors`).
    pub fn load_default() -> Result<Self, BodyError> {
        Self::from_bytes(GARMENTS_ASSET, "embedded assets/body/garments.safetensors")
    }

    /// Reads a library file written by [`GarmentLibrary::save`].
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let bytes = std::fs::read(path).map_err(|e| BodyError::io(path, e))?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Writes the library as a safetensors file.
    pub fn save(&self, path: &Path) -> Result<(), BodyError> {
        let bytes = self.to_bytes()?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| BodyError::io(dir, e))?;
        }
        std::fs::write(path, bytes).map_err(|e| BodyError::io(path, e))
    }

    /// Index of the garment named `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.garments.iter().position(|g| g.name == name)
    }

    /// Indices of the garments of `kind`, in asset order.
    pub fn of_kind(&self, kind: GarmentKind) -> Vec<usize> {
        (0..self.garments.len())
            .filter(|&i| self.garments[i].kind == kind)
            .collect()
    }

    /// Checks every garment against `template` (its skeleton's bones, its vertex count).
    pub fn validate(&self, template: &BodyTemplate, origin: &str) -> Result<(), BodyError> {
        if self.body_occlusion.len() != template.vertices.len() {
            return Err(BodyError::format(
                origin,
                format!(
                    "body occlusion for {} vertices, the template has {}",
                    self.body_occlusion.len(),
                    template.vertices.len()
                ),
            ));
        }
        for g in &self.garments {
            g.validate(template.skeleton.len(), template.vertices.len(), origin)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_and_regions_round_trip_their_names() {
        for k in GarmentKind::ALL {
            assert_eq!(GarmentKind::parse(k.name()), Some(k));
        }
        assert!(GarmentKind::Hair.two_sided() && !GarmentKind::Coat.two_sided());
        for r in GarmentRegion::ALL {
            assert_eq!(GarmentRegion::from_u8(r as u8), Some(r));
        }
        assert_eq!(GarmentRegion::from_u8(8), None);
    }

    #[test]
    fn bone_classes_follow_makehuman_names() {
        assert_eq!(BoneClass::of("upperarm01.L"), BoneClass::Arm);
        assert_eq!(BoneClass::of("finger3-2.R"), BoneClass::Arm);
        assert_eq!(BoneClass::of("lowerleg02.L"), BoneClass::Leg);
        assert_eq!(BoneClass::of("toe1-1.R"), BoneClass::Leg);
        assert_eq!(BoneClass::of("spine03"), BoneClass::Torso);
        assert_eq!(BoneClass::of("clavicle.L"), BoneClass::Torso);
        assert_eq!(BoneClass::of("neck02"), BoneClass::Head);
        assert_eq!(BoneClass::of("jaw"), BoneClass::Head);
    }

    #[test]
    fn refit_adds_scaled_offsets_to_weighted_base_vertices() {
        let binding = GarmentBinding {
            vertices: vec![[0, 1, 2]],
            weights: vec![[0.5, 0.25, 0.25]],
            offsets: vec![Vec3::new(0.0, 0.01, 0.02)],
        };
        let base = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let p = binding.refit(&base, Vec3::ONE).unwrap()[0];
        assert!(p.distance(Vec3::new(0.25, 0.26, 0.02)) < 1e-6);
        let scaled: Vec<Vec3> = base.iter().map(|b| *b * 2.0).collect();
        let q = binding.refit(&scaled, Vec3::splat(2.0)).unwrap()[0];
        assert!(q.distance(p * 2.0) < 1e-6);
        assert!(binding.refit(&base[..2], Vec3::ONE).is_none());
    }
}
