//! Packing canonical Gaussians with their skinning into the `gaussians` PointCloud2 of a
//! `GaussianAvatar` (layout documented in `msg/msg/GaussianAvatar.msg`), and reading them back.

use super::{Header, MsgError, PointCloud2, PointField};
use crate::body::{SkinWeights, MAX_INFLUENCES};
use std::collections::HashMap;

/// Colour of each Gaussian: plain RGB, or spherical-harmonics coefficients.
#[derive(Debug, Clone, PartialEq)]
pub enum GaussianColors {
    /// `r g b` in `[0, 1]` per Gaussian (`sh_degree` 0).
    Rgb(Vec<[f32; 3]>),
    /// SH coefficients of the given degree (at least 1): per Gaussian `3 * (degree + 1)^2`
    /// values, `f_dc_0..2` first, then `f_rest_*` channel-major (3DGS PLY order).
    Sh {
        /// SH degree, 1 to 3 in practice.
        degree: u8,
        /// Coefficients, `3 * (degree + 1)^2` per Gaussian.
        coefficients: Vec<f32>,
    },
}

/// Canonical Gaussians of an avatar as plain arrays, one entry per Gaussian.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianCloud {
    /// Centres (metres).
    pub positions: Vec<[f32; 3]>,
    /// Linear scales (metres).
    pub scales: Vec<[f32; 3]>,
    /// Unit quaternions in `w x y z` order.
    pub rotations: Vec<[f32; 4]>,
    /// Opacities in `[0, 1]`.
    pub opacities: Vec<f32>,
    /// Colours.
    pub colors: GaussianColors,
    /// Bones and weights that move each Gaussian.
    pub skin: SkinWeights,
}

/// Number of SH coefficients per colour channel for a degree.
fn coefficients_per_channel(degree: u8) -> usize {
    (degree as usize + 1).pow(2)
}

/// Names of the float32 fields of a cloud with `sh_degree`, in layout order.
pub fn float_field_names(sh_degree: u8) -> Vec<String> {
    let mut names: Vec<String> = ["x", "y", "z", "scale_0", "scale_1", "scale_2"]
        .into_iter()
        .chain(["rot_0", "rot_1", "rot_2", "rot_3", "opacity"])
        .map(String::from)
        .collect();
    if sh_degree == 0 {
        names.extend(["r", "g", "b"].map(String::from));
    } else {
        names.extend((0..3).map(|i| format!("f_dc_{i}")));
        let rest = 3 * (coefficients_per_channel(sh_degree) - 1);
        names.extend((0..rest).map(|i| format!("f_rest_{i}")));
    }
    names.extend((0..MAX_INFLUENCES).map(|k| format!("weight_{k}")));
    names
}

/// Names of the uint16 bone-index fields, in layout order.
pub fn bone_field_names() -> Vec<String> {
    (0..MAX_INFLUENCES).map(|k| format!("bone_{k}")).collect()
}

impl GaussianCloud {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// SH degree of the colours (0 for plain RGB).
    pub fn sh_degree(&self) -> u8 {
        match &self.colors {
            GaussianColors::Rgb(_) => 0,
            GaussianColors::Sh { degree, .. } => *degree,
        }
    }

    fn check_lengths(&self) -> Result<(), MsgError> {
        let n = self.len();
        let color_len = match &self.colors {
            GaussianColors::Rgb(c) => c.len(),
            GaussianColors::Sh {
                degree,
                coefficients,
            } => {
                if *degree == 0 {
                    return Err(MsgError::Inconsistent(
                        "SH colours need degree 1 or more; use Rgb for degree 0".into(),
                    ));
                }
                let per = 3 * coefficients_per_channel(*degree);
                if coefficients.len() % per != 0 {
                    return Err(MsgError::Inconsistent(format!(
                        "{} SH coefficients is not a multiple of {per}",
                        coefficients.len()
                    )));
                }
                coefficients.len() / per
            }
        };
        let lengths = [
            ("scales", self.scales.len()),
            ("rotations", self.rotations.len()),
            ("opacities", self.opacities.len()),
            ("colors", color_len),
            ("skin bones", self.skin.bones.len()),
            ("skin weights", self.skin.weights.len()),
        ];
        for (what, len) in lengths {
            if len != n {
                return Err(MsgError::Inconsistent(format!(
                    "{n} positions but {len} {what}"
                )));
            }
        }
        Ok(())
    }

