//! The garment library file: one safetensors file, every garment's arrays concatenated.
//!
//! Tensors (`V` garment vertices in all, `T` triangles in all, `G` garments, `B` template
//! vertices): `positions` f16 `[V,3]` (metres, canonical frame), `triangles` u16 `[T,3]`
//! (indices local to each garment), `skin_bones` u8 `[V,4]`, `skin_weights` f16 `[V,4]`,
//! `bind_vertices` u16 `[V,3]` (hm08 base-mesh indices), `bind_weights` f32 `[V,3]` (some
//! fits use weights up to ±5, which f16 would round to millimetres),
//! `bind_offsets` f16 `[V,3]` (metres), `regions` u8 `[V]` ([`GarmentRegion`] values),
//! `occlusion` u8 `[V]` (ambient occlusion × 255), `covers` u8 `[G, ⌈B/8⌉]` (bit `v % 8` of
//! byte `v / 8`: the garment covers template vertex `v`), `body_occlusion` u8 `[B]`.
//! Metadata: `format`, `garments` (JSON list of `{name, kind, source, vertices, triangles}`
//! in file order), `body_vertices`, `frame`, `license`.

use super::{Garment, GarmentBinding, GarmentKind, GarmentLibrary, GarmentRegion};
use crate::body::{BodyError, SkinWeights, MAX_INFLUENCES};
use glam::Vec3;
use half::f16;
use safetensors::tensor::{Dtype, TensorView};
use safetensors::SafeTensors;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// The committed garment library (see `assets/body/README.md`), embedded in the binary.
pub const GARMENTS_ASSET: &[u8] = include_bytes!("../../../assets/body/garments.safetensors");

/// Value of the `format` metadata entry of garment library files.
pub const FORMAT: &str = "lhmpp-garments-v1";

/// Per-garment entry of the `garments` metadata.
#[derive(Serialize, Deserialize)]
struct Entry {
    name: String,
    kind: String,
    source: String,
    vertices: usize,
    triangles: usize,
}

fn f16s(values: impl Iterator<Item = f32>) -> Vec<u8> {
    values
        .flat_map(|v| f16::from_f32(v).to_le_bytes())
        .collect()
}

fn unit_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

