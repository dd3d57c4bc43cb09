//! The two random choices of the official LHM++ inference, as inputs of our forward.
//!
//! The official code draws, at inference too:
//! - after every GridPooling, a permutation of the four serialization orders
//!   (Sonata's `Point.serialization(shuffle_orders=True)`, `torch.randperm(4)`): block i of the
//!   pooled level, and of the decoder level that unpools back to it, attends in
//!   `orders[perm[i % 4]]`;
//! - in every multi-modal block that merges image tokens, ToMe's destination inside each 2×2 cell
//!   (`bipartite_soft_matching_random2d`, `torch.randint(4, (h / 2, w·V / 2, 1))`).
//!
//! Our forward is deterministic: by default every permutation is the identity and every
//! destination is the top-left token of its cell (index 0). Recorded draws replay the official
//! choices exactly (`scripts/parity/official/`).

use std::collections::{HashMap, HashSet};

use candle_core::{DType, Tensor};

/// A draw that does not fit the network it is replayed on.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DrawError {
    /// A pooling-order entry that is not a permutation of `0..orders`.
    #[error("pooling order draw {level}: {perm:?} is not a permutation of 0..{orders}")]
    NotAPermutation {
        /// Index of the GridPooling (0 = the pooling into encoder level 1).
        level: usize,
        /// The entry.
        perm: Vec<usize>,
        /// Number of serialization orders of the backbone.
        orders: usize,
    },
    /// A ToMe draw of the wrong size or with a value outside the cell.
    #[error("ToMe draw {block}: {what}")]
    Destinations {
        /// Multi-modal block (encoder blocks first, then decoder blocks).
        block: usize,
        /// What is wrong.
        what: String,
    },
    /// A draw tensor that is not a 2-D integer tensor with values in range.
    #[error("tensor `{name}`: {what}")]
    Tensor {
        /// `pooling_orders` or `tome_destinations`.
        name: &'static str,
        /// What is wrong.
        what: String,
    },
}

/// Tensor names of the draws in `lhmpp model forward` inputs and the official fixtures.
pub const POOLING_ORDERS: &str = "pooling_orders";
/// See [`POOLING_ORDERS`].
pub const TOME_DESTINATIONS: &str = "tome_destinations";

fn rows(tensors: &HashMap<String, Tensor>, name: &'static str) -> Result<Vec<Vec<i64>>, DrawError> {
    let Some(t) = tensors.get(name) else {
        return Ok(Vec::new());
    };
    let bad = |e: candle_core::Error| DrawError::Tensor {
        name,
        what: e.to_string(),
    };
    if t.dtype().is_float() {
        return Err(DrawError::Tensor {
            name,
            what: format!("{:?}, not an integer dtype", t.dtype()),
        });
    }
    t.to_dtype(DType::I64)
        .and_then(|t| t.to_vec2::<i64>())
        .map_err(bad)
}

/// Cells per side of the ToMe destination grid (`sx = sy = 2`).
pub const CELL: usize = 2;

/// Replayable random choices of one forward pass; the default is the deterministic forward.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ForwardDraws {
    /// One permutation per GridPooling, in encoder order (missing entries: the identity).
    pub pooling_orders: Vec<Vec<usize>>,
    /// One ToMe draw per multi-modal block, encoder blocks first, then decoder blocks, in call
    /// order (missing entries: top-left). Each holds `(h / 2) · (w·V / 2)` values in `0..4`,
    /// row-major over the cells of the `h × w·V` token grid; value k picks the token at
    /// (row `k / 2`, column `k % 2`) of its cell.
    pub tome_destinations: Vec<Vec<u8>>,
}

