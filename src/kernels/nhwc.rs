//! Channels-last (NHWC, one image) f32 operations on borrowed slices, for graphs whose buffers
//! live in one arena: fused activations, zero padding, elementwise add, max pooling,
//! depth-to-space, half-pixel bilinear resizing, concatenation and the logistic function.
//! The convolutions are in [`super::pointwise`] and [`super::depthwise`].
//!
//! Every function takes its input and output as slices plus their shapes and panics when a
//! slice has the wrong length (the callers check shapes when a graph is loaded).

use super::parallel;
use crate::simd::simd_dispatch;

/// Elements per rayon task of the elementwise passes.
const ELEMENTS_PER_TASK: usize = 1 << 15;

/// A fused activation, applied as each value is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Activation {
    /// The identity.
    #[default]
    None,
    /// `max(x, 0)`.
    Relu,
    /// `min(max(x, 0), 6)`.
    Relu6,
}

impl Activation {
    /// The activation of `x`.
    #[inline(always)]
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Self::None => x,
            Self::Relu => x.max(0.0),
            Self::Relu6 => x.clamp(0.0, 6.0),
        }
    }

    /// Lower and upper clamp bounds (±∞ where the activation has none): `apply(x)` is
    /// `x.max(lo).min(hi)` for every finite x.
    #[inline(always)]
    pub fn bounds(self) -> (f32, f32) {
        match self {
            Self::None => (f32::NEG_INFINITY, f32::INFINITY),
            Self::Relu => (0.0, f32::INFINITY),
            Self::Relu6 => (0.0, 6.0),
        }
    }
}

/// What happens to each computed value `x` as it is stored: `post(pre(x + bias) + residual)`
/// (`post` only with a residual).
#[derive(Debug, Clone, Copy, Default)]
pub struct Epilogue<'a> {
    /// Applied to `x + bias`.
    pub pre: Activation,
    /// Values of the output's shape added after `pre`.
    pub residual: Option<&'a [f32]>,
    /// Applied after the residual.
    pub post: Activation,
}

/// The height, width and channels of one NHWC image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Channels per pixel.
    pub channels: usize,
}

impl Shape {
    /// A shape.
    pub const fn new(height: usize, width: usize, channels: usize) -> Self {
        Self {
            height,
            width,
            channels,
        }
    }

    /// `height · width · channels`.
    pub const fn len(&self) -> usize {
        self.height * self.width * self.channels
    }

    /// Whether the shape holds no value.
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `height · width`.
    pub const fn pixels(&self) -> usize {
        self.height * self.width
    }
}

/// Zero rows and columns around an image: `top`, `left`, `bottom`, `right`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Padding {
    /// Rows above.
    pub top: usize,
    /// Columns to the left.
    pub left: usize,
    /// Rows below.
    pub bottom: usize,
    /// Columns to the right.
    pub right: usize,
}

impl Padding {
    /// The same padding on all four sides.
    pub const fn uniform(p: usize) -> Self {
        Self {
            top: p,
            left: p,
            bottom: p,
            right: p,
        }
    }

    /// TensorFlow's `SAME` padding of a window `kernel` moved by `stride` over `size` values:
    /// `(before, after)`, the odd one after.
    pub fn same(size: usize, kernel: usize, stride: usize) -> (usize, usize) {
        let out = size.div_ceil(stride);
        let total = ((out.max(1) - 1) * stride + kernel).saturating_sub(size);
        (total / 2, total - total / 2)
    }

    /// The output side of a window `kernel` moved by `stride` over `size` values padded by
    /// `before + after` (0 when the window does not fit).
    pub fn out_side(
        size: usize,
        before: usize,
        after: usize,
        kernel: usize,
        stride: usize,
    ) -> usize {
        let padded = size + before + after;
        if padded < kernel {
            0
        } else {
            (padded - kernel) / stride + 1
        }
    }
}

#[inline(always)]
fn add_portable(a: &[f32], b: &[f32], out: &mut [f32], lo: f32, hi: f32) {
    for ((o, &x), &y) in out.iter_mut().zip(a).zip(b) {
        *o = (x + y).max(lo).min(hi);
    }
}

simd_dispatch! {
    avx2;
    fn add_chunk[](a: &[f32], b: &[f32], out: &mut [f32], lo: f32, hi: f32) = add_portable;
}

