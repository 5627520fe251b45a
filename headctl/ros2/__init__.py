"""The service on ROS 2 topics without a ROS 2 install: DDS through Cyclone DDS's Python binding,
with ROS 2's names, types, QoS and discovery info (docs/ros2.md).

The outer layer, as `headctl.api` is: it reads the service through `HeadService`
(`headctl.service.control`) and the service never imports it. `messages` (the ROS 2 types and
their CDR), `node` (the participant, topics and QoS, `ros_discovery_info`), `frames` (tf2 from
the nominal geometry), `convert` (the service's data as messages), `streams` (the publishing
threads), `commands` (the command topics and `/head/gaze_state`), `interface` (the front end);
`recorder` (rosbag2 bags of the same messages), `bag` (a bag in numbered MCAP files),
`bagtypes` (the messages from rosbags' typestore, when cyclonedds is missing).
"""
