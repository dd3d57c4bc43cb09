//! The body template: rest mesh, UVs, part labels, skeleton and skinning weights, stored as
//! one safetensors file (arrays as tensors, names and metadata as JSON in the header).

use super::{BodyError, Pose, Skeleton, SkinWeights, MAX_INFLUENCES};
use glam::{Mat3, Vec2, Vec3};
use safetensors::tensor::{Dtype, TensorView};
use safetensors::SafeTensors;
use std::collections::HashMap;
use std::path::Path;

/// The committed MakeHuman template (see `assets/body/README.md`), embedded in the binary.
pub const DEFAULT_ASSET: &[u8] = include_bytes!("../../assets/body/makehuman.safetensors");

/// Value of the `format` metadata entry of template files.
pub const FORMAT: &str = "lhmpp-body-template-v1";

/// A skinned human body template in the canonical frame and pose (see the module doc).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BodyTemplate {
    /// Rest vertex positions (metres).
    pub vertices: Vec<Vec3>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Texture coordinate per vertex (OBJ convention, v up); empty when the source has none.
    pub uvs: Vec<Vec2>,
    /// Body-part index per vertex into `part_names`.
    pub part_labels: Vec<u8>,
    /// Body-part names (`body`, `head`, `hand.L`, ...).
    pub part_names: Vec<String>,
    /// Kinematic tree in the rest pose.
    pub skeleton: Skeleton,
    /// Top-4 skinning weights per vertex.
    pub skin: SkinWeights,
    /// Name of the canonical (rest) pose, e.g. `makehuman-a-pose`.
    pub canonical_pose: String,
}

impl BodyTemplate {
    /// The embedded MakeHuman template.
    pub fn load_default() -> Result<Self, BodyError> {
        Self::from_bytes(DEFAULT_ASSET, "embedded assets/body/makehuman.safetensors")
    }

