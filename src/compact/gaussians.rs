//! The Gaussians blob of a compact avatar: SPZ's quantisation ([`SpzQuantised`]) in a layout
//! that compresses further, gzip-compressed (so a browser opens it with `DecompressionStream`).
//!
//! Layout before compression (little endian):
//!
//! | bytes | content |
//! | --- | --- |
//! | 4 | `LHCA` |
//! | 1 | version, 1 |
//! | 1 | fraction bits of the positions |
//! | 1 | rotation bits kept (1 to 9; the 9-bit magnitudes are multiples of 2^(9 − bits)) |
//! | 1 | SH degree |
//! | 4 | Gaussian count `n` |
//! | 9 × n | positions: for x, y, z, the byte 0, 1, 2 planes of each coordinate's zigzag delta from the previous Gaussian's (24-bit wrapping; the first from 0) |
//! | n | alphas (SPZ) |
//! | 3 × n | colours (SPZ, r g b per Gaussian) |
//! | 3 × n | scales (SPZ) |
//! | 4 × n | rotations (SPZ v3 smallest-three words) |
//! | 3 × ((d + 1)² − 1) × n | SH rest coefficients (SPZ) |
//!
//! Every value is SPZ's, so the blob converts to an SPZ file without loss
//! ([`super::CompactAvatar::to_spz`]); only the positions' layout differs (deltas in planes
//! instead of interleaved absolute values: on avatars, about half the bytes once compressed).

use super::CompactError;
use crate::splat::{sh_coeff_count, SpzQuantised, MAX_SH_DEGREE, MAX_SPZ_GAUSSIANS};
use std::io::{Read, Write};

const MAGIC: &[u8; 4] = b"LHCA";
const VERSION: u8 = 1;
const HEADER: usize = 12;
/// 24-bit wrap-around.
const MASK: i32 = 0xff_ffff;

/// Sign-extends a 24-bit value.
fn sign_extend(v: i32) -> i32 {
    (v << 8) >> 8
}

fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

fn unzigzag(z: u32) -> i32 {
    ((z >> 1) as i32) ^ -((z & 1) as i32)
}

/// Rounds the three 9-bit magnitudes of a smallest-three word to `bits` bits.
pub(super) fn snap_rotation(word: u32, bits: u8) -> u32 {
    if bits >= 9 {
        return word;
    }
    let step = 1u32 << (9 - bits);
    let mut out = word & (0b11 << 30);
    for field in 0..3 {
        let shift = 10 * field;
        let v = (word >> shift) & 0x3ff;
        let magnitude = v & 511;
        let snapped = (((magnitude + step / 2) / step) * step).min(511 / step * step);
        let sign = if snapped == 0 { 0 } else { v & 512 };
        out |= (sign | snapped) << shift;
    }
    out
}

/// The gzip blob of `q`, whose rotation words are snapped to `rotation_bits`.
pub(super) fn encode(q: &SpzQuantised, rotation_bits: u8) -> Result<Vec<u8>, CompactError> {
    let n = q.len();
    let k = sh_coeff_count(q.sh_degree);
    let mut raw = Vec::with_capacity(HEADER + n * (20 + 3 * (k - 1)));
    raw.extend_from_slice(MAGIC);
    raw.extend_from_slice(&[VERSION, q.fractional_bits, rotation_bits, q.sh_degree as u8]);
    raw.extend_from_slice(&(n as u32).to_le_bytes());
    for axis in 0..3 {
        let deltas: Vec<u32> = (0..n)
            .map(|i| {
                let previous = if i == 0 { 0 } else { q.positions[i - 1][axis] };
                zigzag(sign_extend((q.positions[i][axis] - previous) & MASK))
            })
            .collect();
        for byte in 0..3 {
            raw.extend(deltas.iter().map(|d| (d >> (8 * byte)) as u8));
        }
    }
    raw.extend_from_slice(&q.alphas);
    raw.extend(q.colors.iter().flatten());
    raw.extend(q.scales.iter().flatten());
    for &r in &q.rotations {
        raw.extend_from_slice(&snap_rotation(r, rotation_bits).to_le_bytes());
    }
    raw.extend_from_slice(&q.sh_rest);
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    gz.write_all(&raw)
        .map_err(|e| CompactError::Gzip("Gaussians", e))?;
    gz.finish().map_err(|e| CompactError::Gzip("Gaussians", e))
}

