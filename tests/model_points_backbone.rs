//! The staged point backbone on a synthetic body cloud (tiny preset, random weights): stage
//! shapes, level bookkeeping, the way back to the input points, order misuse.

use candle_core::{DType, Device, Result, Tensor};
use candle_nn::{VarBuilder, VarMap};
use lhmpp::model::point::synthetic::body_surface_points;
use lhmpp::model::point::{PointBackbone, PointBackboneConfig};

fn cloud(n: usize, seed: u64) -> Result<(Tensor, Tensor)> {
    let (p, nrm) = body_surface_points(n, seed);
    let dev = Device::Cpu;
    Ok((
        Tensor::from_vec(p.concat(), (n, 3), &dev)?,
        Tensor::from_vec(nrm.concat(), (n, 3), &dev)?,
    ))
}

fn tiny() -> Result<(PointBackbone, VarMap)> {
    let vm = VarMap::new();
    let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
    let b = PointBackbone::new(
        &PointBackboneConfig::tiny(),
        vb.pp("transformer").pp("point_backbone"),
    )?;
    Ok((b, vm))
}

#[test]
fn stages_pool_then_unpool_back_to_the_same_voxels() -> Result<()> {
    let (bb, _vm) = tiny()?;
    let cfg = PointBackboneConfig::tiny();
    let (coords, normals) = cloud(6_000, 2)?;
    let mut s = bb.embed(&coords, &normals)?;
    let level0: Vec<[u32; 3]> = s.grid_coords().to_vec();
    assert_eq!(s.feat().dims(), &[level0.len(), cfg.enc_channels[0]]);
    let mut counts = vec![];
    for l in 0..4 {
        s = bb.encoder_stage(l, s)?;
        assert_eq!(s.feat().dims(), &[s.len(), cfg.enc_channels[l]]);
        counts.push(s.len());
    }
    assert_eq!(counts[0], counts[1], "stride 1 keeps the voxels");
    assert!(counts[1] > counts[2] && counts[2] > counts[3], "{counts:?}");
    let enc3 = s.grid_coords().to_vec();
    for l in (0..3).rev() {
        s = bb.decoder_stage(l, s)?;
        assert_eq!(s.feat().dims(), &[s.len(), cfg.dec_channels[l]]);
    }
    assert_ne!(enc3.len(), s.len());
    // the decoder ends on the level-0 voxels, in their original order
    assert_eq!(s.grid_coords(), level0.as_slice());
    let per_point = s.to_input_points(s.feat())?;
    assert_eq!(per_point.dims(), &[6_000, cfg.dec_channels[0]]);
    let v = per_point.flatten_all()?.to_vec1::<f32>()?;
    assert!(v.iter().all(|x| x.is_finite()));
    Ok(())
}

#[test]
fn the_same_cloud_gives_the_same_features() -> Result<()> {
    let (bb, _vm) = tiny()?;
    let (coords, normals) = cloud(3_000, 4)?;
    let a = bb.forward(&coords, &normals)?;
    let b = bb.forward(&coords, &normals)?;
    let d = (a.feat() - b.feat())?
        .abs()?
        .flatten_all()?
        .max(0)?
        .to_scalar::<f32>()?;
    assert_eq!(d, 0.0);
    Ok(())
}

#[test]
fn hilbert_order_is_a_permutation_of_the_current_points() -> Result<()> {
    let (bb, _vm) = tiny()?;
    let (coords, normals) = cloud(4_000, 5)?;
    let s = bb.encoder_stage(0, bb.embed(&coords, &normals)?)?;
    let s = bb.encoder_stage(1, s)?;
    let s = bb.encoder_stage(2, s)?;
    let mut o = s.hilbert_order()?.to_vec1::<u32>()?;
    o.sort_unstable();
    assert_eq!(o, (0..s.len() as u32).collect::<Vec<_>>());
    Ok(())
}

#[test]
fn replaced_features_flow_into_the_next_stage() -> Result<()> {
    let (bb, _vm) = tiny()?;
    let (coords, normals) = cloud(3_000, 6)?;
    let s = bb.encoder_stage(0, bb.embed(&coords, &normals)?)?;
    let base = bb.encoder_stage(1, s.clone())?;
    let zeroed = s.clone().with_feat(s.feat().zeros_like()?);
    let changed = bb.encoder_stage(1, zeroed)?;
    let d = (base.feat() - changed.feat())?
        .abs()?
        .flatten_all()?
        .max(0)?
        .to_scalar::<f32>()?;
    assert!(d > 1e-4);
    Ok(())
}

#[test]
fn stages_called_out_of_order_are_refused_with_the_level() -> Result<()> {
    let (bb, _vm) = tiny()?;
    let (coords, normals) = cloud(2_000, 7)?;
    let s = bb.embed(&coords, &normals)?;
    let err = bb.encoder_stage(2, s.clone()).unwrap_err().to_string();
    assert!(err.contains("encoder stage 2"), "{err}");
    assert!(bb.decoder_stage(0, s.clone()).is_err());
    assert!(bb.encoder_stage(9, s).is_err());
    Ok(())
}
