"""Board profiles: a frame's last byte on the pty -> its image, for emulated real boards.

An emulated OpenEIT (16 electrodes, replaying data/real/hydrogel_ohmc16) and an emulated
Sciospec EIT32 (32 electrodes, the empty tank's model voltages with a slow wobble) stream on
pseudo-terminals at their links' full rates; a real ``eit_driver`` reads each in the layer's
board profile and a real ``eit_reconstruction`` images it; this process receives the images.
Latency = the image's reception time minus the time the last byte of the latest frame was
written to the pty (frames are 100-235 ms apart, far more than the latency, so an image is
the latest frame's). For the OpenEIT, whose frames are stamped with the host time of their
last byte, the image's own stamp gives the same figure from the driver's side. The first 2 s
after the first image are left out (the backlog of frames that came while the reference was
captured).

    .venv/bin/python -m bench.standing.bench_boards [--seconds 20]  (writes boards.md)
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eit_bench_log_"))

import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from bench.header import run_header
from eit_skin.hardware.board_emulators import OpenEITEmulator
from eit_skin.hardware.sciospec_emulator import SciospecEmulator, SciospecWiring
from eit_skin.io.npz import load_frames_npz
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.pipeline.builder import LayerImager, forward_model
from eit_skin.ros.probe import Probe, stamp_ns, start_node, stop_node
from eit_skin.ros.topics import patch_topics

REPO = Path(__file__).resolve().parents[2]


def disc32(tmp: Path) -> Path:
    """A 32-electrode tank read by a Sciospec EIT32 (adjacent drive, channels 1-32)."""
    data = yaml.safe_load((REPO / "data/real/sciospec_adjacent.yaml").read_text())
    layer = data["layers"][0]
    layer["electrodes"] = {**layer["electrodes"], "count": 32, "width": 0.005}
    layer["device"] = {"profile": "sciospec", "frame_rate_hz": 10.3}
    layer["mesh"] = {
        "max_edge": 0.0075,
        "electrode_edge": 0.0015,
        "min_angle": 30,
        "inverse_max_edge": 0.015,
    }
    data["name"] = "bench_sciospec32"
    path = tmp / "sciospec32.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def openeit16(tmp: Path) -> Path:
    data = yaml.safe_load((REPO / "data/real/hydrogel_ohmc16.yaml").read_text())
    data["layers"][0]["device"] = {"profile": "openeit"}
    data["name"] = "bench_openeit16"
    path = tmp / "openeit16.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def run(name: str, path: Path, board, seconds: float, tmp: Path) -> dict[str, float]:
    patch = load_patch(path)
    layer = patch.layers[0]
    cache = tmp / "cache"
    LayerImager.build(layer, cache_dir=cache)
    topics = patch_topics(patch, f"/{patch.name}").layers[layer.name]
    probe = Probe(f"bench_{name}")
    received: list[tuple[int, int]] = []
    written: list[int] = []  # host time each frame's last byte was written to the pty
    write_frame = board.write_frame

    def timed_write(data: bytes) -> bool:
        ok = write_frame(data)
        if ok and board.pending_bytes == 0:  # the whole frame went into the pty at once
            written.append(time.time_ns())
        return ok

    board.write_frame = timed_write
    probe.node.create_subscription(
        Image,
        topics.image,
        lambda m: received.append((time.time_ns(), stamp_ns(m))),
        qos_profile_sensor_data,
    )
    common = {"patch_config": str(path), "cache_dir": str(cache), "marker_period_s": 0.0}
    recon = start_node("eit_reconstruction", f"/{patch.name}", common, tmp / f"{name}_r.log")
    board.open()
    board.start()
    driver = start_node(
        "eit_driver",
        f"/{patch.name}",
        {"patch_config": str(path), "port": board.slave_path, "publish_tf": False},
        tmp / f"{name}_d.log",
    )
    probe.subscribe(DiagnosticArray, "/diagnostics", 100)
    try:
        if not probe.spin_until(lambda: len(received) > 0, 120):  # reference captured, imaging
            for _, msg in probe.messages["/diagnostics"][-4:]:
                for status in msg.status:
                    print(status.name, status.message, {kv.key: kv.value for kv in status.values})
            raise RuntimeError(f"{name}: no image in 120 s")
        probe.spin_for(2.0)  # the first images: the frames queued while it captured
        received.clear()
        probe.spin_for(seconds)
        n_sent = board.frames_sent
    finally:
        stop_node(driver)
        stop_node(recon)
        board.close()
        probe.close()
    w = np.array(written)
    latency, at = [], []
    for r, _ in received:
        before = w[w <= r]
        if before.size:
            latency.append((r - before[-1]) * 1e-6)
            at.append((r - received[0][0]) * 1e-9)
    latency = np.array(latency)
    slow = [f"{t:.1f} s: {x:.0f} ms" for t, x in zip(at, latency, strict=True) if x > 5.0]
    stamped = np.array([(r - s) * 1e-6 for r, s in received])
    return {
        "stamped_median": float(np.median(stamped)),
        "slow": "; ".join(slow) or "none",
        "images": len(latency),
        "rate": len(latency) / seconds,
        "median": float(np.median(latency)),
        "p99": float(np.percentile(latency, 99)),
        "max": float(latency.max()),
        "sent": n_sent,
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="eit_bench_boards_"))
    rows = []

    path = openeit16(tmp)
    layer = load_patch(path).layers[0]
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    _, frames, _ = load_frames_npz(REPO / "data/real/hydrogel_ohmc16.npz")
    board = OpenEITEmulator(lambda i: frames[i % len(frames)], protocol, rate_hz=4.26)
    rows.append(
        (
            "OpenEIT, 16 electrodes, hydrogel recording",
            "4.26 (115200 bit/s)",
            run("openeit16", path, board, args.seconds, tmp),
        )
    )

    path = disc32(tmp)
    layer = load_patch(path).layers[0]
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    base = forward_model(layer).voltages(layer.material.sheet_conductance_s)  # the empty tank
    board = SciospecEmulator(
        lambda i: base * (1 + 0.01 * np.sin(0.1 * i)),
        protocol,
        rate_hz=10.3,
        wiring=SciospecWiring(channels=32),
    )
    rows.append(
        (
            "Sciospec EIT32, 32 electrodes",
            "10.3 (921600 bit/s)",
            run("sciospec32", path, board, args.seconds, tmp),
        )
    )

    lines = [
        "# Board profiles: last byte -> image (`bench/standing/bench_boards.py`)",
        "",
        f"{run_header()} Emulated boards on "
        "pseudo-terminals at their links' full rates (a pty has no baud rate: the emulators "
        "pace themselves); real eit_driver and eit_reconstruction processes over Fast DDS; "
        "latency = image received minus the time the frame's last byte was written to the pty "
        "(the first 2 s of images left out); last column: image received minus its own stamp "
        "(OpenEIT: the host time the driver read the last byte; Sciospec: its clock mapped to "
        "host time).",
        "",
        "| board | frames/s (link) | images | median | p99 | max | stamp -> received (median) |",
        "|---|---|---:|---:|---:|---:|---:|",
        *(
            f"| {name} | {link} | {r['images']} | {r['median']:.2f} ms | {r['p99']:.2f} ms | "
            f"{r['max']:.2f} ms | {r['stamped_median']:.2f} ms |"
            for name, link, r in rows
        ),
        "",
        "Images slower than 5 ms (time since the first image: latency):",
        "",
        *(f"- {name}: {r['slow']}" for name, _, r in rows),
        "",
        "Goal (issue 34): < 5 ms from the last byte of a frame to its image.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    (Path(__file__).parent / "boards.md").write_text(text)


if __name__ == "__main__":
    main()
