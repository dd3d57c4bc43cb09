//! The shipped default model keeps its quality: held-out-view scores of an evaluation person
//! (a seed never trained on) at 4 input views stay above floors a few dB under the figures
//! reported in assets/model/README.md, floors that seeded random weights do not reach; and on
//! the demo bag it reads the person's own clothes (a yellow sweater, blue trousers) well
//! enough to clear a floor that a model rendering the training average does not.

use lhmpp::config::{Delight, ModelConfig};
use lhmpp::eval::heldout::{evaluate_bag, EvalStages, InputCrop};
use std::path::Path;

const BAG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/bags/eval_seed2.mcap");
/// Floors under the shipped model's figures on this bag (23.71 dB, 0.928, 0.967; the previous
/// default, trained without the patch and attention supervision: 21.44 dB, 0.913, 0.968;
/// seeded random weights: 14.74 dB, 0.731, 0.010), measured with
/// `lhmpp eval bags/eval_seed2.mcap --views 4 --full-frame`. The PSNR floor is one the
/// previous default fails.
const PSNR_FLOOR: f64 = 22.0;
const SSIM_FLOOR: f64 = 0.85;
const IOU_FLOOR: f64 = 0.85;

const DEMO_BAG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/bags/demo.mcap");
/// PSNR floor on the demo bag, views cropped by their masks as the demo runs them: the shipped
/// model scores 23.68 dB there; the previous default 22.67 dB; the one before it, whose clothes
/// came out close to the training average (khaki and grey for this person), 19.23 dB; random
/// weights 13.65 dB (`lhmpp eval bags/demo.mcap --views 4`).
const DEMO_PSNR_FLOOR: f64 = 22.0;

fn scores(checkpoint: &str) -> (f64, f64, f64) {
    scores_on(BAG, checkpoint, InputCrop::FullFrame)
}

fn scores_on(bag: &str, checkpoint: &str, crop: InputCrop) -> (f64, f64, f64) {
    let model = ModelConfig {
        checkpoint: checkpoint.into(),
        ..ModelConfig::default()
    };
    let rows = evaluate_bag(
        Path::new(bag),
        &model,
        &[4],
        &EvalStages {
            crop,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].views, 4);
    rows[0].means()
}

#[test]
fn default_model_reconstructs_an_unseen_person_above_the_floors() {
    let (psnr, ssim, iou) = scores("");
    assert!(psnr >= PSNR_FLOOR, "PSNR {psnr:.2} dB < {PSNR_FLOOR}");
    assert!(ssim >= SSIM_FLOOR, "SSIM {ssim:.4} < {SSIM_FLOOR}");
    assert!(iou >= IOU_FLOOR, "mask IoU {iou:.3} < {IOU_FLOOR}");
}

#[test]
fn random_weights_do_not_pass_the_floors() {
    let (psnr, _, iou) = scores("random");
    assert!(
        psnr < PSNR_FLOOR && iou < IOU_FLOOR,
        "random weights reach PSNR {psnr:.2} dB, IoU {iou:.3}: the floors test nothing"
    );
}

#[test]
fn default_model_reads_the_demo_persons_clothes() {
    let (psnr, _, iou) = scores_on(DEMO_BAG, "", InputCrop::Mask);
    assert!(
        psnr >= DEMO_PSNR_FLOOR,
        "demo PSNR {psnr:.2} dB < {DEMO_PSNR_FLOOR}"
    );
    assert!(iou >= IOU_FLOOR, "demo mask IoU {iou:.3} < {IOU_FLOOR}");
}

/// PSNR at 4 views without a shape topic (the shape read from the views), with the network's
/// colours or recoloured from the input views as the node does.
fn recoloured_gain(bag: &str) -> (f64, f64) {
    use lhmpp::eval::heldout::{ColourSource, ShapeSource};
    let score = |colours| {
        let rows = evaluate_bag(
            Path::new(bag),
            &ModelConfig::default(),
            &[4],
            &EvalStages {
                crop: InputCrop::Mask,
                shape: ShapeSource::Estimate,
                colours,
                refine: None,
            },
        )
        .unwrap();
        rows[0].means().0
    };
    (
        score(ColourSource::Network),
        score(ColourSource::Views(Delight::default())),
    )
}

/// Calibrated views (CameraInfo, TF, a pose topic) recolour the avatar through their real
/// cameras: on both bags the held-out PSNR gains at least 0.4 dB over the network's colours
/// (measured +0.71 and +0.72 dB). Cameras fitted to perceived landmarks and poses instead,
/// as before, gained +0.05 and lost 0.20 dB.
#[test]
fn calibrated_views_recolour_the_avatar_better_than_the_network() {
    for bag in [BAG, DEMO_BAG] {
        let (network, views) = recoloured_gain(bag);
        assert!(
            views >= network + 0.4,
            "{bag}: recoloured {views:.2} dB against the network's {network:.2} dB"
        );
    }
}

/// A dressed person lit by a key light (shadowed on one side, darker than their garments'
/// own colours: the held-out truth is the unlit albedo) and seen by 8 calibrated cameras: with
/// the fitted key light divided out (`perception.delight: calibrated`, the default) the
/// recoloured avatar scores at least 1 dB above the same avatar coloured by the lit views as
/// they are (`never`). Measured on this person: 16.96 → 20.13 dB (16 views, 8 used); on six
/// such people 17.14 → 20.12 dB at 8 views.
#[test]
fn dividing_out_the_key_light_brings_a_lit_person_closer_to_their_garments() {
    use lhmpp::eval::heldout::{ColourSource, ShapeSource};
    use lhmpp::synth::{write_bag, Realism, SynthOptions, SynthPose};
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("dressed31.mcap");
    let options = SynthOptions {
        seed: 31,
        views: 16,
        heldout: 4,
        size: 192,
        pose: SynthPose::Walk(155.0),
        publish_shape: true,
        contrasting_back: true,
        ..SynthOptions::default()
    };
    write_bag(&bag, &options, Realism::Dressed).unwrap();
    let score = |delight| {
        let rows = evaluate_bag(
            &bag,
            &ModelConfig::default(),
            &[8],
            &EvalStages {
                crop: InputCrop::Mask,
                shape: ShapeSource::Estimate,
                colours: ColourSource::Views(delight),
                refine: None,
            },
        )
        .unwrap();
        rows[0].means().0
    };
    let (lit, delit) = (score(Delight::Never), score(Delight::Calibrated));
    println!("as seen {lit:.2} dB, key light divided out {delit:.2} dB");
    assert!(
        delit >= lit + 1.0,
        "de-lit {delit:.2} dB against {lit:.2} dB as seen"
    );
}
