//! Garments the CC0 set lacks, made from the template itself: a long coat, a skirt, a dress and
//! shorts. Fitted parts (torso, sleeves, shorts) are body regions moved out along the skin's
//! normals; hanging parts (skirts, a coat's tails) are tubes around both legs: rings every
//! 2 cm whose radius in each direction is the support function of the skin's cross-section
//! (torso and leg skin in a 4 cm slab: the ring holds the convex hull of both legs), plus the
//! offset, never narrowing downwards and flaring by a set slope. Hanging parts are skinned by
//! blending the nearest left-side and right-side skin's weights across the middle, so they
//! follow both legs.

use super::pieces::Piece;
use crate::body::convert::top_k;
use crate::body::garment::{BoneClass, GarmentBinding, GarmentKind, GarmentRegion};
use crate::body::{vertex_normals, BodyError, BodyTemplate, PointGrid, SkinWeights};
use glam::Vec3;

/// Segments around a hanging tube.
const SEGMENTS: usize = 56;
/// Ring spacing of a hanging tube (metres).
const RING_STEP: f32 = 0.02;
/// Half thickness of the skin slab each ring wraps (metres).
const SLAB: f32 = 0.02;
/// Half width (metres) of the blend between the left and right legs' weights.
const BLEND: f32 = 0.06;

/// Per template vertex: its dominant bone class and whether it is plain skin (part `body`,
/// not head, hands or feet).
struct Skin<'a> {
    template: &'a BodyTemplate,
    class: Vec<BoneClass>,
    plain: Vec<bool>,
    normals: Vec<Vec3>,
    height: f32,
}

impl<'a> Skin<'a> {
    fn new(template: &'a BodyTemplate) -> Self {
        let names = &template.skeleton.bone_names;
        let body = template.part_names.iter().position(|n| n == "body");
        Self {
            template,
            class: (0..template.vertices.len())
                .map(|i| BoneClass::dominant(&template.skin, i, names))
                .collect(),
            plain: template
                .part_labels
                .iter()
                .map(|l| Some(*l as usize) == body)
                .collect(),
            normals: vertex_normals(&template.vertices, &template.triangles),
            height: template.height(),
        }
    }

    /// Plain skin of one of `classes` with height in `lo..=hi` (fractions of the height).
    fn region(&self, classes: &[BoneClass], lo: f32, hi: f32) -> Vec<bool> {
        (0..self.class.len())
            .map(|i| {
                let y = self.template.vertices[i].y / self.height;
                self.plain[i] && classes.contains(&self.class[i]) && (lo..=hi).contains(&y)
            })
            .collect()
    }

    /// The skin triangles whose corners are all in `keep`, moved `distance` metres out along
    /// the normals; `region` labels each source vertex.
    fn offset(
        &self,
        keep: &[bool],
        distance: f32,
        region: impl Fn(usize) -> GarmentRegion,
    ) -> Piece {
        let t = self.template;
        let mut index = vec![u32::MAX; t.vertices.len()];
        let mut kept = Vec::new();
        let mut triangles = Vec::new();
        for tri in t
            .triangles
            .iter()
            .filter(|tri| tri.iter().all(|&i| keep[i as usize]))
        {
            triangles.push(tri.map(|i| {
                let i = i as usize;
                if index[i] == u32::MAX {
                    index[i] = kept.len() as u32;
                    kept.push(i);
                }
                index[i]
            }));
        }
        let offsets: Vec<Vec3> = kept.iter().map(|&i| self.normals[i] * distance).collect();
        Piece {
            name: String::new(),
            source: String::new(),
            kind: GarmentKind::Top,
            vertices: kept
                .iter()
                .zip(&offsets)
                .map(|(&i, o)| t.vertices[i] + *o)
                .collect(),
            triangles,
            skin: SkinWeights {
                bones: kept.iter().map(|&i| t.skin.bones[i]).collect(),
                weights: kept.iter().map(|&i| t.skin.weights[i]).collect(),
            },
            binding: GarmentBinding {
                vertices: kept.iter().map(|&i| [i as u16; 3]).collect(),
                weights: vec![[1.0, 0.0, 0.0]; kept.len()],
                offsets,
            },
            regions: kept.iter().map(|&i| region(i)).collect(),
        }
    }

