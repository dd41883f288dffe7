"""The quality of service of every topic of the nodes, as REP 2003 asks, each overridable.

REP 2003 (sensor data and map QoS): a sensor driver publishes its raw data **reliable**, so
that a consumer asking for reliability gets it, and the consumers subscribe **best effort**
(``qos_profile_sensor_data``), so that a slow or distant consumer never slows the driver nor
receives stale data late. The driver keeps only the last :data:`RAW_FRAMES_DEPTH` frames per
layer for a reliable reader that lags (a bounded queue, never a growing one).

Every publisher and subscription of ``eit_driver``, ``eit_reconstruction`` and
``eit_classifier`` is created with :data:`OVERRIDABLE` (rclpy's ``QoSOverridingOptions``,
as ouster-ros and realsense-ros expose their QoS): read-only parameters
``qos_overrides.<topic>.<publisher|subscription>.<history|depth|reliability>`` given at start
(a parameters file, ``--ros-args -p``) replace these defaults, e.g.
``qos_overrides./arm/pressure/frames.publisher.reliability: best_effort``. docs/nodes.md
lists the defaults.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions

#: Frames a driver keeps per layer for a reliable reader that lags (0.2 s at 50 Hz).
RAW_FRAMES_DEPTH = 10

RAW_FRAMES = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=RAW_FRAMES_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
"""What the driver publishes its raw frames with: reliable, bounded depth, volatile."""

SENSOR_READER = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=20,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)
"""How the consumers read frames: best effort, with room for a short burst."""

OVERRIDABLE = QoSOverridingOptions.with_default_policies()
"""History, depth and reliability of a publisher or subscription overridable by parameters."""
