//! Skinning weights from `weights.default.json` reduced to the top 4 influences per vertex.

use crate::body::{BodyError, SkinWeights, MAX_INFLUENCES};
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};

#[derive(Deserialize)]
struct WeightsFile {
    weights: BTreeMap<String, Vec<(usize, f32)>>,
}

/// Keeps the `MAX_INFLUENCES` largest `(bone, weight)` pairs (ties by bone index), merging
/// duplicate bones and dropping non-positive weights, renormalised to sum to 1. `None` when
/// no positive weight is left.
pub fn top_k(influences: &[(u16, f32)]) -> Option<([u16; MAX_INFLUENCES], [f32; MAX_INFLUENCES])> {
    let mut merged: Vec<(u16, f32)> = Vec::with_capacity(influences.len());
    for &(b, w) in influences {
        match merged.iter_mut().find(|(mb, _)| *mb == b) {
            Some(m) => m.1 += w,
            None => merged.push((b, w)),
        }
    }
    merged.retain(|(_, w)| *w > 0.0);
    merged.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    merged.truncate(MAX_INFLUENCES);
    let total: f32 = merged.iter().map(|(_, w)| w).sum();
    if merged.is_empty() || total <= 0.0 {
        return None;
    }
    let (mut bones, mut weights) = ([0u16; MAX_INFLUENCES], [0f32; MAX_INFLUENCES]);
    for (k, (b, w)) in merged.iter().enumerate() {
        bones[k] = *b;
        weights[k] = w / total;
    }
    Some((bones, weights))
}

/// Parses the weights file and builds top-4 weights for the kept source vertices
/// (`kept[i]` = source vertex index of template vertex `i`).
pub fn skin_weights(
    text: &str,
    origin: &str,
    bone_order: &[String],
    kept: &[usize],
) -> Result<SkinWeights, BodyError> {
    let file: WeightsFile =
        serde_json::from_str(text).map_err(|e| BodyError::format(origin, e.to_string()))?;
    let bone_index: HashMap<&str, u16> = bone_order
        .iter()
        .enumerate()
        .map(|(i, b)| (b.as_str(), i as u16))
        .collect();
    let remap: HashMap<usize, usize> = kept.iter().enumerate().map(|(i, &s)| (s, i)).collect();
    let mut per_vertex: Vec<Vec<(u16, f32)>> = vec![Vec::new(); kept.len()];
    for (bone, list) in &file.weights {
        let b = *bone_index.get(bone.as_str()).ok_or_else(|| {
            BodyError::format(origin, format!("weights for unknown bone `{bone}`"))
        })?;
        for &(v, w) in list {
            if let Some(&i) = remap.get(&v) {
                per_vertex[i].push((b, w));
            }
        }
    }
    let mut skin = SkinWeights::default();
    for (i, infl) in per_vertex.iter().enumerate() {
        let (b, w) = top_k(infl).ok_or_else(|| {
            BodyError::format(
                origin,
                format!("source vertex {} has no positive weight", kept[i]),
            )
        })?;
        skin.bones.push(b);
        skin.weights.push(w);
    }
    Ok(skin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn top_k_keeps_the_four_largest_and_renormalises() {
        let (b, w) =
            top_k(&[(0, 0.1), (1, 0.4), (2, 0.05), (3, 0.2), (4, 0.25), (1, 0.0)]).unwrap();
        assert_eq!(b, [1, 4, 3, 0]);
        let total = 0.4 + 0.25 + 0.2 + 0.1;
        assert!((w[0] - 0.4 / total).abs() < 1e-6);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn no_positive_weight_gives_none() {
        assert!(top_k(&[(0, 0.0)]).is_none());
    }
}
