//! Converter from the CC0 MakeHuman clothes and hair (`.mhclo` + `.obj`, see
//! `/work/shared/assets/makehuman-clothes/README.md`) into the garment library
//! (`assets/body/garments.safetensors`, [`GarmentLibrary`]), run by `lhmpp body garments`.
//!
//! Steps per garment: fit the garment mesh on the MakeHuman base mesh `hm08` (`base.obj`,
//! helper geometry included) through its `.mhclo` references; move it into the template's
//! canonical frame by the template converter's mapping (decimetres → metres, then the offset
//! that puts the template's soles at y = 0 between the feet, recovered from the template's own
//! vertices, which are `base.obj`'s first 13,380); carry skinning weights over from the three
//! reference vertices (`weights.default.json` weights every base vertex, helpers included);
//! drop vertices no face uses; turn meshes whose faces mostly point into the body; split
//! outfits into top and bottom pieces by connected components; label regions; add the four
//! garments made by offsetting body regions (`offset`); compute which skin vertices each
//! garment covers and every vertex's ambient occlusion (`coverage`).

mod coverage;
mod mhclo;
mod offset;
mod pieces;

pub use mhclo::{Mhclo, Reference};
pub use pieces::Piece;

use super::{ObjMesh, SOURCE_UNITS_PER_METRE};
use crate::body::garment::{Garment, GarmentKind, GarmentLibrary};
use crate::body::{BodyError, BodyTemplate};
use glam::Vec3;
use std::path::{Path, PathBuf};

/// Largest distance (metres) between a template vertex and the same `base.obj` vertex mapped
/// into the canonical frame for the two to count as the same mesh.
const FRAME_TOLERANCE: f32 = 1e-4;

/// Garment sources skipped: a variant of a garment kept under another name.
const SKIPPED: [&str; 1] = ["fedora_cocked"];

fn read_text(path: &Path) -> Result<String, BodyError> {
    std::fs::read_to_string(path).map_err(|e| BodyError::io(path, e))
}

/// The `hm08` base mesh in the template's canonical frame, with top-4 skinning weights for
/// every base vertex (helpers included).
pub struct BaseMesh {
    /// Every `base.obj` vertex, canonical frame (metres).
    pub positions: Vec<Vec3>,
    /// Source units (decimetres) to canonical: `p / 10 − offset`.
    pub offset: Vec3,
    /// Skinning weights of every base vertex on the template's bones.
    pub skin: crate::body::SkinWeights,
}

impl BaseMesh {
    /// Reads `base.obj` and `weights.default.json` from `makehuman_dir` and recovers the
    /// template's frame; errors when the template's vertices are not `base.obj`'s first ones.
    pub fn load(makehuman_dir: &Path, template: &BodyTemplate) -> Result<Self, BodyError> {
        let obj_path = makehuman_dir.join("base.obj");
        let origin = obj_path.display().to_string();
        let obj = ObjMesh::parse(&read_text(&obj_path)?, &origin)?;
        let b = template.vertices.len();
        if obj.positions.len() < b {
            return Err(BodyError::format(
                &origin,
                format!(
                    "{} vertices, fewer than the template's {b}",
                    obj.positions.len()
                ),
            ));
        }
        let metres = |p: Vec3| p / SOURCE_UNITS_PER_METRE;
        let offset = (0..b)
            .map(|i| metres(obj.positions[i]) - template.vertices[i])
            .sum::<Vec3>()
            / b as f32;
        let worst = (0..b)
            .map(|i| (metres(obj.positions[i]) - offset).distance(template.vertices[i]))
            .fold(0.0f32, f32::max);
        if worst > FRAME_TOLERANCE {
            return Err(BodyError::format(
                &origin,
                format!("not the template's base mesh: vertices differ by up to {worst:.4} m"),
            ));
        }
        let weights_path = makehuman_dir.join("weights.default.json");
        let all: Vec<usize> = (0..obj.positions.len()).collect();
        let skin = super::weights::skin_weights(
            &read_text(&weights_path)?,
            &weights_path.display().to_string(),
            &template.skeleton.bone_names,
            &all,
        )?;
        Ok(Self {
            positions: obj.positions.iter().map(|p| metres(*p) - offset).collect(),
            offset,
            skin,
        })
    }

