//! The skin blob of a compact avatar: each Gaussian's 4 bone indices and weights, quantised
//! and gzip-compressed (gzip, like SPZ, so a browser opens it with `DecompressionStream`).
//!
//! Layout before compression (little endian):
//!
//! | bytes | content |
//! | --- | --- |
//! | 4 | `LHSK` |
//! | 1 | version, 1 |
//! | 1 | bytes per bone index: 1 (fewer than 256 bones) or 2 |
//! | 1 | weight levels `L` (1 to 255): weights are stored in `1/L` steps |
//! | 1 | zero |
//! | 4 | Gaussian count `n` |
//! | 4 × n × index bytes | slot 0's bone of every Gaussian, then slot 1's, 2's, 3's |
//! | 3 × n | slot 0's weight × `L` of every Gaussian, then slot 1's, 2's (slot 3's is `L` minus their sum) |
//!
//! Each Gaussian's slots are sorted by bone index (zero-weight slots last, bone 0), so that
//! neighbours bound to the same bones repeat the same bytes.

use crate::body::{SkinWeights, MAX_INFLUENCES};
use std::io::{Read, Write};

use super::CompactError;

const MAGIC: &[u8; 4] = b"LHSK";
const VERSION: u8 = 1;
const HEADER: usize = 12;

/// The quantised slots of one Gaussian: bones sorted (zero weights last) and weights in
/// `levels`ths summing to exactly `levels` (largest remainders).
pub(super) fn quantise(
    bones: &[u16; MAX_INFLUENCES],
    weights: &[f32; MAX_INFLUENCES],
    levels: u8,
) -> ([u16; 4], [u8; 4]) {
    let total: f32 = weights.iter().sum();
    let scaled = weights.map(|w| w / total * levels as f32);
    let mut q = scaled.map(|s| s.floor() as i32);
    let mut left = levels as i32 - q.iter().sum::<i32>();
    let mut order = [0usize, 1, 2, 3];
    order.sort_by(|&a, &b| {
        (scaled[b] - scaled[b].floor()).total_cmp(&(scaled[a] - scaled[a].floor()))
    });
    for &k in order.iter().cycle() {
        if left <= 0 {
            break;
        }
        q[k] += 1;
        left -= 1;
    }
    let mut slots: Vec<(u16, u8)> = (0..MAX_INFLUENCES)
        .map(|k| {
            if q[k] > 0 {
                (bones[k], q[k] as u8)
            } else {
                (0, 0)
            }
        })
        .collect();
    slots.sort_by_key(|&(b, w)| (w == 0, b));
    (
        [0, 1, 2, 3].map(|k| slots[k].0),
        [0, 1, 2, 3].map(|k| slots[k].1),
    )
}

/// The gzip-compressed skin blob of `skin`, Gaussians in the given order, weights in
/// `levels` steps.
pub(super) fn encode(
    skin: &SkinWeights,
    order: &[u32],
    levels: u8,
) -> Result<Vec<u8>, CompactError> {
    if levels == 0 {
        return Err(CompactError::Skin("0 weight levels".into()));
    }
    let n = order.len();
    let wide = skin.bones.iter().flatten().any(|&b| b > 255);
    let index_bytes = if wide { 2 } else { 1 };
    let quantised: Vec<([u16; 4], [u8; 4])> = order
        .iter()
        .map(|&i| quantise(&skin.bones[i as usize], &skin.weights[i as usize], levels))
        .collect();
    let mut raw = Vec::with_capacity(HEADER + n * (4 * index_bytes + 3));
    raw.extend_from_slice(MAGIC);
    raw.extend_from_slice(&[VERSION, index_bytes as u8, levels, 0]);
    raw.extend_from_slice(&(n as u32).to_le_bytes());
    for k in 0..MAX_INFLUENCES {
        for (bones, _) in &quantised {
            raw.extend_from_slice(&bones[k].to_le_bytes()[..index_bytes]);
        }
    }
    for k in 0..3 {
        raw.extend(quantised.iter().map(|(_, w)| w[k]));
    }
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    gz.write_all(&raw)
        .map_err(|e| CompactError::Gzip("skin", e))?;
    gz.finish().map_err(|e| CompactError::Gzip("skin", e))
}

