//! PLY files: coloured point clouds written as binary little-endian, and the scalar types
//! every PLY reader of the crate decodes.

use super::BodyError;
use glam::Vec3;
use std::io::Write;
use std::path::Path;

/// A PLY scalar property type (`char`/`int8` ... `double`/`float64`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyScalar {
    /// `char` / `int8`.
    I8,
    /// `uchar` / `uint8`.
    U8,
    /// `short` / `int16`.
    I16,
    /// `ushort` / `uint16`.
    U16,
    /// `int` / `int32`.
    I32,
    /// `uint` / `uint32`.
    U32,
    /// `float` / `float32`.
    F32,
    /// `double` / `float64`.
    F64,
}

impl PlyScalar {
    /// The type named `s` in a `property` line, if known.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    /// Bytes of one value.
    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// The value at the start of `b` (at least [`PlyScalar::size`] bytes), little- or
    /// big-endian.
    pub fn read(self, b: &[u8], little_endian: bool) -> f64 {
        fn bytes<const N: usize>(b: &[u8], little_endian: bool) -> [u8; N] {
            let mut a = [0u8; N];
            a.copy_from_slice(&b[..N]);
            if !little_endian {
                a.reverse();
            }
            a
        }
        let le = little_endian;
        match self {
            Self::I8 => f64::from(b[0] as i8),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(i16::from_le_bytes(bytes(b, le))),
            Self::U16 => f64::from(u16::from_le_bytes(bytes(b, le))),
            Self::I32 => f64::from(i32::from_le_bytes(bytes(b, le))),
            Self::U32 => f64::from(u32::from_le_bytes(bytes(b, le))),
            Self::F32 => f64::from(f32::from_le_bytes(bytes(b, le))),
            Self::F64 => f64::from_le_bytes(bytes(b, le)),
        }
    }
}

/// Writes `points` with one RGB colour each as a binary PLY point cloud.
pub fn write_point_ply(path: &Path, points: &[Vec3], colors: &[[u8; 3]]) -> Result<(), BodyError> {
    assert_eq!(points.len(), colors.len(), "one colour per point");
    let io = |e| BodyError::io(path, e);
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| BodyError::io(dir, e))?;
    }
    let mut buf = Vec::with_capacity(64 + points.len() * 15);
    write!(
        buf,
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    )
    .map_err(io)?;
    for (p, c) in points.iter().zip(colors) {
        for v in p.to_array() {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.extend_from_slice(c);
    }
    std::fs::write(path, buf).map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ply_header_counts_points_and_body_has_fifteen_bytes_each() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.ply");
        write_point_ply(&path, &[Vec3::ONE, Vec3::ZERO], &[[1, 2, 3], [4, 5, 6]]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.contains("element vertex 2\n"));
        let body = bytes.len() - (text.find("end_header\n").unwrap() + "end_header\n".len());
        assert_eq!(body, 30);
        assert_eq!(&bytes[bytes.len() - 3..], &[4, 5, 6]);
    }
}

#[cfg(test)]
mod scalar_tests {
    use super::PlyScalar;

    #[test]
    fn scalars_read_in_either_byte_order() {
        let cases: [(&str, Vec<u8>, f64); 5] = [
            ("char", vec![0xFE], -2.0),
            ("ushort", 513u16.to_le_bytes().to_vec(), 513.0),
            ("int", (-70_000i32).to_le_bytes().to_vec(), -70_000.0),
            ("float", 1.5f32.to_le_bytes().to_vec(), 1.5),
            ("double", (-0.25f64).to_le_bytes().to_vec(), -0.25),
        ];
        for (name, le, value) in cases {
            let t = PlyScalar::parse(name).unwrap();
            assert_eq!(t.size(), le.len(), "{name}");
            assert_eq!(t.read(&le, true), value, "{name}");
            let be: Vec<u8> = le.iter().rev().copied().collect();
            assert_eq!(t.read(&be, false), value, "{name}");
        }
        assert_eq!(PlyScalar::parse("half"), None);
    }
}
