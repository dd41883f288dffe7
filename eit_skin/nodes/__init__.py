"""ROS 2 nodes: thin adapters between ROS parameters/messages and the core."""
