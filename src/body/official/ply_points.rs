//! Reads the positions of a PLY point cloud (the prior's `dense_sample_points/*.ply`, written
//! by pytorch3d's `save_ply`): ASCII or binary (little or big endian), `float`/`double` (or
//! integer) `x`, `y`, `z` in the first element, which must be `vertex`.

use std::path::Path;

use glam::Vec3;

use crate::body::{BodyError, PlyScalar};

/// Reads the `x y z` of every vertex of the PLY file at `path`.
pub fn read_ply_points(path: &Path) -> Result<Vec<Vec3>, BodyError> {
    let origin = path.display().to_string();
    let bad = |m: String| BodyError::format(&origin, m);
    let bytes = std::fs::read(path).map_err(|e| BodyError::io(path, e))?;
    let end = b"end_header";
    let header_end = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| bad("no `end_header` (not a PLY file)".into()))?;
    let mut body = header_end + end.len();
    while body < bytes.len() && bytes[body] != b'\n' {
        body += 1;
    }
    body += 1;
    let header = String::from_utf8_lossy(&bytes[..header_end]);
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(bad("does not start with `ply`".into()));
    }
    let mut format = None;
    let mut count = None;
    let mut props: Vec<(String, String)> = Vec::new();
    let mut in_first = false;
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, ..] => format = Some(f.to_string()),
            ["element", name, n] if count.is_none() => {
                if *name != "vertex" {
                    return Err(bad(format!("first element is `{name}`, expected `vertex`")));
                }
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| bad(format!("bad vertex count `{n}`")))?,
                );
                in_first = true;
            }
            ["element", ..] => in_first = false,
            ["property", "list", ..] if in_first => {
                return Err(bad("list properties in `vertex` are not supported".into()))
            }
            ["property", t, name] if in_first => props.push((t.to_string(), name.to_string())),
            _ => {}
        }
    }
    let n = count.ok_or_else(|| bad("no `element vertex`".into()))?;
    let index = |axis: &str| {
        props
            .iter()
            .position(|(_, p)| p == axis)
            .ok_or_else(|| bad(format!("vertex has no property `{axis}`")))
    };
    let axes = [index("x")?, index("y")?, index("z")?];
    let format = format.ok_or_else(|| bad("no `format` line".into()))?;
    let mut points = Vec::with_capacity(n);
    if format == "ascii" {
        let text = String::from_utf8_lossy(&bytes[body.min(bytes.len())..]);
        for (i, line) in text
            .lines()
            .filter(|l| !l.trim().is_empty())
            .take(n)
            .enumerate()
        {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|w| w.parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| bad(format!("vertex {i}: not numbers")))?;
            if v.len() < props.len() {
                return Err(bad(format!(
                    "vertex {i}: {} values, expected {}",
                    v.len(),
                    props.len()
                )));
            }
            points.push(Vec3::new(
                v[axes[0]] as f32,
                v[axes[1]] as f32,
                v[axes[2]] as f32,
            ));
        }
    } else {
        let little = match format.as_str() {
            "binary_little_endian" => true,
            "binary_big_endian" => false,
            other => return Err(bad(format!("unknown format `{other}`"))),
        };
        let mut offsets = Vec::with_capacity(props.len());
        let mut stride = 0;
        for (t, name) in &props {
            let scalar = PlyScalar::parse(t)
                .ok_or_else(|| bad(format!("property `{name}` has unknown type `{t}`")))?;
            offsets.push((stride, scalar));
            stride += scalar.size();
        }
        let data = &bytes[body.min(bytes.len())..];
        if data.len() < n * stride {
            return Err(bad(format!(
                "truncated: {n} vertices of {stride} bytes need {} bytes, found {}",
                n * stride,
                data.len()
            )));
        }
        for row in data.chunks_exact(stride).take(n) {
            let get = |k: usize| {
                let (o, scalar) = offsets[k];
                scalar.read(&row[o..], little) as f32
            };
            points.push(Vec3::new(get(axes[0]), get(axes[1]), get(axes[2])));
        }
    }
    if points.len() != n {
        return Err(bad(format!(
            "{} vertices read, header says {n}",
            points.len()
        )));
    }
    Ok(points)
}