    /// Reads a template file written by [`BodyTemplate::to_bytes`] (`lhmpp body convert`).
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let bytes = std::fs::read(path).map_err(|e| BodyError::io(path, e))?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Writes the template as a safetensors file.
    pub fn save(&self, path: &Path) -> Result<(), BodyError> {
        let bytes = self.to_bytes()?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| BodyError::io(dir, e))?;
        }
        std::fs::write(path, bytes).map_err(|e| BodyError::io(path, e))
    }

    /// Height of the rest mesh (top minus bottom, metres).
    pub fn height(&self) -> f32 {
        let (lo, hi) = self
            .vertices
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), v| {
                (lo.min(v.y), hi.max(v.y))
            });
        if self.vertices.is_empty() {
            0.0
        } else {
            hi - lo
        }
    }

    /// Number of vertices per part, in `part_names` order.
    pub fn part_counts(&self) -> Vec<usize> {
        let mut counts = vec![0; self.part_names.len()];
        for l in &self.part_labels {
            if let Some(c) = counts.get_mut(*l as usize) {
                *c += 1;
            }
        }
        counts
    }

    /// Rest vertices moved by `pose` (linear blend skinning); errors on unknown bones.
    pub fn posed_vertices(&self, pose: &Pose) -> Result<Vec<Vec3>, BodyError> {
        let m = self.skeleton.try_skinning_matrices(pose)?;
        Ok(self.skin.skin_points(&self.vertices, &m))
    }

    /// Checks array lengths and index ranges; `origin` names the source in errors.
    pub fn validate(&self, origin: &str) -> Result<(), BodyError> {
        let n = self.vertices.len();
        let bad = |m: String| Err(BodyError::format(origin, m));
        if self.part_labels.len() != n || self.skin.len() != n {
            return bad(format!(
                "{n} vertices but {} part labels and {} weight rows",
                self.part_labels.len(),
                self.skin.len()
            ));
        }
        if !self.uvs.is_empty() && self.uvs.len() != n {
            return bad(format!("{n} vertices but {} uvs", self.uvs.len()));
        }
        if let Some(t) = self
            .triangles
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= n))
        {
            return bad(format!("triangle {t:?} indexes past {n} vertices"));
        }
        if let Some(l) = self
            .part_labels
            .iter()
            .find(|&&l| l as usize >= self.part_names.len())
        {
            return bad(format!(
                "part label {l} past {} part names",
                self.part_names.len()
            ));
        }
        let bones = self.skeleton.len();
        if let Some(b) = self
            .skin
            .bones
            .iter()
            .flatten()
            .find(|&&b| b as usize >= bones)
        {
            return bad(format!("skinning bone index {b} past {bones} bones"));
        }
        self.skeleton.validate(origin)
    }

    /// Serialises the template as safetensors bytes (deterministic).
    pub fn to_bytes(&self) -> Result<Vec<u8>, BodyError> {
        let flat_v: Vec<f32> = self.vertices.iter().flat_map(|v| v.to_array()).collect();
        let flat_t: Vec<u32> = self.triangles.iter().flatten().copied().collect();
        let flat_uv: Vec<f32> = self.uvs.iter().flat_map(|v| v.to_array()).collect();
        let flat_j: Vec<f32> = self
            .skeleton
            .joints
            .iter()
            .flat_map(|v| v.to_array())
            .collect();
        let parents: Vec<i32> = self
            .skeleton
            .parents
            .iter()
            .map(|p| p.map_or(-1, |p| p as i32))
            .collect();
        let orient: Vec<f32> = self
            .skeleton
            .rest_orientations
            .iter()
            .flat_map(|m| m.to_cols_array())
            .collect();
        let sb: Vec<u16> = self.skin.bones.iter().flatten().copied().collect();
        let sw: Vec<f32> = self.skin.weights.iter().flatten().copied().collect();
        let (nv, nj, k) = (self.vertices.len(), self.skeleton.len(), MAX_INFLUENCES);
        let entries: Vec<(&str, Dtype, Vec<usize>, &[u8])> = vec![
            (
                "vertices",
                Dtype::F32,
                vec![nv, 3],
                bytemuck::cast_slice(&flat_v),
            ),
            (
                "triangles",
                Dtype::U32,
                vec![self.triangles.len(), 3],
                bytemuck::cast_slice(&flat_t),
            ),
            (
                "uvs",
                Dtype::F32,
                vec![self.uvs.len(), 2],
                bytemuck::cast_slice(&flat_uv),
            ),
            (
                "part_labels",
                Dtype::U8,
                vec![self.part_labels.len()],
                &self.part_labels,
            ),
            (
                "joints",
                Dtype::F32,
                vec![nj, 3],
                bytemuck::cast_slice(&flat_j),
            ),
            (
                "parents",
                Dtype::I32,
                vec![nj],
                bytemuck::cast_slice(&parents),
            ),
            (
                "rest_orientations",
                Dtype::F32,
                vec![nj, 3, 3],
                bytemuck::cast_slice(&orient),
            ),
            (
                "skin_bones",
                Dtype::U16,
                vec![self.skin.len(), k],
                bytemuck::cast_slice(&sb),
            ),
            (
                "skin_weights",
                Dtype::F32,
                vec![self.skin.len(), k],
                bytemuck::cast_slice(&sw),
            ),
        ];
        let mut views = Vec::new();
        for (name, dtype, shape, data) in entries {
            let view = TensorView::new(dtype, shape, data)
                .map_err(|e| BodyError::format(name, e.to_string()))?;
            views.push((name.to_string(), view));
        }
        let json = |v: &Vec<String>| serde_json::to_string(v).expect("strings serialise");
        let metadata = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("bone_names".to_string(), json(&self.skeleton.bone_names)),
            ("part_names".to_string(), json(&self.part_names)),
            ("canonical_pose".to_string(), self.canonical_pose.clone()),
            (
                "frame".to_string(),
                "metres, +Y up, facing +Z, y=0 at the soles, x/z centred between the feet"
                    .to_string(),
            ),
            (
                "rest_orientations".to_string(),
                "column-major 3x3: bone X, Y (head->tail), Z axes in canonical coordinates"
                    .to_string(),
            ),
        ]);
        let bytes = safetensors::serialize(views, Some(metadata))
            .map_err(|e| BodyError::format("template", e.to_string()))?;
        Ok(canonical_header(bytes))
    }

    /// Parses safetensors bytes written by [`BodyTemplate::to_bytes`].
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Self, BodyError> {
        let (_, meta) = SafeTensors::read_metadata(bytes)
            .map_err(|e| BodyError::format(origin, e.to_string()))?;
        let st = SafeTensors::deserialize(bytes)
            .map_err(|e| BodyError::format(origin, e.to_string()))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let get_meta = |key: &str| {
            meta.get(key)
                .cloned()
                .ok_or_else(|| BodyError::missing(origin, format!("metadata.{key}")))
        };
        if get_meta("format")? != FORMAT {
            return Err(BodyError::format(
                origin,
                format!("metadata.format is not {FORMAT}"),
            ));
        }
        let names = |key: &str| -> Result<Vec<String>, BodyError> {
            serde_json::from_str(&get_meta(key)?)
                .map_err(|e| BodyError::format(origin, format!("metadata.{key}: {e}")))
        };
        let tensors = Tensors { st: &st, origin };
        let vertices = tensors
            .f32_rows::<3>("vertices")?
            .into_iter()
            .map(Vec3::from)
            .collect();
        let triangles = tensors.rows::<u32, 3>("triangles", Dtype::U32)?;
        let uvs = tensors
            .f32_rows::<2>("uvs")?
            .into_iter()
            .map(Vec2::from)
            .collect();
        let part_labels = tensors.rows::<u8, 1>("part_labels", Dtype::U8)?.concat();
        let joints = tensors
            .f32_rows::<3>("joints")?
            .into_iter()
            .map(Vec3::from)
            .collect();
        let parents = tensors
            .rows::<i32, 1>("parents", Dtype::I32)?
            .into_iter()
            .map(|[p]| usize::try_from(p).ok())
            .collect();
        let rest_orientations = tensors
            .f32_rows::<9>("rest_orientations")?
            .iter()
            .map(Mat3::from_cols_array)
            .collect();
        let skin = SkinWeights {
            bones: tensors.rows::<u16, MAX_INFLUENCES>("skin_bones", Dtype::U16)?,
            weights: tensors.f32_rows::<MAX_INFLUENCES>("skin_weights")?,
        };
        let template = Self {
            vertices,
            triangles,
            uvs,
            part_labels,
            part_names: names("part_names")?,
            skeleton: Skeleton {
                bone_names: names("bone_names")?,
                parents,
                joints,
                rest_orientations,
            },
            skin,
            canonical_pose: get_meta("canonical_pose")?,
        };
        template.validate(origin)?;
        Ok(template)
    }
}

