//! A channels-last (NHWC) f32 feature map on the host: the layout the CPU convolution,
//! transposed-convolution and bilinear-resize kernels ([`super::conv2d`],
//! [`super::conv_transpose`], [`super::upsample`]) share, so a chain of them never transposes.
//! In NHWC every pixel's channels are one contiguous row: a 1×1 convolution is one matrix
//! product over the pixel rows and a 3×3 tap gathers whole channel rows.

use candle_core::{DType, Device, Result, Tensor};
use rayon::prelude::*;

/// Pixels per rayon task of the element-wise passes.
const PIXELS_PER_TASK: usize = 4096;

/// `[batch, height, width, channels]` f32 values, row-major (channels fastest).
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureMap {
    /// The `batch·height·width·channels` values.
    pub data: Vec<f32>,
    /// Images.
    pub batch: usize,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Channels per pixel.
    pub channels: usize,
}

impl FeatureMap {
    /// Wraps NHWC values; fails when `data` does not hold `b·h·w·c` of them.
    pub fn new(
        data: Vec<f32>,
        batch: usize,
        height: usize,
        width: usize,
        channels: usize,
    ) -> Result<Self> {
        if data.len() != batch * height * width * channels {
            candle_core::bail!(
                "feature map: {} values for [{batch}, {height}, {width}, {channels}]",
                data.len()
            );
        }
        Ok(Self {
            data,
            batch,
            height,
            width,
            channels,
        })
    }

    /// An all-zero map.
    pub fn zeros(batch: usize, height: usize, width: usize, channels: usize) -> Self {
        Self {
            data: vec![0.0; batch * height * width * channels],
            batch,
            height,
            width,
            channels,
        }
    }

    /// Pixels over all images (`b·h·w`).
    pub fn pixels(&self) -> usize {
        self.batch * self.height * self.width
    }

    /// From a `[B, C, H, W]` tensor (any device and float dtype; copied to the host as f32).
    pub fn from_nchw(t: &Tensor) -> Result<Self> {
        let (b, c, h, w) = t.dims4()?;
        let data = t
            .to_device(&Device::Cpu)?
            .to_dtype(DType::F32)?
            .permute((0, 2, 3, 1))?
            .flatten_all()?
            .to_vec1::<f32>()?;
        Self::new(data, b, h, w, c)
    }

    /// From a `[B, H·W, C]` token tensor (row-major pixel order, as a ViT emits its patches).
    pub fn from_tokens(t: &Tensor, height: usize, width: usize) -> Result<Self> {
        let (b, n, c) = t.dims3()?;
        if n != height * width {
            candle_core::bail!("feature map: {n} tokens are not a {height}×{width} grid");
        }
        let data = t
            .to_device(&Device::Cpu)?
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        Self::new(data, b, height, width, c)
    }

    /// As a `[B, C, H, W]` f32 tensor on `device`.
    pub fn to_nchw(&self, device: &Device) -> Result<Tensor> {
        // One parallel pass over (image, channel, block of pixels): each task gathers its
        // channel's values from the interleaved pixels (candle's strided copy of the permuted
        // view runs on one thread).
        let (c, hw) = (self.channels, self.height * self.width);
        let mut out = vec![0f32; self.data.len()];
        const BLOCK: usize = 1 << 14;
        let plane = hw.max(1);
        out.par_chunks_mut(plane)
            .enumerate()
            .flat_map(|(bc, chunk)| {
                chunk
                    .par_chunks_mut(BLOCK)
                    .enumerate()
                    .map(move |(i, dst)| (bc, i, dst))
            })
            .for_each(|(bc, i, dst)| {
                let (b, ch) = (bc / c, bc % c);
                let first = b * hw * c + i * BLOCK * c + ch;
                for (j, v) in dst.iter_mut().enumerate() {
                    *v = self.data[first + j * c];
                }
            });
        Tensor::from_vec(out, (self.batch, c, self.height, self.width), &Device::Cpu)?
            .to_device(device)
    }

    /// `max(x, 0)` in place.
    pub fn relu_in_place(&mut self) {
        self.data
            .par_chunks_mut(PIXELS_PER_TASK)
            .for_each(|c| c.iter_mut().for_each(|v| *v = v.max(0.0)));
    }

