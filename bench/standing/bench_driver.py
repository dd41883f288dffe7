"""Driver latency: last byte of a frame written to the pty -> EitFrame received over DDS.

A FakeDevice writes wire frames at 100 Hz and 1 kHz into a pseudo-terminal; a real
``eit_driver`` process reads it and publishes; this process subscribes and compares the
reception time of every frame with the time its last byte was written (same host clock).
The figure includes DDS delivery to the subscriber, so it is an upper bound of "last byte
-> publish". Writes bench/driver.md.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_driver [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eit_bench_log_"))

from eit_skin_msgs.msg import EitFrame
from rclpy.qos import QoSProfile, ReliabilityPolicy

from bench.header import run_header
from eit_skin.hardware.fake_device import FakeDevice
from eit_skin.hardware.wire import encode_frame
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import patch_topics

TOPIC = patch_topics(load_patch(config_path("arm")), "/bench").layers["pressure"].frames


def frame_writer(
    device: FakeDevice, rate_hz: float, written: dict[int, int], stop: threading.Event
):
    """A thread body writing whole frames to the pty at ``rate_hz``, noting when each is out."""

    def writer() -> None:
        period = 1.0 / rate_hz
        start = time.perf_counter()
        i = 0
        while not stop.is_set():
            data = encode_frame(device.frame(i, device_time_us=int(i * period * 1e6)))
            view = memoryview(data)
            while view:  # the pty master is non-blocking: write the whole frame
                try:
                    view = view[os.write(device._master, view) :]
                except BlockingIOError:
                    time.sleep(0.0001)
            written[i] = time.time_ns()
            i += 1
            delay = start + i * period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)

    return writer


def in_process(rate_hz: float, seconds: float, workdir: Path) -> dict[str, float]:
    """The real DriverNode in this process: last byte written -> its publish() returned."""
    import rclpy
    from rclpy.parameter import Parameter

    from eit_skin.ros.driver import DriverNode

    volts = np.random.default_rng(2).normal(0, 0.05, (64, 208))
    device = FakeDevice(lambda i: volts[i % 64], rate_hz=rate_hz)
    device.open()
    link = workdir / f"eit_bench_inproc_{int(rate_hz)}"
    device.link(link)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = DriverNode(
        context=context,
        namespace="/bench_inproc",
        parameter_overrides=[
            Parameter("patch_config", value="arm"),
            Parameter("port", value=str(link)),
            Parameter("layer", value="pressure"),
        ],
    )
    published: dict[int, int] = {}
    sink = node.source.sink  # the node's publish, called on the serial reader thread

    def timed(record) -> None:
        sink(record)
        published.setdefault(record.sequence, time.time_ns())

    node.source.sink = timed
    written: dict[int, int] = {}
    stop = threading.Event()
    time.sleep(1.0)
    thread = threading.Thread(target=frame_writer(device, rate_hz, written, stop), daemon=True)
    thread.start()
    time.sleep(seconds)
    stop.set()
    thread.join()
    time.sleep(0.3)
    node.destroy_node()
    rclpy.shutdown(context=context)
    device.close()
    common = sorted(set(written) & set(published))[int(rate_hz) :]
    ms = np.array([(published[k] - written[k]) / 1e6 for k in common])
    return {"median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99))}


def measure(rate_hz: float, seconds: float, workdir: Path) -> dict[str, float]:
    volts = np.random.default_rng(1).normal(0, 0.05, (64, 208))
    device = FakeDevice(lambda i: volts[i % 64], rate_hz=rate_hz)
    device.open()
    link = workdir / f"eit_bench_{int(rate_hz)}"
    device.link(link)
    written: dict[int, int] = {}
    probe = Probe("bench_probe")
    received: dict[int, int] = {}
    probe.node.create_subscription(
        EitFrame,
        TOPIC,
        lambda m: received.setdefault(m.sequence, time.time_ns()),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT),
    )
    node = start_node(
        "eit_driver", "/bench", {"patch_config": "arm", "port": str(link), "layer": "pressure"},
        workdir / f"driver_{int(rate_hz)}.log",
    )  # fmt: skip
    stop = threading.Event()
    writer = frame_writer(device, rate_hz, written, stop)

    time.sleep(2.0)  # driver start-up and discovery
    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    probe.spin_for(seconds)
    stop.set()
    thread.join()
    probe.spin_for(0.5)
    stop_node(node)
    probe.close()
    device.close()
    if not received:
        raise SystemExit(f"no frames received; driver log: {workdir}")
    common = sorted(set(written) & set(received))[int(rate_hz) :]  # skip the first second
    latency_ms = np.array([(received[k] - written[k]) / 1e6 for k in common])
    return {
        "rate_hz": rate_hz,
        "frames_written": len(written),
        "frames_received": len(received),
        "median_ms": float(np.median(latency_ms)),
        "p99_ms": float(np.percentile(latency_ms, 99)),
        "max_ms": float(latency_ms.max()),
    }


PUBLISHER = """
import sys, time, array, rclpy
from eit_skin_msgs.msg import EitFrame
from rclpy.qos import qos_profile_sensor_data
rate, seconds, topic = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
rclpy.init()
node = rclpy.create_node("bench_dds_publisher")
pub = node.create_publisher(EitFrame, topic, qos_profile_sensor_data)
time.sleep(2.0)
volts = array.array("f", [0.01] * 208)
start = time.perf_counter()
for k in range(int(rate * seconds)):
    msg = EitFrame(n_electrodes=16, voltages=volts, sequence=k)
    now = time.time_ns()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 10**9)
    pub.publish(msg)
    delay = start + (k + 1) / rate - time.perf_counter()
    if delay > 0:
        time.sleep(delay)
