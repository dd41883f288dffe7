"""Start and stop the node graph of :mod:`eit_skin.ros.node_graph` as separate processes.

This is what ``eit-skin run`` uses instead of ``ros2 launch`` (which needs launch_ros): the
same :class:`~eit_skin.ros.node_graph.NodeSpec` list the launch files build, each node started
as its console script with ``--ros-args`` remappings and parameters.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from eit_skin.ros.node_graph import NODE_ENVIRONMENT, NodeSpec


def find_executable(name: str) -> Path:
    """Path of an ``eit_skin`` console script.

    Looked up next to this Python (venv), in an ament install (``<prefix>/lib/eit_skin``),
    then on ``PATH``.
    """
    candidates = [Path(sys.executable).parent / name]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "lib" / "eit_skin" / name)
    for candidate in candidates:
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"executable {name!r} not found (is eit_skin installed?)")
    return Path(found)


EMPTY_STRING = "''"
"""An empty string parameter on the command line (``port:=''``; ``port:=`` would be null)."""


def ros_arguments(spec: NodeSpec) -> list[str]:
    """``--ros-args`` for a node: its name, namespace and parameters."""
    args = ["--ros-args", "-r", f"__node:={spec.name}", "-r", f"__ns:={spec.namespace}"]
    for key, value in spec.parameters.items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        args += ["-p", f"{key}:={text or EMPTY_STRING}"]
    return args


@dataclass
class RunningNode:
    """A started node process and where its output goes."""

    spec: NodeSpec
    process: subprocess.Popen
    log_path: Path

    @property
    def label(self) -> str:
        return f"{self.spec.namespace}/{self.spec.name}"


PR_SET_PDEATHSIG = 1
"""prctl option (Linux): the signal a process gets when its parent dies."""


def _stop_with_parent(parent: int) -> None:
    """In a started node, between fork and exec: SIGTERM when the starter dies (Linux).

    So a killed ``eit-skin run`` (SIGKILL, OOM killer) leaves no node graph behind. The
    kernel ties this to the starting thread: :func:`start` is called from the main thread.
    """
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != parent:  # the starter died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)


def start(spec: NodeSpec, log_dir: Path) -> RunningNode:
    """Start one node; its stdout/stderr go to ``log_dir/<namespace>_<name>.log``.

    On Linux the node gets SIGTERM (a clean stop) if this process dies without stopping it.
    """
    log_dir.mkdir(parents=True, exist_ok=True)
    log_path = log_dir / f"{spec.namespace.strip('/').replace('/', '_')}_{spec.name}.log"
    command = [str(find_executable(spec.executable)), *ros_arguments(spec)]
    env = {**NODE_ENVIRONMENT, **os.environ}
    parent = os.getpid()
    on_linux = sys.platform.startswith("linux")
    with log_path.open("w") as log:
        process = subprocess.Popen(
            command,
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            preexec_fn=(lambda: _stop_with_parent(parent)) if on_linux else None,
        )
    return RunningNode(spec, process, log_path)


#: Wait (s) for a node after its SIGINT before SIGKILL: above the ceilings of its own
#: clean-up (15 s) and of rclpy's teardown (3.5 s) in eit_skin.ros.node_runner, so a hung
#: node's watchdog prints its stacks to its log before the kill.
STOP_TIMEOUT_S = 20.0


def stop(nodes: list[RunningNode], timeout_s: float = STOP_TIMEOUT_S) -> dict[str, int]:
    """SIGINT every node (like Ctrl-C in ros2 launch), then wait; returns exit codes."""
    for node in nodes:
        if node.process.poll() is None:
            node.process.send_signal(signal.SIGINT)
    codes = {}
    for node in nodes:
        try:
            codes[node.label] = node.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            node.process.kill()
            codes[node.label] = node.process.wait()
    return codes


def last_lines(path: Path, n: int = 5) -> str:
    """The last lines of a node log, for error messages."""
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""
