//! The garment library prepared once per process for dressing people: the rest template and
//! every garment with ray-casting hierarchies, shading normals and bounds, and the rules that
//! decide which surface is seen where garments and skin overlap.

use super::person::SynthError;
use crate::body::garment::{covered, shading_normals, COVER_DEPTH, COVER_RANGE};
use crate::body::raycast::{RayHit, TriangleBvh};
use crate::body::{vertex_normals, BodyTemplate, GarmentKind, GarmentLibrary};
use glam::Vec3;
use std::sync::OnceLock;

/// The library, the rest template and their ray-casting structures (rest pose, rest shape).
pub struct DressingRoom {
    /// The garments.
    pub library: GarmentLibrary,
    /// The template at its rest shape.
    pub template: BodyTemplate,
    /// The template's triangles.
    pub body_bvh: TriangleBvh,
    /// The template's unit vertex normals.
    pub body_normals: Vec<Vec3>,
    /// Each garment's triangles.
    pub garment_bvhs: Vec<TriangleBvh>,
    /// Each garment's shading normals per vertex.
    pub garment_normals: Vec<Vec<Vec3>>,
    /// Each garment's bounding box (rest).
    pub garment_bounds: Vec<(Vec3, Vec3)>,
}

/// Stacking order of garment kinds where one pokes through another: a surface under a garment
/// of a higher layer is hidden even where it pokes a little through it.
pub fn layer(kind: GarmentKind) -> u8 {
    match kind {
        GarmentKind::Shoes => 0,
        GarmentKind::Bottom | GarmentKind::Top | GarmentKind::OnePiece => 1,
        GarmentKind::Coat => 2,
        GarmentKind::Hair => 3,
        GarmentKind::Hat => 4,
    }
}

/// The outermost garment surface over a point, found by [`DressingRoom::outermost`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceHit {
    /// Library index of the garment.
    pub garment: usize,
    /// Triangle of the garment.
    pub triangle: u32,
    /// Barycentric weights in it.
    pub barycentric: Vec3,
}

static SHARED: OnceLock<Result<DressingRoom, String>> = OnceLock::new();