    /// The unordered (height 1), dense, little-endian PointCloud2 of these Gaussians.
    pub fn to_point_cloud(&self, header: Header) -> Result<PointCloud2, MsgError> {
        self.check_lengths()?;
        let float_names = float_field_names(self.sh_degree());
        let mut fields: Vec<PointField> = float_names
            .iter()
            .enumerate()
            .map(|(i, name)| PointField {
                name: name.clone(),
                offset: (4 * i) as u32,
                datatype: PointField::FLOAT32,
                count: 1,
            })
            .collect();
        let bones_at = 4 * float_names.len();
        fields.extend(
            bone_field_names()
                .into_iter()
                .enumerate()
                .map(|(k, name)| PointField {
                    name,
                    offset: (bones_at + 2 * k) as u32,
                    datatype: PointField::UINT16,
                    count: 1,
                }),
        );
        let point_step = bones_at + 2 * MAX_INFLUENCES;
        let mut data = Vec::with_capacity(point_step * self.len());
        for i in 0..self.len() {
            let mut floats: Vec<f32> = Vec::with_capacity(float_names.len());
            floats.extend(self.positions[i]);
            floats.extend(self.scales[i]);
            floats.extend(self.rotations[i]);
            floats.push(self.opacities[i]);
            match &self.colors {
                GaussianColors::Rgb(c) => floats.extend(c[i]),
                GaussianColors::Sh {
                    degree,
                    coefficients,
                } => {
                    let per = 3 * coefficients_per_channel(*degree);
                    floats.extend_from_slice(&coefficients[i * per..(i + 1) * per]);
                }
            }
            floats.extend(self.skin.weights[i]);
            for f in floats {
                data.extend_from_slice(&f.to_le_bytes());
            }
            for b in self.skin.bones[i] {
                data.extend_from_slice(&b.to_le_bytes());
            }
        }
        let is_dense = self.positions.iter().flatten().all(|v| v.is_finite());
        Ok(PointCloud2 {
            header,
            height: 1,
            width: self.len() as u32,
            fields,
            is_bigendian: false,
            point_step: point_step as u32,
            row_step: (point_step * self.len()) as u32,
            data,
            is_dense,
        })
    }