    /// A tube around torso and legs from height `top` down to `bottom` (fractions of the
    /// height), `distance` metres off the skin's hull, its radius growing by `flare` metres per
    /// metre downwards.
    fn hanging(&self, top: f32, bottom: f32, distance: f32, flare: f32) -> Piece {
        let t = self.template;
        let allowed: Vec<usize> = (0..t.vertices.len())
            .filter(|&i| {
                self.plain[i] && matches!(self.class[i], BoneClass::Torso | BoneClass::Leg)
            })
            .collect();
        let (top, bottom) = (top * self.height, bottom * self.height);
        let rings = ((top - bottom) / RING_STEP).ceil().max(1.0) as usize;
        let step = (top - bottom) / rings as f32;
        let dirs: Vec<(f32, f32)> = (0..SEGMENTS)
            .map(|j| (std::f32::consts::TAU * j as f32 / SEGMENTS as f32).sin_cos())
            .map(|(s, c)| (c, s))
            .collect();
        let mut vertices = Vec::with_capacity((rings + 1) * SEGMENTS);
        let mut previous: Option<Vec<f32>> = None;
        let mut centre_z = 0.0f32;
        for k in 0..=rings {
            let y = top - step * k as f32;
            let slab: Vec<Vec3> = allowed
                .iter()
                .map(|&i| t.vertices[i])
                .filter(|v| (v.y - y).abs() <= SLAB)
                .collect();
            if !slab.is_empty() {
                let (lo, hi) = slab
                    .iter()
                    .fold((f32::MAX, f32::MIN), |(l, h), v| (l.min(v.z), h.max(v.z)));
                let z = 0.5 * (lo + hi);
                centre_z = if k == 0 { z } else { 0.7 * centre_z + 0.3 * z };
            }
            let mut radii: Vec<f32> = dirs
                .iter()
                .map(|&(c, s)| {
                    slab.iter()
                        .map(|v| v.x * c + (v.z - centre_z) * s)
                        .fold(0.0f32, f32::max)
                        + distance
                })
                .collect();
            if let Some(prev) = &previous {
                for (r, p) in radii.iter_mut().zip(prev) {
                    *r = r.max(p + flare * step);
                }
            }
            vertices.extend(
                radii
                    .iter()
                    .zip(&dirs)
                    .map(|(r, &(c, s))| Vec3::new(r * c, y, centre_z + r * s)),
            );
            previous = Some(radii);
        }
        let mut triangles = Vec::with_capacity(rings * SEGMENTS * 2);
        for k in 0..rings {
            for j in 0..SEGMENTS {
                let j1 = (j + 1) % SEGMENTS;
                let at = |k: usize, j: usize| (k * SEGMENTS + j) as u32;
                let (a, b, c, d) = (at(k, j), at(k + 1, j), at(k + 1, j1), at(k, j1));
                // θ grows from +X towards +Z: (a, c, b) faces out.
                triangles.push([a, c, b]);
                triangles.push([a, d, c]);
            }
        }
        // Skinning: the nearest allowed skin on each side, blended across the middle.
        let side = |left: bool| -> (Vec<usize>, PointGrid) {
            let ids: Vec<usize> = allowed
                .iter()
                .copied()
                .filter(|&i| (t.vertices[i].x >= 0.0) == left)
                .collect();
            let pts: Vec<Vec3> = ids.iter().map(|&i| t.vertices[i]).collect();
            let grid = PointGrid::for_surface(&pts);
            (ids, grid)
        };
        let (left_ids, left) = side(true);
        let (right_ids, right) = side(false);
        let mut skin = SkinWeights::default();
        let mut binding = GarmentBinding::default();
        for p in &vertices {
            let l = left_ids[left.nearest(*p).unwrap_or(0)];
            let r = right_ids[right.nearest(*p).unwrap_or(0)];
            let s = smoothstep(-BLEND, BLEND, p.x);
            let mut influences = Vec::with_capacity(8);
            for (v, w) in [(l, s), (r, 1.0 - s)] {
                for (b, x) in t.skin.bones[v].iter().zip(&t.skin.weights[v]) {
                    influences.push((*b, x * w));
                }
            }
            let near = if p.distance_squared(t.vertices[l]) <= p.distance_squared(t.vertices[r]) {
                l
            } else {
                r
            };
            let (b, w) = top_k(&influences).unwrap_or((t.skin.bones[near], t.skin.weights[near]));
            skin.bones.push(b);
            skin.weights.push(w);
            binding.vertices.push([near as u16; 3]);
            binding.weights.push([1.0, 0.0, 0.0]);
            binding.offsets.push(*p - t.vertices[near]);
        }
        let n = vertices.len();
        Piece {
            name: String::new(),
            source: String::new(),
            kind: GarmentKind::Bottom,
            vertices,
            triangles,
            skin,
            binding,
            regions: vec![GarmentRegion::Bottom; n],
        }
    }
}

