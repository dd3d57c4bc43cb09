//! MakeHuman `.mhclo` files: how a garment's own mesh hangs on the `hm08` base mesh.
//!
//! After `verts 0`, one line per garment vertex: `i` (on base vertex `i`) or
//! `i j k wi wj wk dx dy dz` (weighted base vertices plus the offset scaled per axis by
//! `|base[a] − base[b]| / d` from the `x_scale a b d` lines, and y, z alike). Keyword lines may
//! follow `verts 0` (hair files); `delete_verts` ends the reference lines.

use crate::body::BodyError;
use glam::Vec3;

/// One reference line: three base vertices, their weights, the unscaled offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// Base-mesh vertex indices.
    pub vertices: [u32; 3],
    /// Their weights.
    pub weights: [f32; 3],
    /// Offset in source units before the axis scales.
    pub offset: Vec3,
}

/// The parts of a `.mhclo` file the converter uses.
#[derive(Debug, Clone, PartialEq)]
pub struct Mhclo {
    /// `name`.
    pub name: String,
    /// `obj_file`: the garment mesh, relative to the `.mhclo`.
    pub obj_file: String,
    /// `x_scale`, `y_scale`, `z_scale`: base vertices `a`, `b` and the divisor `d`.
    pub scales: [(u32, u32, f32); 3],
    /// One reference per garment-mesh vertex, in order.
    pub references: Vec<Reference>,
}

