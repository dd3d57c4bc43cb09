//! Timing of the point backbone stages (ignored by default; random weights, f32, CPU):
//! `cargo test --release --test model_points_bench -- --ignored --nocapture`
//! Sizes from `LHMPP_BENCH_POINTS` (default "40000,160000") and presets from
//! `LHMPP_BENCH_PRESETS` (default "tiny,m").

use std::time::Instant;

use candle_core::{DType, Device, Result, Tensor};
use candle_nn::{VarBuilder, VarMap};
use lhmpp::model::point::synthetic::body_surface_points;
use lhmpp::model::point::{PointBackbone, PointBackboneConfig};

fn list(var: &str, default: &str) -> Vec<String> {
    std::env::var(var)
        .unwrap_or_else(|_| default.to_string())
        .split(',')
        .map(|s| s.trim().to_string())
        .collect()
}

#[test]
#[ignore = "benchmark; run with --ignored --nocapture"]
fn time_point_backbone_stages() -> Result<()> {
    let dev = Device::Cpu;
    for preset in list("LHMPP_BENCH_PRESETS", "tiny,m") {
        let cfg = match preset.as_str() {
            "tiny" => PointBackboneConfig::tiny(),
            "s" => PointBackboneConfig::small(),
            "l" => PointBackboneConfig::large(),
            _ => PointBackboneConfig::lhmpp_700m(),
        };
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &dev);
        let bb = PointBackbone::new(&cfg, vb.pp("transformer").pp("point_backbone"))?;
        for n in list("LHMPP_BENCH_POINTS", "40000,160000") {
            let n: usize = n.parse().expect("point count");
            let (p, nrm) = body_surface_points(n, 42);
            let coords = Tensor::from_vec(p.concat(), (n, 3), &dev)?;
            let normals = Tensor::from_vec(nrm.concat(), (n, 3), &dev)?;
            let total = Instant::now();
            let t = Instant::now();
            let mut s = bb.embed(&coords, &normals)?;
            let mut line = format!(
                "{preset} N={n}: embed {:.0} ms",
                t.elapsed().as_secs_f64() * 1e3
            );
            for l in 0..cfg.num_levels() {
                let t = Instant::now();
                s = bb.encoder_stage(l, s)?;
                line += &format!(
                    ", enc{l} ({} pts) {:.0} ms",
                    s.len(),
                    t.elapsed().as_secs_f64() * 1e3
                );
            }
            for l in (0..cfg.num_levels() - 1).rev() {
                let t = Instant::now();
                s = bb.decoder_stage(l, s)?;
                line += &format!(", dec{l} {:.0} ms", t.elapsed().as_secs_f64() * 1e3);
            }
            let _ = s.to_input_points(s.feat())?;
            line += &format!("; total {:.0} ms", total.elapsed().as_secs_f64() * 1e3);
            println!("{line}");
        }
    }
    Ok(())
}
