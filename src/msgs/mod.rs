//! ROS 2 message types (standard and `lhmpp_msgs`) as serde structs encoded in CDR, matching
//! the `.msg` definitions under `msg/` byte for byte.
