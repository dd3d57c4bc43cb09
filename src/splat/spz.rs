//! SPZ, Niantic's compressed Gaussian-splat format (MIT), version 3, written and read here
//! from the published layout: a 16-byte header, then every Gaussian's position, then every
//! alpha, colour, scale, rotation and SH rest coefficient (one array per attribute), the whole
//! gzip-compressed.
//!
//! | attribute | bytes per Gaussian | encoding |
//! | --- | --- | --- |
//! | position | 9 | 3 × 24-bit signed fixed point, `fractional_bits` fraction bits |
//! | alpha | 1 | opacity × 255 |
//! | colour | 3 | SH DC coefficient × 0.15 × 255 + 127.5 |
//! | scale | 3 | (ln σ + 10) × 16 |
//! | rotation | 4 | "smallest three": index of the largest component (2 bits), the other three as 9-bit magnitudes over 1/√2 with a sign bit each |
//! | SH rest | 3 × ((d + 1)² − 1) | x × 128 + 128, coefficient-major, channels inner |
//!
//! Positions are in the Gaussians' own frame (SPZ's files are right-up-back; this crate's
//! canonical frame, +Y up and facing +Z, is that frame already). Feature channels are not
//! carried.

use super::{GaussianError, Gaussians, MAX_SH_DEGREE};
use glam::{Quat, Vec3};
use std::io::{Read, Write};
use thiserror::Error;

/// `NGSP` read as a little-endian u32.
const MAGIC: u32 = 0x5053_474e;
/// The version written: 3 (smallest-three rotations).
const VERSION: u32 = 3;
/// Header bytes.
const HEADER: usize = 16;
/// SPZ's colour scale (`colorScale` in the reference code).
const COLOR_SCALE: f32 = 0.15;
/// Position fraction bits written by default: 1/4096 m steps, ±2 km range.
pub const DEFAULT_FRACTIONAL_BITS: u8 = 12;
/// Largest Gaussian count read back (bounds the allocation a header can ask for).
pub const MAX_SPZ_GAUSSIANS: usize = 10_000_000;

/// Why SPZ bytes cannot be written or read.
#[derive(Debug, Error)]
pub enum SpzError {
    /// Not gzip, or the gzip stream is damaged.
    #[error("SPZ: gzip stream: {0}")]
    Gzip(std::io::Error),
    /// The header is not SPZ's or names something this reader does not handle.
    #[error("SPZ header: {0}")]
    Header(String),
    /// Fewer bytes than the header promises.
    #[error("SPZ: {actual} bytes after the header, {expected} expected for {count} Gaussians")]
    Truncated {
        /// Bytes found.
        actual: usize,
        /// Bytes the header implies.
        expected: usize,
        /// Gaussians in the header.
        count: usize,
    },
    /// The Gaussians to write, or those read, are malformed.
    #[error("SPZ: {0}")]
    Gaussians(#[from] GaussianError),
}

/// Bytes of one Gaussian's attributes before compression.
fn bytes_per_gaussian(sh_degree: usize) -> usize {
    9 + 1 + 3 + 3 + 4 + 3 * (super::sh_coeff_count(sh_degree) - 1)
}

fn to_u8(x: f32) -> u8 {
    x.round().clamp(0.0, 255.0) as u8
}

/// Gaussians quantised as SPZ stores them, one entry per Gaussian, before any layout or
/// compression: what both [`write_spz`] and the compact avatar's own layout write.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SpzQuantised {
    /// Fraction bits of the fixed-point positions.
    pub fractional_bits: u8,
    /// SH degree of the colours.
    pub sh_degree: usize,
    /// Positions in `1 / 2^fractional_bits` steps (24-bit range).
    pub positions: Vec<[i32; 3]>,
    /// Opacity × 255.
    pub alphas: Vec<u8>,
    /// SH DC coefficient × 0.15 × 255 + 127.5, per channel.
    pub colors: Vec<[u8; 3]>,
    /// (ln σ + 10) × 16, per axis.
    pub scales: Vec<[u8; 3]>,
    /// Smallest-three rotation words (see [`pack_rotation`]).
    pub rotations: Vec<u32>,
    /// SH rest coefficients × 128 + 128, `3 × ((d + 1)² − 1)` per Gaussian.
    pub sh_rest: Vec<u8>,
}

