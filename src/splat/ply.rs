//! Gaussian PLY files in the original 3DGS layout (binary little endian, one `vertex` element):
//! `x y z nx ny nz f_dc_0..2 f_rest_0.. opacity scale_0..2 rot_0..3`, all `float`.
//!
//! `f_rest` is channel-major (all red coefficients 1.., then green, then blue), opacity is
//! stored as a logit, scales as logs, rotations as `w x y z`. Standard viewers (SuperSplat, the
//! INRIA viewer) read these files. Optional extensions, ignored by viewers: skinning weights as
//! `skin_bone_0..3 skin_weight_0..3` (floats), feature channels as `feat_0..`, and the body
//! model id in a `comment lhmpp body_model <id>` header line.

use super::gaussians::{sh_coeff_count, GaussianError, Gaussians, MAX_SH_DEGREE};
use crate::body::{PlyScalar, SkinWeights, MAX_INFLUENCES};
use glam::{Quat, Vec3};
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Why a PLY file could not be read or written.
#[derive(Debug, Error)]
pub enum PlyError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// File path.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The header is malformed or uses something this reader does not support.
    #[error("{path}: bad PLY header: {reason}")]
    Header {
        /// File path.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A property the 3DGS layout requires is absent.
    #[error("{path}: PLY vertex element lacks property `{name}`")]
    MissingProperty {
        /// File path.
        path: PathBuf,
        /// Property name.
        name: String,
    },
    /// The body is shorter than the header promises.
    #[error(
        "{path}: truncated PLY: header promises {expected} bytes of vertex data, file has {actual}"
    )]
    Truncated {
        /// File path.
        path: PathBuf,
        /// Bytes expected.
        expected: usize,
        /// Bytes present.
        actual: usize,
    },
    /// The values read do not form a valid Gaussian set.
    #[error("{path}: {source}")]
    Gaussians {
        /// File path.
        path: PathBuf,
        /// Underlying error.
        source: GaussianError,
    },
    /// Skinning weights to write do not have one row per Gaussian.
    #[error("{path}: {skin} skinning rows for {gaussians} Gaussians")]
    SkinRows {
        /// File path.
        path: PathBuf,
        /// Skin rows.
        skin: usize,
        /// Gaussians.
        gaussians: usize,
    },
}

/// What a Gaussian PLY file holds.
#[derive(Debug, Clone, PartialEq)]
pub struct PlyGaussians {
    /// The Gaussians (activated: linear scales, opacities in `[0, 1]`, unit rotations).
    pub gaussians: Gaussians,
    /// Skinning weights, when the file has the `skin_*` extension.
    pub skin: Option<SkinWeights>,
    /// Body model id, when the file names one.
    pub body_model: Option<String>,
}

/// Bounds used before taking `logit(opacity)` and `ln(scale)`, keeping the file finite.
const OPACITY_EPS: f64 = 1e-6;
const MIN_SCALE: f32 = 1e-10;

/// Writes Gaussians (and optionally skinning weights and a body model id) to `path`.
pub fn write_ply(
    path: &Path,
    gaussians: &Gaussians,
    skin: Option<&SkinWeights>,
    body_model: Option<&str>,
) -> Result<(), PlyError> {
    let io = |source| PlyError::Io {
        path: path.to_owned(),
        source,
    };
    gaussians.validate().map_err(|source| PlyError::Gaussians {
        path: path.to_owned(),
        source,
    })?;
    if let Some(s) = skin {
        if s.len() != gaussians.len() || s.weights.len() != s.bones.len() {
            return Err(PlyError::SkinRows {
                path: path.to_owned(),
                skin: s.len(),
                gaussians: gaussians.len(),
            });
        }
    }
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = BufWriter::new(file);
    write_ply_to(&mut w, gaussians, skin, body_model).map_err(io)?;
    w.flush().map_err(io)
}