/// The quantised Gaussians of a blob. Allocates no more than the blob holds.
pub(super) fn decode(blob: &[u8]) -> Result<SpzQuantised, CompactError> {
    let bad = |what: String| CompactError::Gaussians(what);
    let cap =
        (HEADER + MAX_SPZ_GAUSSIANS * (20 + 3 * (sh_coeff_count(MAX_SH_DEGREE) - 1))) as u64 + 1;
    let mut raw = Vec::new();
    flate2::read::GzDecoder::new(blob)
        .take(cap)
        .read_to_end(&mut raw)
        .map_err(|e| CompactError::Gzip("Gaussians", e))?;
    if raw.len() < HEADER || &raw[0..4] != MAGIC {
        return Err(bad("not an LHCA Gaussians blob".into()));
    }
    let (version, fractional_bits, rotation_bits, sh_degree) =
        (raw[4], raw[5], raw[6], raw[7] as usize);
    if version != VERSION {
        return Err(bad(format!("version {version} (1 is read)")));
    }
    if fractional_bits > 23 || !(1..=9).contains(&rotation_bits) || sh_degree > MAX_SH_DEGREE {
        return Err(bad(format!(
            "{fractional_bits} fraction bits (at most 23), {rotation_bits} rotation bits (1 to \
             9), SH degree {sh_degree} (at most {MAX_SH_DEGREE})"
        )));
    }
    let n = u32::from_le_bytes(raw[8..12].try_into().expect("4 bytes")) as usize;
    let rest = 3 * (sh_coeff_count(sh_degree) - 1);
    let want = n * (20 + rest);
    let body = &raw[HEADER..];
    if n > MAX_SPZ_GAUSSIANS || body.len() != want {
        return Err(bad(format!(
            "{} bytes after the header, {want} expected for {n} Gaussians",
            body.len()
        )));
    }
    let (planes, body) = body.split_at(9 * n);
    let mut positions = vec![[0i32; 3]; n];
    for (axis, plane) in planes.chunks_exact(3 * n).enumerate() {
        let mut value = 0i32;
        for (i, p) in positions.iter_mut().enumerate() {
            let z = (0..3).fold(0u32, |z, b| z | (plane[b * n + i] as u32) << (8 * b));
            value = sign_extend((value + unzigzag(z)) & MASK);
            p[axis] = value;
        }
    }
    let (alphas, body) = body.split_at(n);
    let (colors, body) = body.split_at(3 * n);
    let (scales, body) = body.split_at(3 * n);
    let (rotations, sh_rest) = body.split_at(4 * n);
    Ok(SpzQuantised {
        fractional_bits,
        sh_degree,
        positions,
        alphas: alphas.to_vec(),
        colors: colors.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        scales: scales.chunks_exact(3).map(|s| [s[0], s[1], s[2]]).collect(),
        rotations: rotations
            .chunks_exact(4)
            .map(|r| u32::from_le_bytes([r[0], r[1], r[2], r[3]]))
            .collect(),
        sh_rest: sh_rest.to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_survive_the_delta_planes_across_the_whole_24_bit_range() {
        let q = SpzQuantised {
            fractional_bits: 12,
            sh_degree: 0,
            positions: vec![
                [0, 0, 0],
                [(1 << 23) - 1, -(1 << 23) + 1, 5],
                [-(1 << 23) + 1, (1 << 23) - 1, -5],
                [17, -3, 1_000_000],
            ],
            alphas: vec![1, 2, 3, 4],
            colors: vec![[1, 2, 3]; 4],
            scales: vec![[9, 8, 7]; 4],
            rotations: vec![0xc000_0000, 0x4010_0401, 0x8000_0000, 0x0123_4567],
            sh_rest: Vec::new(),
        };
        let back = decode(&encode(&q, 9).unwrap()).unwrap();
        assert_eq!(back, q);
        let e = decode(b"nope").unwrap_err().to_string();
        assert!(e.contains("gzip"), "{e}");
    }

    #[test]
    fn snapped_rotations_keep_their_index_and_round_each_magnitude() {
        // Largest index 3, magnitudes 511, 6, 1 with signs on all three.
        let word = (3 << 30) | ((512 | 511) << 20) | ((512 | 6) << 10) | (512 | 1);
        let snapped = snap_rotation(word, 7);
        assert_eq!(snapped >> 30, 3);
        assert_eq!(
            (snapped >> 20) & 0x3ff,
            512 | 508,
            "511 → the largest multiple of 4"
        );
        assert_eq!((snapped >> 10) & 0x3ff, 512 | 8);
        assert_eq!(snapped & 0x3ff, 0, "1 → 0, and zero carries no sign");
        assert_eq!(snap_rotation(word, 9), word);
    }
}