impl SpzQuantised {
    /// Quantises `g` with positions at `fractional_bits` fraction bits (coordinates beyond
    /// ±2^(23 − fractional_bits) are clamped).
    pub fn from_gaussians(g: &Gaussians, fractional_bits: u8) -> Result<Self, SpzError> {
        g.validate()?;
        if fractional_bits > 23 {
            return Err(SpzError::Header(format!(
                "{fractional_bits} fractional bits (at most 23)"
            )));
        }
        let unit = (1u32 << fractional_bits) as f32;
        let limit = (1i32 << 23) - 1;
        let k = g.sh_per_gaussian();
        Ok(Self {
            fractional_bits,
            sh_degree: g.sh_degree,
            positions: g
                .positions
                .iter()
                .map(|p| {
                    p.to_array()
                        .map(|c| ((c * unit).round() as i32).clamp(-limit, limit))
                })
                .collect(),
            alphas: g.opacities.iter().map(|a| to_u8(a * 255.0)).collect(),
            colors: (0..g.len())
                .map(|i| g.sh_of(i)[0].map(|c| to_u8(c * (COLOR_SCALE * 255.0) + 0.5 * 255.0)))
                .collect(),
            scales: g
                .scales
                .iter()
                .map(|s| {
                    s.to_array()
                        .map(|v| to_u8((v.max(1e-30).ln() + 10.0) * 16.0))
                })
                .collect(),
            rotations: g.rotations.iter().map(|q| pack_rotation(*q)).collect(),
            sh_rest: (0..g.len())
                .flat_map(|i| {
                    g.sh_of(i)[1..k]
                        .iter()
                        .flat_map(|c| c.map(|v| to_u8(v * 128.0 + 128.0)))
                })
                .collect(),
        })
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// The Gaussians these values stand for. Fails when the arrays disagree in length.
    pub fn to_gaussians(&self) -> Result<Gaussians, SpzError> {
        let n = self.len();
        let k = super::sh_coeff_count(self.sh_degree);
        let rest = 3 * (k - 1);
        let consistent = [
            self.alphas.len(),
            self.colors.len(),
            self.scales.len(),
            self.rotations.len(),
        ]
        .iter()
        .all(|&l| l == n)
            && self.sh_rest.len() == n * rest;
        if self.sh_degree > MAX_SH_DEGREE || self.fractional_bits > 23 || !consistent {
            return Err(SpzError::Header(format!(
                "{n} positions with {} alphas, {} colours, {} scales, {} rotations, {} SH rest \
                 values, SH degree {}, {} fractional bits",
                self.alphas.len(),
                self.colors.len(),
                self.scales.len(),
                self.rotations.len(),
                self.sh_rest.len(),
                self.sh_degree,
                self.fractional_bits
            )));
        }
        let unit = 1.0 / (1u32 << self.fractional_bits) as f32;
        let mut sh = Vec::with_capacity(n * k);
        for i in 0..n {
            sh.push(self.colors[i].map(|c| (c as f32 / 255.0 - 0.5) / COLOR_SCALE));
            for c in self.sh_rest[rest * i..rest * (i + 1)].chunks_exact(3) {
                sh.push([c[0], c[1], c[2]].map(|v| (v as f32 - 128.0) / 128.0));
            }
        }
        let g = Gaussians {
            positions: self
                .positions
                .iter()
                .map(|p| Vec3::from_array(p.map(|c| c as f32 * unit)))
                .collect(),
            scales: self
                .scales
                .iter()
                .map(|s| Vec3::from_array(s.map(|b| (b as f32 / 16.0 - 10.0).exp())))
                .collect(),
            rotations: self.rotations.iter().map(|&r| unpack_rotation(r)).collect(),
            opacities: self.alphas.iter().map(|&a| a as f32 / 255.0).collect(),
            sh_degree: self.sh_degree,
            sh,
            feature_channels: 0,
            features: Vec::new(),
        };
        g.validate()?;
        Ok(g)
    }

    /// The SPZ v3 file of these values (gzip-compressed).
    pub fn to_spz(&self) -> Result<Vec<u8>, SpzError> {
        let n = self.len();
        let mut raw = Vec::with_capacity(HEADER + n * bytes_per_gaussian(self.sh_degree));
        raw.extend_from_slice(&MAGIC.to_le_bytes());
        raw.extend_from_slice(&VERSION.to_le_bytes());
        raw.extend_from_slice(&(n as u32).to_le_bytes());
        raw.extend_from_slice(&[self.sh_degree as u8, self.fractional_bits, 0, 0]);
        for p in &self.positions {
            for c in p {
                raw.extend_from_slice(&c.to_le_bytes()[..3]);
            }
        }
        raw.extend_from_slice(&self.alphas);
        raw.extend(self.colors.iter().flatten());
        raw.extend(self.scales.iter().flatten());
        for r in &self.rotations {
            raw.extend_from_slice(&r.to_le_bytes());
        }
        raw.extend_from_slice(&self.sh_rest);
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        gz.write_all(&raw).map_err(SpzError::Gzip)?;
        gz.finish().map_err(SpzError::Gzip)
    }
}

/// The SPZ v3 bytes (gzip-compressed) of `g`, positions with `fractional_bits` fraction bits
/// (coordinates beyond ±2^(23 − fractional_bits) are clamped).
pub fn write_spz(g: &Gaussians, fractional_bits: u8) -> Result<Vec<u8>, SpzError> {
    SpzQuantised::from_gaussians(g, fractional_bits)?.to_spz()
}

/// "Smallest three": the largest component's index in the top 2 bits, then the other three
/// in index order (x y z w), 10 bits each (sign, 9-bit magnitude over 1/√2), the last in the
/// low bits.
pub fn pack_rotation(q: Quat) -> u32 {
    let q = q.normalize().to_array();
    let largest = (0..4)
        .max_by(|&a, &b| q[a].abs().total_cmp(&q[b].abs()))
        .unwrap_or(3);
    let negate = q[largest] < 0.0;
    let mut packed = largest as u32;
    for (i, &c) in q.iter().enumerate() {
        if i == largest {
            continue;
        }
        let sign = ((c < 0.0) != negate) as u32;
        let magnitude = (511.0 * (c.abs() / std::f32::consts::FRAC_1_SQRT_2) + 0.5)
            .floor()
            .min(511.0) as u32;
        packed = (packed << 10) | (sign << 9) | magnitude;
    }
    packed
}

/// The unit quaternion of a [`pack_rotation`] word.
pub fn unpack_rotation(mut packed: u32) -> Quat {
    let largest = (packed >> 30) as usize;
    let mut q = [0.0f32; 4];
    let mut sum = 0.0;
    for i in (0..4).rev() {
        if i == largest {
            continue;
        }
        let magnitude = (packed & 511) as f32;
        let negative = (packed >> 9) & 1 == 1;
        packed >>= 10;
        let v = std::f32::consts::FRAC_1_SQRT_2 * magnitude / 511.0;
        q[i] = if negative { -v } else { v };
        sum += v * v;
    }
    q[largest] = (1.0 - sum).max(0.0).sqrt();
    Quat::from_array(q).normalize()
}

/// The Gaussians of SPZ bytes (versions 2 and 3, gzip-compressed or not). Allocates no more
/// than the bytes hold.
pub fn read_spz(bytes: &[u8]) -> Result<Gaussians, SpzError> {
    let mut raw = Vec::new();
    if bytes.starts_with(&[0x1f, 0x8b]) {
        // Bounded: the largest SPZ this reader accepts, plus one byte to tell it is larger.
        let cap = (HEADER + MAX_SPZ_GAUSSIANS * bytes_per_gaussian(MAX_SH_DEGREE)) as u64 + 1;
        flate2::read::GzDecoder::new(bytes)
            .take(cap)
            .read_to_end(&mut raw)
            .map_err(SpzError::Gzip)?;
    } else {
        raw.extend_from_slice(bytes);
    }
    if raw.len() < HEADER {
        return Err(SpzError::Header(format!(
            "{} bytes, a header has {HEADER}",
            raw.len()
        )));
    }
    let word = |at: usize| u32::from_le_bytes(raw[at..at + 4].try_into().expect("4 bytes"));
    if word(0) != MAGIC {
        return Err(SpzError::Header(format!(
            "magic {:#010x}, not NGSP ({MAGIC:#010x})",
            word(0)
        )));
    }
    let version = word(4);
    if !(2..=3).contains(&version) {
        return Err(SpzError::Header(format!(
            "version {version} (2 and 3 are read)"
        )));
    }
    let n = word(8) as usize;
    let (sh_degree, fractional_bits) = (raw[12] as usize, raw[13]);
    if n > MAX_SPZ_GAUSSIANS || sh_degree > MAX_SH_DEGREE || fractional_bits > 23 {
        return Err(SpzError::Header(format!(
            "{n} Gaussians (at most {MAX_SPZ_GAUSSIANS}), SH degree {sh_degree} (at most \
             {MAX_SH_DEGREE}), {fractional_bits} fractional bits (at most 23)"
        )));
    }
    let rotation_bytes = if version == 3 { 4 } else { 3 };
    let k = super::sh_coeff_count(sh_degree);
    let per = 9 + 1 + 3 + 3 + rotation_bytes + 3 * (k - 1);
    let body = &raw[HEADER..];
    if body.len() < n * per {
        return Err(SpzError::Truncated {
            actual: body.len(),
            expected: n * per,
            count: n,
        });
    }
    let (positions, rest) = body.split_at(9 * n);
    let (alphas, rest) = rest.split_at(n);
    let (colors, rest) = rest.split_at(3 * n);
    let (scales, rest) = rest.split_at(3 * n);
    let (rotations, rest) = rest.split_at(rotation_bytes * n);
    let coordinate =
        |b: &[u8]| i32::from_le_bytes([b[0], b[1], b[2], if b[2] & 0x80 != 0 { 0xff } else { 0 }]);
    let q = SpzQuantised {
        fractional_bits,
        sh_degree,
        positions: positions
            .chunks_exact(9)
            .map(|p| {
                [
                    coordinate(&p[0..3]),
                    coordinate(&p[3..6]),
                    coordinate(&p[6..9]),
                ]
            })
            .collect(),
        alphas: alphas.to_vec(),
        colors: colors.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        scales: scales.chunks_exact(3).map(|s| [s[0], s[1], s[2]]).collect(),
        rotations: rotations
            .chunks_exact(rotation_bytes)
            .map(|r| match version {
                3 => u32::from_le_bytes([r[0], r[1], r[2], r[3]]),
                _ => {
                    let xyz = Vec3::from_array([r[0], r[1], r[2]].map(|b| b as f32 / 127.5 - 1.0));
                    let w = (1.0 - xyz.length_squared()).max(0.0).sqrt();
                    pack_rotation(Quat::from_xyzw(xyz.x, xyz.y, xyz.z, w))
                }
            })
            .collect(),
        sh_rest: rest[..3 * (k - 1) * n].to_vec(),
    };
    q.to_gaussians()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splat::rgb_to_sh_dc;

    fn sample(n: usize) -> Gaussians {
        let mut g = Gaussians::default();
        for i in 0..n {
            let t = i as f32 / n as f32;
            g.positions
                .push(Vec3::new(t - 0.5, 1.7 * t, -0.3 + 0.6 * (7.0 * t).sin()));
            g.scales
                .push(Vec3::new(0.002 + 0.01 * t, 0.004, 0.03 * (1.0 - t) + 1e-4));
            g.rotations.push(
                Quat::from_euler(glam::EulerRot::XYZ, 3.0 * t, -2.0 * t, 5.0 * t).normalize(),
            );
            g.opacities.push(t);
            g.sh.push(rgb_to_sh_dc(Vec3::new(t, 1.0 - t, 0.5)));
        }
        g
    }

    #[test]
    fn a_round_trip_keeps_every_attribute_within_its_quantisation_step() {
        let g = sample(500);
        let bytes = write_spz(&g, DEFAULT_FRACTIONAL_BITS).unwrap();
        assert_eq!(&bytes[..2], &[0x1f, 0x8b], "gzip");
        let back = read_spz(&bytes).unwrap();
        assert_eq!(back.len(), g.len());
        for i in 0..g.len() {
            let dp = (back.positions[i] - g.positions[i]).abs().max_element();
            assert!(dp <= 0.5 / 4096.0 + 1e-6, "position {i}: {dp}");
            let ds = (back.scales[i] / g.scales[i]).to_array();
            for r in ds {
                // Half a step of 1/16 in ln σ.
                assert!((r.ln()).abs() <= 1.0 / 32.0 + 1e-4, "scale {i}: ratio {r}");
            }
            let dot = back.rotations[i].dot(g.rotations[i]).abs();
            assert!(dot > 0.9999, "rotation {i}: |q·q'| {dot}");
            assert!((back.opacities[i] - g.opacities[i]).abs() <= 0.5 / 255.0 + 1e-6);
            let rgb = crate::splat::sh_dc_to_rgb(back.sh[i]);
            let want = crate::splat::sh_dc_to_rgb(g.sh[i]);
            // One colour byte is 1 / (255 · 0.15 / SH_C0) ≈ 0.0074 of RGB.
            assert!((rgb - want).abs().max_element() <= 0.0038, "colour {i}");
        }
    }

    #[test]
    fn the_header_and_the_layout_are_spz_version_3() {
        let g = sample(3);
        let mut raw = Vec::new();
        flate2::read::GzDecoder::new(&write_spz(&g, 12).unwrap()[..])
            .read_to_end(&mut raw)
            .unwrap();
        assert_eq!(&raw[0..4], b"NGSP");
        assert_eq!(u32::from_le_bytes(raw[4..8].try_into().unwrap()), 3);
        assert_eq!(u32::from_le_bytes(raw[8..12].try_into().unwrap()), 3);
        assert_eq!(&raw[12..16], &[0, 12, 0, 0]);
        assert_eq!(raw.len(), HEADER + 3 * 20);
        // The second Gaussian's x: 1/3 − 0.5 in 1/4096 steps, 24-bit little endian.
        let x = i32::from_le_bytes([raw[25], raw[26], raw[27], 0xff]);
        assert_eq!(x, ((1.0f32 / 3.0 - 0.5) * 4096.0).round() as i32);
    }

    #[test]
    fn higher_sh_degrees_round_trip() {
        let mut g = sample(4);
        g.sh_degree = 1;
        g.sh = (0..4)
            .flat_map(|i| {
                [
                    [0.1 * i as f32, 0.0, 0.0],
                    [0.25, -0.5, 0.75],
                    [0.0; 3],
                    [-0.99, 0.5, 0.1],
                ]
            })
            .collect();
        let back = read_spz(&write_spz(&g, 12).unwrap()).unwrap();
        assert_eq!(back.sh_degree, 1);
        for (a, b) in back.sh.iter().zip(&g.sh).skip(1) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() <= 0.5 / 128.0 + 0.05, "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn damaged_bytes_are_refused_with_a_reason() {
        let bytes = write_spz(&sample(10), 12).unwrap();
        let e = read_spz(&bytes[..bytes.len() / 2]).unwrap_err().to_string();
        assert!(e.contains("gzip"), "{e}");
        let e = read_spz(b"not an spz file at all").unwrap_err().to_string();
        assert!(e.contains("magic"), "{e}");
        let mut raw = Vec::new();
        flate2::read::GzDecoder::new(&bytes[..])
            .read_to_end(&mut raw)
            .unwrap();
        let e = read_spz(&raw[..raw.len() - 5]).unwrap_err().to_string();
        assert!(e.contains("expected for 10 Gaussians"), "{e}");
        raw[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = read_spz(&raw).unwrap_err().to_string();
        assert!(e.contains("at most"), "{e}");
    }
}