impl DressingRoom {
    /// Prepares `library` for dressing `template` (both at rest).
    pub fn new(library: GarmentLibrary, template: BodyTemplate) -> Result<Self, SynthError> {
        library.validate(&template, "garment library")?;
        if library.garments.len() >= u8::MAX as usize {
            return Err(SynthError::Dressing(format!(
                "{} garments: ids must fit in a byte",
                library.garments.len()
            )));
        }
        let head = template.part_names.iter().position(|n| n == "head");
        let on_head: Vec<Vec3> = template
            .vertices
            .iter()
            .zip(&template.part_labels)
            .filter(|(_, l)| Some(**l as usize) == head)
            .map(|(v, _)| *v)
            .collect();
        let head_centre = on_head.iter().sum::<Vec3>() / on_head.len().max(1) as f32;
        let garment_bvhs = library
            .garments
            .iter()
            .map(|g| TriangleBvh::new(&g.vertices, &g.triangles))
            .collect();
        let garment_normals = library
            .garments
            .iter()
            .map(|g| shading_normals(g.kind, &g.vertices, &g.triangles, head_centre))
            .collect();
        let garment_bounds = library
            .garments
            .iter()
            .map(|g| {
                g.vertices
                    .iter()
                    .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), v| {
                        (lo.min(*v), hi.max(*v))
                    })
            })
            .collect();
        Ok(Self {
            body_bvh: TriangleBvh::new(&template.vertices, &template.triangles),
            body_normals: vertex_normals(&template.vertices, &template.triangles),
            garment_bvhs,
            garment_normals,
            garment_bounds,
            library,
            template,
        })
    }

    /// The embedded library and template, prepared on first use and shared.
    pub fn shared() -> Result<&'static Self, SynthError> {
        SHARED
            .get_or_init(|| {
                let library = GarmentLibrary::load_default().map_err(|e| e.to_string())?;
                let template = BodyTemplate::load_default().map_err(|e| e.to_string())?;
                Self::new(library, template).map_err(|e| e.to_string())
            })
            .as_ref()
            .map_err(|e| SynthError::Dressing(e.clone()))
    }

    /// Whether the segment from `p − COVER_DEPTH · n` to `p + COVER_RANGE · n` (every ray the
    /// cover tests cast from `p`) crosses garment `g`'s box.
    fn near(&self, g: usize, p: Vec3, n: Vec3) -> bool {
        let (lo, hi) = self.garment_bounds[g];
        let (lo, hi) = (lo - Vec3::splat(1e-3), hi + Vec3::splat(1e-3));
        let inv = n.recip();
        let t0 = (lo - p) * inv;
        let t1 = (hi - p) * inv;
        // NaN (n parallel to a slab, p on its plane) counts as a crossing.
        let near = t0.min(t1).max_element().max(-COVER_DEPTH);
        let far = t0.max(t1).min_element().min(COVER_RANGE);
        near.is_nan() || far.is_nan() || near <= far
    }

    /// Whether the ray from `p` (rest) along `n` leaves through garment `h`'s outside (any
    /// side of hair) before meeting the body.
    fn covered_going_out(&self, h: usize, p: Vec3, n: Vec3) -> bool {
        let origin = p + n * 1e-3;
        let two_sided = self.library.garments[h].kind.two_sided();
        self.garment_bvhs[h]
            .first_hit(origin, n, COVER_RANGE)
            .is_some_and(|hit| {
                (two_sided || hit.exits)
                    && self
                        .body_bvh
                        .first_hit(origin, n, hit.t)
                        .is_none_or(|b| b.t >= hit.t)
            })
    }

    /// Stacking rank of each of the `worn` garments (higher is outer): by [`layer`], and within
    /// a layer by which garment covers more of the other where they overlap (an overall's bib
    /// over a shirt, a shirt's hem over trousers), measured on up to 300 vertices of each.
    pub fn ranks(&self, worn: &[usize]) -> Vec<u32> {
        let share = |g: usize, h: usize| {
            let garment = &self.library.garments[g];
            let step = (garment.vertices.len() / 300).max(1);
            let sampled = (0..garment.vertices.len()).step_by(step);
            let total = sampled.len().max(1);
            let covered = (0..garment.vertices.len())
                .step_by(step)
                .filter(|&i| {
                    let (p, n) = (garment.vertices[i], self.garment_normals[g][i]);
                    self.near(h, p, n) && self.covered_going_out(h, p, n)
                })
                .count();
            covered as f32 / total as f32
        };
        let layers: Vec<u8> = worn
            .iter()
            .map(|&g| layer(self.library.garments[g].kind))
            .collect();
        (0..worn.len())
            .map(|a| {
                let over = (0..worn.len())
                    .filter(|&b| b != a && layers[a] == layers[b])
                    .filter(|&b| share(worn[b], worn[a]) > share(worn[a], worn[b]))
                    .count() as u32;
                layers[a] as u32 * 16 + over
            })
            .collect()
    }

    /// Whether a point of worn garment `worn[k]` at rest point `p` with normal `n` is hidden
    /// by a garment of a higher rank ([`DressingRoom::ranks`]) that covers it going out or
    /// that it pokes through, or by one of the same rank that covers it going out. A garment
    /// of a lower rank never hides it: where that one pokes out, its own points are hidden.
    pub fn garment_point_hidden(
        &self,
        worn: &[usize],
        ranks: &[u32],
        k: usize,
        p: Vec3,
        n: Vec3,
    ) -> bool {
        (0..worn.len())
            .filter(|&j| j != k && ranks[j] >= ranks[k] && self.near(worn[j], p, n))
            .any(|j| {
                let h = worn[j];
                if ranks[j] > ranks[k] {
                    let g = &self.library.garments[h];
                    covered(
                        &self.garment_bvhs[h],
                        g.kind.two_sided(),
                        &self.body_bvh,
                        p,
                        n,
                    )
                } else {
                    self.covered_going_out(h, p, n)
                }
            })
    }

    /// The outermost surface of the `worn` garments over the skin point `p` (rest) with normal
    /// `n`: going out along the normal, every garment left through its outside (or any hair
    /// card) before meeting a garment's outside or the body again; of those, the one of the
    /// highest rank, the farthest among equals. Where the skin pokes through a garment, that
    /// garment (the highest rank first).
    pub fn outermost(&self, worn: &[usize], ranks: &[u32], p: Vec3, n: Vec3) -> Option<SurfaceHit> {
        let origin = p + n * 1e-3;
        let body = self
            .body_bvh
            .first_hit(origin, n, COVER_RANGE)
            .map_or(f32::INFINITY, |h| h.t);
        let mut hits: Vec<(RayHit, usize)> = Vec::new();
        let mut buffer = Vec::new();
        for &g in worn.iter().filter(|&&g| self.near(g, p, n)) {
            buffer.clear();
            self.garment_bvhs[g].hits(origin, n, COVER_RANGE.min(body), &mut buffer);
            hits.extend(buffer.iter().map(|h| (*h, g)));
        }
        hits.sort_by(|a, b| a.0.t.total_cmp(&b.0.t));
        let rank = |g: usize| worn.iter().position(|&w| w == g).map_or(0, |k| ranks[k]);
        let mut outer: Option<(SurfaceHit, u32)> = None;
        for (hit, g) in hits {
            if !(self.library.garments[g].kind.two_sided() || hit.exits) {
                break;
            }
            // The highest rank wins (a lower one poking out is hidden where it does).
            if outer.is_none_or(|(_, r)| rank(g) >= r) {
                let surface = SurfaceHit {
                    garment: g,
                    triangle: hit.triangle,
                    barycentric: hit.barycentric,
                };
                outer = Some((surface, rank(g)));
            }
        }
        let outer = outer.map(|(s, _)| s);
        if outer.is_some() {
            return outer;
        }
        let mut order: Vec<usize> = (0..worn.len()).collect();
        order.sort_by_key(|&k| std::cmp::Reverse(ranks[k]));
        order.into_iter().map(|k| worn[k]).find_map(|g| {
            let two_sided = self.library.garments[g].kind.two_sided();
            self.garment_bvhs[g]
                .first_hit(origin, -n, COVER_DEPTH)
                .filter(|h| two_sided || !h.exits)
                .map(|h| SurfaceHit {
                    garment: g,
                    triangle: h.triangle,
                    barycentric: h.barycentric,
                })
        })
    }
}
