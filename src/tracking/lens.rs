//! Lens distortion of a calibrated camera (`sensor_msgs/CameraInfo`'s `D`), undone for single
//! image points (a box's bottom, a landmark) before they are cast through the pinhole `K`:
//! OpenCV's `plumb_bob` (k1, k2, p1, p2, k3) and `rational_polynomial` (k1, k2, p1, p2, k3,
//! k4, k5, k6) models, the ones ROS camera drivers publish for ordinary lenses.

/// Fixed-point iterations of [`LensDistortion::undistort`] (OpenCV's `undistortPoints` runs
/// as many by default); ample for the distortions of real lenses.
const UNDISTORT_ITERATIONS: usize = 20;

/// A lens's radial and tangential distortion, in normalised image coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LensDistortion {
    /// k1, k2, k3 (numerator) and k4, k5, k6 (denominator) of the radial term.
    radial: [f32; 6],
    /// p1, p2.
    tangential: [f32; 2],
}

impl LensDistortion {
    /// The distortion a CameraInfo gives: `None` when `d` is empty or all zero (a pinhole, or
    /// images already rectified); an error naming the model for models other than
    /// `plumb_bob` and `rational_polynomial`, and for values that are not finite.
    pub fn from_camera_info(model: &str, d: &[f64]) -> Result<Option<Self>, String> {
        if d.iter().all(|v| *v == 0.0) {
            return Ok(None);
        }
        let most = match model {
            "plumb_bob" => 5,
            "rational_polynomial" => 8,
            other => {
                return Err(format!(
                    "distortion model `{other}` is not supported (plumb_bob, \
                     rational_polynomial): its image points are used as if undistorted"
                ))
            }
        };
        if d.len() > most || d.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "{model} distortion {d:?}: expected at most {most} finite coefficients"
            ));
        }
        let at = |i: usize| d.get(i).copied().unwrap_or(0.0) as f32;
        Ok(Some(Self {
            radial: [at(0), at(1), at(4), at(5), at(6), at(7)],
            tangential: [at(2), at(3)],
        }))
    }

    /// Radial factor (numerator over denominator) and tangential shift at `(x, y)`.
    fn terms(&self, x: f32, y: f32) -> (f32, [f32; 2]) {
        let [k1, k2, k3, k4, k5, k6] = self.radial;
        let [p1, p2] = self.tangential;
        let r2 = x * x + y * y;
        let (r4, r6) = (r2 * r2, r2 * r2 * r2);
        let radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
        let shift = [
            2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        ];
        (radial, shift)
    }

    /// Where the lens puts the ideal normalised point `(x, y)`.
    pub fn distort(&self, x: f32, y: f32) -> [f32; 2] {
        let (radial, [dx, dy]) = self.terms(x, y);
        [x * radial + dx, y * radial + dy]
    }

    /// The ideal normalised point the lens put at `(x, y)` (inverts [`Self::distort`] by
    /// fixed-point iteration; the last finite estimate where the model folds over).
    pub fn undistort(&self, x: f32, y: f32) -> [f32; 2] {
        let mut ideal = [x, y];
        for _ in 0..UNDISTORT_ITERATIONS {
            let (radial, [dx, dy]) = self.terms(ideal[0], ideal[1]);
            let next = [(x - dx) / radial, (y - dy) / radial];
            if !(radial > 0.0 && next[0].is_finite() && next[1].is_finite()) {
                break;
            }
            ideal = next;
        }
        ideal
    }

    /// The pixel an ideal pinhole camera `[fx, fy, cx, cy]` would have seen where this lens
    /// put `pixel`.
    pub fn undistort_pixel(&self, pixel: [f32; 2], intrinsics: [f32; 4]) -> [f32; 2] {
        let [fx, fy, cx, cy] = intrinsics;
        let [x, y] = self.undistort((pixel[0] - cx) / fx, (pixel[1] - cy) / fy);
        [fx * x + cx, fy * y + cy]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistorting_a_distorted_point_gives_it_back_across_a_wide_lens() {
        // A wide-angle plumb_bob lens (barrel, k1 -0.3) and a rational one.
        for (model, d) in [
            ("plumb_bob", vec![-0.3, 0.1, 0.001, -0.002, -0.02]),
            (
                "rational_polynomial",
                vec![0.5, -0.1, 0.0005, 0.0007, 0.01, 0.8, 0.05, 0.002],
            ),
        ] {
            let lens = LensDistortion::from_camera_info(model, &d)
                .unwrap()
                .unwrap();
            for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.6, 0.45), (0.7, 0.7)] {
                let [xd, yd] = lens.distort(x, y);
                let [xu, yu] = lens.undistort(xd, yd);
                assert!(
                    (xu - x).abs() < 1e-4 && (yu - y).abs() < 1e-4,
                    "{model} ({x}, {y}) -> ({xd}, {yd}) -> ({xu}, {yu})"
                );
            }
        }
    }

    #[test]
    fn no_coefficients_is_a_pinhole_and_other_models_are_refused_by_name() {
        assert_eq!(
            LensDistortion::from_camera_info("plumb_bob", &[0.0; 5]),
            Ok(None)
        );
        assert_eq!(LensDistortion::from_camera_info("", &[]), Ok(None));
        let e = LensDistortion::from_camera_info("equidistant", &[0.1, 0.0, 0.0, 0.0]).unwrap_err();
        assert!(e.contains("equidistant"), "{e}");
        let e = LensDistortion::from_camera_info("plumb_bob", &[f64::NAN, 0.0, 0.0, 0.0, 0.0])
            .unwrap_err();
        assert!(e.contains("finite"), "{e}");
    }
}
