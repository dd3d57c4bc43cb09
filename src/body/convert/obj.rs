//! A minimal Wavefront OBJ reader: positions, texture coordinates and grouped polygon faces.

use crate::body::BodyError;
use glam::{Vec2, Vec3};
use std::collections::BTreeSet;

/// One polygon: `(vertex, texcoord)` indices per corner (0-based; texcoord may be absent).
#[derive(Debug, Clone, PartialEq)]
pub struct ObjFace {
    /// Group (`g` line) the face belongs to.
    pub group: String,
    /// Corners as 0-based `(vertex index, texcoord index)`.
    pub corners: Vec<(usize, Option<usize>)>,
}

/// The parsed content of an OBJ file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjMesh {
    /// All `v` positions in file order.
    pub positions: Vec<Vec3>,
    /// All `vt` coordinates in file order.
    pub texcoords: Vec<Vec2>,
    /// All faces in file order.
    pub faces: Vec<ObjFace>,
}

impl ObjMesh {
    /// Parses OBJ text; `origin` names the file in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self, BodyError> {
        let mut mesh = Self::default();
        let mut group = String::from("default");
        for (line_no, line) in text.lines().enumerate() {
            let err = |m: &str| BodyError::format(origin, format!("line {}: {m}", line_no + 1));
            let mut it = line.split_whitespace();
            let floats = |it: std::str::SplitWhitespace, n: usize| -> Result<Vec<f32>, BodyError> {
                let v: Vec<f32> = it
                    .take(n)
                    .map(|s| s.parse::<f32>().map_err(|_| err("bad number")))
                    .collect::<Result<_, _>>()?;
                if v.len() == n {
                    Ok(v)
                } else {
                    Err(err("too few numbers"))
                }
            };
            match it.next() {
                Some("v") => {
                    let v = floats(it, 3)?;
                    mesh.positions.push(Vec3::new(v[0], v[1], v[2]));
                }
                Some("vt") => {
                    let v = floats(it, 2)?;
                    mesh.texcoords.push(Vec2::new(v[0], v[1]));
                }
                Some("g") => group = it.collect::<Vec<_>>().join(" "),
                Some("f") => {
                    let corners = it
                        .map(|c| parse_corner(c).ok_or_else(|| err("bad face corner")))
                        .collect::<Result<Vec<_>, _>>()?;
                    if corners.len() < 3 {
                        return Err(err("face with fewer than 3 corners"));
                    }
                    mesh.faces.push(ObjFace {
                        group: group.clone(),
                        corners,
                    });
                }
                _ => {}
            }
        }
        let (nv, nt) = (mesh.positions.len(), mesh.texcoords.len());
        for f in &mesh.faces {
            for (v, t) in &f.corners {
                if *v >= nv || t.is_some_and(|t| t >= nt) {
                    return Err(BodyError::format(
                        origin,
                        format!("face in group `{}` indexes past the vertex list", f.group),
                    ));
                }
            }
        }
        Ok(mesh)
    }

    /// Sorted distinct vertex indices used by the faces of `group`.
    pub fn group_vertices(&self, group: &str) -> BTreeSet<usize> {
        self.faces
            .iter()
            .filter(|f| f.group == group)
            .flat_map(|f| f.corners.iter().map(|c| c.0))
            .collect()
    }
}

/// Parses `v`, `v/t`, `v//n` or `v/t/n` (1-based) into 0-based indices.
fn parse_corner(corner: &str) -> Option<(usize, Option<usize>)> {
    let mut parts = corner.split('/');
    let v = parts.next()?.parse::<usize>().ok()?.checked_sub(1)?;
    let t = match parts.next() {
        Some("") | None => None,
        Some(t) => Some(t.parse::<usize>().ok()?.checked_sub(1)?),
    };
    Some((v, t))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faces_keep_their_group_and_zero_based_indices() {
        let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\ng body\nf 1/1 2/1 3/1 4/1\ng helper\nf 1 2 3\n";
        let m = ObjMesh::parse(text, "t.obj").unwrap();
        assert_eq!(m.faces.len(), 2);
        assert_eq!(m.faces[0].group, "body");
        assert_eq!(m.faces[0].corners[3], (3, Some(0)));
        assert_eq!(m.faces[1].corners[2], (2, None));
        assert_eq!(m.group_vertices("helper").len(), 3);
    }

    #[test]
    fn out_of_range_face_is_an_error_naming_the_file() {
        let err = ObjMesh::parse("v 0 0 0\nf 1 2 3\n", "bad.obj").unwrap_err();
        assert!(err.to_string().contains("bad.obj"));
    }
}
