//! A tokio task sleeps on the listener's file descriptor and wakes when a sample is published
//! from another thread.

use std::time::Duration;

use lhmpp::transport::{FrameView, PayloadBody, ShmNode, ShmOptions, Stamp};

#[tokio::test(flavor = "current_thread")]
async fn wait_async_wakes_a_tokio_task_when_a_frame_is_published() {
    let person = format!("async{}", std::process::id());
    let node = ShmNode::new(&format!("{person}-sub"), ShmOptions::default()).unwrap();
    let mut subscriber = node.subscriber(&person, &["cam0"]).unwrap();
    assert!(subscriber.try_receive().unwrap().is_none());

    let publisher_person = person.clone();
    let publisher = std::thread::spawn(move || {
        let node = ShmNode::new(&format!("{publisher_person}-pub"), ShmOptions::default()).unwrap();
        let publisher = node.frame_publisher(&publisher_person, "cam0").unwrap();
        let pixels = vec![7u8; 8 * 4 * 3];
        let frame = FrameView {
            width: 8,
            height: 4,
            channels: 3,
            pixels: &pixels,
            alpha: None,
            depth: None,
        };
        // The subscriber exists before this publisher, so the frame reaches it.
        let delivered = publisher
            .publish(Stamp::now(5), &PayloadBody::Frame(frame))
            .unwrap();
        (publisher, delivered)
    });

    tokio::time::timeout(Duration::from_secs(30), subscriber.wait_async())
        .await
        .expect("woken within 30 s")
        .unwrap();
    let sample = subscriber
        .try_receive()
        .unwrap()
        .expect("a frame after the wake-up");
    assert_eq!(sample.decode().unwrap().stamp.revision, 5);
    let (_publisher, delivered) = publisher.join().unwrap();
    assert_eq!(delivered, 1);
}
