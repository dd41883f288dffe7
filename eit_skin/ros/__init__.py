"""ROS 2 adapters: thin nodes around the core, the node graph, bring-up and launch helpers.

Modules (imported on demand: importing this package does not import rclpy): ``driver``,
``reconstruction`` and ``classifier`` (the three nodes), ``node_runner`` (what every node does
the same way), ``exit_timer`` (a native exit for a stop stuck inside Fast DDS),
``node_graph`` (the nodes of a patch, shared by launch files and ``eit-skin run``),
``topics`` (every topic and service name of a patch, derived from the patch), ``bringup``
(start/stop node processes), ``launch_actions`` (launch_ros actions), ``skin_monitor`` (the
watching side of ``eit-skin run``), ``probe`` (a subscriber for tests and benchmarks),
``parameters`` (every node parameter with its descriptor, rclpy-free), ``param_docs``
(writes docs/nodes.md's parameter tables from them), ``rviz_config`` (an rviz2
configuration generated from the launched patches' topics), ``entry`` (the nodes' console
scripts: a Ctrl-C during their imports ends them quietly), ``surface_fields`` (a contact's
3-D point and normal on the placed surface, for the messages), ``qos`` (every topic's QoS,
overridable by parameters).
"""
