"""``eit-skin record-postures``: record no-load references across a joint's range.

Run it while the skin's driver is publishing and the joint is moved slowly through its
range WITHOUT touching the skin (on the simulator: the driver running a posture-only
scenario). Every frame of every layer is paired with the angle of ``--joint``
(``/joint_states``) interpolated at the frame's acquisition stamp; frames are averaged per
angle bin and written to ``--out``, the file the reconstruction node's
``posture_references`` parameter takes. The ``--duration`` counts from the first frame, so a
driver that is slow to start does not shorten the sweep; Ctrl-C (or SIGTERM) ends the
recording early and still writes what was recorded, so a sweep of unknown length can be
recorded with a long ``--duration`` and stopped when the joint has been through its range.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from eit_skin.cli.options import add_patch_options

if TYPE_CHECKING:
    import numpy as np

    from eit_skin.pipeline.reference import JointAngleHistory
    from eit_skin.ros.topics import PatchTopics


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser, default="elbow", layer=False)
    parser.add_argument("--namespace", default="", help="ROS namespace (default: patch name)")
    parser.add_argument("--joint", required=True, help="joint name in /joint_states")
    parser.add_argument(
        "--duration",
        type=float,
        default=30.0,
        help="recording time from the first frame received, s",
    )
    parser.add_argument(
        "--wait",
        type=float,
        default=60.0,
        help="longest wait for the first frame, s (the driver may still be starting)",
    )
    parser.add_argument("--bin-deg", type=float, default=10.0, help="angle bin width, degrees")
    parser.add_argument("--min-frames", type=int, default=5, help="frames needed per bin")
    parser.add_argument("--out", type=Path, required=True, help="output npz")


def run(args: argparse.Namespace) -> int:
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.resources import config_path
    from eit_skin.ros.topics import patch_topics

    try:
        patch = load_patch(config_path(args.patch))
    except (PatchError, OSError) as error:
        print(f"eit-skin record-postures: {error}", file=sys.stderr)
        return 2
    namespace = "/" + (args.namespace or Path(str(config_path(args.patch))).stem).strip("/")
    topics = patch_topics(patch, namespace)
    history, samples = _record(args, patch.layer_names, topics)
    return _save_tables(args, topics, history, samples)


def _record(
    args: argparse.Namespace, layers: tuple[str, ...], topics: PatchTopics
) -> tuple[JointAngleHistory, dict[str, list[tuple[int, np.ndarray]]]]:
    """Record the joint's angles and every layer's frames ``(stamp ns, [M] V)``.

    Until ``--duration`` s after the first frame, ``--wait`` s without one, or a signal.
    """
    import numpy as np
    import rclpy
    from eit_skin_msgs.msg import EitFrame
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState

    from eit_skin.pipeline.reference import JointAngleHistory
    from eit_skin.ros.node_runner import StopSignals

    stop = StopSignals()  # a signal ends the recording; what was recorded is still written
    stop.spinning = True
    with stop.installed():
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node("eit_posture_calibration")
        history = JointAngleHistory(span_ns=10**12)  # keep the whole sweep
        samples: dict[str, list[tuple[int, np.ndarray]]] = {layer: [] for layer in layers}

        def stamp_ns(msg) -> int:
            return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec

        def on_joint(msg: JointState) -> None:
            if args.joint in msg.name:
                history.add(stamp_ns(msg), float(msg.position[list(msg.name).index(args.joint)]))

        def on_frame(layer: str, msg: EitFrame) -> None:
            frame = np.frombuffer(msg.voltages, dtype=np.float32).astype(np.float64)
            samples[layer].append((stamp_ns(msg), frame))

        node.create_subscription(JointState, topics.joint_states, on_joint, 50)
        for layer in layers:
            node.create_subscription(
                EitFrame,
                topics.layers[layer].frames,
                lambda msg, name=layer: on_frame(name, msg),
                qos_profile_sensor_data,
            )
        print(
            f"recording {args.duration:.0f} s: move joint {args.joint!r} slowly through its "
            "range without touching the skin (Ctrl-C ends it early)",
            flush=True,
        )
        started = time.monotonic()
        first: float | None = None  # monotonic time of the first frame
        try:
            while not stop.requested.is_set():
                rclpy.spin_once(node, timeout_sec=0.1)
                now = time.monotonic()
                if first is None and any(samples.values()):
                    first = now
                if first is not None and now - first >= args.duration:
                    break
                if first is None and now - started >= args.wait:
                    break
        finally:
            stop.ignore()
            node.destroy_node()
            rclpy.shutdown()
    if stop.requested.is_set():
        print("stopped by a signal: writing what was recorded", flush=True)
    return history, samples


def _save_tables(
    args: argparse.Namespace,
    topics: PatchTopics,
    history: JointAngleHistory,
    samples: dict[str, list[tuple[int, np.ndarray]]],
) -> int:
    """Bin each layer's frames by angle and save its references; the exit code."""
    import numpy as np

    from eit_skin.pipeline.reference import bin_posture_frames

    code = 0
    for layer, items in samples.items():
        if not items:
            print(f"{layer}: no frames on {topics.layers[layer].frames}", file=sys.stderr)
            code = 1
            continue
        # the angle at each frame's acquisition time, not at its arrival
        angles = np.array([history.at(stamp) for stamp, _ in items])
        frames = np.stack([f for _, f in items])
        try:
            table = bin_posture_frames(
                args.joint, angles, frames, math.radians(args.bin_deg), args.min_frames
            )
        except ValueError as error:
            print(f"{layer}: {error}", file=sys.stderr)
            code = 1
            continue
        table.save(args.out, layer)
        degrees = ", ".join(f"{math.degrees(a):.0f}" for a in table.angles_rad)
        print(f"{layer}: {len(items)} frames -> references at {degrees} deg in {args.out}")
    return code