/// Property names in file order for a set with this SH degree, skin flag and feature count.
fn property_names(sh_degree: usize, skin: bool, channels: usize) -> Vec<String> {
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    names.extend((0..3 * (sh_coeff_count(sh_degree) - 1)).map(|k| format!("f_rest_{k}")));
    names.push("opacity".into());
    names.extend((0..3).map(|k| format!("scale_{k}")));
    names.extend((0..4).map(|k| format!("rot_{k}")));
    if skin {
        names.extend((0..MAX_INFLUENCES).map(|k| format!("skin_bone_{k}")));
        names.extend((0..MAX_INFLUENCES).map(|k| format!("skin_weight_{k}")));
    }
    names.extend((0..channels).map(|k| format!("feat_{k}")));
    names
}

/// Writes a PLY to any writer (see [`write_ply`]); the set must be valid.
pub fn write_ply_to<W: Write>(
    w: &mut W,
    g: &Gaussians,
    skin: Option<&SkinWeights>,
    body_model: Option<&str>,
) -> std::io::Result<()> {
    let names = property_names(g.sh_degree, skin.is_some(), g.feature_channels);
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    if let Some(id) = body_model {
        header.push_str(&format!(
            "comment lhmpp body_model {}\n",
            id.replace(char::is_whitespace, "_")
        ));
    }
    header.push_str(&format!("element vertex {}\n", g.len()));
    for n in &names {
        header.push_str(&format!("property float {n}\n"));
    }
    header.push_str("end_header\n");
    w.write_all(header.as_bytes())?;

    let k = g.sh_per_gaussian();
    let mut row: Vec<f32> = Vec::with_capacity(names.len());
    let mut bytes: Vec<u8> = Vec::with_capacity(names.len() * 4);
    for i in 0..g.len() {
        row.clear();
        row.extend(g.positions[i].to_array());
        row.extend([0.0; 3]);
        let sh = g.sh_of(i);
        row.extend(sh[0]);
        for ch in 0..3 {
            row.extend(sh[1..k].iter().map(|c| c[ch]));
        }
        let o = (g.opacities[i] as f64).clamp(OPACITY_EPS, 1.0 - OPACITY_EPS);
        row.push((o / (1.0 - o)).ln() as f32);
        row.extend(g.scales[i].to_array().map(|s| s.max(MIN_SCALE).ln()));
        let q = g.rotations[i];
        row.extend([q.w, q.x, q.y, q.z]);
        if let Some(s) = skin {
            row.extend(s.bones[i].map(|b| b as f32));
            row.extend(s.weights[i]);
        }
        row.extend_from_slice(g.features_of(i));
        bytes.clear();
        for v in &row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&bytes)?;
    }
    Ok(())
}

/// Reads a Gaussian PLY (3DGS layout, any SH degree 0..=3, optional lhmpp extensions).
pub fn read_ply(path: &Path) -> Result<PlyGaussians, PlyError> {
    let file = std::fs::File::open(path).map_err(|source| PlyError::Io {
        path: path.to_owned(),
        source,
    })?;
    read_ply_from(BufReader::new(file), path)
}

/// The parsed header: vertex count, properties (name, type, byte offset), record size.
struct Header {
    count: usize,
    properties: Vec<(String, PlyScalar, usize)>,
    stride: usize,
    body_model: Option<String>,
}

