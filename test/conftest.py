"""Test-wide isolation: every run gets its own DDS domain, discovery stays on
localhost, and ROS logs go to a temporary folder (never ~/.ros)."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Before any test module imports rclpy: a domain id per pytest process (so two
# runs on one machine never see each other), localhost-only discovery, logs
# under build/ or /tmp. Child processes inherit these.
os.environ["ROS_DOMAIN_ID"] = str(1 + os.getpid() % 100)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eit_skin_ros_log_"))
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
# reconstruction matrices: make test keeps them in build/cache; never in the home folder
os.environ.setdefault("EIT_SKIN_CACHE", tempfile.mkdtemp(prefix="eit_skin_cache_"))


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository root."""
    return REPO
