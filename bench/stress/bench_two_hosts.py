"""Patches across a link between two emulated hosts: lost frames, latency, recovery from a cut.

``sudo python -m bench.stress.bench_two_hosts --patches 10 --rate 100 --seconds 300 --cut 5``

Host A (network namespace, 10.39.0.1) runs ``--patches`` simulated drivers (the face patch,
no touch, ``--rate`` Hz, namespaces ``/p0``, ``/p1``, ...); host B (10.39.0.2), joined by a
veth pair, runs this script again as the observer: it subscribes every patch's frames
RELIABLE (what a recorder or a remote consumer asking for reliability gets; REP 2003) and
counts them by sequence number. Discovery by ``ROS_STATIC_PEERS``, UDP only (no shared
memory across the emulated hosts). After ``--seconds`` the link is pulled for ``--cut`` s,
restored, and watched for as long again. Printed: frames received and lost per patch before
the cut, latency (acquisition stamp to arrival on B; one kernel, one clock), and how long
after the link came up every patch's frames arrived again. Needs root and ``ip``
(iproute2); nodes are never restarted.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

SUBNET = "10.39.0"


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=30)


def observe(namespaces: list[str], out: Path) -> None:
    """Host B: count frames per patch until SIGINT, then write the summary to ``out``."""
    import numpy as np
    import rclpy
    from eit_skin_msgs.msg import EitFrame
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = Node("two_host_bench_observer")
    heard: dict[str, list[tuple[int, int, int]]] = {ns: [] for ns in namespaces}
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    for ns in namespaces:
        node.create_subscription(
            EitFrame,
            f"{ns}/pressure/frames",
            lambda m, ns=ns: heard[ns].append(
                (time.time_ns(), m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.sequence)
            ),
            qos,
        )
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    while not stop:
        rclpy.spin_once(node, timeout_sec=0.1)
    summary = {
        ns: np.array(rows, dtype=np.int64).tolist() if rows else [] for ns, rows in heard.items()
    }
    out.write_text(json.dumps(summary))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--patches", type=int, default=10)
    parser.add_argument("--rate", type=float, default=100.0, help="frames per second per patch")
    parser.add_argument("--seconds", type=float, default=300.0, help="before the cut, s")
    parser.add_argument("--cut", type=float, default=5.0, help="link down for this long, s")
    parser.add_argument("--observe", default="", help=argparse.SUPPRESS)
    parser.add_argument("--out", default="", help=argparse.SUPPRESS)
    args = parser.parse_args()
    namespaces = [f"/p{i}" for i in range(args.patches)]
    if args.observe:
        observe(args.observe.split(","), Path(args.out))
        return 0
    import numpy as np

    from eit_skin.ros.bringup import find_executable, ros_arguments
    from eit_skin.ros.node_graph import NodeSpec

    tag = str(os.getpid() % 100000)
    a, b, link = f"bth{tag}a", f"bth{tag}b", f"w{tag}a"
    ip("netns", "add", a)
    ip("netns", "add", b)
    work = Path(f"/tmp/bench_two_hosts_{tag}")
    work.mkdir()
    processes = []
    try:
        ip("link", "add", link, "type", "veth", "peer", "name", f"w{tag}b")
        ip("link", "set", link, "netns", a)
        ip("link", "set", f"w{tag}b", "netns", b)
        ip("-n", a, "addr", "add", f"{SUBNET}.1/24", "dev", link)
        ip("-n", b, "addr", "add", f"{SUBNET}.2/24", "dev", f"w{tag}b")
        for host, dev in ((a, link), (b, f"w{tag}b")):
            ip("-n", host, "link", "set", "lo", "up")
            ip("-n", host, "link", "set", dev, "up")
        base = dict(
            os.environ,
            ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET",
            FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
            ROS_LOG_DIR=str(work / "ros_log"),
            OPENBLAS_NUM_THREADS="1",
        )
        for ns in namespaces:
            params = {
                "patch_config": "face",
                "scenario": "idle",
                "rate_hz": args.rate,
                "wait_for_subscribers": 0,
            }
            spec = NodeSpec("eit_driver", "eit_driver", ns, params)
            command = [str(find_executable("eit_driver")), *ros_arguments(spec)]
            log = (work / f"driver{ns.replace('/', '_')}.log").open("w")
            processes.append(
                subprocess.Popen(
                    ["ip", "netns", "exec", a, *command],
                    env={**base, "ROS_STATIC_PEERS": f"{SUBNET}.2"},
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )
            )
        out = work / "observed.json"
        observer = subprocess.Popen(
            ["ip", "netns", "exec", b, sys.executable, "-m", __spec__.name,
             "--patches", str(args.patches), "--observe", ",".join(namespaces), "--out", str(out)],
            env={**base, "ROS_STATIC_PEERS": f"{SUBNET}.1"},  # the same venv: no PYTHONPATH
        )  # fmt: skip
        time.sleep(args.seconds)  # a benchmark: the window is the measurement
        ip("-n", a, "link", "set", link, "down")
        cut_ns = time.time_ns()
        time.sleep(args.cut)
        ip("-n", a, "link", "set", link, "up")
        up_ns = time.time_ns()
        time.sleep(max(args.cut, 10.0))
        observer.send_signal(signal.SIGINT)
        observer.wait(60)
        alive = all(p.poll() is None for p in processes)
        observed = json.loads(out.read_text())
    finally:
        for process in processes:
            process.send_signal(signal.SIGINT)
        for process in processes:
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()
        subprocess.run(["ip", "netns", "del", a], capture_output=True)
        subprocess.run(["ip", "netns", "del", b], capture_output=True)
    lost, received, latency, back = 0, 0, [], []
    for rows in observed.values():
        if not rows:
            print("a patch was never heard", file=sys.stderr)
            return 1
        rx, stamp, seq = (np.array(c) for c in zip(*rows, strict=True))
        before = rx < cut_ns
        first = int(np.argmax(before))
        seq_before = np.unique(seq[before][first:])
        received += seq_before.size
        lost += int(seq_before.max() - seq_before.min() + 1 - seq_before.size)
        latency.extend(((rx - stamp)[before] / 1e6).tolist())
        after = rx >= up_ns
        back.append((rx[after].min() - up_ns) / 1e9 if after.any() else float("inf"))
    lat = np.array(latency)
    print(
        f"{args.patches} patches at {args.rate:g} Hz for {args.seconds:g} s across the link: "
        f"{received} frames received, {lost} lost (by sequence number, reliable reader); "
        f"latency median {np.median(lat):.2f} ms, p99 {np.percentile(lat, 99):.2f} ms, "
        f"max {lat.max():.1f} ms; link cut {(up_ns - cut_ns) / 1e9:.1f} s: every patch's "
        f"frames back {max(back):.2f} s after the link came up (median {np.median(back):.2f} s); "
        f"nodes restarted: {'none' if alive else 'SOME EXITED'}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