fn parse_header<R: BufRead>(r: &mut R, path: &Path) -> Result<Header, PlyError> {
    let bad = |reason: String| PlyError::Header {
        path: path.to_owned(),
        reason,
    };
    let mut line = Vec::new();
    let mut next_line = |r: &mut R| -> Result<String, PlyError> {
        line.clear();
        let n = r
            .read_until(b'\n', &mut line)
            .map_err(|source| PlyError::Io {
                path: path.to_owned(),
                source,
            })?;
        if n == 0 {
            return Err(PlyError::Header {
                path: path.to_owned(),
                reason: "ends before `end_header`".into(),
            });
        }
        Ok(String::from_utf8_lossy(&line).trim_end().to_string())
    };
    if next_line(r)? != "ply" {
        return Err(bad("does not start with `ply`".into()));
    }
    let mut header = Header {
        count: 0,
        properties: Vec::new(),
        stride: 0,
        body_model: None,
    };
    let mut element: Option<String> = None;
    let mut seen_vertex = false;
    let mut format_ok = false;
    loop {
        let l = next_line(r)?;
        let words: Vec<&str> = l.split_whitespace().collect();
        match words.as_slice() {
            ["end_header"] => break,
            ["format", "binary_little_endian", _] => format_ok = true,
            ["format", other, ..] => {
                return Err(bad(format!(
                    "format `{other}` unsupported (need binary_little_endian)"
                )))
            }
            ["comment", "lhmpp", "body_model", id] => header.body_model = Some(id.to_string()),
            ["comment", ..] | ["obj_info", ..] | [] => {}
            ["element", name, count] => {
                if seen_vertex {
                    // Elements after the vertex data are never read.
                    element = Some(name.to_string());
                    continue;
                }
                if *name != "vertex" {
                    return Err(bad(format!(
                        "element `{name}` before `vertex` is unsupported"
                    )));
                }
                header.count = count
                    .parse()
                    .map_err(|_| bad(format!("vertex count `{count}` is not a number")))?;
                seen_vertex = true;
                element = Some(name.to_string());
            }
            ["property", "list", ..] if element.as_deref() == Some("vertex") => {
                return Err(bad("list properties in `vertex` are unsupported".into()));
            }
            ["property", ty, name] => {
                if element.as_deref() == Some("vertex") {
                    let scalar = PlyScalar::parse(ty)
                        .ok_or_else(|| bad(format!("property `{name}` has unknown type `{ty}`")))?;
                    header
                        .properties
                        .push((name.to_string(), scalar, header.stride));
                    header.stride += scalar.size();
                }
            }
            ["property", "list", ..] => {}
            _ => return Err(bad(format!("unexpected line `{l}`"))),
        }
    }
    if !format_ok {
        return Err(bad("no `format` line".into()));
    }
    if !seen_vertex {
        return Err(bad("no `vertex` element".into()));
    }
    Ok(header)
}