"""


def dds_baseline(rate_hz: float, seconds: float) -> dict[str, float]:
    """Publish -> receive of the same EitFrame between two Python processes (no driver)."""
    import subprocess

    probe = Probe("bench_baseline")
    latency: list[float] = []
    probe.node.create_subscription(
        EitFrame,
        TOPIC,
        lambda m: latency.append(
            (time.time_ns() - (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)) / 1e6
        ),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT),
    )
    proc = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(rate_hz), str(seconds), TOPIC])
    probe.spin_until(lambda: proc.poll() is not None, seconds + 30)
    probe.spin_for(0.3)
    probe.close()
    ms = np.array(latency[int(rate_hz) :])
    return {"median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("driver.md"))
    args = parser.parse_args()
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="eit_bench_driver_"))
    for rate in (100.0, 1000.0):
        rows.append(measure(rate, args.seconds, tmp))
        r = rows[-1]
        base = dds_baseline(rate, args.seconds)
        r["dds_median_ms"], r["dds_p99_ms"] = base["median_ms"], base["p99_ms"]
        own = in_process(rate, args.seconds, tmp)
        r["own_median_ms"], r["own_p99_ms"] = own["median_ms"], own["p99_ms"]
        print(f"{rate:6.0f} Hz: {r['frames_received']}/{r['frames_written']} frames, "
              f"median {r['median_ms']:.3f} ms, p99 {r['p99_ms']:.3f} ms; "
              f"DDS alone median {base['median_ms']:.3f} ms; last byte -> publish() "
              f"median {own['median_ms']:.3f} ms, p99 {own['p99_ms']:.3f} ms")  # fmt: skip
    lines = [
        "# Driver latency (last byte written to the pty -> EitFrame received)",
        "",
        f"{run_header()} {args.seconds:g} s per rate, first second skipped. Includes DDS "
        "delivery to a subscriber in another process, so it bounds last byte -> publish from "
        "above.",
        "",
        "| rate | frames written | received | median | p99 | max | DDS alone: median | p99 "
        "| driver share (median difference) | last byte -> publish(): median | p99 |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['rate_hz']:.0f} Hz | {r['frames_written']} | {r['frames_received']} | "
        f"{r['median_ms']:.3f} ms | {r['p99_ms']:.3f} ms | {r['max_ms']:.3f} ms | "
        f"{r['dds_median_ms']:.3f} ms | {r['dds_p99_ms']:.3f} ms | "
        f"{r['median_ms'] - r['dds_median_ms']:.3f} ms | {r['own_median_ms']:.3f} ms | "
        f"{r['own_p99_ms']:.3f} ms |"
        for r in rows
    ]
    lines += [
        "",
        "DDS alone: the same EitFrame published by a plain Python process at the same rate and "
        "received by the same subscriber, stamped at publish; the driver's share (last byte -> "
        "publish, including the pty read) is the end-to-end median minus that. Last byte -> "
        "publish(): the real DriverNode run inside the benchmark process, timed from the write "
        "of a frame's last byte to the return of the node's publish for it (the target's "
        "definition).",
    ]
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
