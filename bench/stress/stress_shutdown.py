"""Shutdown stress: face graphs signalled at random moments, hung or crashed nodes reported.

Usage: `.venv/bin/python -m bench.stress.stress_shutdown ROUNDS BATCH OUTDIR` (environment as
for the tests: AMENT_PREFIX_PATH, ROS_LOG_DIR, ROS_DOMAIN_ID, EIT_SKIN_CACHE). Prints "bad N
bounded M" at the end (M: stops whose DDS teardown was cut by the native exit timer, exit 0).

On a process alive EXIT_S after its signal: SIGUSR1 (faulthandler Python stacks) then gdb
C stacks into the log dir; on a negative exit code: its log is printed.
"""

from __future__ import annotations

import contextlib
import random
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from sensor_msgs.msg import Image

from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.ros.bringup import start
from eit_skin.ros.node_graph import patch_nodes
from eit_skin.ros.probe import Probe
from eit_skin.ros.topics import patch_topics

ROUNDS = int(sys.argv[1]) if len(sys.argv) > 1 else 5
BATCH = int(sys.argv[2]) if len(sys.argv) > 2 else 5
OUT = Path(sys.argv[3] if len(sys.argv) > 3 else "/tmp/stress")
EXIT_S = 20.0


def image_topic(ns: str) -> str:
    topics = patch_topics(load_patch(config_path("face")), ns)
    return next(iter(topics.layers.values())).image


rng = random.Random(int(time.time()))
probe = Probe("stress_probe")
bad = 0
bounded = 0  # exits 0 after a stuck DDS teardown (docs/nodes.md, Stopping)
for rnd in range(ROUNDS):
    graphs = {}
    for run in range(BATCH):
        ns = f"/s{rnd}_{run}"
        driver, *others = patch_nodes("face", namespace=ns)
        rec = {**driver.parameters, "record_path": str(OUT / f"{rnd}_{run}.mcap")}
        probe.subscribe(Image, image_topic(ns))
        graphs[ns] = [
            start(s, OUT / f"logs{rnd}") for s in [replace(driver, parameters=rec), *others]
        ]
    procs = [n.process for g in graphs.values() for n in g]
    topics = [image_topic(ns) for ns in graphs]
    probe.spin_until(
        lambda topics=topics, procs=procs: (
            all(probe.messages[t] for t in topics) or any(p.poll() is not None for p in procs)
        ),
        300,
    )
    missing = [t for t in topics if not probe.messages[t]]
    died = [
        (n.label, n.process.returncode)
        for g in graphs.values()
        for n in g
        if n.process.poll() is not None
    ]
    print(f"round {rnd}: missing {missing} died {died}", flush=True)
    for g in graphs.values():
        probe.spin_for(rng.uniform(0, 0.4))
        sigs = [signal.SIGINT] * 2 if rng.random() < 0.5 else [signal.SIGTERM]
        for s in sigs:
            for n in g:
                if n.process.poll() is None:
                    n.process.send_signal(s)
    deadline = time.monotonic() + EXIT_S
    for g in graphs.values():
        for n in g:
            with contextlib.suppress(subprocess.TimeoutExpired):
                n.process.wait(max(0.1, deadline - time.monotonic()))
    for g in graphs.values():
        for n in g:
            code = n.process.poll()
            if code is None:
                bad += 1
                print(f"HANG {n.label} pid {n.process.pid}", flush=True)
                n.process.send_signal(signal.SIGUSR1)
                time.sleep(1)
                gdb = subprocess.run(
                    ["gdb", "-p", str(n.process.pid), "-batch", "-ex", "thread apply all bt"],
                    capture_output=True,
                    text=True,
                    timeout=120,
                )
                (OUT / f"gdb_{rnd}_{n.label.replace('/', '_')}.txt").write_text(
                    gdb.stdout + gdb.stderr
                )
                n.process.kill()
                n.process.wait()
                print(n.log_path.read_text()[-6000:], flush=True)
            elif code != 0:
                bad += 1
                print(f"EXIT {code} {n.label}", flush=True)
                print(n.log_path.read_text()[-6000:], flush=True)
            else:
                log = n.log_path.read_text()
                if "teardown not done" in log:  # rclpy's teardown was cut by the native exit timer
                    bounded += 1
                    print(f"BOUNDED {n.label}\n{log[-3000:]}", flush=True)
                elif "Traceback" in log or "FATAL" in log:
                    bad += 1
                    print(f"DIRTY {n.label}\n{log[-3000:]}", flush=True)
probe.close()
print(f"bad {bad} bounded {bounded}")
