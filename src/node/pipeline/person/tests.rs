//! `Person`'s frame store when a camera takes up someone else.

use super::*;
use crate::config::PoseSource;
use crate::reconstruct::preprocess::{BBox, Preprocessed};
use std::sync::Arc;

/// A view from `camera` with an embedding of its own (no two are duplicates).
fn view(frame_id: u64, camera: &str) -> View {
    let mut embedding = vec![0.0; 8];
    embedding[frame_id as usize % 8] = 1.0;
    View {
        frame_id,
        camera: camera.into(),
        stamp_ns: frame_id as i64,
        arrival: Duration::from_millis(frame_id * 100),
        image: Arc::new(Preprocessed {
            height: 2,
            width: 2,
            chw: vec![0.5; 12],
            region: BBox {
                x0: 0,
                y0: 0,
                x1: 2,
                y1: 2,
            },
        }),
        embedding,
        evidence: None,
        hidden: 0.0,
    }
}

fn person() -> Person {
    Person::new(
        StoreLimits::default(),
        SchedulerConfig::from_debounce_ms(100),
        PosePath::new(PoseSource::Walk, None),
        true,
    )
}

#[test]
fn a_camera_that_takes_up_someone_else_loses_its_views_and_the_rest_are_rebuilt() {
    let mut p = person();
    for (id, camera) in [(1, "/cam0"), (2, "/cam1"), (3, "/cam0"), (4, "/cam1")] {
        assert!(p
            .add_view(view(id, camera), Duration::from_millis(id * 100))
            .changed());
    }
    // Their first avatar is made of the four views.
    let (_, job) = p
        .poll("p", Duration::from_secs(2))
        .expect("a job after the debounce");
    let first = p.start(job.clone(), false).expect("views held");
    assert_eq!(first.views.views.len(), 4);
    p.failed(&job);

    let dropped = p.drop_camera("/cam0", Duration::from_secs(3));
    assert_eq!(dropped, vec![1, 3]);
    assert_eq!(p.frame_ids().collect::<Vec<_>>(), vec![2, 4]);
    assert!(p.drop_camera("/cam2", Duration::from_secs(3)).is_empty());
    // The next avatar is made of the other camera's views alone.
    let (_, job) = p
        .poll("p", Duration::from_secs(5))
        .expect("the view set changed: a job");
    let next = p.start(job, false).expect("views held");
    let cameras: Vec<&str> = next.views.views.iter().map(|v| v.camera.as_str()).collect();
    assert_eq!(cameras, ["/cam1", "/cam1"]);
}

#[test]
fn when_only_that_camera_gave_views_the_store_is_empty_until_the_new_persons_come() {
    let mut p = person();
    for id in 1..=3 {
        p.add_view(view(id, "/cam0"), Duration::from_millis(id * 100));
    }
    assert_eq!(
        p.drop_camera("/cam0", Duration::from_secs(1)),
        vec![1, 2, 3]
    );
    assert_eq!(p.views_held(), 0);
    // A job due for the views before finds none: it fails, nothing is made of them.
    if let Some((_, job)) = p.poll("p", Duration::from_secs(2)) {
        assert!(p.start(job, false).is_none());
    }
    p.add_view(view(4, "/cam0"), Duration::from_secs(3));
    let (_, job) = p
        .poll("p", Duration::from_secs(5))
        .expect("a job for the new views");
    let next = p.start(job, false).expect("views held");
    assert_eq!(next.views.views.len(), 1);
    assert_eq!(next.views.views[0].frame_id, 4);
}