/// The skin of a blob, for `expected` Gaussians.
pub(super) fn decode(blob: &[u8], expected: usize) -> Result<SkinWeights, CompactError> {
    let bad = |what: String| CompactError::Skin(what);
    let mut raw = Vec::new();
    // At most what `expected` Gaussians take, plus one byte to tell a longer blob.
    let cap = (HEADER + expected * (4 * 2 + 3)) as u64 + 1;
    flate2::read::GzDecoder::new(blob)
        .take(cap)
        .read_to_end(&mut raw)
        .map_err(|e| CompactError::Gzip("skin", e))?;
    if raw.len() < HEADER || &raw[0..4] != MAGIC {
        return Err(bad("not an LHSK skin blob".into()));
    }
    if raw[4] != VERSION {
        return Err(bad(format!("version {} (1 is read)", raw[4])));
    }
    let index_bytes = raw[5] as usize;
    if !(1..=2).contains(&index_bytes) {
        return Err(bad(format!("{index_bytes} bytes per bone index (1 or 2)")));
    }
    let levels = raw[6] as u32;
    if levels == 0 {
        return Err(bad("0 weight levels".into()));
    }
    let n = u32::from_le_bytes(raw[8..12].try_into().expect("4 bytes")) as usize;
    if n != expected {
        return Err(bad(format!("{n} Gaussians, the splats have {expected}")));
    }
    let body = &raw[HEADER..];
    let want = n * (4 * index_bytes + 3);
    if body.len() != want {
        return Err(bad(format!(
            "{} bytes after the header, {want} expected for {n} Gaussians",
            body.len()
        )));
    }
    let (bone_planes, weight_planes) = body.split_at(4 * n * index_bytes);
    let bone = |k: usize, i: usize| {
        let at = (k * n + i) * index_bytes;
        match index_bytes {
            1 => bone_planes[at] as u16,
            _ => u16::from_le_bytes([bone_planes[at], bone_planes[at + 1]]),
        }
    };
    let mut skin = SkinWeights {
        bones: Vec::with_capacity(n),
        weights: Vec::with_capacity(n),
    };
    for i in 0..n {
        let w3 = [0, 1, 2].map(|k| weight_planes[k * n + i] as u32);
        let sum: u32 = w3.iter().sum();
        if sum > levels {
            return Err(bad(format!("Gaussian {i}: weights sum to {sum}/{levels}")));
        }
        let w = [w3[0], w3[1], w3[2], levels - sum].map(|q| q as f32 / levels as f32);
        skin.bones.push([0, 1, 2, 3].map(|k| bone(k, i)));
        skin.weights.push(w);
    }
    Ok(skin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantised_weights_sum_to_255_and_keep_their_bones() {
        let (b, w) = quantise(&[7, 3, 9, 1], &[0.5, 0.25, 0.0, 0.25], 255);
        assert_eq!(w.iter().map(|&x| x as u32).sum::<u32>(), 255);
        assert_eq!(b, [1, 3, 7, 0], "sorted by bone, the zero slot last");
        assert_eq!(w[3], 0);
        assert_eq!(
            w,
            [64, 64, 127, 0],
            "63.75, 63.75, 127.5: the largest remainders round up"
        );
        let (_, w) = quantise(&[0, 1, 2, 3], &[1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0, 0.0], 255);
        assert_eq!(w[..3].iter().map(|&x| x as u32).sum::<u32>(), 255);
        let (_, w) = quantise(&[0, 1, 2, 3], &[0.7, 0.2, 0.1, 0.0], 63);
        assert_eq!(w, [44, 13, 6, 0], "0.7, 0.2, 0.1 of 63, summing to 63");
    }

    #[test]
    fn a_blob_round_trips_within_half_a_step_and_refuses_other_counts() {
        let skin = SkinWeights {
            bones: vec![[0, 1, 0, 0], [300, 2, 5, 0], [4, 4, 4, 4]],
            weights: vec![
                [1.0, 0.0, 0.0, 0.0],
                [0.6, 0.3, 0.1, 0.0],
                [0.25, 0.25, 0.25, 0.25],
            ],
        };
        let blob = encode(&skin, &[2, 0, 1], 255).unwrap();
        let back = decode(&blob, 3).unwrap();
        // Gaussian 0 of the blob is skin row 2, and so on.
        for (j, &i) in [2usize, 0, 1].iter().enumerate() {
            let mut want: Vec<(u16, f32)> = (0..4)
                .filter(|&k| skin.weights[i][k] > 0.0)
                .map(|k| (skin.bones[i][k], skin.weights[i][k]))
                .collect();
            want.sort_by_key(|s| s.0);
            let got: Vec<(u16, f32)> = (0..4)
                .filter(|&k| back.weights[j][k] > 0.0)
                .map(|k| (back.bones[j][k], back.weights[j][k]))
                .collect();
            assert_eq!(got.len(), want.len(), "row {i}");
            for ((gb, gw), (wb, ww)) in got.iter().zip(&want) {
                assert_eq!(gb, wb);
                assert!((gw - ww).abs() <= 1.0 / 255.0, "{gw} {ww}");
            }
        }
        let e = decode(&blob, 4).unwrap_err().to_string();
        assert!(e.contains("3 Gaussians, the splats have 4"), "{e}");
        assert!(decode(b"junk", 3).is_err());
    }
}
