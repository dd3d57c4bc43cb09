//! Reading a perception weights file: a safetensors file whose metadata holds the format tag
//! and version, the source model's name, hash and licence, and the graph (JSON); its tensors
//! are the graph's weights in float16, dense or as non-zero values plus a bit mask.

use std::collections::{HashMap, HashSet};

use safetensors::{Dtype, SafeTensors};

use super::graph::{GraphDef, WeightStorage};
use crate::perception::PerceptionError;

/// The `format` metadata value of a perception weights file.
pub const FORMAT: &str = "lhmpp-perception-graph";

/// The `format_version` this build reads.
pub const FORMAT_VERSION: &str = "1";

/// A parsed weights file.
#[derive(Debug)]
pub(crate) struct WeightsFile {
    /// The graph.
    pub graph: GraphDef,
    /// Every weight, dense f32 in row-major order, by name.
    pub weights: HashMap<String, Vec<f32>>,
    /// The source model file's name.
    pub source_file: String,
    /// The source model file's sha256.
    pub source_sha256: String,
}

/// Parses and checks `bytes`; `origin` names the file in errors.
pub(crate) fn read(bytes: &[u8], origin: &str) -> Result<WeightsFile, PerceptionError> {
    let fail = |reason: String| PerceptionError::format(origin, reason);
    let (_, meta) = SafeTensors::read_metadata(bytes)
        .map_err(|e| fail(format!("not a safetensors file: {e}")))?;
    let meta = meta
        .metadata()
        .clone()
        .ok_or_else(|| fail("no metadata: not a perception weights file".into()))?;
    let field = |key: &str| {
        meta.get(key)
            .cloned()
            .ok_or_else(|| fail(format!("metadata field `{key}` is missing")))
    };
    let format = field("format")?;
    if format != FORMAT {
        return Err(fail(format!("format `{format}`, expected `{FORMAT}`")));
    }
    let version = field("format_version")?;
    if version != FORMAT_VERSION {
        return Err(fail(format!(
            "format version {version}; this build reads version {FORMAT_VERSION} \
             (regenerate with scripts/perception/convert.py)"
        )));
    }
    let source_file = field("source_file")?;
    let source_sha256 = field("source_sha256")?;
    field("licence")?;
    let graph: GraphDef = serde_json::from_str(&field("graph")?)
        .map_err(|e| fail(format!("metadata `graph`: {e}")))?;
    let tensors = SafeTensors::deserialize(bytes).map_err(|e| fail(format!("tensors: {e}")))?;
    let mut used = HashSet::new();
    let mut weights = HashMap::new();
    for (name, def) in &graph.weights {
        let count: usize = def.shape.iter().product();
        let values = match def.storage {
            WeightStorage::Dense => {
                used.insert(name.clone());
                f16_tensor(&tensors, name, Some(&def.shape)).map_err(&fail)?
            }
            WeightStorage::Bitmask => {
                let (vname, mname) = (format!("{name}.values"), format!("{name}.mask"));
                used.insert(vname.clone());
                used.insert(mname.clone());
                let values = f16_tensor(&tensors, &vname, None).map_err(&fail)?;
                let mask = tensors
                    .tensor(&mname)
                    .map_err(|e| fail(format!("weight `{mname}`: {e}")))?;
                if mask.dtype() != Dtype::U8 || mask.shape() != [count.div_ceil(8)] {
                    return Err(fail(format!(
                        "weight `{mname}` is {:?} {:?}, expected U8 [{}]",
                        mask.dtype(),
                        mask.shape(),
                        count.div_ceil(8)
                    )));
                }
                expand(&values, mask.data(), count)
                    .ok_or_else(|| fail(format!("weight `{name}`: mask and values disagree")))?
            }
        };
        weights.insert(name.clone(), values);
    }
    if let Some(extra) = tensors.names().into_iter().find(|n| !used.contains(*n)) {
        return Err(fail(format!(
            "tensor `{extra}` is not a weight of the graph"
        )));
    }
    Ok(WeightsFile {
        graph,
        weights,
        source_file,
        source_sha256,
    })
}

/// The f32 values of F16 tensor `name`, checked against `shape` when given.
fn f16_tensor(t: &SafeTensors, name: &str, shape: Option<&[usize]>) -> Result<Vec<f32>, String> {
    let view = t
        .tensor(name)
        .map_err(|e| format!("weight `{name}`: {e}"))?;
    if view.dtype() != Dtype::F16 || view.shape().len() != shape.map_or(1, |s| s.len()) {
        return Err(format!(
            "weight `{name}` is {:?} {:?}, expected F16 {}",
            view.dtype(),
            view.shape(),
            shape.map_or("[n]".to_string(), |s| format!("{s:?}"))
        ));
    }
    if let Some(s) = shape {
        if view.shape() != s {
            return Err(format!(
                "weight `{name}` has shape {:?}, the graph says {s:?}",
                view.shape()
            ));
        }
    }
    Ok(view
        .data()
        .chunks_exact(2)
        .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
        .collect())
}

/// The dense values of `count` elements whose non-zero `values` sit where `mask`'s bits are
/// set (least significant bit first); `None` when the counts disagree.
fn expand(values: &[f32], mask: &[u8], count: usize) -> Option<Vec<f32>> {
    let set: usize = mask.iter().map(|b| b.count_ones() as usize).sum();
    let tail_clear = count % 8 == 0 || mask.last().is_some_and(|b| b >> (count % 8) == 0);
    if set != values.len() || !tail_clear {
        return None;
    }
    let mut out = vec![0.0; count];
    let mut next = values.iter();
    for (i, o) in out.iter_mut().enumerate() {
        if mask[i / 8] >> (i % 8) & 1 == 1 {
            *o = *next.next()?;
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bitmask_expansion_places_values_and_checks_counts() {
        let mask = [0b0000_0101u8, 0b0000_0010];
        assert_eq!(
            expand(&[1.0, 2.0, 3.0], &mask, 10),
            Some(vec![1.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0])
        );
        assert_eq!(expand(&[1.0, 2.0], &mask, 10), None);
        // a set bit past the end
        assert_eq!(expand(&[1.0, 2.0, 3.0], &[0b101, 0b100], 10), None);
    }
}