/// Rewrites the safetensors JSON header with sorted keys: the crate writes its metadata map in
/// hash order, and the converter must reproduce the committed asset bit for bit. The sorted
/// header has the same length, so tensor offsets are unchanged.
pub(super) fn canonical_header(mut bytes: Vec<u8>) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8-byte length")) as usize;
    let header: std::collections::BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(&bytes[8..8 + n]).expect("safetensors wrote valid JSON");
    let header: std::collections::BTreeMap<String, serde_json::Value> = header
        .into_iter()
        .map(|(k, v)| {
            let v = match v {
                serde_json::Value::Object(m) => {
                    let sorted: std::collections::BTreeMap<_, _> = m.into_iter().collect();
                    serde_json::to_value(sorted).expect("json value")
                }
                other => other,
            };
            (k, v)
        })
        .collect();
    let mut text = serde_json::to_vec(&header).expect("json serialises");
    debug_assert!(text.len() <= n);
    text.resize(n, b' ');
    bytes[8..8 + n].copy_from_slice(&text);
    bytes
}

/// Typed access to the tensors of one safetensors file.
struct Tensors<'a> {
    st: &'a SafeTensors<'a>,
    origin: &'a str,
}

impl Tensors<'_> {
    fn rows<T: bytemuck::Pod, const K: usize>(
        &self,
        key: &str,
        dtype: Dtype,
    ) -> Result<Vec<[T; K]>, BodyError> {
        let view = self
            .st
            .tensor(key)
            .map_err(|_| BodyError::missing(self.origin, key))?;
        let cols: usize = view.shape().iter().skip(1).product();
        let cols = if view.shape().len() == 1 { 1 } else { cols };
        if view.dtype() != dtype || cols != K {
            return Err(BodyError::format(
                self.origin,
                format!(
                    "tensor `{key}` is {:?} {:?}, expected {dtype:?} with {K} values per row",
                    view.dtype(),
                    view.shape()
                ),
            ));
        }
        // The file's bytes may be unaligned: copy element by element.
        Ok(view
            .data()
            .chunks_exact(std::mem::size_of::<T>() * K)
            .map(|row| {
                let mut out = [T::zeroed(); K];
                bytemuck::cast_slice_mut::<T, u8>(&mut out[..]).copy_from_slice(row);
                out
            })
            .collect())
    }

    fn f32_rows<const K: usize>(&self, key: &str) -> Result<Vec<[f32; K]>, BodyError> {
        self.rows::<f32, K>(key, Dtype::F32)
    }
}