    /// `1 / (1 + e^(−x))` in place.
    pub fn sigmoid_in_place(&mut self) {
        self.data
            .par_chunks_mut(PIXELS_PER_TASK)
            .for_each(|c| c.iter_mut().for_each(|v| *v = 1.0 / (1.0 + (-*v).exp())));
    }

    /// `self += other` (same shape).
    pub fn add_assign(&mut self, other: &FeatureMap) -> Result<()> {
        self.check_same_shape(other, "add")?;
        self.data
            .par_chunks_mut(PIXELS_PER_TASK)
            .zip(other.data.par_chunks(PIXELS_PER_TASK))
            .for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(a, b)| *a += b));
        Ok(())
    }

    /// Adds `column[x] ++ row[y]` to the channels of pixel (y, x) of every image: a position
    /// embedding whose first channels depend on the column only and the rest on the row only.
    pub fn add_separable(&mut self, column: &[Vec<f32>], row: &[Vec<f32>]) -> Result<()> {
        let (h, w, c) = (self.height, self.width, self.channels);
        let cx = column.first().map_or(0, Vec::len);
        let ok = column.len() == w
            && row.len() == h
            && column.iter().all(|x| x.len() == cx)
            && row.iter().all(|y| y.len() + cx == c);
        if !ok {
            candle_core::bail!("feature map: separable embedding does not fit [{h}, {w}, {c}]");
        }
        if c == 0 || w == 0 {
            return Ok(());
        }
        self.data
            .par_chunks_mut(w * c)
            .enumerate()
            .for_each(|(r, line)| {
                let y = &row[r % h];
                for (px, xe) in line.chunks_exact_mut(c).zip(column) {
                    let (a, b) = px.split_at_mut(xe.len());
                    a.iter_mut().zip(xe).for_each(|(v, e)| *v += e);
                    b.iter_mut().zip(y).for_each(|(v, e)| *v += e);
                }
            });
        Ok(())
    }

    /// Fails unless `other` has this map's shape; `op` names the caller.
    pub fn check_same_shape(&self, other: &FeatureMap, op: &str) -> Result<()> {
        let a = (self.batch, self.height, self.width, self.channels);
        let b = (other.batch, other.height, other.width, other.channels);
        if a != b {
            candle_core::bail!("feature map {op}: shapes {a:?} and {b:?} differ");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nchw_of_a_large_map_equals_the_permuted_tensor() -> Result<()> {
        // more pixels than one transpose block, several images and channels
        let t = Tensor::randn(0f32, 1.0, (2, 3, 130, 150), &Device::Cpu)?;
        let m = FeatureMap::from_nchw(&t)?;
        let back = m.to_nchw(&Device::Cpu)?;
        assert_eq!(back.dims(), t.dims());
        assert_eq!(crate::testing::max_abs_diff(&back, &t), 0.0);
        Ok(())
    }

    #[test]
    fn nchw_round_trip_keeps_every_value_in_place() -> Result<()> {
        let t = Tensor::arange(0f32, 2.0 * 3.0 * 4.0 * 5.0, &Device::Cpu)?.reshape((2, 3, 4, 5))?;
        let m = FeatureMap::from_nchw(&t)?;
        // pixel (b=1, y=2, x=3), channel 1 of the NHWC buffer is t[1, 1, 2, 3]
        let at = ((4 + 2) * 5 + 3) * 3 + 1;
        assert_eq!(
            m.data[at],
            t.get(1)?.get(1)?.get(2)?.get(3)?.to_scalar::<f32>()?
        );
        let back = m.to_nchw(&Device::Cpu)?;
        assert_eq!(
            back.flatten_all()?.to_vec1::<f32>()?,
            t.flatten_all()?.to_vec1::<f32>()?
        );
        Ok(())
    }

    #[test]
    fn separable_embedding_adds_column_then_row_channels() -> Result<()> {
        let mut m = FeatureMap::zeros(1, 2, 3, 3);
        let column: Vec<Vec<f32>> = (0..3).map(|x| vec![x as f32, 10.0 * x as f32]).collect();
        let row: Vec<Vec<f32>> = (0..2).map(|y| vec![100.0 * y as f32]).collect();
        m.add_separable(&column, &row)?;
        // pixel (y=1, x=2)
        assert_eq!(&m.data[(3 + 2) * 3..(3 + 2) * 3 + 3], &[2.0, 20.0, 100.0]);
        assert!(m.add_separable(&row, &column).is_err());
        Ok(())
    }
}
