//! Reading a whole safetensors file into candle tensors, BOOL tensors included (candle has no
//! bool dtype: they become u8 0/1), for the inputs of `lhmpp model forward` and the official
//! fixtures (PyTorch writes its masks as BOOL).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::safetensors::Load;
use candle_core::{Device, Tensor};

/// A safetensors file that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum TensorFileError {
    /// The file cannot be read.
    #[error("reading {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not safetensors.
    #[error("parsing {path}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        reason: String,
    },
    /// One tensor cannot be converted.
    #[error("{path}: tensor `{name}`: {source}")]
    Tensor {
        /// The file.
        path: PathBuf,
        /// The tensor.
        name: String,
        /// The cause.
        source: Box<candle_core::Error>,
    },
}

/// Every tensor of `path` on `dev`; BOOL tensors as u8.
pub fn read_safetensors(
    path: &Path,
    dev: &Device,
) -> Result<HashMap<String, Tensor>, TensorFileError> {
    let bytes = std::fs::read(path).map_err(|source| TensorFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let st =
        safetensors::SafeTensors::deserialize(&bytes).map_err(|e| TensorFileError::Format {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    st.tensors()
        .into_iter()
        .map(|(name, view)| {
            let t = match view.dtype() {
                safetensors::Dtype::BOOL => {
                    Tensor::from_vec(view.data().to_vec(), view.shape(), dev)
                }
                _ => view.load(dev),
            };
            t.map(|t| (name.clone(), t))
                .map_err(|source| TensorFileError::Tensor {
                    path: path.to_path_buf(),
                    name,
                    source: Box::new(source),
                })
        })
        .collect()
}

/// The string metadata of a safetensors file (empty when it has none).
pub fn read_metadata(path: &Path) -> Result<HashMap<String, String>, TensorFileError> {
    let bytes = std::fs::read(path).map_err(|source| TensorFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let (_, meta) =
        safetensors::SafeTensors::read_metadata(&bytes).map_err(|e| TensorFileError::Format {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    Ok(meta.metadata().clone().unwrap_or_default())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bool_tensors_are_read_as_u8() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.safetensors");
        let flags = [1u8, 0, 1];
        let vals: Vec<u8> = [1.5f32, -2.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let views = vec![
            (
                "mask",
                safetensors::tensor::TensorView::new(safetensors::Dtype::BOOL, vec![3], &flags)
                    .unwrap(),
            ),
            (
                "x",
                safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![2], &vals)
                    .unwrap(),
            ),
        ];
        let meta = HashMap::from([("k".to_string(), "v".to_string())]);
        safetensors::serialize_to_file(views, Some(meta), &path).unwrap();
        let t = read_safetensors(&path, &Device::Cpu).unwrap();
        assert_eq!(t["mask"].to_vec1::<u8>().unwrap(), vec![1, 0, 1]);
        assert_eq!(t["x"].to_vec1::<f32>().unwrap(), vec![1.5, -2.0]);
        assert_eq!(read_metadata(&path).unwrap()["k"], "v");
        assert!(read_safetensors(&dir.path().join("none"), &Device::Cpu).is_err());
    }
}