/// `out = act(a + b)`, elementwise.
pub fn add(a: &[f32], b: &[f32], out: &mut [f32], act: Activation) {
    assert!(
        a.len() == out.len() && b.len() == out.len(),
        "add: lengths differ"
    );
    let (lo, hi) = act.bounds();
    let per = parallel::items_per_task(out.len(), out.len(), ELEMENTS_PER_TASK, 16);
    parallel::for_each_chunk(out, per, |i, o| {
        let at = i * per;
        add_chunk(&a[at..at + o.len()], &b[at..at + o.len()], o, lo, hi);
    });
}

/// `out` = `input` with `pad` zero rows/columns around it and `extra` zero channels after each
/// pixel's `input_shape.channels` (TFLite's PAD on NHWC with zero batch padding).
pub fn pad(
    input: &[f32],
    input_shape: Shape,
    pad: Padding,
    extra_channels: (usize, usize),
    out: &mut [f32],
) {
    let Shape {
        height: h,
        width: w,
        channels: c,
    } = input_shape;
    let oc = c + extra_channels.0 + extra_channels.1;
    let ow = w + pad.left + pad.right;
    let oh = h + pad.top + pad.bottom;
    assert_eq!(input.len(), input_shape.len(), "pad: input length");
    assert_eq!(out.len(), oh * ow * oc, "pad: output length");
    parallel::for_each_row(out, ow * oc, ow * oc, |y, row| {
        if y < pad.top || y >= pad.top + h {
            row.fill(0.0);
            return;
        }
        let src = &input[(y - pad.top) * w * c..(y - pad.top + 1) * w * c];
        row[..pad.left * oc].fill(0.0);
        row[(pad.left + w) * oc..].fill(0.0);
        for (dst, px) in row[pad.left * oc..(pad.left + w) * oc]
            .chunks_exact_mut(oc)
            .zip(src.chunks_exact(c))
        {
            dst[..extra_channels.0].fill(0.0);
            dst[extra_channels.0..extra_channels.0 + c].copy_from_slice(px);
            dst[extra_channels.0 + c..].fill(0.0);
        }
    });
}

/// Max pooling with a `window` (rows, columns) moved by `stride`, zero-sized `pad` ignored (the
/// maximum runs over the in-bounds values only, as TFLite's), then `act`.
pub fn max_pool(
    input: &[f32],
    shape: Shape,
    window: (usize, usize),
    stride: (usize, usize),
    pad: Padding,
    act: Activation,
    out: &mut [f32],
) {
    let c = shape.channels;
    let oh = Padding::out_side(shape.height, pad.top, pad.bottom, window.0, stride.0);
    let ow = Padding::out_side(shape.width, pad.left, pad.right, window.1, stride.1);
    assert_eq!(input.len(), shape.len(), "max_pool: input length");
    assert_eq!(out.len(), oh * ow * c, "max_pool: output length");
    if out.is_empty() {
        return;
    }
    parallel::for_each_row(out, ow * c, ow * c * window.0 * window.1, |oy, row| {
        for (ox, px) in row.chunks_exact_mut(c).enumerate() {
            px.fill(f32::NEG_INFINITY);
            for ky in 0..window.0 {
                let Some(iy) = (oy * stride.0 + ky).checked_sub(pad.top) else {
                    continue;
                };
                if iy >= shape.height {
                    continue;
                }
                for kx in 0..window.1 {
                    let Some(ix) = (ox * stride.1 + kx).checked_sub(pad.left) else {
                        continue;
                    };
                    if ix >= shape.width {
                        continue;
                    }
                    let src = &input[(iy * shape.width + ix) * c..][..c];
                    for (o, &v) in px.iter_mut().zip(src) {
                        *o = o.max(v);
                    }
                }
            }
            px.iter_mut().for_each(|v| *v = act.apply(*v));
        }
    });
}

/// TFLite's DEPTH_TO_SPACE: each input pixel's `block²·C` channels become a `block×block`
/// patch of `C`-channel pixels (channel index `(dy·block + dx)·C + c`).
pub fn depth_to_space(input: &[f32], shape: Shape, block: usize, out: &mut [f32]) {
    assert!(
        block > 0 && shape.channels % (block * block) == 0,
        "depth_to_space: channels"
    );
    assert_eq!(input.len(), shape.len(), "depth_to_space: input length");
    assert_eq!(out.len(), input.len(), "depth_to_space: output length");
    let c = shape.channels / (block * block);
    let ow = shape.width * block;
    parallel::for_each_row(out, ow * c, ow * c, |oy, row| {
        let (y, dy) = (oy / block, oy % block);
        for (ox, px) in row.chunks_exact_mut(c).enumerate() {
            let (x, dx) = (ox / block, ox % block);
            let src = (y * shape.width + x) * shape.channels + (dy * block + dx) * c;
            px.copy_from_slice(&input[src..src + c]);
        }
    });
}

