//! Cluster members hear each other over DDS: two node endpoints of a two-member cluster
//! (loopback only) exchange heartbeats on `cluster/heartbeat`, each hears the other's (and not
//! its own); heartbeat text that is not a member of a cluster does not parse.

mod dds_domain;

use lhmpp::config::NodeConfig;
use lhmpp::node::inputs::InputEvent;
use lhmpp::node::ros::{RosNode, RosNodeOptions};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

fn member(index: u32, domain: i32) -> (RosNode, lhmpp::node::ros::LiveInputs) {
    let mut cfg = NodeConfig {
        domain_id: domain,
        namespace: "/lhmpp_cluster_test".into(),
        ..NodeConfig::default()
    };
    cfg.tracking.enabled = true;
    cfg.cluster.members = 2;
    cfg.cluster.index = index;
    cfg.outputs.preview_rate_hz = 0.0;
    let mut opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None)
        .unwrap()
        .loopback_only();
    opts.node_name = format!("lhmpp_member{index}");
    RosNode::start(&opts).expect("node starts")
}

#[test]
fn members_hear_each_others_heartbeats() {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let _guard = runtime.enter();
    let domain = i32::from(dds_domain::test_domain(90));
    let (a, mut a_in) = member(0, domain);
    let (b, mut b_in) = member(1, domain);
    let deadline = Instant::now() + Duration::from_secs(20);
    let (mut a_heard, mut b_heard) = (None, None);
    while Instant::now() < deadline && (a_heard.is_none() || b_heard.is_none()) {
        a.publish_heartbeat().unwrap();
        b.publish_heartbeat().unwrap();
        for (queue, heard) in [(&mut a_in, &mut a_heard), (&mut b_in, &mut b_heard)] {
            while let Some(event) = queue.recv_timeout(Duration::from_millis(50)) {
                if let InputEvent::ClusterHeartbeat { index, members, .. } = event {
                    *heard = Some((index, members));
                }
            }
        }
    }
    assert_eq!(a_heard, Some((1, 2)), "member 0 hears member 1, not itself");
    assert_eq!(b_heard, Some((0, 2)), "member 1 hears member 0, not itself");
    assert!(lhmpp::node::ros::parse_heartbeat("lhmpp cluster member 2 of 2").is_err());
    assert!(lhmpp::node::ros::parse_heartbeat("hello").is_err());
    a.shutdown();
    b.shutdown();
}
