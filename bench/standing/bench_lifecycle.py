"""Lifecycle transitions of 10 managed drivers, as a lifecycle manager sees them.

Ten ``eit_driver`` processes (simulator; the shipped arm, face and elbow patches in turn,
each in its own namespace) start with ``autostart:=false``. This process plays the robot's
lifecycle manager: it sends each ChangeState request over DDS and times request -> response
(the transition's callbacks run in between), driver after driver, through configure,
activate, deactivate, activate, deactivate, cleanup, configure, activate; then all ten
deactivate and activate at once. For activate it also times the first frame received after
the request. Writes bench/standing/lifecycle.md (goal of issue 38: every transition < 1 s).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_lifecycle [--drivers 10]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eit_bench_log_"))

from eit_skin_msgs.msg import EitFrame
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState

from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.ros.node_graph import ROBOT_PATCHES
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import patch_topics

SEQUENCE = (
    "configure",
    "activate",
    "deactivate",
    "activate",
    "deactivate",
    "cleanup",
    "configure",
    "activate",
)
TRANSITIONS = {
    "configure": Transition.TRANSITION_CONFIGURE,
    "activate": Transition.TRANSITION_ACTIVATE,
    "deactivate": Transition.TRANSITION_DEACTIVATE,
    "cleanup": Transition.TRANSITION_CLEANUP,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drivers", type=int, default=10)
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("lifecycle.md"))
    args = parser.parse_args()
    logs = Path(tempfile.mkdtemp(prefix="eit_bench_lifecycle_"))
    probe = Probe("bench_lifecycle_manager")
    drivers, clients, topics = [], [], []
    for i in range(args.drivers):
        patch, namespace = ROBOT_PATCHES[i % len(ROBOT_PATCHES)], f"/bench_lc_{i}"
        params = {"patch_config": patch, "autostart": False}
        drivers.append(start_node("eit_driver", namespace, params, logs / f"driver_{i}.log"))
        clients.append(
            probe.node.create_client(ChangeState, f"{namespace}/eit_driver/change_state")
        )
        layer = load_patch(config_path(patch)).layers[0].name
        topics.append(patch_topics(load_patch(config_path(patch)), namespace).layers[layer].frames)
        probe.subscribe(EitFrame, topics[-1])
    try:
        for client in clients:
            assert client.wait_for_service(300.0), "a driver did not start"
        rows: dict[str, list[float]] = {name: [] for name in SEQUENCE}  # s, every round
        first_frame: list[float] = []

        def change(i: int, name: str) -> float:
            started = time.perf_counter()
            request = ChangeState.Request(transition=Transition(id=TRANSITIONS[name]))
            future = clients[i].call_async(request)
            assert probe.spin_until(future.done, 60.0) and future.result().success, (i, name)
            return time.perf_counter() - started

        for name in SEQUENCE:
            for i in range(args.drivers):
                sent = time.perf_counter()
                frames = len(probe.messages[topics[i]])
                rows[name].append(change(i, name))
                if name == "activate":
                    assert probe.spin_until(
                        lambda t=topics[i], n=frames: len(probe.messages[t]) > n, 60.0
                    )
                    first_frame.append(time.perf_counter() - sent)
        together = {}
        for name in ("deactivate", "activate"):
            started = time.perf_counter()
            request = ChangeState.Request(transition=Transition(id=TRANSITIONS[name]))
            futures = [client.call_async(request) for client in clients]
            assert probe.spin_until(lambda fs=futures: all(f.done() for f in fs), 60.0)
            assert all(f.result().success for f in futures)
            together[name] = time.perf_counter() - started
    finally:
        codes = [stop_node(process) for process in drivers]
        probe.close()
    assert codes == [0] * len(codes), codes
    load = os.getloadavg()
    lines = [
        f"# Lifecycle transitions of {args.drivers} managed drivers",
        "",
        f"`{' '.join(['python', *sys.argv])}` on {platform.node()}: {os.cpu_count()} cores, "
        f"Python {platform.python_version()}; load average {load[0]:.1f} / {load[1]:.1f} / "
        f"{load[2]:.1f} (1 / 5 / 15 min) at the end: measured on a machine shared with other "
        "jobs, not an idle one. Simulator drivers (arm, face, elbow in turn), one process "
        "each; the times are ChangeState request -> response over DDS from a manager in "
        "another process, one driver after the other.",
        "",
        "| transition | n | median | max | all < 1 s |",
        "|---|---|---|---|---|",
    ]
    for name in dict.fromkeys(SEQUENCE):  # each transition once, all its rounds together
        values = np.array(rows[name])
        lines.append(
            f"| {name} | {values.size} | {np.median(values) * 1e3:.0f} ms | "
            f"{values.max() * 1e3:.0f} ms | {'yes' if values.max() < 1.0 else 'NO'} |"
        )
    lines += [
        f"| activate -> first frame received | {len(first_frame)} | "
        f"{np.median(first_frame) * 1e3:.0f} ms | {max(first_frame) * 1e3:.0f} ms | "
        f"{'yes' if max(first_frame) < 1.0 else 'NO'} |",
        *(
            f"| all {args.drivers} {name} at once (until the last answer) | 1 | "
            f"{t * 1e3:.0f} ms | {t * 1e3:.0f} ms | {'yes' if t < 1.0 else 'NO'} |"
            for name, t in together.items()
        ),
        "",
        "configure, the slowest, loads the patch and builds the simulator; activate and "
        "deactivate only start and stop the frame timer; cleanup drops "
        "the source and the publishers. A board driver's configure opens the port and starts "
        "its reader thread instead of the simulator (not measured here).",
    ]
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
