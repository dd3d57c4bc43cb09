//! Image-quality metrics used by `lhmpp eval`: PSNR, SSIM (11×11 Gaussian window, σ = 1.5,
//! as Wang et al. 2004) and mask IoU, on images stored as interleaved f32 in [0, 1].

/// An image view for scoring: `channels` interleaved f32 values per pixel, row-major.
#[derive(Debug, Clone, Copy)]
pub struct ImageRef<'a> {
    /// Pixel values in [0, 1], `width * height * channels` long.
    pub data: &'a [f32],
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Values per pixel.
    pub channels: usize,
}

impl<'a> ImageRef<'a> {
    /// Wraps a buffer; panics if its length disagrees with the dimensions (a programming error).
    pub fn new(data: &'a [f32], width: usize, height: usize, channels: usize) -> Self {
        assert_eq!(data.len(), width * height * channels, "image buffer size");
        Self {
            data,
            width,
            height,
            channels,
        }
    }

    fn same_shape(&self, other: &ImageRef) -> bool {
        (self.width, self.height, self.channels) == (other.width, other.height, other.channels)
    }
}

/// Peak signal-to-noise ratio in dB for values in [0, 1]; `f64::INFINITY` for identical images.
pub fn psnr(a: ImageRef, b: ImageRef) -> f64 {
    assert!(a.same_shape(&b), "PSNR needs images of one shape");
    let mse = a
        .data
        .iter()
        .zip(b.data)
        .map(|(x, y)| {
            let d = (*x as f64) - (*y as f64);
            d * d
        })
        .sum::<f64>()
        / a.data.len().max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// The normalised 11-tap Gaussian (σ = 1.5) used by SSIM.
fn ssim_kernel() -> [f64; 11] {
    let mut k = [0.0; 11];
    for (i, v) in k.iter_mut().enumerate() {
        let x = i as f64 - 5.0;
        *v = (-x * x / (2.0 * 1.5 * 1.5)).exp();
    }
    let s: f64 = k.iter().sum();
    k.map(|v| v / s)
}

/// Separable "valid" Gaussian filtering of one plane (output shrinks by 10 on each axis).
fn blur_valid(plane: &[f64], w: usize, h: usize, k: &[f64; 11]) -> Vec<f64> {
    let (ow, oh) = (w - 10, h - 10);
    let mut rows = vec![0.0; ow * h];
    for y in 0..h {
        for x in 0..ow {
            rows[y * ow + x] = (0..11).map(|i| k[i] * plane[y * w + x + i]).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..11).map(|i| k[i] * rows[(y + i) * ow + x]).sum();
        }
    }
    out
}

/// Mean SSIM over channels and valid window positions (no padding), data range 1.
/// Images smaller than the 11×11 window score 1 when equal and 0 otherwise.
pub fn ssim(a: ImageRef, b: ImageRef) -> f64 {
    assert!(a.same_shape(&b), "SSIM needs images of one shape");
    let (w, h, c) = (a.width, a.height, a.channels);
    if w < 11 || h < 11 {
        return if a.data == b.data { 1.0 } else { 0.0 };
    }
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let k = ssim_kernel();
    let mut total = 0.0;
    for ch in 0..c {
        let plane = |img: &ImageRef| -> Vec<f64> {
            (0..w * h).map(|i| img.data[i * c + ch] as f64).collect()
        };
        let (x, y) = (plane(&a), plane(&b));
        let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f64> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
        let (mx, my) = (blur_valid(&x, w, h, &k), blur_valid(&y, w, h, &k));
        let (sxx, syy, sxy) = (
            blur_valid(&xx, w, h, &k),
            blur_valid(&yy, w, h, &k),
            blur_valid(&xy, w, h, &k),
        );
        let mut sum = 0.0;
        for i in 0..mx.len() {
            let (ux, uy) = (mx[i], my[i]);
            let vx = sxx[i] - ux * ux;
            let vy = syy[i] - uy * uy;
            let cov = sxy[i] - ux * uy;
            sum += ((2.0 * ux * uy + c1) * (2.0 * cov + c2))
                / ((ux * ux + uy * uy + c1) * (vx + vy + c2));
        }
        total += sum / mx.len() as f64;
    }
    total / c as f64
}

/// Intersection over union of two masks thresholded at 0.5; 1 when both are empty.
pub fn mask_iou(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len(), "masks of one size");
    let (mut inter, mut union) = (0usize, 0usize);
    for (x, y) in a.iter().zip(b) {
        let (p, q) = (*x >= 0.5, *y >= 0.5);
        inter += (p && q) as usize;
        union += (p || q) as usize;
    }
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Vec<f32> {
        (0..w * h * 3)
            .map(|i| ((i * 37) % 101) as f32 / 100.0)
            .collect()
    }

    #[test]
    fn identical_images_score_perfectly() {
        let a = ramp(32, 24);
        let img = ImageRef::new(&a, 32, 24, 3);
        assert!(psnr(img, img).is_infinite());
        assert!((ssim(img, img) - 1.0).abs() < 1e-12);
        assert_eq!(mask_iou(&[1.0, 0.0, 1.0], &[1.0, 0.0, 1.0]), 1.0);
    }

    #[test]
    fn psnr_matches_closed_form_for_uniform_error() {
        let a = vec![0.5f32; 16 * 16 * 3];
        let b = vec![0.6f32; 16 * 16 * 3];
        let p = psnr(ImageRef::new(&a, 16, 16, 3), ImageRef::new(&b, 16, 16, 3));
        // mse = 0.01 → 20 dB (f32 rounding of 0.6 - 0.5 moves it in the 5th decimal).
        assert!((p - 20.0).abs() < 1e-4, "{p}");
    }

    #[test]
    fn ssim_of_constant_shift_follows_luminance_term() {
        // For constant images x = a, y = b the structure terms are 1 and SSIM is the luminance
        // term (2ab + c1) / (a² + b² + c1).
        let (a, b) = (0.2f64, 0.7f64);
        let x = vec![a as f32; 20 * 20];
        let y = vec![b as f32; 20 * 20];
        let s = ssim(ImageRef::new(&x, 20, 20, 1), ImageRef::new(&y, 20, 20, 1));
        let c1 = 1e-4;
        let expected = (2.0 * a * b + c1) / (a * a + b * b + c1);
        assert!((s - expected).abs() < 1e-6, "{s} vs {expected}");
    }

    #[test]
    fn ssim_drops_with_noise_and_is_symmetric() {
        let a = ramp(40, 40);
        let b: Vec<f32> = a
            .iter()
            .enumerate()
            .map(|(i, v)| (v + if i % 2 == 0 { 0.1 } else { -0.1 }).clamp(0.0, 1.0))
            .collect();
        let (ia, ib) = (ImageRef::new(&a, 40, 40, 3), ImageRef::new(&b, 40, 40, 3));
        let s = ssim(ia, ib);
        assert!(s < 0.99 && s > 0.0, "{s}");
        assert!((s - ssim(ib, ia)).abs() < 1e-12);
    }

    #[test]
    fn mask_iou_counts_overlap() {
        let a = [1.0, 1.0, 0.0, 0.0];
        let b = [1.0, 0.0, 1.0, 0.0];
        assert!((mask_iou(&a, &b) - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(mask_iou(&[0.0; 4], &[0.0; 4]), 1.0);
    }
}
