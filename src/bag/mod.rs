//! MCAP bags in the rosbag2 layout: record, read, and replay topics of ROS 2 messages.
