"""A reconstruction node with a press calibration, driven by a test's probe.

Shared by test/ros/test_calibrated_contacts_node.py and test_calibrated_multi_touch_node.py:
wait until a started node hears the probe's frame publisher and publishes ``calibrated_contacts``,
read its pressure layer's ``reference_ready`` from ``/diagnostics``, and feed it frames
(:class:`CalibratedFeed`).
"""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.patch.model import Layer
from eit_skin.ros.probe import Probe, frame_msg, stamp_ns
from eit_skin.ros.topics import DIAGNOSTICS
from test.support.patience import EVENT_S


def wait_linked(
    probe: Probe, node: subprocess.Popen, publisher: Any, contacts_topic: str, log: Path
) -> None:
    """Until ``node`` hears ``publisher`` and publishes ``contacts_topic`` (or exits: the
    assertion then shows the node's ``log``)."""
    linked = probe.spin_until(
        lambda: (
            node.poll() is not None
            or (
                publisher.get_subscription_count() > 0
                and probe.node.count_publishers(contacts_topic) > 0
            )
        ),
        EVENT_S,
    )
    assert linked and node.poll() is None, log.read_text()


def reference_ready(probe: Probe) -> bool:
    """The node's pressure layer reported its no-load reference taken (``/diagnostics``)."""
    return any(
        kv.key == "reference_ready" and kv.value == "true"
        for _, msg in probe.messages[DIAGNOSTICS]
        for status in msg.status
        if status.name.endswith("eit_reconstruction: pressure")
        for kv in status.values
    )


class CalibratedFeed:
    """Frames to the node (numbered from 0) and, for each, its calibrated contacts array."""

    def __init__(
        self, probe: Probe, publisher: Any, layer: Layer, contacts_topic: str, log: Path
    ) -> None:
        self.probe, self.publisher, self.layer, self.log = probe, publisher, layer, log
        self.got = probe.messages[contacts_topic]
        self.sent = 0

    def take_reference(self, unloaded: Sequence[np.ndarray], most: int) -> None:
        """Publish the ``unloaded`` frames in turn until the node reports its reference taken
        (a short wait after each frame, a long one after each round; at most ``most``)."""
        while not reference_ready(self.probe):
            assert self.sent < most, self.log.read_text()
            voltages = unloaded[self.sent % len(unloaded)]
            self.publisher.publish(frame_msg(self.layer, self.sent, voltages))
            self.sent += 1
            patience = 0.1 if self.sent % len(unloaded) else 5
            self.probe.spin_until(lambda: reference_ready(self.probe), patience)

    def send(self, voltages: np.ndarray) -> Any:
        """Publish a frame, wait for its calibrated array (best effort: resend if lost)."""
        for _attempt in range(5):
            msg = frame_msg(self.layer, self.sent, voltages)
            self.sent += 1
            stamp = stamp_ns(msg)
            self.publisher.publish(msg)
            if self.probe.spin_until(
                lambda s=stamp: any(stamp_ns(m) == s for _, m in self.got), 30
            ):
                return next(m for _, m in self.got if stamp_ns(m) == stamp)
        raise AssertionError(self.log.read_text())
