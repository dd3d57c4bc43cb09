//! The point backbone and the neural renderer built with the `lhmpp_700m` presets ask for exactly
//! the parameter names and shapes of the released LHMPP-700M checkpoint (fixture copied from the
//! official key list; `neural_renderer.transformer_block.*`, unused at inference, left out).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use candle_core::{DType, Device, Result, Shape, Tensor};
use candle_nn::var_builder::SimpleBackend;
use candle_nn::VarBuilder;
use lhmpp::model::dpt::{DptConfig, NeuralRenderer};
use lhmpp::model::point::{PointBackbone, PointBackboneConfig};

const KEYS: &str = include_str!("fixtures/lhmpp_700m_point_dpt_keys.txt");

/// Records every requested name and shape; hands out zeros (broadcast, not allocated).
#[derive(Default, Clone)]
struct Recorder(Arc<Mutex<BTreeMap<String, Vec<usize>>>>);

impl SimpleBackend for Recorder {
    fn get(
        &self,
        s: Shape,
        name: &str,
        _: candle_nn::Init,
        dtype: DType,
        dev: &Device,
    ) -> Result<Tensor> {
        let previous = self
            .0
            .lock()
            .unwrap()
            .insert(name.to_string(), s.dims().to_vec());
        assert!(previous.is_none(), "{name} requested twice");
        Tensor::zeros((), dtype, dev)?.broadcast_as(s)
    }
    fn get_unchecked(&self, name: &str, _: DType, _: &Device) -> Result<Tensor> {
        candle_core::bail!("unexpected unchecked get of {name}")
    }
    fn contains_tensor(&self, _: &str) -> bool {
        true
    }
}

fn official(prefix: &str) -> BTreeMap<String, Vec<usize>> {
    KEYS.lines()
        .filter(|l| l.starts_with(prefix))
        .map(|l| {
            let (name, shape) = l.split_once('\t').expect("name<TAB>shape");
            let dims = shape
                .trim_matches(|c| c == '[' || c == ']')
                .split(',')
                .map(|d| d.trim().parse::<usize>().expect("dim"))
                .collect();
            (name.to_string(), dims)
        })
        .collect()
}

fn diff(ours: &BTreeMap<String, Vec<usize>>, theirs: &BTreeMap<String, Vec<usize>>) -> Vec<String> {
    let mut out = Vec::new();
    for (k, v) in theirs {
        match ours.get(k) {
            None => out.push(format!("missing {k} {v:?}")),
            Some(o) if o != v => out.push(format!("shape {k}: ours {o:?}, official {v:?}")),
            _ => {}
        }
    }
    for k in ours.keys().filter(|k| !theirs.contains_key(*k)) {
        out.push(format!("extra {k}"));
    }
    out
}

#[test]
fn point_backbone_700m_asks_for_the_official_keys_and_shapes() -> Result<()> {
    let rec = Recorder::default();
    let vb = VarBuilder::from_backend(Box::new(rec.clone()), DType::F32, Device::Cpu);
    PointBackbone::new(
        &PointBackboneConfig::lhmpp_700m(),
        vb.pp("transformer").pp("point_backbone"),
    )?;
    let ours = rec.0.lock().unwrap().clone();
    let theirs = official("transformer.point_backbone.");
    assert_eq!(theirs.len(), 544);
    let d = diff(&ours, &theirs);
    assert!(d.is_empty(), "{d:#?}");
    Ok(())
}

#[test]
fn neural_renderer_700m_asks_for_the_official_keys_and_shapes() -> Result<()> {
    let rec = Recorder::default();
    let vb = VarBuilder::from_backend(Box::new(rec.clone()), DType::F32, Device::Cpu);
    NeuralRenderer::new(&DptConfig::lhmpp_700m(), vb.pp("neural_renderer"))?;
    let ours = rec.0.lock().unwrap().clone();
    let theirs = official("neural_renderer.");
    assert_eq!(theirs.len(), 63);
    let d = diff(&ours, &theirs);
    assert!(d.is_empty(), "{d:#?}");
    Ok(())
}