impl ForwardDraws {
    /// The draws held by `tensors` ([`POOLING_ORDERS`] `[P, 4]`, [`TOME_DESTINATIONS`]
    /// `[B, cells]`, any integer dtype); absent tensors leave the defaults.
    pub fn from_tensors(tensors: &HashMap<String, Tensor>) -> Result<Self, DrawError> {
        let range = |name: &'static str, v: i64, max: i64| {
            (0..max).contains(&v).then_some(v).ok_or(DrawError::Tensor {
                name,
                what: format!("value {v} outside 0..{max}"),
            })
        };
        let pooling_orders = rows(tensors, POOLING_ORDERS)?
            .into_iter()
            .map(|r| {
                r.into_iter()
                    .map(|v| range(POOLING_ORDERS, v, i64::from(u16::MAX)).map(|v| v as usize))
                    .collect()
            })
            .collect::<Result<_, _>>()?;
        let tome_destinations = rows(tensors, TOME_DESTINATIONS)?
            .into_iter()
            .map(|r| {
                r.into_iter()
                    .map(|v| range(TOME_DESTINATIONS, v, (CELL * CELL) as i64).map(|v| v as u8))
                    .collect()
            })
            .collect::<Result<_, _>>()?;
        Ok(Self {
            pooling_orders,
            tome_destinations,
        })
    }

    /// True when every choice is the deterministic default (identity, top-left).
    pub fn is_default(&self) -> bool {
        self.pooling_orders
            .iter()
            .all(|p| p.iter().enumerate().all(|(i, &j)| i == j))
            && self
                .tome_destinations
                .iter()
                .all(|d| d.iter().all(|&k| k == 0))
    }

    /// The permutation for GridPooling `level` (0-based) over `orders` orders, checked.
    pub fn pooling_order(
        &self,
        level: usize,
        orders: usize,
    ) -> Result<Option<&[usize]>, DrawError> {
        let Some(perm) = self.pooling_orders.get(level) else {
            return Ok(None);
        };
        let seen: HashSet<usize> = perm.iter().copied().collect();
        if perm.len() != orders || seen.len() != orders || perm.iter().any(|&p| p >= orders) {
            return Err(DrawError::NotAPermutation {
                level,
                perm: perm.clone(),
                orders,
            });
        }
        Ok(Some(perm))
    }

    /// The ToMe draw of multi-modal block `block` for an `h × w` token grid, checked.
    pub fn destinations(
        &self,
        block: usize,
        h: usize,
        w: usize,
    ) -> Result<Option<&[u8]>, DrawError> {
        let Some(d) = self.tome_destinations.get(block) else {
            return Ok(None);
        };
        let cells = (h / CELL) * (w / CELL);
        if d.len() != cells {
            return Err(DrawError::Destinations {
                block,
                what: format!(
                    "{} values, the {h}x{w} token grid has {cells} cells of {CELL}x{CELL}",
                    d.len()
                ),
            });
        }
        if let Some(&k) = d.iter().find(|&&k| k as usize >= CELL * CELL) {
            return Err(DrawError::Destinations {
                block,
                what: format!("value {k} outside 0..{}", CELL * CELL),
            });
        }
        Ok(Some(d))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_draws_are_deterministic_and_checked() {
        let mut d = ForwardDraws::default();
        assert!(d.is_default());
        assert_eq!(d.pooling_order(0, 4), Ok(None));
        d.pooling_orders = vec![vec![0, 1, 2, 3], vec![2, 0, 3, 1]];
        assert!(!d.is_default());
        assert_eq!(d.pooling_order(1, 4).unwrap(), Some(&[2, 0, 3, 1][..]));
        d.pooling_orders[0] = vec![0, 0, 1, 2];
        assert!(d.pooling_order(0, 4).is_err());
        d.tome_destinations = vec![vec![0, 3, 1, 2, 0, 0]];
        assert!(d.destinations(0, 4, 6).unwrap().is_some());
        assert!(d.destinations(0, 4, 8).is_err());
        d.tome_destinations[0][1] = 4;
        assert!(d.destinations(0, 4, 6).is_err());
    }

    #[test]
    fn draws_are_read_from_integer_tensors() {
        let dev = candle_core::Device::Cpu;
        let mut t = HashMap::new();
        assert_eq!(
            ForwardDraws::from_tensors(&t).unwrap(),
            ForwardDraws::default()
        );
        t.insert(
            POOLING_ORDERS.to_string(),
            Tensor::new(&[[1i64, 2, 0, 3], [0, 1, 2, 3]], &dev).unwrap(),
        );
        t.insert(
            TOME_DESTINATIONS.to_string(),
            Tensor::new(&[[3u8, 0, 2]], &dev).unwrap(),
        );
        let d = ForwardDraws::from_tensors(&t).unwrap();
        assert_eq!(d.pooling_orders, vec![vec![1, 2, 0, 3], vec![0, 1, 2, 3]]);
        assert_eq!(d.tome_destinations, vec![vec![3, 0, 2]]);
        t.insert(
            TOME_DESTINATIONS.to_string(),
            Tensor::new(&[[5u8, 0, 2]], &dev).unwrap(),
        );
        assert!(ForwardDraws::from_tensors(&t).is_err());
        t.insert(
            TOME_DESTINATIONS.to_string(),
            Tensor::new(&[[1f32]], &dev).unwrap(),
        );
        assert!(ForwardDraws::from_tensors(&t).is_err());
    }
}
