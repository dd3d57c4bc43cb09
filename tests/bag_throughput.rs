//! Measures bag write and read throughput on camera-sized images (ignored by default: a
//! measurement, not a check). Run with
//! `cargo test --release --test bag_throughput -- --ignored --nocapture`.

use lhmpp::bag::{BagReader, BagWriter};
use lhmpp::msgs::Image;
use rand::{Rng, SeedableRng};
use std::time::Instant;

#[test]
#[ignore = "measurement; run explicitly"]
fn write_and_read_throughput_of_vga_images() {
    const COUNT: u64 = 60;
    let (width, height) = (640u32, 480u32);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    // A smooth gradient with sensor-like noise: compresses like a camera frame, not like zeros.
    let frame: Vec<u8> = (0..width * height * 3)
        .map(|i| ((i / 3 % width + i / 3 / width) / 5) as u8 ^ (rng.gen::<u8>() & 0x07))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("vga.mcap");
    let raw_bytes = COUNT * frame.len() as u64;

    let start = Instant::now();
    let mut writer = BagWriter::create(&path).unwrap();
    for i in 0..COUNT {
        let image = Image {
            height,
            width,
            encoding: "rgb8".into(),
            step: width * 3,
            data: frame.clone(),
            ..Default::default()
        };
        writer
            .write("/camera/image_raw", i * 33_000_000, &image)
            .unwrap();
    }
    writer.finish().unwrap();
    let write_s = start.elapsed().as_secs_f64();
    let size = std::fs::metadata(&path).unwrap().len();

    let start = Instant::now();
    let bag = BagReader::open(&path).unwrap();
    let images = bag.read_topic::<Image>("/camera/image_raw").unwrap();
    let read_s = start.elapsed().as_secs_f64();
    assert_eq!(images.len(), COUNT as usize);
    assert_eq!(images[7].1.data, frame);

    let mb = raw_bytes as f64 / 1e6;
    println!(
        "{COUNT} rgb8 {width}x{height} images, {mb:.1} MB raw -> {:.1} MB bag (zstd, ratio {:.2}); \
         write {write_s:.2} s ({:.0} MB/s), open+decode {read_s:.2} s ({:.0} MB/s)",
        size as f64 / 1e6,
        raw_bytes as f64 / size as f64,
        mb / write_s,
        mb / read_s
    );
}
