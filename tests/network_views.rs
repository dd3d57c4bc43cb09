//! `model.max_views`: given more views than it may read, the network reads the most different
//! ones (and the token cache still holds every view), so a near-duplicate view changes nothing
//! while a view of another kind is read.

use lhmpp::config::ModelConfig;
use lhmpp::reconstruct::photos::preprocess_config;
use lhmpp::reconstruct::preprocess::{preprocess, Preprocessed, Subject};
use lhmpp::reconstruct::Reconstructor;

fn view(recon: &Reconstructor, colour: [u8; 3], stripe: u32) -> Preprocessed {
    let image = image::RgbImage::from_fn(96, 160, |x, y| {
        if (x / stripe + y / stripe) % 2 == 0 {
            image::Rgb(colour)
        } else {
            image::Rgb([255 - colour[0], 128, 255 - colour[2]])
        }
    });
    preprocess(&image, Subject::FullFrame, &preprocess_config(recon)).unwrap()
}

fn config(max_views: usize) -> ModelConfig {
    ModelConfig {
        checkpoint: "random:7".into(),
        max_views,
        ..ModelConfig::default()
    }
}

#[test]
fn the_network_reads_at_most_max_views_the_most_different_ones() {
    let mut capped = Reconstructor::new(&config(2), 8).unwrap();
    let a = view(&capped, [200, 40, 40], 8);
    let a_again = view(&capped, [201, 40, 40], 8);
    let b = view(&capped, [20, 200, 90], 3);
    // Three views, two nearly alike: the network reads the first and the different one.
    let three = capped
        .reconstruct(&[(1, &a), (2, &a_again), (3, &b)])
        .unwrap();
    let mut fresh = Reconstructor::new(&config(2), 8).unwrap();
    let chosen = fresh.reconstruct(&[(1, &a), (3, &b)]).unwrap();
    assert_eq!(
        three.canonical.positions, chosen.canonical.positions,
        "the capped network read other views than the first and the most different one"
    );
    assert_eq!(three.canonical.sh, chosen.canonical.sh);
    // Uncapped (0: a checkpoint other than the embedded one reads up to 16), all three count.
    let mut all = Reconstructor::new(&config(0), 8).unwrap();
    let uncapped = all.reconstruct(&[(1, &a), (2, &a_again), (3, &b)]).unwrap();
    assert_ne!(uncapped.canonical.sh, chosen.canonical.sh);
    assert_eq!(
        config(0).network_views(),
        ModelConfig::OFFICIAL_TRAINED_VIEWS
    );
    assert_eq!(
        ModelConfig::default().network_views(),
        ModelConfig::EMBEDDED_TRAINED_VIEWS
    );
}