/// Reads a Gaussian PLY from any reader; `path` is only used in error messages.
pub fn read_ply_from<R: BufRead>(mut r: R, path: &Path) -> Result<PlyGaussians, PlyError> {
    let header = parse_header(&mut r, path)?;
    let expected = header
        .count
        .checked_mul(header.stride)
        .ok_or_else(|| PlyError::Header {
            path: path.to_owned(),
            reason: format!("vertex count {} is too large", header.count),
        })?;
    let mut body = Vec::with_capacity(expected.min(1 << 30));
    r.take(expected as u64)
        .read_to_end(&mut body)
        .map_err(|source| PlyError::Io {
            path: path.to_owned(),
            source,
        })?;
    if body.len() < expected {
        return Err(PlyError::Truncated {
            path: path.to_owned(),
            expected,
            actual: body.len(),
        });
    }
    let find = |name: &str| {
        header
            .properties
            .iter()
            .find(|p| p.0 == name)
            .map(|p| (p.1, p.2))
    };
    let need = |name: &str| {
        find(name).ok_or_else(|| PlyError::MissingProperty {
            path: path.to_owned(),
            name: name.to_string(),
        })
    };
    let cols = |names: &[&str]| names.iter().map(|n| need(n)).collect::<Result<Vec<_>, _>>();
    let pos = cols(&["x", "y", "z"])?;
    let dc = cols(&["f_dc_0", "f_dc_1", "f_dc_2"])?;
    let opacity = need("opacity")?;
    let scale = cols(&["scale_0", "scale_1", "scale_2"])?;
    let rot = cols(&["rot_0", "rot_1", "rot_2", "rot_3"])?;
    let rest_count = (0..)
        .take_while(|k| find(&format!("f_rest_{k}")).is_some())
        .count();
    let degree = (0..=MAX_SH_DEGREE)
        .find(|d| 3 * (sh_coeff_count(*d) - 1) == rest_count)
        .ok_or_else(|| PlyError::Header {
            path: path.to_owned(),
            reason: format!("{rest_count} `f_rest_*` properties match no SH degree 0..=3"),
        })?;
    let rest: Vec<_> = (0..rest_count)
        .map(|k| need(&format!("f_rest_{k}")))
        .collect::<Result<_, _>>()?;
    let skin_cols = match find("skin_bone_0") {
        Some(_) => {
            let bones: Vec<_> = (0..MAX_INFLUENCES)
                .map(|k| need(&format!("skin_bone_{k}")))
                .collect::<Result<_, _>>()?;
            let weights: Vec<_> = (0..MAX_INFLUENCES)
                .map(|k| need(&format!("skin_weight_{k}")))
                .collect::<Result<_, _>>()?;
            Some((bones, weights))
        }
        None => None,
    };
    let channels = (0..)
        .take_while(|k| find(&format!("feat_{k}")).is_some())
        .count();
    let feat: Vec<_> = (0..channels)
        .map(|k| need(&format!("feat_{k}")).expect("counted"))
        .collect();

    let n = header.count;
    let k = sh_coeff_count(degree);
    let mut g = Gaussians {
        positions: Vec::with_capacity(n),
        scales: Vec::with_capacity(n),
        rotations: Vec::with_capacity(n),
        opacities: Vec::with_capacity(n),
        sh_degree: degree,
        sh: Vec::with_capacity(n * k),
        feature_channels: channels,
        features: Vec::with_capacity(n * channels),
    };
    let mut skin = skin_cols.as_ref().map(|_| SkinWeights::default());
    for rec in body.chunks_exact(header.stride.max(1)).take(n) {
        let get = |(t, o): (PlyScalar, usize)| t.read(&rec[o..], true) as f32;
        let v3 = |c: &[(PlyScalar, usize)]| Vec3::new(get(c[0]), get(c[1]), get(c[2]));
        g.positions.push(v3(&pos));
        g.scales.push(v3(&scale).to_array().map(f32::exp).into());
        let q = Quat::from_xyzw(get(rot[1]), get(rot[2]), get(rot[3]), get(rot[0]));
        let len = q.length();
        g.rotations.push(if len > 0.0 && len.is_finite() {
            q / len
        } else {
            q
        });
        let logit = get(opacity) as f64;
        g.opacities.push((1.0 / (1.0 + (-logit).exp())) as f32);
        g.sh.push([get(dc[0]), get(dc[1]), get(dc[2])]);
        let (red, green_blue) = rest.split_at(k - 1);
        let (green, blue) = green_blue.split_at(k - 1);
        for ((r, g_), b) in red.iter().zip(green).zip(blue) {
            g.sh.push([get(*r), get(*g_), get(*b)]);
        }
        g.features.extend(feat.iter().map(|c| get(*c)));
        if let (Some(s), Some((bones, weights))) = (skin.as_mut(), skin_cols.as_ref()) {
            s.bones.push(std::array::from_fn(|j| {
                get(bones[j]).clamp(0.0, u16::MAX as f32) as u16
            }));
            s.weights.push(std::array::from_fn(|j| get(weights[j])));
        }
    }
    if header.stride == 0 && n > 0 {
        return Err(PlyError::Header {
            path: path.to_owned(),
            reason: "vertex element has no properties".into(),
        });
    }
    g.validate().map_err(|source| PlyError::Gaussians {
        path: path.to_owned(),
        source,
    })?;
    Ok(PlyGaussians {
        gaussians: g,
        skin,
        body_model: header.body_model,
    })
}
