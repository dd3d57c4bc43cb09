//! Coloured point clouds as binary little-endian PLY files.

use super::BodyError;
use glam::Vec3;
use std::io::Write;
use std::path::Path;

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
