//! A garment mesh on its way into the library: fitted from a `.mhclo`, cleaned, split into
//! pieces, labelled by region and turned to face out.

use super::coverage::BodyScene;
use super::Reference;
use crate::body::convert::{top_k, ObjMesh};
use crate::body::garment::{BoneClass, GarmentBinding, GarmentKind, GarmentRegion};
use crate::body::{BodyError, BodyTemplate, SkinWeights};
use glam::Vec3;

/// Connected components with fewer vertices than this are details (buttons, belts, socks).
const MAJOR_COMPONENT: usize = 300;

/// Shoe vertices below this height (metres) are the sole.
const SOLE_HEIGHT: f32 = 0.02;

/// Fraction of the template's height under which outfit parts count as the bottom.
pub(super) const WAIST_FRACTION: f32 = 0.58;

/// A garment mesh before coverage and occlusion are computed.
#[derive(Debug, Clone, PartialEq)]
pub struct Piece {
    /// Garment name.
    pub name: String,
    /// Where it comes from.
    pub source: String,
    /// What it is.
    pub kind: GarmentKind,
    /// Rest vertices (canonical frame).
    pub vertices: Vec<Vec3>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Skinning weights per vertex.
    pub skin: SkinWeights,
    /// Base-mesh binding per vertex.
    pub binding: GarmentBinding,
    /// Region per vertex.
    pub regions: Vec<GarmentRegion>,
}

