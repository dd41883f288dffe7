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
# one BLAS thread per process: two workers and their nodes already fill both cores, and
# OpenBLAS threads spinning beside them made a numeric test up to 10x slower (4 -> 42 s)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# reconstruction matrices: make test keeps them in build/cache; never in the home folder
os.environ.setdefault("EIT_SKIN_CACHE", tempfile.mkdtemp(prefix="eit_skin_cache_"))


def _compile_frame_kernel_once() -> None:
    """The compiled frame kernel in a disk cache of this run's own, filled here by the first
    pytest process before its xdist workers and any node start: every later process (node,
    command, worker) loads it, about 0.3 s of CPU, instead of compiling it, about 1.5 s.
    Written once and then only read, so processes that start together never write it at
    the same time (numba issue #4807, eit_skin.pipeline.frame_kernel)."""
    if "NUMBA_CACHE_DIR" in os.environ:  # a worker: its first process filled it
        return
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="eit_skin_numba_")
    os.environ["EIT_SKIN_JIT_CACHE"] = "1"
    from eit_skin.pipeline.frame_kernel import compiled_step_status

    compiled_step_status()


_compile_frame_kernel_once()


#: Most a test's time budget is stretched on a loaded machine.
MOST_SLOWDOWN = 5.0


def _machine_slowdown() -> float:
    """How much slower than idle this machine runs the suite: the 1-min load average per
    core before the suite starts (its own workers not yet counted), at least 1, at most
    :data:`MOST_SLOWDOWN`. Measured once by the first pytest process; its xdist workers
    inherit it through the environment."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    return min(max(1.0, load / (os.cpu_count() or 1)), MOST_SLOWDOWN)


os.environ.setdefault("EIT_SKIN_TEST_SLOWDOWN", f"{_machine_slowdown():.2f}")
SLOWDOWN = float(os.environ["EIT_SKIN_TEST_SLOWDOWN"])


def _budget_s(item: pytest.Item) -> float | None:
    """The test's own budget: its ``timeout`` mark, else the run's default (pytest.ini or
    ``--timeout``); None when it has none."""
    mark = item.get_closest_marker("timeout")
    if mark is not None:
        return float(mark.args[0] if mark.args else mark.kwargs["timeout"])
    default = item.config.getoption("timeout", None) or item.config.getini("timeout")
    return float(default) if default else None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Time budgets are for an idle machine: on a loaded one each is stretched by
    :data:`SLOWDOWN`, so that a healthy test on a busy machine is not cut off while a hang
    still names itself (within a minute when idle)."""
    if SLOWDOWN == 1.0:
        return
    for item in items:
        budget = _budget_s(item)
        if budget:  # prepended: nearer than the test's own mark
            item.add_marker(pytest.mark.timeout(budget * SLOWDOWN), append=False)


def pytest_report_header(config: pytest.Config) -> str:
    default = config.getoption("timeout", None) or config.getini("timeout")
    return (
        f"time budget per test: {default} s (longer where marked) x {SLOWDOWN:g} for this "
        f"machine's load ({os.cpu_count()} cores)"
    )


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository root."""
    return REPO
