//! A dressed synthetic person: the shaped template wearing a seeded [`Wardrobe`], as canonical
//! Gaussians sampled by area on the garments' surfaces and on the skin they leave bare (skin
//! under garments, and garment surfaces under other garments, are left out), coloured with
//! their albedo (unlit colour), each with a normal, ambient occlusion and gloss for lighting
//! and the garment it lies on; and the per-anchor ground truth (albedo, garment and position
//! of the outermost surface over each anchor).

use super::dressing_room::{DressingRoom, SurfaceHit};
use super::person::{SynthError, SyntheticPerson};
use super::wardrobe::Wardrobe;
use crate::avatar::Avatar;
use crate::body::convert::top_k;
use crate::body::raycast::TriangleBvh;
use crate::body::{
    AnchorPoints, BodyTemplate, GarmentRegion, MakeHumanShape, SkinWeights, MAKEHUMAN_MODEL_ID,
};
use crate::splat::Gaussians;
use glam::{Mat4, Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Gloss of bare skin.
const SKIN_GLOSS: f32 = 0.15;

/// How far shadow rays start off their Gaussian, along its normal and towards the light
/// (metres): clear of the surface the Gaussian lies on.
const SHADOW_BIAS: f32 = 0.005;

/// Longest shadow ray (metres): the whole person.
const SHADOW_RANGE: f32 = 2.5;

/// A dressed person and its ground-truth avatar.
#[derive(Debug, Clone)]
pub struct DressedPerson {
    /// The template after shape variation.
    pub template: BodyTemplate,
    /// What the person wears.
    pub wardrobe: Wardrobe,
    /// Ground-truth canonical Gaussians (albedo colours) with their skinning.
    pub avatar: Avatar,
    /// Unit normal of each Gaussian (canonical, shaped).
    pub normals: Vec<Vec3>,
    /// Ambient occlusion of each Gaussian (1 open).
    pub occlusion: Vec<f32>,
    /// Gloss of each Gaussian (0 matte).
    pub gloss: Vec<f32>,
    /// What each Gaussian lies on: 0 the skin, `1 + i` garment `i` of the library.
    pub garment_ids: Vec<u8>,
    /// Height scale applied to the template.
    pub height_scale: f32,
    /// Girth scale applied to the template.
    pub girth_scale: f32,
}

/// Ground truth per anchor.
#[derive(Debug, Clone, PartialEq)]
pub struct AnchorTruth {
    /// Albedo of the outermost surface over each anchor (garment over skin, hair over head).
    pub albedo: Vec<Vec3>,
    /// What that surface is: 0 the skin, `1 + i` garment `i` of the library.
    pub garment: Vec<u8>,
    /// Where that surface is (canonical, shaped).
    pub surface: Vec<Vec3>,
    /// Skinning weights of that surface point.
    pub surface_skin: SkinWeights,
}

/// A surface to sample: the skin (`None`) or worn garment `Some(k)`, with its shaped
/// triangle areas.
struct Surface {
    garment: Option<usize>,
    triangles: Vec<[u32; 3]>,
    areas: Vec<f32>,
}

fn blend_skin(skin: &SkinWeights, t: [u32; 3], bary: Vec3) -> ([u16; 4], [f32; 4]) {
    let mut influences = Vec::with_capacity(12);
    for (k, &v) in t.iter().enumerate() {
        for (b, w) in skin.bones[v as usize].iter().zip(&skin.weights[v as usize]) {
            influences.push((*b, w * bary[k]));
        }
    }
    let v = t[0] as usize;
    top_k(&influences).unwrap_or((skin.bones[v], skin.weights[v]))
}

fn interpolate<T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>>(
    values: &[T],
    t: [u32; 3],
    bary: Vec3,
) -> T {
    values[t[0] as usize] * bary.x + values[t[1] as usize] * bary.y + values[t[2] as usize] * bary.z
}

fn nearest_corner(t: [u32; 3], bary: Vec3) -> usize {
    let k = if bary.x >= bary.y && bary.x >= bary.z {
        0
    } else if bary.y >= bary.z {
        1
    } else {
        2
    };
    t[k] as usize
}

impl DressedPerson {
    /// The dressed person of `seed` (body shape as [`SyntheticPerson::new`] draws it for the
    /// same seed) with `points` Gaussians on the surfaces that show.
    pub fn new(seed: u64, points: usize) -> Result<Self, SynthError> {
        Self::new_with(seed, points, false)
    }

    /// [`Self::new`]; with `contrasting_backs`, every upper garment gets a back panel of
    /// another colour ([`Wardrobe::with_contrasting_backs`]).
    pub fn new_with(seed: u64, points: usize, contrasting_backs: bool) -> Result<Self, SynthError> {
        let room = DressingRoom::shared()?;
        let (height_scale, girth_scale) = SyntheticPerson::shape_of(seed);
        let shape = MakeHumanShape {
            height_scale,
            girth_scale,
        };
        let mut wardrobe = Wardrobe::random(seed, &room.library);
        if contrasting_backs {
            wardrobe = wardrobe.with_contrasting_backs(seed, &room.library);
        }
        Self::dress(room, seed, shape, wardrobe, points)
    }

    /// `wardrobe` on the template of `shape` in `room`, `points` Gaussians drawn with `seed`
    /// (area-uniform over the bare skin and the garments; draws on hidden garment surfaces are
    /// dropped and drawn again, up to four draws per Gaussian).
    pub fn dress(
        room: &DressingRoom,
        seed: u64,
        shape: MakeHumanShape,
        wardrobe: Wardrobe,
        points: usize,
    ) -> Result<Self, SynthError> {
        let rest = &room.template;
        let template = shape.shaped(rest);
        let s = shape.axis_scale();
        let worn: Vec<usize> = wardrobe.garments.iter().map(|g| g.index).collect();
        let area = |v: &[Vec3], t: &[u32; 3]| {
            let [a, b, c] = t.map(|i| v[i as usize] * s);
            0.5 * (b - a).cross(c - a).length()
        };
        // The skin left bare: triangles not wholly covered by one of the worn garments.
        let hidden: Vec<bool> = (0..rest.vertices.len())
            .map(|v| worn.iter().any(|&g| room.library.garments[g].covers[v]))
            .collect();
        let mut surfaces = vec![{
            let triangles: Vec<[u32; 3]> = rest
                .triangles
                .iter()
                .filter(|t| !t.iter().all(|&i| hidden[i as usize]))
                .copied()
                .collect();
            let areas = triangles.iter().map(|t| area(&rest.vertices, t)).collect();
            Surface {
                garment: None,
                triangles,
                areas,
            }
        }];
        for (k, &g) in worn.iter().enumerate() {
            let garment = &room.library.garments[g];
            surfaces.push(Surface {
                garment: Some(k),
                triangles: garment.triangles.clone(),
                areas: garment
                    .triangles
                    .iter()
                    .map(|t| area(&garment.vertices, t))
                    .collect(),
            });
        }
        let mut cdf = Vec::new();
        let mut total = 0.0f64;
        for (si, surface) in surfaces.iter().enumerate() {
            for (ti, a) in surface.areas.iter().enumerate() {
                total += *a as f64;
                cdf.push((total, si as u32, ti as u32));
            }
        }
        let ranks = room.ranks(&worn);
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0064_7265_7373_6564);
        let height = rest.height();
        let mut out = Builder::default();
        // Draw until `points` are kept (hidden garment surfaces are drawn and dropped).
        let mut draws = 0usize;
        while out.positions.len() < points && draws < 4 * points {
            draws += 1;
            let target = rng.gen::<f64>() * total;
            let at = cdf.partition_point(|c| c.0 <= target).min(cdf.len() - 1);
            let (_, si, ti) = cdf[at];
            let (r1, r2): (f32, f32) = (rng.gen(), rng.gen());
            let q = r1.sqrt();
            let bary = Vec3::new(1.0 - q, q * (1.0 - r2), q * r2);
            let surface = &surfaces[si as usize];
            let t = surface.triangles[ti as usize];
            match surface.garment {
                None => {
                    let p = interpolate(&rest.vertices, t, bary);
                    let n = interpolate(&room.body_normals, t, bary).normalize_or(Vec3::Y);
                    let corner = nearest_corner(t, bary);
                    let part = &rest.part_names[rest.part_labels[corner] as usize];
                    out.push(
                        p,
                        n,
                        wardrobe.body_albedo(part, p, height),
                        interpolate(&room.library.body_occlusion, t, bary),
                        SKIN_GLOSS,
                        0,
                        blend_skin(&rest.skin, t, bary),
                    );
                }
                Some(k) => {
                    let g = worn[k];
                    let garment = &room.library.garments[g];
                    let p = interpolate(&garment.vertices, t, bary);
                    let n = interpolate(&room.garment_normals[g], t, bary).normalize_or(Vec3::Y);
                    if room.garment_point_hidden(&worn, &ranks, k, p, n) {
                        continue;
                    }
                    let region = garment.regions[nearest_corner(t, bary)];
                    out.push(
                        p,
                        n,
                        wardrobe.garment_albedo(k, region, p, n),
                        interpolate(&garment.occlusion, t, bary),
                        wardrobe.gloss(k, region),
                        g as u8 + 1,
                        blend_skin(&garment.skin, t, bary),
                    );
                }
            }
        }
        let n = out.positions.len();
        // Disc-like splats whose footprints close the surface: every draw stands for an equal
        // share of the whole (visible and hidden) area.
        let radius = 0.9 * (total as f32 / draws.max(1) as f32).sqrt();
        let normals: Vec<Vec3> = out
            .normals
            .iter()
            .map(|n| (*n / s).normalize_or(Vec3::Y))
            .collect();
        let rotations: Vec<Quat> = normals
            .iter()
            .map(|n| Quat::from_rotation_arc(Vec3::Z, *n))
            .collect();
        let gaussians = Gaussians::from_rgb(
            out.positions.iter().map(|p| *p * s).collect(),
            vec![Vec3::new(radius, radius, 0.2 * radius); n],
            rotations,
            vec![0.98; n],
            &out.albedo,
        )?;
        let avatar = Avatar::new(gaussians, out.skin, MAKEHUMAN_MODEL_ID)?;
        Ok(Self {
            template,
            wardrobe,
            avatar,
            normals,
            occlusion: out.occlusion,
            gloss: out.gloss,
            garment_ids: out.garment_ids,
            height_scale: shape.height_scale,
            girth_scale: shape.girth_scale,
        })
    }

    /// The shape applied to the template.
    pub fn shape(&self) -> MakeHumanShape {
        MakeHumanShape {
            height_scale: self.height_scale,
            girth_scale: self.girth_scale,
        }
    }

    /// How much of a directional light from `direction` reaches each Gaussian of `posed` (this
    /// person posed by `matrices`): 0 where the posed body or garments cast a shadow on it, 1
    /// elsewhere, by a ray from each Gaussian towards the light against the posed meshes.
    pub fn light_visibility(
        &self,
        matrices: &[Mat4],
        posed: &Gaussians,
        direction: Vec3,
    ) -> Result<Vec<f32>, SynthError> {
        let room = DressingRoom::shared()?;
        let s = self.shape().axis_scale();
        let mut vertices = self
            .template
            .skin
            .skin_points(&self.template.vertices, matrices);
        let mut triangles = self.template.triangles.clone();
        for g in &self.wardrobe.garments {
            let garment = &room.library.garments[g.index];
            let shaped: Vec<Vec3> = garment.vertices.iter().map(|v| *v * s).collect();
            let base = vertices.len() as u32;
            vertices.extend(garment.skin.skin_points(&shaped, matrices));
            triangles.extend(garment.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        let bvh = TriangleBvh::new(&vertices, &triangles);
        let l = direction.normalize_or(Vec3::Y);
        Ok(posed
            .positions
            .par_iter()
            .zip(&posed.rotations)
            .map(|(p, r)| {
                let n = *r * Vec3::Z;
                let side = if n.dot(l) >= 0.0 { n } else { -n };
                let origin = *p + (side + l) * SHADOW_BIAS;
                if bvh.any_hit(origin, l, SHADOW_RANGE) {
                    0.0
                } else {
                    1.0
                }
            })
            .collect())
    }

    /// The albedo of every Gaussian.
    pub fn albedo(&self) -> Vec<Vec3> {
        let g = &self.avatar.canonical;
        (0..g.len())
            .map(|i| crate::splat::sh_dc_to_rgb(g.sh_of(i)[0]))
            .collect()
    }

    /// Ground truth for `anchors` sampled on this person's (shaped) template: the outermost
    /// surface over each anchor, found in the rest pose and shape.
    pub fn anchor_truth(&self, anchors: &AnchorPoints) -> Result<AnchorTruth, SynthError> {
        let room = DressingRoom::shared()?;
        Ok(self.anchor_truth_in(room, anchors))
    }

    /// [`DressedPerson::anchor_truth`] with the library of `room`.
    pub fn anchor_truth_in(&self, room: &DressingRoom, anchors: &AnchorPoints) -> AnchorTruth {
        let rest = &room.template;
        let s = self.shape().axis_scale();
        let worn: Vec<usize> = self.wardrobe.garments.iter().map(|g| g.index).collect();
        let height = rest.height();
        let ranks = room.ranks(&worn);
        let mut truth = AnchorTruth {
            albedo: Vec::with_capacity(anchors.len()),
            garment: Vec::with_capacity(anchors.len()),
            surface: Vec::with_capacity(anchors.len()),
            surface_skin: SkinWeights::default(),
        };
        for i in 0..anchors.len() {
            let t = rest.triangles[anchors.triangles[i] as usize];
            let bary = anchors.barycentric[i];
            let p = interpolate(&rest.vertices, t, bary);
            let n = interpolate(&room.body_normals, t, bary).normalize_or(Vec3::Y);
            let (albedo, id, at, skin) = match room.outermost(&worn, &ranks, p, n) {
                Some(SurfaceHit {
                    garment,
                    triangle,
                    barycentric,
                }) => {
                    let g = &room.library.garments[garment];
                    let gt = g.triangles[triangle as usize];
                    let q = interpolate(&g.vertices, gt, barycentric);
                    let m = interpolate(&room.garment_normals[garment], gt, barycentric)
                        .normalize_or(n);
                    let region: GarmentRegion = g.regions[nearest_corner(gt, barycentric)];
                    let k = worn.iter().position(|&w| w == garment).unwrap_or(0);
                    (
                        self.wardrobe.garment_albedo(k, region, q, m),
                        garment as u8 + 1,
                        q,
                        blend_skin(&g.skin, gt, barycentric),
                    )
                }
                None => {
                    let part = &rest.part_names[anchors.part_labels[i] as usize];
                    (
                        self.wardrobe.body_albedo(part, p, height),
                        0,
                        p,
                        (anchors.skin.bones[i], anchors.skin.weights[i]),
                    )
                }
            };
            truth.albedo.push(Vec3::from(albedo));
            truth.garment.push(id);
            truth.surface.push(at * s);
            truth.surface_skin.bones.push(skin.0);
            truth.surface_skin.weights.push(skin.1);
        }
        truth
    }
}

/// Gaussian attributes gathered while sampling.
#[derive(Default)]
struct Builder {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    albedo: Vec<Vec3>,
    occlusion: Vec<f32>,
    gloss: Vec<f32>,
    garment_ids: Vec<u8>,
    skin: SkinWeights,
}

impl Builder {
    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        p: Vec3,
        n: Vec3,
        albedo: [f32; 3],
        occlusion: f32,
        gloss: f32,
        garment: u8,
        skin: ([u16; 4], [f32; 4]),
    ) {
        self.positions.push(p);
        self.normals.push(n);
        self.albedo.push(Vec3::from(albedo));
        self.occlusion.push(occlusion);
        self.gloss.push(gloss);
        self.garment_ids.push(garment);
        self.skin.bones.push(skin.0);
        self.skin.weights.push(skin.1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dressed_people_repeat_per_seed_and_hide_covered_skin() {
        let a = DressedPerson::new(1_000_003, 6000).unwrap();
        let b = DressedPerson::new(1_000_003, 6000).unwrap();
        assert_eq!(a.avatar, b.avatar);
        assert_eq!(a.garment_ids, b.garment_ids);
        let n = a.avatar.canonical.len();
        assert_eq!(n, 6000);
        assert_eq!(a.normals.len(), n);
        assert_eq!(a.occlusion.len(), n);
        // Most Gaussians lie on garments; the skin shows where nothing covers it.
        let on_skin = a.garment_ids.iter().filter(|g| **g == 0).count();
        assert!(
            on_skin > 100 && on_skin < n / 2,
            "{on_skin} of {n} on the skin"
        );
        for (i, n) in a.normals.iter().enumerate() {
            assert!((n.length() - 1.0).abs() < 1e-3, "normal {i}");
        }
        let (height, girth) = SyntheticPerson::shape_of(1_000_003);
        assert_eq!((a.height_scale, a.girth_scale), (height, girth));
    }

    #[test]
    fn a_light_from_above_lights_the_head_and_leaves_the_feet_in_shadow() {
        let person = DressedPerson::new(1_000_005, 8000).unwrap();
        let m = person
            .template
            .skeleton
            .try_skinning_matrices(&crate::body::Pose::identity())
            .unwrap();
        let posed = person.avatar.animate(&m);
        let seen = person.light_visibility(&m, &posed, Vec3::Y).unwrap();
        let h = person.template.height();
        let share = |lo: f32, hi: f32| {
            let band: Vec<f32> = (0..seen.len())
                .filter(|&i| (lo..hi).contains(&(posed.positions[i].y / h)))
                .map(|i| seen[i])
                .collect();
            band.iter().sum::<f32>() / band.len().max(1) as f32
        };
        assert!(share(0.97, 1.1) > 0.9, "crown lit {}", share(0.97, 1.1));
        assert!(share(0.0, 0.04) < 0.3, "soles lit {}", share(0.0, 0.04));
        let all = seen.iter().sum::<f32>() / seen.len() as f32;
        assert!(all > 0.2 && all < 0.8, "{all}");
    }
}
