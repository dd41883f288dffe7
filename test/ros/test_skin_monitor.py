"""The `eit-skin run` monitor: touch pictures never hold its run loop back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rclpy

from eit_skin.ros.node_graph import patch_nodes
from eit_skin.ros.skin_monitor import SkinMonitor, patch_views


def test_touch_pictures_are_written_one_per_pass_when_asked(tmp_path: Path) -> None:
    """Touches queue pictures faster than a loaded machine draws them (seconds each): the run
    loop writes one per pass, so its duration check still comes between two pictures."""
    rclpy.init()
    try:
        out = tmp_path
        monitor = SkinMonitor(patch_views(patch_nodes("face")), out, {})
        view = monitor.views[0]
        image = np.linspace(0.0, 5e4, 64 * 45).reshape(45, 64)
        monitor.pending_snapshots = [(view, {"pressure": image}, f"push{k}") for k in range(3)]
        monitor.save_pending_snapshots(limit=1)
        assert sorted(p.name for p in out.glob("*.png")) == ["face_01_push0.png"]
        assert [label for *_, label in monitor.pending_snapshots] == ["push1", "push2"]
        monitor.save_pending_snapshots()  # at the end of the run: every one left
        assert len(list(out.glob("*.png"))) == 3 and not monitor.pending_snapshots
        monitor.destroy_node()
    finally:
        rclpy.shutdown()