impl GarmentLibrary {
    /// Serialises the library as safetensors bytes (deterministic: sorted header).
    pub fn to_bytes(&self) -> Result<Vec<u8>, BodyError> {
        let origin = "garment library";
        let all = || self.garments.iter();
        let body = self.body_occlusion.len();
        let mut triangles = Vec::new();
        for g in all() {
            if g.vertices.len() > u16::MAX as usize + 1 {
                return Err(BodyError::format(
                    origin,
                    format!("garment `{}` has more than 65,536 vertices", g.name),
                ));
            }
            triangles.extend(
                g.triangles
                    .iter()
                    .flatten()
                    .flat_map(|&i| (i as u16).to_le_bytes()),
            );
        }
        let mut bones = Vec::new();
        for g in all() {
            for row in &g.skin.bones {
                for &b in row {
                    bones.push(u8::try_from(b).map_err(|_| {
                        BodyError::format(origin, format!("bone {b} does not fit in a byte"))
                    })?);
                }
            }
        }
        let v: usize = all().map(|g| g.vertices.len()).sum();
        let t: usize = all().map(|g| g.triangles.len()).sum();
        let row_bytes = body.div_ceil(8);
        let mut covers = vec![0u8; self.garments.len() * row_bytes];
        for (k, g) in all().enumerate() {
            for (i, _) in g.covers.iter().enumerate().filter(|(_, c)| **c) {
                covers[k * row_bytes + i / 8] |= 1 << (i % 8);
            }
        }
        let positions = f16s(all().flat_map(|g| g.vertices.iter().flat_map(|p| p.to_array())));
        let skin_weights = f16s(all().flat_map(|g| g.skin.weights.iter().flatten().copied()));
        let bind_vertices: Vec<u8> = all()
            .flat_map(|g| {
                g.binding
                    .vertices
                    .iter()
                    .flatten()
                    .flat_map(|i| i.to_le_bytes())
            })
            .collect();
        let bind_weights: Vec<u8> = all()
            .flat_map(|g| {
                g.binding
                    .weights
                    .iter()
                    .flatten()
                    .flat_map(|w| w.to_le_bytes())
            })
            .collect();
        let bind_offsets =
            f16s(all().flat_map(|g| g.binding.offsets.iter().flat_map(|o| o.to_array())));
        let regions: Vec<u8> = all()
            .flat_map(|g| g.regions.iter().map(|r| *r as u8))
            .collect();
        let occlusion: Vec<u8> = all()
            .flat_map(|g| g.occlusion.iter().map(|a| unit_u8(*a)))
            .collect();
        let body_occlusion: Vec<u8> = self.body_occlusion.iter().map(|a| unit_u8(*a)).collect();
        let k = MAX_INFLUENCES;
        let entries: Vec<(&str, Dtype, Vec<usize>, &[u8])> = vec![
            ("positions", Dtype::F16, vec![v, 3], &positions),
            ("triangles", Dtype::U16, vec![t, 3], &triangles),
            ("skin_bones", Dtype::U8, vec![v, k], &bones),
            ("skin_weights", Dtype::F16, vec![v, k], &skin_weights),
            ("bind_vertices", Dtype::U16, vec![v, 3], &bind_vertices),
            ("bind_weights", Dtype::F32, vec![v, 3], &bind_weights),
            ("bind_offsets", Dtype::F16, vec![v, 3], &bind_offsets),
            ("regions", Dtype::U8, vec![v], &regions),
            ("occlusion", Dtype::U8, vec![v], &occlusion),
            (
                "covers",
                Dtype::U8,
                vec![self.garments.len(), row_bytes],
                &covers,
            ),
            ("body_occlusion", Dtype::U8, vec![body], &body_occlusion),
        ];
        let views = entries
            .into_iter()
            .map(|(name, dtype, shape, data)| {
                TensorView::new(dtype, shape, data)
                    .map(|view| (name.to_string(), view))
                    .map_err(|e| BodyError::format(name, e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let list: Vec<Entry> = all()
            .map(|g| Entry {
                name: g.name.clone(),
                kind: g.kind.name().to_string(),
                source: g.source.clone(),
                vertices: g.vertices.len(),
                triangles: g.triangles.len(),
            })
            .collect();
        let metadata = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            (
                "garments".to_string(),
                serde_json::to_string(&list).expect("entries serialise"),
            ),
            ("body_vertices".to_string(), body.to_string()),
            (
                "frame".to_string(),
                "metres, +Y up, facing +Z, y=0 at the soles, x/z centred between the feet (the \
                 body template's canonical frame and rest A-pose)"
                    .to_string(),
            ),
            (
                "license".to_string(),
                "CC0 1.0: MakeHuman community assets (makehuman-assets, base/clothes, base/hair) \
                 and garments derived from the CC0 MakeHuman body"
                    .to_string(),
            ),
        ]);
        let bytes = safetensors::serialize(views, Some(metadata))
            .map_err(|e| BodyError::format(origin, e.to_string()))?;
        Ok(crate::body::template::canonical_header(bytes))
    }

    /// Parses safetensors bytes written by [`GarmentLibrary::to_bytes`]; `origin` names the
    /// source in errors. Skinning weights are renormalised (they are stored as f16).
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Self, BodyError> {
        let (_, meta) = SafeTensors::read_metadata(bytes)
            .map_err(|e| BodyError::format(origin, e.to_string()))?;
        let st = SafeTensors::deserialize(bytes)
            .map_err(|e| BodyError::format(origin, e.to_string()))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let get = |key: &str| {
            meta.get(key)
                .cloned()
                .ok_or_else(|| BodyError::missing(origin, format!("metadata.{key}")))
        };
        if get("format")? != FORMAT {
            return Err(BodyError::format(
                origin,
                format!("metadata.format is not {FORMAT}"),
            ));
        }
        let list: Vec<Entry> = serde_json::from_str(&get("garments")?)
            .map_err(|e| BodyError::format(origin, format!("metadata.garments: {e}")))?;
        let body: usize = get("body_vertices")?
            .parse()
            .map_err(|e| BodyError::format(origin, format!("metadata.body_vertices: {e}")))?;
        let v: usize = list.iter().map(|e| e.vertices).sum();
        let t: usize = list.iter().map(|e| e.triangles).sum();
        let g = list.len();
        let row_bytes = body.div_ceil(8);
        let raw = |key: &str, dtype: Dtype, shape: &[usize]| -> Result<Vec<u8>, BodyError> {
            let view = st
                .tensor(key)
                .map_err(|_| BodyError::missing(origin, key))?;
            if view.dtype() != dtype || view.shape() != shape {
                return Err(BodyError::format(
                    origin,
                    format!(
                        "tensor `{key}` is {:?} {:?}, expected {dtype:?} {shape:?}",
                        view.dtype(),
                        view.shape()
                    ),
                ));
            }
            Ok(view.data().to_vec())
        };
        let halfs = |key: &str, cols: usize| -> Result<Vec<f32>, BodyError> {
            Ok(raw(key, Dtype::F16, &[v, cols])?
                .chunks_exact(2)
                .map(|b| f16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect())
        };
        let u16s = |key: &str, rows: usize| -> Result<Vec<u16>, BodyError> {
            Ok(raw(key, Dtype::U16, &[rows, 3])?
                .chunks_exact(2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
                .collect())
        };
        let positions = halfs("positions", 3)?;
        let triangles = u16s("triangles", t)?;
        let skin_bones = raw("skin_bones", Dtype::U8, &[v, MAX_INFLUENCES])?;
        let skin_weights = halfs("skin_weights", MAX_INFLUENCES)?;
        let bind_vertices = u16s("bind_vertices", v)?;
        let bind_weights: Vec<f32> = raw("bind_weights", Dtype::F32, &[v, 3])?
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let bind_offsets = halfs("bind_offsets", 3)?;
        let regions = raw("regions", Dtype::U8, &[v])?;
        let occlusion = raw("occlusion", Dtype::U8, &[v])?;
        let covers = raw("covers", Dtype::U8, &[g, row_bytes])?;
        let body_occlusion = raw("body_occlusion", Dtype::U8, &[body])?;

        let vec3 = |data: &[f32], i: usize| Vec3::from_slice(&data[3 * i..3 * i + 3]);
        let mut garments = Vec::with_capacity(g);
        let (mut v0, mut t0) = (0usize, 0usize);
        for (k, e) in list.into_iter().enumerate() {
            let kind = GarmentKind::parse(&e.kind).ok_or_else(|| {
                BodyError::format(
                    origin,
                    format!("garment `{}`: unknown kind `{}`", e.name, e.kind),
                )
            })?;
            let range = v0..v0 + e.vertices;
            let mut skin = SkinWeights::default();
            for i in range.clone() {
                let mut b = [0u16; MAX_INFLUENCES];
                let mut w = [0f32; MAX_INFLUENCES];
                for j in 0..MAX_INFLUENCES {
                    b[j] = skin_bones[i * MAX_INFLUENCES + j] as u16;
                    w[j] = skin_weights[i * MAX_INFLUENCES + j].max(0.0);
                }
                let sum: f32 = w.iter().sum();
                if sum > 0.0 {
                    w.iter_mut().for_each(|x| *x /= sum);
                }
                skin.bones.push(b);
                skin.weights.push(w);
            }
            let regions = range
                .clone()
                .map(|i| {
                    GarmentRegion::from_u8(regions[i]).ok_or_else(|| {
                        BodyError::format(
                            origin,
                            format!("garment `{}`: region {} unknown", e.name, regions[i]),
                        )
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            let binding = GarmentBinding {
                vertices: range
                    .clone()
                    .map(|i| [0, 1, 2].map(|j| bind_vertices[3 * i + j]))
                    .collect(),
                weights: range
                    .clone()
                    .map(|i| [0, 1, 2].map(|j| bind_weights[3 * i + j]))
                    .collect(),
                offsets: range.clone().map(|i| vec3(&bind_offsets, i)).collect(),
            };
            garments.push(Garment {
                name: e.name,
                kind,
                source: e.source,
                vertices: range.clone().map(|i| vec3(&positions, i)).collect(),
                triangles: (t0..t0 + e.triangles)
                    .map(|i| [0, 1, 2].map(|j| triangles[3 * i + j] as u32))
                    .collect(),
                skin,
                binding,
                regions,
                occlusion: range.map(|i| occlusion[i] as f32 / 255.0).collect(),
                covers: (0..body)
                    .map(|i| covers[k * row_bytes + i / 8] & (1 << (i % 8)) != 0)
                    .collect(),
            });
            v0 += e.vertices;
            t0 += e.triangles;
        }
        let library = Self {
            garments,
            body_occlusion: body_occlusion.iter().map(|a| *a as f32 / 255.0).collect(),
        };
        for garment in &library.garments {
            garment.validate(256, body, origin)?;
        }
        Ok(library)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> GarmentLibrary {
        let skin = SkinWeights {
            bones: vec![[3, 0, 0, 0], [1, 2, 0, 0], [2, 0, 0, 0]],
            weights: vec![
                [1.0, 0.0, 0.0, 0.0],
                [0.25, 0.75, 0.0, 0.0],
                [1.0, 0.0, 0.0, 0.0],
            ],
        };
        GarmentLibrary {
            garments: vec![Garment {
                name: "cape".into(),
                kind: GarmentKind::Coat,
                source: "test".into(),
                vertices: vec![
                    Vec3::ZERO,
                    Vec3::new(0.5, 1.0, 0.0),
                    Vec3::new(0.0, 1.5, 0.25),
                ],
                triangles: vec![[0, 1, 2]],
                skin,
                binding: GarmentBinding {
                    vertices: vec![[0, 1, 2]; 3],
                    weights: vec![[1.0, 0.0, 0.0]; 3],
                    offsets: vec![Vec3::new(0.0, 0.0, 0.03); 3],
                },
                regions: vec![
                    GarmentRegion::Top,
                    GarmentRegion::Sleeve,
                    GarmentRegion::Bottom,
                ],
                occlusion: vec![1.0, 0.5, 0.0],
                covers: (0..11).map(|i| i % 3 == 0).collect(),
            }],
            body_occlusion: vec![0.2; 11],
        }
    }

    #[test]
    fn a_library_survives_its_file_format() {
        let lib = tiny();
        let bytes = lib.to_bytes().unwrap();
        assert_eq!(bytes, lib.to_bytes().unwrap(), "deterministic bytes");
        let back = GarmentLibrary::from_bytes(&bytes, "t").unwrap();
        let (a, b) = (&lib.garments[0], &back.garments[0]);
        assert_eq!(a.name, b.name);
        assert_eq!(a.kind, b.kind);
        assert_eq!(a.triangles, b.triangles);
        assert_eq!(a.skin.bones, b.skin.bones);
        assert_eq!(a.regions, b.regions);
        assert_eq!(a.covers, b.covers);
        for (p, q) in a.vertices.iter().zip(&b.vertices) {
            assert!(p.distance(*q) < 1e-3);
        }
        assert!((b.occlusion[1] - 0.5).abs() < 0.003);
        assert!((back.body_occlusion[0] - 0.2).abs() < 0.003);
    }

    #[test]
    fn a_wrong_format_or_missing_tensor_is_named() {
        let err = GarmentLibrary::from_bytes(&[1, 2, 3], "bad.safetensors").unwrap_err();
        assert!(err.to_string().contains("bad.safetensors"));
        let template = crate::body::BodyTemplate::load_default().unwrap();
        let err = GarmentLibrary::from_bytes(&template.to_bytes().unwrap(), "body.st").unwrap_err();
        assert!(err.to_string().contains(FORMAT), "{err}");
    }
}