/// One output coordinate's two source indices and the weight of the second, as TFLite's
/// RESIZE_BILINEAR computes them with `half_pixel_centers` (and `align_corners` false).
#[inline]
fn half_pixel_source(o: usize, scale: f32, size: usize) -> (usize, usize, f32) {
    let s = (o as f32 + 0.5) * scale - 0.5;
    let floor = s.floor();
    let lo = (floor.max(0.0) as usize).min(size - 1);
    let hi = (s.ceil().max(0.0) as usize).min(size - 1);
    (lo, hi, s - floor)
}

/// Bilinear resize to `out_size` (rows, columns) with half-pixel centres and corners not
/// aligned (TFLite's RESIZE_BILINEAR with `half_pixel_centers`), then `+ residual` when given.
pub fn resize_bilinear_half_pixel(
    input: &[f32],
    shape: Shape,
    out_size: (usize, usize),
    residual: Option<&[f32]>,
    out: &mut [f32],
) {
    let c = shape.channels;
    let (oh, ow) = out_size;
    assert_eq!(input.len(), shape.len(), "resize: input length");
    assert_eq!(out.len(), oh * ow * c, "resize: output length");
    if let Some(r) = residual {
        assert_eq!(r.len(), out.len(), "resize: residual length");
    }
    if out.is_empty() || shape.is_empty() {
        return;
    }
    let sy = shape.height as f32 / oh as f32;
    let sx = shape.width as f32 / ow as f32;
    let cols: Vec<(usize, usize, f32)> = (0..ow)
        .map(|ox| half_pixel_source(ox, sx, shape.width))
        .collect();
    parallel::for_each_row(out, ow * c, 4 * ow * c, |oy, row| {
        let (y0, y1, fy) = half_pixel_source(oy, sy, shape.height);
        let line = |y: usize| &input[y * shape.width * c..(y + 1) * shape.width * c];
        let res = residual.map(|r| &r[oy * ow * c..(oy + 1) * ow * c]);
        #[cfg(target_arch = "x86_64")]
        if c % 8 == 0 && super::gemm_avx2::available() {
            // SAFETY: the CPU has AVX2 (checked above).
            unsafe { resize_row_avx2(line(y0), line(y1), fy, &cols, c, res, row) };
            return;
        }
        resize_row(line(y0), line(y1), fy, &cols, c, res, row);
    });
}

/// [`resize_row_portable`] for channel counts that are multiples of 8, with AVX2 intrinsics
/// (the same products and sums in the same order, 8 channels at a time).
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn resize_row_avx2(
    top: &[f32],
    bottom: &[f32],
    fy: f32,
    cols: &[(usize, usize, f32)],
    c: usize,
    residual: Option<&[f32]>,
    row: &mut [f32],
) {
    use std::arch::x86_64::*;
    assert!(c % 8 == 0 && row.len() == cols.len() * c && bottom.len() == top.len());
    assert!(cols
        .iter()
        .all(|&(x0, x1, _)| (x0.max(x1) + 1) * c <= top.len()));
    assert!(residual.is_none_or(|r| r.len() >= row.len()));
    for (ox, &(x0, x1, fx)) in cols.iter().enumerate() {
        let wa = _mm256_set1_ps((1.0 - fy) * (1.0 - fx));
        let wd = _mm256_set1_ps(fy * (1.0 - fx));
        let wb = _mm256_set1_ps((1.0 - fy) * fx);
        let we = _mm256_set1_ps(fy * fx);
        let (a, b) = (top.as_ptr().add(x0 * c), top.as_ptr().add(x1 * c));
        let (d, e) = (bottom.as_ptr().add(x0 * c), bottom.as_ptr().add(x1 * c));
        let o = row.as_mut_ptr().add(ox * c);
        for i in (0..c).step_by(8) {
            let mut v = _mm256_add_ps(
                _mm256_mul_ps(_mm256_loadu_ps(a.add(i)), wa),
                _mm256_mul_ps(_mm256_loadu_ps(d.add(i)), wd),
            );
            v = _mm256_add_ps(v, _mm256_mul_ps(_mm256_loadu_ps(b.add(i)), wb));
            v = _mm256_add_ps(v, _mm256_mul_ps(_mm256_loadu_ps(e.add(i)), we));
            if let Some(r) = residual {
                v = _mm256_add_ps(v, _mm256_loadu_ps(r.as_ptr().add(ox * c + i)));
            }
            _mm256_storeu_ps(o.add(i), v);
        }
    }
}