    /// Reads Gaussians back from a cloud laid out as documented for `GaussianAvatar` with the
    /// given `sh_degree`. Fields may come in any order and the cloud may carry extra fields;
    /// missing fields, wrong types or short data are errors naming the field.
    pub fn from_point_cloud(cloud: &PointCloud2, sh_degree: u8) -> Result<Self, MsgError> {
        if cloud.is_bigendian {
            return Err(MsgError::Inconsistent(
                "big-endian Gaussian clouds are not supported".into(),
            ));
        }
        let point_step = cloud.point_step as usize;
        let (width, height) = (cloud.width as usize, cloud.height as usize);
        let row_step = cloud.row_step as usize;
        let needed = match height {
            0 => 0,
            h => (h - 1) * row_step + width * point_step,
        };
        if cloud.data.len() < needed || (height > 0 && row_step < width * point_step) {
            return Err(MsgError::Inconsistent(format!(
                "{} data bytes for {width}x{height} points of {point_step} bytes (row_step {row_step})",
                cloud.data.len()
            )));
        }
        let by_name: HashMap<&str, &PointField> =
            cloud.fields.iter().map(|f| (f.name.as_str(), f)).collect();
        let offset_of = |name: &str, datatype: u8| -> Result<usize, MsgError> {
            let field = by_name
                .get(name)
                .ok_or_else(|| MsgError::Inconsistent(format!("field `{name}` is missing")))?;
            let size = PointField::datatype_size(datatype).expect("known datatype");
            if field.datatype != datatype || field.count != 1 {
                return Err(MsgError::Inconsistent(format!(
                    "field `{name}` has datatype {} count {}, expected datatype {datatype} count 1",
                    field.datatype, field.count
                )));
            }
            let offset = field.offset as usize;
            if offset + size > point_step {
                return Err(MsgError::Inconsistent(format!(
                    "field `{name}` at offset {offset} overruns the {point_step}-byte point"
                )));
            }
            Ok(offset)
        };
        let float_offsets = float_field_names(sh_degree)
            .iter()
            .map(|n| offset_of(n, PointField::FLOAT32))
            .collect::<Result<Vec<_>, _>>()?;
        let bone_offsets = bone_field_names()
            .iter()
            .map(|n| offset_of(n, PointField::UINT16))
            .collect::<Result<Vec<_>, _>>()?;

        let n = width * height;
        let color_count = float_offsets.len() - 11 - MAX_INFLUENCES;
        let mut out = GaussianCloud {
            positions: Vec::with_capacity(n),
            scales: Vec::with_capacity(n),
            rotations: Vec::with_capacity(n),
            opacities: Vec::with_capacity(n),
            colors: GaussianColors::Rgb(Vec::new()),
            skin: SkinWeights::default(),
        };
        let mut rgb = Vec::new();
        let mut coefficients = Vec::new();
        for row in 0..height {
            for col in 0..width {
                let point = &cloud.data[row * row_step + col * point_step..][..point_step];
                let f = |k: usize| {
                    let at = float_offsets[k];
                    f32::from_le_bytes(point[at..at + 4].try_into().expect("4 bytes"))
                };
                out.positions.push([f(0), f(1), f(2)]);
                out.scales.push([f(3), f(4), f(5)]);
                out.rotations.push([f(6), f(7), f(8), f(9)]);
                out.opacities.push(f(10));
                if sh_degree == 0 {
                    rgb.push([f(11), f(12), f(13)]);
                } else {
                    coefficients.extend((0..color_count).map(|k| f(11 + k)));
                }
                let w0 = 11 + color_count;
                out.skin.weights.push(std::array::from_fn(|k| f(w0 + k)));
                out.skin.bones.push(std::array::from_fn(|k| {
                    let at = bone_offsets[k];
                    u16::from_le_bytes([point[at], point[at + 1]])
                }));
            }
        }
        out.colors = if sh_degree == 0 {
            GaussianColors::Rgb(rgb)
        } else {
            GaussianColors::Sh {
                degree: sh_degree,
                coefficients,
            }
        };
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(n: usize, colors: GaussianColors) -> GaussianCloud {
        GaussianCloud {
            positions: (0..n).map(|i| [i as f32, 0.5, -1.0]).collect(),
            scales: (0..n).map(|i| [0.01, 0.02, 0.001 * i as f32]).collect(),
            rotations: (0..n).map(|_| [1.0, 0.0, 0.0, 0.0]).collect(),
            opacities: (0..n).map(|i| i as f32 / n as f32).collect(),
            colors,
            skin: SkinWeights {
                bones: (0..n).map(|i| [i as u16, 1, 2, 65535]).collect(),
                weights: (0..n).map(|_| [0.7, 0.2, 0.1, 0.0]).collect(),
            },
        }
    }

    #[test]
    fn rgb_gaussians_survive_the_point_cloud_round_trip() {
        let g = cloud(
            5,
            GaussianColors::Rgb((0..5).map(|i| [0.1 * i as f32, 0.2, 1.0]).collect()),
        );
        let pc = g.to_point_cloud(Header::default()).unwrap();
        assert_eq!(pc.width, 5);
        assert_eq!(pc.point_step, 4 * 18 + 8);
        assert_eq!(pc.data.len(), 5 * pc.point_step as usize);
        assert_eq!(&pc.fields[0].name, "x");
        assert_eq!(GaussianCloud::from_point_cloud(&pc, 0).unwrap(), g);
    }

    #[test]
    fn sh_degree_3_gaussians_survive_with_48_coefficients_each() {
        let coefficients: Vec<f32> = (0..2 * 48).map(|i| i as f32 * 0.01).collect();
        let g = cloud(
            2,
            GaussianColors::Sh {
                degree: 3,
                coefficients,
            },
        );
        let pc = g.to_point_cloud(Header::default()).unwrap();
        assert!(pc.fields.iter().any(|f| f.name == "f_rest_44"));
        assert!(!pc.fields.iter().any(|f| f.name == "f_rest_45"));
        assert_eq!(GaussianCloud::from_point_cloud(&pc, 3).unwrap(), g);
    }

    #[test]
    fn mismatched_array_lengths_are_rejected() {
        let mut g = cloud(3, GaussianColors::Rgb(vec![[0.0; 3]; 3]));
        g.opacities.pop();
        let err = g.to_point_cloud(Header::default()).unwrap_err();
        assert!(err.to_string().contains("opacities"), "{err}");
    }

    #[test]
    fn missing_or_mistyped_fields_and_short_data_are_named() {
        let g = cloud(2, GaussianColors::Rgb(vec![[0.0; 3]; 2]));
        let pc = g.to_point_cloud(Header::default()).unwrap();
        let mut no_opacity = pc.clone();
        no_opacity.fields.retain(|f| f.name != "opacity");
        let err = GaussianCloud::from_point_cloud(&no_opacity, 0).unwrap_err();
        assert!(err.to_string().contains("`opacity`"), "{err}");
        let mut short = pc.clone();
        short.data.truncate(10);
        assert!(GaussianCloud::from_point_cloud(&short, 0).is_err());
        let mut wrong_type = pc.clone();
        wrong_type.fields[0].datatype = PointField::FLOAT64;
        let err = GaussianCloud::from_point_cloud(&wrong_type, 0).unwrap_err();
        assert!(err.to_string().contains("`x`"), "{err}");
        assert!(
            GaussianCloud::from_point_cloud(&pc, 1).is_err(),
            "degree mismatch"
        );
    }
}
