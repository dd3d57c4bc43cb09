//! Bilinear resize with `align_corners = true` on channels-last f32 maps ([`FeatureMap`]).
//!
//! The source rows/columns and weights of every output row and column are computed once
//! (f64 positions, as candle and PyTorch do); each output pixel is then a blend of four
//! contiguous channel rows, which the compiler vectorises. Output rows run in parallel.

use candle_core::Result;
use rayon::prelude::*;

use super::feature_map::FeatureMap;

/// Source index pair and weight of the second one, per output index (`align_corners = true`).
fn taps(n_in: usize, n_out: usize) -> Vec<(usize, usize, f32)> {
    let scale = if n_out > 1 {
        (n_in as f64 - 1.0) / (n_out as f64 - 1.0)
    } else {
        0.0
    };
    (0..n_out)
        .map(|o| {
            let src = scale * o as f64;
            let i0 = (src.floor() as usize).min(n_in - 1);
            let i1 = (i0 + 1).min(n_in - 1);
            (i0, i1, (src - i0 as f64) as f32)
        })
        .collect()
}

/// `[B, H, W, C]` → `[B, out_h, out_w, C]`, bilinear with aligned corners.
pub fn upsample_bilinear(x: &FeatureMap, out_h: usize, out_w: usize) -> Result<FeatureMap> {
    let c = x.channels;
    let mut out = FeatureMap::zeros(x.batch, out_h, out_w, c);
    if out.data.is_empty() {
        return Ok(out);
    }
    if x.height == 0 || x.width == 0 {
        candle_core::bail!("bilinear upsample: empty {}×{} input", x.height, x.width);
    }
    let rows = taps(x.height, out_h);
    let cols = taps(x.width, out_w);
    let line = x.width * c;
    let image = x.height * line;
    out.data
        .par_chunks_mut(out_w * c)
        .enumerate()
        .for_each(|(r, dst)| {
            let (b, oy) = (r / out_h, r % out_h);
            let (y0, y1, wy) = rows[oy];
            let top = &x.data[b * image + y0 * line..b * image + (y0 + 1) * line];
            let bottom = &x.data[b * image + y1 * line..b * image + (y1 + 1) * line];
            for (px, &(x0, x1, wx)) in dst.chunks_exact_mut(c).zip(&cols) {
                let (a, bb) = (&top[x0 * c..(x0 + 1) * c], &top[x1 * c..(x1 + 1) * c]);
                let (cc, d) = (&bottom[x0 * c..(x0 + 1) * c], &bottom[x1 * c..(x1 + 1) * c]);
                for i in 0..c {
                    let t = a[i] + wx * (bb[i] - a[i]);
                    let u = cc[i] + wx * (d[i] - cc[i]);
                    px[i] = t + wy * (u - t);
                }
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::max_abs_diff;
    use candle_core::{Device, Tensor};

    #[test]
    fn matches_candle_aligned_bilinear_over_odd_shapes() {
        let dev = Device::Cpu;
        for &(b, c, h, w, oh, ow) in &[
            (1, 3, 2, 2, 3, 3),
            (2, 5, 7, 9, 14, 18),
            (1, 16, 42, 42, 84, 84),
            (1, 4, 13, 11, 5, 7),
            (1, 2, 1, 1, 3, 4),
            (1, 3, 6, 5, 1, 1),
            (1, 8, 84, 84, 73, 91),
        ] {
            let x = Tensor::randn(0f32, 1.0, (b, c, h, w), &dev).unwrap();
            let want = x.upsample_bilinear2d(oh, ow, true).unwrap();
            let got = upsample_bilinear(&FeatureMap::from_nchw(&x).unwrap(), oh, ow)
                .unwrap()
                .to_nchw(&dev)
                .unwrap();
            assert_eq!(got.dims(), want.dims());
            let d = max_abs_diff(&got, &want);
            assert!(d < 1e-5, "{b}x{c}x{h}x{w} -> {oh}x{ow}: {d}");
        }
    }

    #[test]
    fn corners_are_copied_exactly() {
        let x = FeatureMap::new(vec![1.0, 2.0, 3.0, 4.0], 1, 2, 2, 1).unwrap();
        let u = upsample_bilinear(&x, 5, 4).unwrap();
        assert_eq!(
            (u.data[0], u.data[3], u.data[16], u.data[19]),
            (1.0, 2.0, 3.0, 4.0)
        );
    }
}