impl Mhclo {
    /// Parses `.mhclo` text; `origin` names the file in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self, BodyError> {
        let mut name = None;
        let mut obj_file = None;
        let mut scales = [None; 3];
        let mut references = Vec::new();
        let mut in_verts = false;
        for (line_no, line) in text.lines().enumerate() {
            let err = |m: &str| BodyError::format(origin, format!("line {}: {m}", line_no + 1));
            let tokens: Vec<&str> = line.split_whitespace().collect();
            let Some(first) = tokens.first() else {
                continue;
            };
            if first.starts_with('#') {
                continue;
            }
            let numeric = first.parse::<f64>().is_ok();
            if in_verts && numeric {
                let ints = |k: usize| -> Result<u32, BodyError> {
                    tokens[k]
                        .parse::<u32>()
                        .map_err(|_| err("bad vertex index"))
                };
                let floats = |k: usize| -> Result<f32, BodyError> {
                    tokens[k].parse::<f32>().map_err(|_| err("bad number"))
                };
                match tokens.len() {
                    1 => references.push(Reference {
                        vertices: [ints(0)?; 3],
                        weights: [1.0, 0.0, 0.0],
                        offset: Vec3::ZERO,
                    }),
                    9 => references.push(Reference {
                        vertices: [ints(0)?, ints(1)?, ints(2)?],
                        weights: [floats(3)?, floats(4)?, floats(5)?],
                        offset: Vec3::new(floats(6)?, floats(7)?, floats(8)?),
                    }),
                    n => return Err(err(&format!("reference line with {n} numbers"))),
                }
                continue;
            }
            if numeric {
                continue; // delete_verts ranges and other number lists
            }
            match *first {
                "name" if tokens.len() > 1 => name = Some(tokens[1..].join(" ")),
                "obj_file" if tokens.len() > 1 => obj_file = Some(tokens[1..].join(" ")),
                "x_scale" | "y_scale" | "z_scale" => {
                    let axis = (first.as_bytes()[0] - b'x') as usize;
                    if tokens.len() != 4 {
                        return Err(err("scale line needs `a b d`"));
                    }
                    let a = tokens[1].parse().map_err(|_| err("bad scale vertex"))?;
                    let b = tokens[2].parse().map_err(|_| err("bad scale vertex"))?;
                    let d: f32 = tokens[3].parse().map_err(|_| err("bad scale divisor"))?;
                    if d <= 0.0 {
                        return Err(err("scale divisor must be positive"));
                    }
                    scales[axis] = Some((a, b, d));
                }
                "verts" => in_verts = true,
                "delete_verts" => in_verts = false,
                _ => {}
            }
        }
        let missing = |key: &str| BodyError::missing(origin, key);
        Ok(Self {
            name: name.ok_or_else(|| missing("name"))?,
            obj_file: obj_file.ok_or_else(|| missing("obj_file"))?,
            scales: [
                scales[0].ok_or_else(|| missing("x_scale"))?,
                scales[1].ok_or_else(|| missing("y_scale"))?,
                scales[2].ok_or_else(|| missing("z_scale"))?,
            ],
            references,
        })
    }

    /// Per-axis offset scale on `base` (source units).
    pub fn axis_scale(&self, base: &[Vec3], origin: &str) -> Result<Vec3, BodyError> {
        let mut s = Vec3::ZERO;
        for (axis, &(a, b, d)) in self.scales.iter().enumerate() {
            let (pa, pb) = (base.get(a as usize), base.get(b as usize));
            let (Some(pa), Some(pb)) = (pa, pb) else {
                return Err(BodyError::format(
                    origin,
                    format!("scale vertex {a} or {b} past the base mesh"),
                ));
            };
            s[axis] = (pa[axis] - pb[axis]).abs() / d;
        }
        Ok(s)
    }

    /// The garment's vertices fitted on `base` (source units).
    pub fn fit(&self, base: &[Vec3], origin: &str) -> Result<Vec<Vec3>, BodyError> {
        let scale = self.axis_scale(base, origin)?;
        self.references
            .iter()
            .map(|r| {
                let mut p = r.offset * scale;
                for k in 0..3 {
                    let v = base.get(r.vertices[k] as usize).ok_or_else(|| {
                        BodyError::format(
                            origin,
                            format!("reference vertex {} past the base mesh", r.vertices[k]),
                        )
                    })?;
                    p += *v * r.weights[k];
                }
                Ok(p)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "# comment\nname cap\nobj_file cap.obj\nx_scale 0 1 2.0\ny_scale 0 2 1.0\n\
        z_scale 0 3 4.0\nverts 0\n2\n 0 1 2 0.5 0.25 0.25 1.0 2.0 3.0\nmaterial cap.mhmat\n\
        3\ndelete_verts\n1 - 3 5\n";

    #[test]
    fn references_and_scales_are_read_and_fitted() {
        let m = Mhclo::parse(TEXT, "cap.mhclo").unwrap();
        assert_eq!(m.name, "cap");
        assert_eq!(m.obj_file, "cap.obj");
        assert_eq!(m.references.len(), 3);
        assert_eq!(m.references[0].vertices, [2, 2, 2]);
        assert_eq!(m.references[2].vertices, [3, 3, 3]);
        let base = [
            Vec3::ZERO,
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(0.0, 3.0, 0.0),
            Vec3::new(0.0, 0.0, 8.0),
        ];
        assert_eq!(m.axis_scale(&base, "t").unwrap(), Vec3::new(2.0, 3.0, 2.0));
        let fit = m.fit(&base, "t").unwrap();
        assert_eq!(fit[0], base[2]);
        // 0.25·(4,0,0) + 0.25·(0,3,0) + (1,2,3)·(2,3,2)
        assert!(fit[1].distance(Vec3::new(3.0, 6.75, 6.0)) < 1e-6);
    }

    #[test]
    fn a_missing_key_or_bad_line_is_named() {
        let err = Mhclo::parse("name x\n", "a.mhclo").unwrap_err().to_string();
        assert!(err.contains("a.mhclo") && err.contains("obj_file"), "{err}");
        let bad = "name x\nobj_file x.obj\nverts 0\n1 2 3\n";
        let err = Mhclo::parse(bad, "b.mhclo").unwrap_err().to_string();
        assert!(err.contains("line 4"), "{err}");
    }
}