/// Component index per vertex (union-find over triangle edges).
fn components(n: usize, triangles: &[[u32; 3]]) -> Vec<usize> {
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    for t in triangles {
        for k in 1..3 {
            let (a, b) = (
                find(&mut parent, t[0] as usize),
                find(&mut parent, t[k] as usize),
            );
            if a != b {
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    (0..n).map(|i| find(&mut parent, i)).collect()
}

impl Piece {
    /// The piece of a fitted `.mhclo`: `positions` are the fitted vertices in the canonical
    /// frame, `scale` the per-axis offset scale in metres per source unit of offset, `base_skin`
    /// the skinning weights of every base vertex. Vertices no face uses are dropped; kind and
    /// regions are placeholders until [`Piece::labelled`] or [`Piece::split_outfit`].
    pub fn from_fit(
        obj: &ObjMesh,
        positions: &[Vec3],
        references: &[Reference],
        scale: Vec3,
        base_skin: &SkinWeights,
    ) -> Result<Self, BodyError> {
        let mut index = vec![u32::MAX; positions.len()];
        let mut kept = Vec::new();
        let mut triangles = Vec::new();
        for face in &obj.faces {
            let corners: Vec<u32> = face
                .corners
                .iter()
                .map(|&(v, _)| {
                    if index[v] == u32::MAX {
                        index[v] = kept.len() as u32;
                        kept.push(v);
                    }
                    index[v]
                })
                .collect();
            for k in 1..corners.len() - 1 {
                triangles.push([corners[0], corners[k], corners[k + 1]]);
            }
        }
        let mut skin = SkinWeights::default();
        let mut binding = GarmentBinding::default();
        for &v in &kept {
            let r = &references[v];
            let mut influences = Vec::with_capacity(12);
            for k in 0..3 {
                let b = r.vertices[k] as usize;
                if b >= base_skin.len() || b > u16::MAX as usize {
                    return Err(BodyError::format(
                        "garment",
                        format!("reference vertex {b} past the base mesh"),
                    ));
                }
                for (bone, w) in base_skin.bones[b].iter().zip(&base_skin.weights[b]) {
                    influences.push((*bone, w * r.weights[k].max(0.0)));
                }
            }
            let strongest = (0..3)
                .max_by(|a, b| r.weights[*a].total_cmp(&r.weights[*b]))
                .unwrap_or(0);
            let s = r.vertices[strongest] as usize;
            let (bones, weights) =
                top_k(&influences).unwrap_or((base_skin.bones[s], base_skin.weights[s]));
            skin.bones.push(bones);
            skin.weights.push(weights);
            binding.vertices.push(r.vertices.map(|i| i as u16));
            binding.weights.push(r.weights);
            binding.offsets.push(r.offset * scale);
        }
        let n = kept.len();
        Ok(Self {
            name: String::new(),
            source: String::new(),
            kind: GarmentKind::OnePiece,
            vertices: kept.iter().map(|&v| positions[v]).collect(),
            triangles,
            skin,
            binding,
            regions: vec![GarmentRegion::Top; n],
        })
    }

    /// The sub-mesh of the vertices with `keep` set (triangles with every corner kept).
    pub fn subset(&self, keep: &[bool]) -> Self {
        let mut index = vec![u32::MAX; self.vertices.len()];
        let mut kept = Vec::new();
        for (i, _) in keep.iter().enumerate().filter(|(_, k)| **k) {
            index[i] = kept.len() as u32;
            kept.push(i);
        }
        let triangles = self
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&i| keep[i as usize]))
            .map(|t| t.map(|i| index[i as usize]))
            .collect();
        let pick = |v: &[[u16; 4]]| kept.iter().map(|&i| v[i]).collect::<Vec<_>>();
        Self {
            name: self.name.clone(),
            source: self.source.clone(),
            kind: self.kind,
            vertices: kept.iter().map(|&i| self.vertices[i]).collect(),
            triangles,
            skin: SkinWeights {
                bones: pick(&self.skin.bones),
                weights: kept.iter().map(|&i| self.skin.weights[i]).collect(),
            },
            binding: GarmentBinding {
                vertices: kept.iter().map(|&i| self.binding.vertices[i]).collect(),
                weights: kept.iter().map(|&i| self.binding.weights[i]).collect(),
                offsets: kept.iter().map(|&i| self.binding.offsets[i]).collect(),
            },
            regions: kept.iter().map(|&i| self.regions[i]).collect(),
        }
    }

    /// Which vertices lie in components of fewer than [`MAJOR_COMPONENT`] vertices.
    fn minor_vertices(&self) -> (Vec<usize>, Vec<bool>) {
        let comp = components(self.vertices.len(), &self.triangles);
        let mut counts = vec![0usize; self.vertices.len()];
        for &c in &comp {
            counts[c] += 1;
        }
        let minor = comp.iter().map(|&c| counts[c] < MAJOR_COMPONENT).collect();
        (comp, minor)
    }

    /// The piece as a garment of `kind` with its regions: shoes (sole below 2 cm, upper, small
    /// parts as details), hair, hat.
    pub fn labelled(mut self, kind: GarmentKind) -> Self {
        self.kind = kind;
        let (_, minor) = self.minor_vertices();
        self.regions = self
            .vertices
            .iter()
            .zip(&minor)
            .map(|(v, m)| match kind {
                GarmentKind::Shoes if *m => GarmentRegion::Detail,
                GarmentKind::Shoes if v.y < SOLE_HEIGHT => GarmentRegion::Sole,
                GarmentKind::Shoes => GarmentRegion::Upper,
                GarmentKind::Hair => GarmentRegion::Hair,
                GarmentKind::Hat => GarmentRegion::Hat,
                _ => GarmentRegion::Top,
            })
            .collect();
        self
    }

    /// Splits an outfit into a top and a bottom piece by its connected components (a
    /// component whose mean height is under the waist is part of the bottom; small components
    /// go with the nearest large one, as details), or keeps it whole as a one-piece when all
    /// its large components fall on one side. Regions: sleeves where arm bones dominate, top,
    /// bottom (for a one-piece: by height against the waist), details.
    pub fn split_outfit(self, template: &BodyTemplate) -> Vec<Self> {
        let waist = WAIST_FRACTION * template.height();
        let (comp, minor) = self.minor_vertices();
        let n = self.vertices.len();
        let mut sum = vec![0f32; n];
        let mut count = vec![0usize; n];
        for (i, &c) in comp.iter().enumerate() {
            sum[c] += self.vertices[i].y;
            count[c] += 1;
        }
        let lower = |c: usize| sum[c] / (count[c].max(1) as f32) < waist;
        let majors: Vec<usize> = (0..n).filter(|&i| !minor[i]).collect();
        let mut bottom: Vec<bool> = comp.iter().map(|&c| lower(c)).collect();
        let both = majors.iter().any(|&i| bottom[i]) && majors.iter().any(|&i| !bottom[i]);
        let names = &template.skeleton.bone_names;
        let arms: Vec<bool> = (0..n)
            .map(|i| BoneClass::dominant(&self.skin, i, names) == BoneClass::Arm)
            .collect();
        let arm = |i: usize| arms[i];
        if !both {
            let mut whole = self;
            whole.kind = GarmentKind::OnePiece;
            whole.regions = (0..n)
                .map(|i| {
                    if minor[i] {
                        GarmentRegion::Detail
                    } else if arm(i) {
                        GarmentRegion::Sleeve
                    } else if whole.vertices[i].y >= waist {
                        GarmentRegion::Top
                    } else {
                        GarmentRegion::Bottom
                    }
                })
                .collect();
            return vec![whole];
        }
        // Small components follow the large component nearest to their first vertex.
        for i in 0..n {
            if minor[i] {
                let p = self.vertices[i];
                if let Some(&j) = majors.iter().min_by(|a, b| {
                    self.vertices[**a]
                        .distance_squared(p)
                        .total_cmp(&self.vertices[**b].distance_squared(p))
                }) {
                    bottom[i] = lower(comp[j]);
                }
            }
        }
        let mut labelled = self;
        labelled.regions = (0..n)
            .map(|i| {
                if minor[i] {
                    GarmentRegion::Detail
                } else if bottom[i] {
                    GarmentRegion::Bottom
                } else if arm(i) {
                    GarmentRegion::Sleeve
                } else {
                    GarmentRegion::Top
                }
            })
            .collect();
        [
            (GarmentKind::Top, false, "top"),
            (GarmentKind::Bottom, true, "bottom"),
        ]
        .into_iter()
        .map(|(kind, side, suffix)| {
            let keep: Vec<bool> = bottom.iter().map(|b| *b == side).collect();
            let mut piece = labelled.subset(&keep);
            piece.kind = kind;
            piece.name = format!("{}.{suffix}", labelled.name);
            piece
        })
        .collect()
    }

    /// Fraction of the triangles (by area) whose normal points away from the nearest skin
    /// vertex.
    pub fn outward_fraction(&self, body: &BodyScene) -> f32 {
        let (mut out, mut total) = (0.0f32, 0.0f32);
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.vertices[i as usize]);
            let n = (b - a).cross(c - a);
            let centre = (a + b + c) / 3.0;
            let area = n.length();
            if let Some(v) = body.grid.nearest(centre) {
                total += area;
                if n.dot(centre - body.template.vertices[v]) > 0.0 {
                    out += area;
                }
            }
        }
        if total > 0.0 {
            out / total
        } else {
            1.0
        }
    }

    /// The piece with every triangle turned when most of its area faces the body (hair cards
    /// have no outside and are kept as they are).
    pub fn facing_out(mut self, body: &BodyScene) -> Self {
        if !self.kind.two_sided() && self.outward_fraction(body) < 0.5 {
            for t in &mut self.triangles {
                t.swap(1, 2);
            }
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn components_join_through_shared_corners() {
        let c = components(7, &[[0, 1, 2], [2, 3, 4], [5, 6, 5]]);
        assert_eq!(c[0], c[4]);
        assert_eq!(c[5], c[6]);
        assert_ne!(c[0], c[5]);
    }
}
