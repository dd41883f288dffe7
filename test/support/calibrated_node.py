"""A reconstruction node with a press calibration, driven by a test's probe.

Shared by test/ros/test_calibrated_contacts_node.py and test_calibrated_multi_touch_node.py:
wait until a started node hears the probe's frame publisher and publishes ``calibrated_contacts``,
and read its pressure layer's ``reference_ready`` from ``/diagnostics``.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

from eit_skin.ros.probe import Probe
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
