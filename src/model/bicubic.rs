//! Separable antialiased bicubic resampling, as `torch.nn.functional.interpolate(mode="bicubic",
//! antialias=True, align_corners=False)` computes it (PIL-style kernel, a = −0.5).
//!
//! Used to fit the encoder's stored position-embedding grid to any patch grid. For each output
//! index `i` with `scale = in/out`: `center = scale·(i + 0.5)`, `support = 2·max(scale, 1)`,
//! taps `j ∈ [⌊center − support + 0.5⌋, ⌊center + support + 0.5⌋)` clipped to the input,
//! weights `cubic((j − center + 0.5) / max(scale, 1))` normalised to sum 1.

/// Keys cubic kernel with a = −0.5 (the antialiased torch/PIL variant).
fn cubic(x: f64) -> f64 {
    const A: f64 = -0.5;
    let x = x.abs();
    if x < 1.0 {
        ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        (((x - 5.0) * x + 8.0) * x - 4.0) * A
    } else {
        0.0
    }
}

/// Per output index: first input tap and the normalised weights.
fn taps(input: usize, output: usize) -> Vec<(usize, Vec<f64>)> {
    let scale = input as f64 / output as f64;
    let support = 2.0 * scale.max(1.0);
    let inv = 1.0 / scale.max(1.0);
    (0..output)
        .map(|i| {
            let center = scale * (i as f64 + 0.5);
            let lo = ((center - support + 0.5).floor().max(0.0)) as usize;
            let hi = ((center + support + 0.5).floor() as usize).min(input);
            let mut w: Vec<f64> = (lo..hi)
                .map(|j| cubic((j as f64 - center + 0.5) * inv))
                .collect();
            let total: f64 = w.iter().sum();
            if total != 0.0 {
                w.iter_mut().for_each(|x| *x /= total);
            }
            (lo, w)
        })
        .collect()
}

/// Resamples a row-major `[in_h, in_w, channels]` grid to `[out_h, out_w, channels]`.
pub fn resize_bicubic_aa(
    src: &[f32],
    in_h: usize,
    in_w: usize,
    channels: usize,
    out_h: usize,
    out_w: usize,
) -> Vec<f32> {
    assert_eq!(src.len(), in_h * in_w * channels, "bicubic input size");
    // Horizontal pass: [in_h, out_w, C].
    let tx = taps(in_w, out_w);
    let mut mid = vec![0f64; in_h * out_w * channels];
    for y in 0..in_h {
        for (x, (lo, w)) in tx.iter().enumerate() {
            let dst = &mut mid[(y * out_w + x) * channels..][..channels];
            for (t, &wt) in w.iter().enumerate() {
                let s = &src[(y * in_w + lo + t) * channels..][..channels];
                dst.iter_mut()
                    .zip(s)
                    .for_each(|(d, &v)| *d += wt * v as f64);
            }
        }
    }
    // Vertical pass: [out_h, out_w, C].
    let ty = taps(in_h, out_h);
    let mut out = vec![0f32; out_h * out_w * channels];
    for (y, (lo, w)) in ty.iter().enumerate() {
        for x in 0..out_w {
            let dst = &mut out[(y * out_w + x) * channels..][..channels];
            for (c, d) in dst.iter_mut().enumerate() {
                let v: f64 = w
                    .iter()
                    .enumerate()
                    .map(|(t, &wt)| wt * mid[((lo + t) * out_w + x) * channels + c])
                    .sum();
                *d = v as f32;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_size_is_the_identity() {
        let src: Vec<f32> = (0..5 * 4 * 2).map(|i| (i as f32 * 0.37).sin()).collect();
        assert_eq!(resize_bicubic_aa(&src, 5, 4, 2, 5, 4), src);
    }

    #[test]
    fn constant_grid_stays_constant_up_and_down() {
        let src = vec![0.75f32; 37 * 37];
        for (h, w) in [(60, 36), (8, 8), (3, 50)] {
            let out = resize_bicubic_aa(&src, 37, 37, 1, h, w);
            assert!(out.iter().all(|v| (v - 0.75).abs() < 1e-6), "{h}x{w}");
        }
    }

    #[test]
    fn upsampling_reproduces_a_linear_ramp_away_from_the_border() {
        // Keys' cubic (a = −0.5) reproduces linear functions exactly where no tap is clipped.
        let n = 10;
        let src: Vec<f32> = (0..n).map(|i| i as f32).collect();
        let out = resize_bicubic_aa(&src, 1, n, 1, 1, 2 * n);
        for (i, v) in out.iter().enumerate().take(2 * n - 4).skip(4) {
            let expect = (i as f32 + 0.5) / 2.0 - 0.5;
            assert!((v - expect).abs() < 1e-5, "{i}: {v} vs {expect}");
        }
    }

    #[test]
    fn downsampling_averages_like_torch_antialias() {
        // 4 → 2 with antialias: each output sees a stretched kernel, symmetric about its centre,
        // so an alternating signal averages out to (nearly) its mean in the interior.
        let src = vec![0.0f32, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0];
        let out = resize_bicubic_aa(&src, 1, 8, 1, 1, 4);
        for v in &out[1..3] {
            assert!((v - 0.5).abs() < 0.1, "{out:?}");
        }
    }
}