fn smoothstep(lo: f32, hi: f32, x: f32) -> f32 {
    let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// `b` appended to `a`.
fn join(mut a: Piece, b: Piece) -> Piece {
    let shift = a.vertices.len() as u32;
    a.vertices.extend(b.vertices);
    a.triangles
        .extend(b.triangles.iter().map(|t| t.map(|i| i + shift)));
    a.skin.bones.extend(b.skin.bones);
    a.skin.weights.extend(b.skin.weights);
    a.binding.vertices.extend(b.binding.vertices);
    a.binding.weights.extend(b.binding.weights);
    a.binding.offsets.extend(b.binding.offsets);
    a.regions.extend(b.regions);
    a
}

fn named(mut piece: Piece, name: &str, kind: GarmentKind, how: &str) -> Piece {
    piece.name = name.to_string();
    piece.kind = kind;
    piece.source = format!("offset from the body template: {how}");
    piece
}

/// The long coat, skirt, dress and shorts made from `template`.
pub fn offset_garments(template: &BodyTemplate) -> Result<Vec<Piece>, BodyError> {
    if template.skin.bones.len() > u16::MAX as usize + 1 {
        return Err(BodyError::format(
            "template",
            "more vertices than a garment binding can index",
        ));
    }
    let skin = Skin::new(template);
    let sleeve_or_top = |i: usize| {
        if skin.class[i] == BoneClass::Arm {
            GarmentRegion::Sleeve
        } else {
            GarmentRegion::Top
        }
    };
    use BoneClass::{Arm, Leg, Torso};
    let coat_body = skin.offset(
        &skin.region(&[Torso, Arm, Leg], 0.515, 1.0),
        0.025,
        sleeve_or_top,
    );
    let coat = join(coat_body, skin.hanging(0.54, 0.19, 0.025, 0.25));
    let dress_body = skin.offset(&skin.region(&[Torso], 0.57, 1.0), 0.012, |_| {
        GarmentRegion::Top
    });
    let dress = join(dress_body, skin.hanging(0.6, 0.29, 0.015, 0.25));
    let skirt = skin.hanging(0.6, 0.29, 0.015, 0.18);
    let shorts = skin.offset(&skin.region(&[Torso, Leg], 0.39, 0.6), 0.013, |_| {
        GarmentRegion::Bottom
    });
    Ok(vec![
        named(
            coat,
            "long_coat",
            GarmentKind::Coat,
            "torso and arms above the hips 2.5 cm out, flared tails to mid-calf",
        ),
        named(
            dress,
            "dress",
            GarmentKind::OnePiece,
            "sleeveless torso 1.2 cm out, flared skirt to the knee",
        ),
        named(
            skirt,
            "skirt",
            GarmentKind::Bottom,
            "waist to the knee, flared",
        ),
        named(
            shorts,
            "shorts",
            GarmentKind::Bottom,
            "waist to mid-thigh 1.3 cm out",
        ),
    ])
}
