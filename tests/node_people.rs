//! Several people in the node (`tracking.enabled`), through bag replay of a synthetic crowd
//! scene (`lhmpp synth --people 2`): each tracked person gets an avatar of their own, and
//! nodes sharing the persons (`cluster.members: 2`) agree on the ids and reconstruct each
//! person exactly once between them.

use lhmpp::config::NodeConfig;
use lhmpp::node::run::{run, RunSummary};
use lhmpp::synth::crowd::{write_crowd_bag, CrowdOptions};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

fn people_config(out: &Path, bag: &Path, extra: &[String]) -> NodeConfig {
    let mut overrides = vec![
        format!("outputs.dir={}", out.display()),
        format!("replay.bag={}", bag.display()),
        "outputs.render_rate_hz=0".to_string(),
    ];
    overrides.extend(extra.iter().cloned());
    NodeConfig::load(
        Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/launch_configs/people.yaml"
        )),
        &overrides,
    )
    .unwrap()
}

fn reconstructed(summary: &RunSummary) -> BTreeSet<String> {
    summary
        .persons
        .iter()
        .filter(|p| p.reconstructed_here)
        .map(|p| p.id.clone())
        .collect()
}

#[test]
fn two_people_get_one_avatar_each_and_two_nodes_split_them() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("people.mcap");
    let options = CrowdOptions {
        seed: 5,
        people: 2,
        cameras: 1,
        frames: 16,
        ..CrowdOptions::default()
    };
    write_crowd_bag(&bag, &options, |_, _| {}).unwrap();

    // One node: both people, one avatar each, from views of their own.
    let out = dir.path().join("one");
    let summary = run(&people_config(&out, &bag, &[]), BTreeMap::new()).unwrap();
    let ids: Vec<&str> = summary.persons.iter().map(|p| p.id.as_str()).collect();
    assert_eq!(ids, ["person_0", "person_1"], "{:?}", summary.persons);
    for p in &summary.persons {
        assert!(p.reconstructed_here && p.revision >= 1, "{p:?}");
        assert!(p.views >= 4, "{p:?}");
        assert!(out.join(format!("avatar_{}.ply", p.id)).is_file(), "{p:?}");
    }
    assert_eq!(summary.stats.persons_started, 2);

    // Two nodes on the same bag: the same ids, each person reconstructed by exactly one.
    let mut owners: BTreeMap<String, usize> = BTreeMap::new();
    for index in 0..2 {
        let out = dir.path().join(format!("member{index}"));
        let extra = [
            "cluster.members=2".to_string(),
            format!("cluster.index={index}"),
        ];
        let member = run(&people_config(&out, &bag, &extra), BTreeMap::new()).unwrap();
        let tracked: Vec<&str> = member.persons.iter().map(|p| p.id.as_str()).collect();
        assert_eq!(
            tracked, ids,
            "every member tracks everyone under the same ids"
        );
        for id in reconstructed(&member) {
            *owners.entry(id.clone()).or_default() += 1;
            assert!(out.join(format!("avatar_{id}.ply")).is_file());
        }
        for p in member.persons.iter().filter(|p| !p.reconstructed_here) {
            assert_eq!((p.views, p.revision), (0, 0), "{p:?}");
            assert!(!out.join(format!("avatar_{}.ply", p.id)).exists());
        }
    }
    let expected: BTreeMap<String, usize> = ids.iter().map(|id| (id.to_string(), 1)).collect();
    assert_eq!(owners, expected, "each person reconstructed exactly once");
}

#[test]
fn tracking_needs_perception_masks() {
    let dir = tempfile::tempdir().unwrap();
    let overrides = ["inputs.person_mask=topic".to_string()];
    let err = NodeConfig::load(
        Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/launch_configs/people.yaml"
        )),
        &overrides,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("tracking.enabled") && err.contains("person_mask"),
        "{err}"
    );
    let overrides = [
        "tracking.enabled=false".to_string(),
        "cluster.members=2".to_string(),
    ];
    let err = NodeConfig::load(&dir.path().join("missing.yaml"), &overrides)
        .unwrap_err()
        .to_string();
    assert!(err.contains("missing.yaml"), "{err}");
    let err = NodeConfig::load(
        Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/launch_configs/people.yaml"
        )),
        &overrides,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("cluster.members"), "{err}");
}