#[inline(always)]
fn resize_row_portable(
    top: &[f32],
    bottom: &[f32],
    fy: f32,
    cols: &[(usize, usize, f32)],
    c: usize,
    residual: Option<&[f32]>,
    row: &mut [f32],
) {
    for (ox, px) in row.chunks_exact_mut(c).enumerate() {
        let (x0, x1, fx) = cols[ox];
        let (a, b) = (&top[x0 * c..][..c], &top[x1 * c..][..c]);
        let (d, e) = (&bottom[x0 * c..][..c], &bottom[x1 * c..][..c]);
        // TFLite's reference: the four corners weighted by (1-fy)(1-fx), fy(1-fx), …
        let (wa, wd) = ((1.0 - fy) * (1.0 - fx), fy * (1.0 - fx));
        let (wb, we) = ((1.0 - fy) * fx, fy * fx);
        for ((((o, &a), &b), &d), &e) in px.iter_mut().zip(a).zip(b).zip(d).zip(e) {
            *o = a * wa + d * wd + b * wb + e * we;
        }
        if let Some(r) = residual {
            for (o, &v) in px.iter_mut().zip(&r[ox * c..][..c]) {
                *o += v;
            }
        }
    }
}

simd_dispatch! {
    avx2;
    fn resize_row[](
        top: &[f32],
        bottom: &[f32],
        fy: f32,
        cols: &[(usize, usize, f32)],
        c: usize,
        residual: Option<&[f32]>,
        row: &mut [f32],
    ) = resize_row_portable;
}

/// Concatenates row-major tensors along one axis: each input is `outer × inner_i` values
/// (`outer` = the product of the dimensions before the axis, `inner_i` = the input's extent
/// along the axis times the product of the dimensions after it); `out` is `outer × Σ inner_i`.
pub fn concat(inputs: &[(&[f32], usize)], outer: usize, act: Activation, out: &mut [f32]) {
    let total: usize = inputs.iter().map(|(_, inner)| inner).sum();
    assert_eq!(out.len(), outer * total, "concat: output length");
    let mut at = 0;
    for o in 0..outer {
        for &(data, inner) in inputs {
            assert_eq!(data.len(), outer * inner, "concat: input length");
            for (dst, &v) in out[at..at + inner]
                .iter_mut()
                .zip(&data[o * inner..(o + 1) * inner])
            {
                *dst = act.apply(v);
            }
            at += inner;
        }
    }
}