    /// Source-unit positions (as `.mhclo` fits expect them).
    pub fn source_positions(&self) -> Vec<Vec3> {
        self.positions
            .iter()
            .map(|p| (*p + self.offset) * SOURCE_UNITS_PER_METRE)
            .collect()
    }
}

/// Every `.mhclo` under `clothes_dir/clothes/*/` and `clothes_dir/hair/*/`, sorted, with the
/// kind its folder implies (`None`: an outfit, split into pieces later).
fn sources(clothes_dir: &Path) -> Result<Vec<(PathBuf, Option<GarmentKind>)>, BodyError> {
    let mut out = Vec::new();
    for (sub, hair) in [("clothes", false), ("hair", true)] {
        let dir = clothes_dir.join(sub);
        let mut folders: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map_err(|e| BodyError::io(&dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        folders.sort();
        for folder in folders {
            let mut files: Vec<PathBuf> = std::fs::read_dir(&folder)
                .map_err(|e| BodyError::io(&folder, e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "mhclo"))
                .collect();
            files.sort();
            for file in files {
                let stem = file
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .unwrap_or_default();
                if SKIPPED.contains(&stem) {
                    continue;
                }
                let kind = if hair {
                    Some(GarmentKind::Hair)
                } else if stem.starts_with("shoes") {
                    Some(GarmentKind::Shoes)
                } else if stem.starts_with("fedora") {
                    Some(GarmentKind::Hat)
                } else {
                    None
                };
                out.push((file, kind));
            }
        }
    }
    if out.is_empty() {
        return Err(BodyError::format(
            clothes_dir.display(),
            "no .mhclo files under clothes/*/ or hair/*/",
        ));
    }
    Ok(out)
}

/// Converts the MakeHuman clothes folder `clothes_dir` (with `clothes/` and `hair/`) for
/// `template`, fitted on the base mesh and weights in `makehuman_dir`.
pub fn convert_garments(
    clothes_dir: &Path,
    makehuman_dir: &Path,
    template: &BodyTemplate,
) -> Result<GarmentLibrary, BodyError> {
    let base = BaseMesh::load(makehuman_dir, template)?;
    let source_base = base.source_positions();
    let body = coverage::BodyScene::new(template);
    let mut pieces = Vec::new();
    for (path, kind) in sources(clothes_dir)? {
        let origin = path.display().to_string();
        let mhclo = Mhclo::parse(&read_text(&path)?, &origin)?;
        let obj_path = path.with_file_name(&mhclo.obj_file);
        let obj = ObjMesh::parse(&read_text(&obj_path)?, &obj_path.display().to_string())?;
        if mhclo.references.len() != obj.positions.len() {
            return Err(BodyError::format(
                &origin,
                format!(
                    "{} reference lines for {} vertices of {}",
                    mhclo.references.len(),
                    obj.positions.len(),
                    mhclo.obj_file
                ),
            ));
        }
        let fitted = mhclo.fit(&source_base, &origin)?;
        let scale = mhclo.axis_scale(&source_base, &origin)? / SOURCE_UNITS_PER_METRE;
        let folder = path
            .parent()
            .and_then(|p| p.file_name())
            .and_then(|n| n.to_str())
            .unwrap_or(&mhclo.name);
        let relative = path
            .strip_prefix(clothes_dir)
            .unwrap_or(&path)
            .display()
            .to_string();
        let piece = Piece::from_fit(
            &obj,
            &fitted
                .iter()
                .map(|p| *p / SOURCE_UNITS_PER_METRE - base.offset)
                .collect::<Vec<_>>(),
            &mhclo.references,
            scale,
            &base.skin,
        )?;
        let piece = Piece {
            name: folder.to_string(),
            source: format!("makehuman-clothes/{relative}"),
            ..piece
        };
        match kind {
            Some(kind) => pieces.push(piece.labelled(kind)),
            None => pieces.extend(piece.split_outfit(template)),
        }
    }
    pieces.extend(offset::offset_garments(template)?);
    let garments: Vec<Garment> = pieces
        .into_iter()
        .map(|p| {
            let p = p.facing_out(&body);
            coverage::finish(p, &body)
        })
        .collect();
    let library = GarmentLibrary {
        garments,
        body_occlusion: body.occlusion(),
    };
    library.validate(template, &clothes_dir.display().to_string())?;
    Ok(library)
}
