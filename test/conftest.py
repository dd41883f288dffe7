"""Test-wide isolation: every run gets its own DDS domain, discovery stays on
localhost, and ROS logs go to a temporary folder (never ~/.ros)."""

from __future__ import annotations

import fcntl
import os
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _claim_domain_id() -> tuple[int, object]:
    """A DDS domain no other pytest run on this machine holds: an exclusive lock on
    /tmp/eit_skin_domain_<id>.lock, kept for the life of this process (the kernel drops
    it when the process ends, however it ends). Domains 1-100, starting from the pid so
    concurrent runs rarely try the same one first."""
    start = os.getpid() % 100
    for offset in range(100):
        domain = 1 + (start + offset) % 100
        lock = open(Path(tempfile.gettempdir()) / f"eit_skin_domain_{domain}.lock", "a")  # noqa: SIM115
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        return domain, lock
    raise RuntimeError("all DDS domains 1-100 are held by other test runs on this machine")


# Before any test module imports rclpy: a domain id per pytest process (so runs in
# parallel on one machine never see each other), localhost-only discovery, logs
# under build/ or /tmp. Child processes inherit these.
_DOMAIN, _DOMAIN_LOCK = _claim_domain_id()
os.environ["ROS_DOMAIN_ID"] = str(_DOMAIN)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eit_skin_ros_log_"))
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
# reconstruction matrices: make test keeps them in build/cache; never in the home folder
os.environ.setdefault("EIT_SKIN_CACHE", tempfile.mkdtemp(prefix="eit_skin_cache_"))


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository root."""
    return REPO
