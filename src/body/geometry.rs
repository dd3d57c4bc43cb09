//! Small mesh-geometry helpers: vertex normals and the generalized winding number.

use glam::Vec3;

/// Area-weighted vertex normals (unit length; zero for vertices no triangle uses).
pub fn vertex_normals(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut normals = vec![Vec3::ZERO; vertices.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices[i as usize]);
        let n = (b - a).cross(c - a);
        for i in t {
            normals[*i as usize] += n;
        }
    }
    normals.iter().map(|n| n.normalize_or_zero()).collect()
}

/// Generalized winding number of `point` with respect to a triangle mesh (Jacobson et al.
/// 2013): the sum of signed solid angles over 4π. About 1 inside a closed outward-oriented
/// mesh, 0 outside, and degrades gracefully for meshes with holes.
pub fn generalized_winding_number(point: Vec3, vertices: &[Vec3], triangles: &[[u32; 3]]) -> f32 {
    let mut total = 0.0f64;
    for t in triangles {
        let [a, b, c] = t.map(|i| (vertices[i as usize] - point).as_dvec3());
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let det = a.dot(b.cross(c));
        let denom = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
        total += 2.0 * det.atan2(denom);
    }
    (total / (4.0 * std::f64::consts::PI)) as f32
}

/// Distance from `p` to the triangle `(a, b, c)`.
pub fn point_triangle_distance(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f32 {
    // Ericson, Real-Time Collision Detection, 5.1.5: closest point by Voronoi regions.
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return p.distance(a);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return p.distance(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return p.distance(a + ab * (d1 / (d1 - d3)));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return p.distance(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return p.distance(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return p.distance(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denom = 1.0 / (va + vb + vc);
    p.distance(a + ab * (vb * denom) + ac * (vc * denom))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let v: Vec<Vec3> = (0..8)
            .map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32))
            .collect();
        // Outward-oriented faces of the unit cube.
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let t = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        (v, t)
    }

    #[test]
    fn winding_number_is_one_inside_and_zero_outside_a_cube() {
        let (v, t) = cube();
        let inside = generalized_winding_number(Vec3::splat(0.3), &v, &t);
        let outside = generalized_winding_number(Vec3::new(2.0, 0.5, 0.5), &v, &t);
        assert!((inside - 1.0).abs() < 1e-4, "{inside}");
        assert!(outside.abs() < 1e-4, "{outside}");
    }

    #[test]
    fn point_above_triangle_is_at_its_height() {
        let d = point_triangle_distance(Vec3::new(0.2, 0.2, 0.5), Vec3::ZERO, Vec3::X, Vec3::Y);
        assert!((d - 0.5).abs() < 1e-6);
        let corner =
            point_triangle_distance(Vec3::new(-1.0, 0.0, 0.0), Vec3::ZERO, Vec3::X, Vec3::Y);
        assert!((corner - 1.0).abs() < 1e-6);
    }
}
