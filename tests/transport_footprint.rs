//! The shared memory a publisher reserves is the documented worst case (preallocated samples
//! × payload capacity), not a multiple of it.

use lhmpp::transport::footprint::ShmSnapshot;
use lhmpp::transport::{PayloadKind, ShmNode, ShmOptions};

#[test]
fn frame_publisher_reserves_its_preallocated_samples_of_initial_capacity() {
    let person = format!("footprint{}", std::process::id());
    let options = ShmOptions {
        initial_capacity: 4 << 20,
        ..ShmOptions::default()
    };
    let expected =
        (options.preallocated_samples(PayloadKind::Frame) * options.initial_capacity) as u64;
    let before = ShmSnapshot::take();
    let node = ShmNode::new(&format!("{person}-pub"), options).unwrap();
    let publisher = node.frame_publisher(&person, "cam0").unwrap();
    let grown = ShmSnapshot::take().growth_since(&before);
    drop(publisher);
    // Data segment plus small management files (a few KiB each).
    assert!(grown.reserved >= expected, "{grown:?} < {expected}");
    assert!(
        grown.reserved < expected + expected / 10,
        "{grown:?} vs {expected}"
    );
}
