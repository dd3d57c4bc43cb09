//! Refinement as a user meets it: the node's default reconstruction of a person (shape
//! estimated, colours from the views), fitted to its 8 input views, scored on the bag's
//! held-out cameras it never saw. A dressed, lit person comes out closer to the truth than the
//! network left them; a plain one never comes out worse.

use lhmpp::config::{Delight, ModelConfig, NodeConfig};
use lhmpp::eval::heldout::{evaluate_bag, ColourSource, EvalStages, InputCrop, ShapeSource};
use lhmpp::synth::{write_bag, Realism, SynthOptions, SynthPose};

/// Held-out (PSNR, IoU) at 8 views without and with refinement (the node's settings, with at
/// most `steps` steps so that the test stays short).
fn before_after(realism: Realism, seed: u64, steps: usize) -> ((f64, f64), (f64, f64)) {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("person.mcap");
    let options = SynthOptions {
        seed,
        views: 12,
        heldout: 4,
        size: 256,
        pose: SynthPose::Random,
        ..SynthOptions::default()
    };
    write_bag(&bag, &options, realism).unwrap();
    let mut fit = NodeConfig::default().refine.fit_config();
    fit.max_iterations = steps;
    fit.budget = std::time::Duration::from_secs(600);
    let score = |refine| {
        let stages = EvalStages {
            crop: InputCrop::Mask,
            shape: ShapeSource::Estimate,
            colours: ColourSource::Views(Delight::default()),
            refine,
        };
        let rows = evaluate_bag(&bag, &ModelConfig::default(), &[8], &stages).unwrap();
        let (psnr, _, iou) = rows[0].means();
        (psnr, iou, rows[0].refine.clone())
    };
    let (p0, i0, none) = score(None);
    assert!(none.is_none());
    let (p1, i1, report) = score(Some(fit));
    let report = report.expect("refinement ran on 8 calibrated views");
    eprintln!("seed {seed}: {p0:.2} dB / IoU {i0:.3} → {p1:.2} dB / IoU {i1:.3}; {report:?}");
    ((p0, i0), (p1, i1))
}

#[test]
fn a_dressed_person_comes_out_closer_to_the_unseen_views() {
    let ((p0, i0), (p1, i1)) = before_after(Realism::Dressed, 40, 150);
    assert!(p1 >= p0 + 1.0, "PSNR {p0:.2} → {p1:.2} dB");
    assert!(i1 >= i0 + 0.03, "mask IoU {i0:.3} → {i1:.3}");
}

#[test]
fn a_plain_person_never_comes_out_worse() {
    let ((p0, _), (p1, _)) = before_after(Realism::Plain, 3, 150);
    assert!(p1 >= p0 - 0.1, "PSNR {p0:.2} → {p1:.2} dB");
}