/// `out = 1 / (1 + e^−x)`, elementwise.
pub fn logistic(input: &[f32], out: &mut [f32]) {
    assert_eq!(input.len(), out.len(), "logistic: lengths differ");
    for (o, &x) in out.iter_mut().zip(input) {
        *o = 1.0 / (1.0 + (-x).exp());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(n: usize, scale: f32) -> Vec<f32> {
        (0..n)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) * scale)
            .collect()
    }

    #[test]
    fn same_padding_matches_tensorflow() {
        assert_eq!(Padding::same(8, 3, 2), (0, 1));
        assert_eq!(Padding::same(7, 3, 1), (1, 1));
        assert_eq!(Padding::same(14, 5, 1), (2, 2));
        assert_eq!(Padding::same(4, 2, 2), (0, 0));
        assert_eq!(Padding::out_side(8, 0, 1, 3, 2), 4);
        assert_eq!(Padding::out_side(2, 0, 0, 3, 1), 0);
    }

    #[test]
    fn add_applies_the_activation() {
        let a = ramp(70_000, 0.2);
        let b = ramp(70_000, -0.05);
        let mut out = vec![0.0; a.len()];
        add(&a, &b, &mut out, Activation::Relu6);
        for i in 0..a.len() {
            assert_eq!(out[i], (a[i] + b[i]).clamp(0.0, 6.0));
        }
    }

    #[test]
    fn pad_places_the_image_and_zero_channels() {
        let s = Shape::new(2, 3, 2);
        let x = ramp(s.len(), 1.0);
        let p = Padding {
            top: 1,
            left: 0,
            bottom: 2,
            right: 1,
        };
        let mut out = vec![f32::NAN; 5 * 4 * 3];
        pad(&x, s, p, (0, 1), &mut out);
        for y in 0..5 {
            for xx in 0..4 {
                for c in 0..3 {
                    let inside = (1..3).contains(&y) && xx < 3 && c < 2;
                    let want = if inside {
                        x[((y - 1) * 3 + xx) * 2 + c]
                    } else {
                        0.0
                    };
                    assert_eq!(out[(y * 4 + xx) * 3 + c], want, "{y} {xx} {c}");
                }
            }
        }
    }

    #[test]
    fn max_pool_and_depth_to_space_match_the_definitions() {
        let s = Shape::new(4, 6, 3);
        let x = ramp(s.len(), 0.1);
        let mut out = vec![0.0; 2 * 3 * 3];
        max_pool(
            &x,
            s,
            (2, 2),
            (2, 2),
            Padding::default(),
            Activation::None,
            &mut out,
        );
        for oy in 0..2 {
            for ox in 0..3 {
                for c in 0..3 {
                    let mut m = f32::MIN;
                    for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        m = m.max(x[((2 * oy + dy) * 6 + 2 * ox + dx) * 3 + c]);
                    }
                    assert_eq!(out[(oy * 3 + ox) * 3 + c], m);
                }
            }
        }
        let s = Shape::new(2, 3, 8);
        let x = ramp(s.len(), 1.0);
        let mut out = vec![0.0; s.len()];
        depth_to_space(&x, s, 2, &mut out);
        for y in 0..4 {
            for xx in 0..6 {
                for c in 0..2 {
                    let src = ((y / 2) * 3 + xx / 2) * 8 + ((y % 2) * 2 + xx % 2) * 2 + c;
                    assert_eq!(out[(y * 6 + xx) * 2 + c], x[src]);
                }
            }
        }
    }

    #[test]
    fn bilinear_upsampling_by_two_uses_quarter_weights() {
        // 2× half-pixel upsampling: output 2i+1 sits 1/4 of the way from input i to i+1, and
        // the outermost outputs copy the edge.
        let s = Shape::new(1, 3, 1);
        let x = vec![0.0, 4.0, 8.0];
        let mut out = vec![0.0; 6];
        resize_bilinear_half_pixel(&x, s, (1, 6), None, &mut out);
        assert_eq!(out, vec![0.0, 1.0, 3.0, 5.0, 7.0, 8.0]);
        let res = vec![1.0; 6];
        resize_bilinear_half_pixel(&x, s, (1, 6), Some(&res), &mut out);
        assert_eq!(out, vec![1.0, 2.0, 4.0, 6.0, 8.0, 9.0]);
    }

    #[test]
    fn bilinear_resize_rows_match_the_portable_loop() {
        // 16 channels take the vector path; compare with the plain loop over odd sizes
        for (h, w, c, oh, ow) in [(5, 7, 16, 10, 14), (3, 4, 8, 7, 9), (6, 5, 24, 3, 11)] {
            let s = Shape::new(h, w, c);
            let x = ramp(s.len(), 0.37);
            let res = ramp(oh * ow * c, -0.11);
            let mut got = vec![0.0; oh * ow * c];
            resize_bilinear_half_pixel(&x, s, (oh, ow), Some(&res), &mut got);
            let (sy, sx) = (h as f32 / oh as f32, w as f32 / ow as f32);
            let cols: Vec<_> = (0..ow).map(|o| half_pixel_source(o, sx, w)).collect();
            for oy in 0..oh {
                let (y0, y1, fy) = half_pixel_source(oy, sy, h);
                let mut want = vec![0.0; ow * c];
                resize_row_portable(
                    &x[y0 * w * c..(y0 + 1) * w * c],
                    &x[y1 * w * c..(y1 + 1) * w * c],
                    fy,
                    &cols,
                    c,
                    Some(&res[oy * ow * c..(oy + 1) * ow * c]),
                    &mut want,
                );
                assert_eq!(&got[oy * ow * c..(oy + 1) * ow * c], &want[..], "row {oy}");
            }
        }
    }

    #[test]
    fn concat_interleaves_along_the_axis() {
        let a = vec![1.0, 2.0, 3.0, 4.0];
        let b = vec![5.0, 6.0];
        let mut out = vec![0.0; 6];
        concat(&[(&a, 2), (&b, 1)], 2, Activation::None, &mut out);
        assert_eq!(out, vec![1.0, 2.0, 5.0, 3.0, 4.0, 6.0]);
        let mut l = vec![0.0; 2];
        logistic(&[0.0, 2.0], &mut l);
        assert_eq!(l[0], 0.5);
        assert!((l[1] - 0.880_797).abs() < 1e-6);
    }
}
