"""The watching side of ``eit-skin run``: start the node graph, print events, save pictures.

A small rclpy node subscribes to every patch's touch events and images, prints each event
as it arrives, keeps a status line, saves a PNG of the pressure/stretch images at the
strongest moment of every touch and an animated GIF per patch, and stops the nodes at the
end. The nodes themselves are separate processes (:mod:`eit_skin.ros.bringup`).
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.colour_scale import ColourScale
from eit_skin.ros.bringup import RunningNode, last_lines, start, stop
from eit_skin.ros.node_graph import NodeSpec
from eit_skin.ros.node_runner import StopSignals
from eit_skin.ros.topics import PatchTopics, patch_topics
from eit_skin.touch.events import LABELS, STATES

GIF_PERIOD_S = 0.2
GIF_MAX_FRAMES = 1500
"""The GIF keeps the last 5 minutes at 5 frames per second."""
SCALES = {"pressure": (10000.0, "Pa"), "stretch": (0.05, "")}  # as the node's colour scale


@dataclass
class PatchView:
    """What the monitor keeps of one patch."""

    namespace: str
    name: str
    topics: PatchTopics  # absolute names in the patch's namespace
    quantities: dict[str, str]  # layer -> pressure | stretch
    extent: tuple[float, float, float, float]
    latest: dict[str, np.ndarray] = field(default_factory=dict)
    images: int = 0
    frames: int = 0  # highest frame sequence seen + 1 (script progress)
    end_stamp_ns: int | None = None  # acquisition stamp of the frame ending the script pass
    image_stamp_ns: int = -1  # newest acquisition stamp imaged (first layer)
    events: list[tuple[float, str, str]] = field(default_factory=list)
    touch_peak: float = -np.inf
    touch_best: dict[str, np.ndarray] | None = None
    # the GIF's frames: images every GIF_PERIOD_S of acquisition time (not wall time, so a
    # loaded machine still gets every one), rendered at the end
    gif_images: deque[dict[str, np.ndarray]] = field(
        default_factory=lambda: deque(maxlen=GIF_MAX_FRAMES)
    )
    gif_stamp_ns: int | None = None
    calibrated: dict[int, object] = field(default_factory=dict)  # stamp ns -> Contact

    @property
    def layers(self) -> list[str]:
        """Layer names, in the patch's order."""
        return list(self.topics.layers)


class SkinMonitor(Node):
    """Subscribes to the patches' outputs; all drawing happens in the main thread."""

    def __init__(self, views: list[PatchView], out: Path, script_frames: dict[str, int]) -> None:
        super().__init__("eit_skin_run")
        from eit_skin_msgs.msg import ContactArray, EitFrame, TouchEvent

        self.views = views
        self.out = out
        self.script_frames = script_frames
        self.pending_snapshots: list[tuple[PatchView, dict[str, np.ndarray], str]] = []
        self.t0: float | None = None
        self.snapshots = 0
        for view in views:
            self.create_subscription(
                TouchEvent,
                view.topics.touch_events,
                lambda msg, v=view: self._on_event(v, msg),
                50,
            )
            self.create_subscription(
                ContactArray,
                view.topics.calibrated_contacts,
                lambda msg, v=view: self._on_calibrated(v, msg),
                10,
            )
            first_layer = next(iter(view.layers))
            self.create_subscription(
                EitFrame,
                view.topics.layers[first_layer].frames,
                lambda msg, v=view: self._on_frame(v, msg),
                qos_profile_sensor_data,
            )
            for layer, topics in view.topics.layers.items():
                self.create_subscription(
                    Image,
                    topics.image,
                    lambda msg, v=view, name=layer: self._on_image(v, name, msg),
                    qos_profile_sensor_data,
                )

    def elapsed(self) -> float:
        return 0.0 if self.t0 is None else time.monotonic() - self.t0

    def _on_frame(self, view: PatchView, msg) -> None:
        view.frames = max(view.frames, msg.sequence + 1)
        end = self.script_frames.get(view.namespace)
        if end is not None and view.end_stamp_ns is None and view.frames >= end + TAIL_FRAMES:
            view.end_stamp_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec

    def _on_image(self, view: PatchView, layer: str, msg: Image) -> None:
        image = np.frombuffer(bytes(msg.data), dtype=np.float32).reshape(msg.height, msg.width)
        view.latest[layer] = image
        view.images += 1
        first = next(iter(view.layers))
        if layer == first:
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            view.image_stamp_ns = max(view.image_stamp_ns, stamp)
            if view.gif_stamp_ns is None or stamp - view.gif_stamp_ns >= GIF_PERIOD_S * 1e9:
                view.gif_images.append(dict(view.latest))  # arrays are new per message
                view.gif_stamp_ns = stamp
        if layer == first and view.touch_best is not None:
            peak = float(np.nanmax(image, initial=0.0))
            if peak > view.touch_peak:
                view.touch_peak = peak
                view.touch_best = {k: v.copy() for k, v in view.latest.items()}

    def _on_calibrated(self, view: PatchView, msg) -> None:
        if msg.contacts:
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            view.calibrated[stamp] = msg.contacts[0]
            while len(view.calibrated) > 50:
                view.calibrated.pop(next(iter(view.calibrated)))

    def _on_event(self, view: PatchView, msg) -> None:
        label = LABELS[msg.label] if msg.label < len(LABELS) else str(msg.label)
        state = STATES[msg.state].upper() if msg.state < len(STATES) else str(msg.state)
        duration = msg.duration.sec + 1e-9 * msg.duration.nanosec
        if state == "START":
            view.touch_peak, view.touch_best = -np.inf, {}
        if state != "UPDATE":
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            press = view.calibrated.get(stamp)
            calibrated = "" if press is None else _calibrated_text(press)
            _clear_status()
            print(
                f"[{self.elapsed():6.2f} s] {view.name:<6} {label.upper():<5} {state:<6} "
                f"conf {msg.confidence:.2f}  at ({msg.centroid.x * 1e3:+6.1f}, "
                f"{msg.centroid.y * 1e3:+6.1f}) mm  area {msg.area_m2 * 1e4:5.2f} cm^2  "
                f"peak {msg.peak / 1e3:5.1f} kPa  {duration:4.2f} s{calibrated}",
                flush=True,
            )
        if state == "END":
            view.events.append((self.elapsed(), label, state))
            if view.touch_best:  # drawn by the main thread (matplotlib is slow)
                self.pending_snapshots.append((view, view.touch_best, label))
            view.touch_best = None

    def save_pending_snapshots(self, limit: int | None = None) -> None:
        """Write the pending touch pictures, at most ``limit`` of them (None: all).

        A picture takes a few seconds on a loaded machine; the run loop writes one per pass
        so that touches arriving faster than that cannot keep it from its duration check.
        """
        written = 0
        while self.pending_snapshots and (limit is None or written < limit):
            written += 1
            view, images, label = self.pending_snapshots.pop(0)
            self.snapshots += 1
            path = self.out / f"{view.name}_{self.snapshots:02d}_{label}.png"
            save_snapshot(view, images, f"{view.name}: {label}", path)


def _calibrated_text(press) -> str:
    """The calibrated press (``eit_skin_msgs/Contact``) of an event's frame, for a log line."""
    x, y = press.centroid.x * 1e3, press.centroid.y * 1e3
    return (
        f"  calibrated ({x:+6.1f}, {y:+6.1f}) mm depth {press.depth_m * 1e3:.1f} mm "
        f"conf {press.confidence:.2f}"
    )


def render_rgb(view: PatchView, images: dict[str, np.ndarray], zoom: int = 3) -> np.ndarray:
    """Layers side by side in false colour, ``[H*zoom, W*zoom*layers, 3]`` uint8."""
    tiles = []
    for layer in view.layers:
        image = images.get(layer)
        if image is None:
            continue
        top = SCALES[view.quantities[layer]][0]
        rgb = ColourScale.named(0.0, top).to_rgb(image[::-1])  # row 0 at the bottom (y up)
        tiles.append(np.kron(rgb, np.ones((zoom, zoom, 1), dtype=np.uint8)))
        tiles.append(np.zeros((rgb.shape[0] * zoom, 4, 3), np.uint8))
    return np.concatenate(tiles[:-1], axis=1)


def save_snapshot(view: PatchView, images: dict[str, np.ndarray], title: str, path: Path) -> None:
    """PNG of every layer's image with axes in millimetres and a colour bar."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    layers = [layer for layer in view.layers if layer in images]
    fig, axes = plt.subplots(1, len(layers), figsize=(4.2 * len(layers), 3.6), squeeze=False)
    extent = [1e3 * v for v in view.extent]
    for ax, layer in zip(axes[0], layers, strict=True):
        quantity = view.quantities[layer]
        _, unit = SCALES[quantity]
        scale = 1e-3 if quantity == "pressure" else 1.0
        # a snapshot scales to its own peak so weak touches stay visible
        top = max(float(np.nanmax(images[layer], initial=0.0)), 1e-9)
        shown = ax.imshow(
            images[layer] * scale,
            origin="lower",
            extent=extent,
            cmap="inferno",
            vmin=0.0,
            vmax=top * scale,
        )
        ax.set_title(f"{layer} ({quantity})")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        fig.colorbar(shown, ax=ax, label="kPa" if unit == "Pa" else "strain")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def patch_views(specs: list[NodeSpec]) -> list[PatchView]:
    """One :class:`PatchView` per reconstruction node of ``specs`` (its patch's topics)."""
    views = []
    for spec in specs:
        if spec.executable != "eit_reconstruction":
            continue
        patch = load_patch(str(spec.parameters["patch_config"]))
        outline = np.concatenate([layer.outline for layer in patch.layers])
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        views.append(
            PatchView(
                namespace=spec.namespace,
                name=spec.namespace.strip("/"),
                topics=patch_topics(patch, spec.namespace),
                quantities={layer.name: layer.material.quantity for layer in patch.layers},
                extent=(lo[0], hi[0], lo[1], hi[1]),
            )
        )
    return views


_STATUS_WIDTH = [0]


def _status(text: str) -> None:
    if sys.stderr.isatty():
        sys.stderr.write("\r" + text.ljust(_STATUS_WIDTH[0]))
        _STATUS_WIDTH[0] = len(text)
        sys.stderr.flush()


def _clear_status() -> None:
    if sys.stderr.isatty() and _STATUS_WIDTH[0]:
        sys.stderr.write("\r" + " " * _STATUS_WIDTH[0] + "\r")
        sys.stderr.flush()


def _dead(nodes: list[RunningNode]) -> RunningNode | None:
    return next((node for node in nodes if node.process.poll() is not None), None)


#: How long drivers may take to publish their first frame before the run gives up, s.
FIRST_FRAME_TIMEOUT_S = 120.0


def run_skin(
    specs: list[NodeSpec],
    out: Path,
    duration_s: float | None = None,
    script_frames: dict[str, int] | None = None,
    first_frame_timeout_s: float | None = FIRST_FRAME_TIMEOUT_S,
) -> int:
    """Start the nodes, watch them, clean up.

    Stops ``duration_s`` seconds after the first frame, or once every simulated patch has
    published ``script_frames[namespace]`` frames (one pass of its script) plus a short tail
    and the last of them is imaged, or on Ctrl-C when neither is given. Gives up (exit 1)
    when no frame arrives within ``first_frame_timeout_s`` (None: wait for a board forever).
    """
    out.mkdir(parents=True, exist_ok=True)
    signals = StopSignals()
    signals.spinning = True  # a signal only sets the flag the loops below check
    with signals.installed():
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        monitor = SkinMonitor(patch_views(specs), out, script_frames or {})
        return _run(specs, monitor, signals, duration_s, first_frame_timeout_s)


def _run(
    specs: list[NodeSpec],
    monitor: SkinMonitor,
    signals: StopSignals,
    duration_s: float | None,
    first_frame_timeout_s: float | None,
) -> int:
    """:func:`run_skin` once rclpy is up, the signals are handled and ``monitor`` is made."""
    out = monitor.out
    logs = out / "logs"
    stop_requested = signals.requested
    nodes: list[RunningNode] = []
    executor: SingleThreadedExecutor | None = None
    code = 0
    try:
        print(f"eit-skin run: {len(specs)} nodes, output in {out}/", flush=True)
        nodes += [start(spec, logs) for spec in specs if spec.executable != "eit_driver"]
        code = _wait_ready(monitor, nodes, stop_requested)
        if code or stop_requested.is_set():
            return code
        nodes += [start(spec, logs) for spec in specs if spec.executable == "eit_driver"]
        started = time.monotonic()
        next_line = 0.0
        # callbacks on their own thread, so pictures and the status line keep wall-clock time
        executor = SingleThreadedExecutor()
        executor.add_node(monitor)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        while not _finished(monitor, duration_s) and not stop_requested.is_set():
            time.sleep(0.02)
            monitor.save_pending_snapshots(limit=1)
            if monitor.t0 is None:  # the clock starts with the first frame of any patch
                if any(view.frames for view in monitor.views):
                    monitor.t0 = time.monotonic()
                elif (
                    first_frame_timeout_s is not None
                    and time.monotonic() - started > first_frame_timeout_s
                ):
                    _clear_status()
                    print(
                        f"eit-skin run: no frame within {first_frame_timeout_s:.0f} s; "
                        f"see the driver logs in {logs}",
                        file=sys.stderr,
                    )
                    return 1
            dead = _dead(nodes)
            if dead is not None:
                _clear_status()
                print(
                    f"eit-skin run: {dead.label} exited ({dead.process.returncode}):\n"
                    f"{last_lines(dead.log_path)}",
                    file=sys.stderr,
                )
                return 1
            now = monitor.elapsed()
            if now >= next_line:
                _status(_status_line(monitor, now, duration_s))
                next_line = now + 0.5
    finally:
        signals.ignore()  # a second Ctrl-C must not interrupt the clean-up
        _clear_status()
        codes = stop(nodes)
        if executor is not None:
            executor.shutdown()
        monitor.save_pending_snapshots()
        failed = {label: rc for label, rc in codes.items() if rc != 0}
        if failed and not code:
            print(f"eit-skin run: nodes exited with errors: {failed}", file=sys.stderr)
            code = 1
        _finish(monitor)
        monitor.destroy_node()
        rclpy.shutdown()
    return code


#: Frames published after the script's end before a one-pass run stops (events end).
TAIL_FRAMES = 25


def _status_line(monitor: SkinMonitor, now: float, duration_s: float | None) -> str:
    """The progress line at ``now`` s: time, script progress, images and touches so far."""
    total = "" if duration_s is None else f"/{duration_s:.0f}"
    if monitor.script_frames:
        done = min(v.frames / max(1, monitor.script_frames[v.namespace]) for v in monitor.views)
        total = f" s, script {100 * min(done, 1.0):3.0f} %"
    images = ", ".join(f"{v.name} {v.images}" for v in monitor.views)
    events = sum(len(v.events) for v in monitor.views)
    return f"  {now:5.1f}{total}  images: {images}  touches: {events}"


def _finished(monitor: SkinMonitor, duration_s: float | None) -> bool:
    if duration_s is not None:
        return monitor.t0 is not None and monitor.elapsed() >= duration_s
    if monitor.script_frames:
        # the pass is over when its last frame is imaged, not merely published: on a loaded
        # machine the images lag the frames by seconds
        return all(
            view.end_stamp_ns is not None and view.image_stamp_ns >= view.end_stamp_ns
            for view in monitor.views
        )
    return False


def _wait_ready(monitor: SkinMonitor, nodes: list[RunningNode], stop: threading.Event) -> int:
    """Wait for every reconstruction node's rezero service (its matrices are built)."""
    clients = [monitor.create_client(Trigger, view.topics.rezero) for view in monitor.views]
    started = time.monotonic()
    while not all(client.service_is_ready() for client in clients):
        if stop.is_set():
            _clear_status()
            return 0
        rclpy.spin_once(monitor, timeout_sec=0.1)
        dead = _dead(nodes)
        if dead is not None:
            print(
                f"eit-skin run: {dead.label} exited ({dead.process.returncode}):\n"
                f"{last_lines(dead.log_path)}",
                file=sys.stderr,
            )
            return 1
        _status(
            f"  building reconstruction matrices ({time.monotonic() - started:4.1f} s; "
            "cached for the next run)"
        )
    _clear_status()
    print(f"reconstruction ready after {time.monotonic() - started:.1f} s; starting drivers")
    return 0


def _finish(monitor: SkinMonitor) -> None:
    from PIL import Image as PilImage

    for view in monitor.views:
        labels = [label for _, label, _ in view.events]
        print(f"{view.name}: {view.images} images, touches: {', '.join(labels) or 'none'}")
        gif_frames = [render_rgb(view, images) for images in view.gif_images]
        if gif_frames:
            height = max(f.shape[0] for f in gif_frames)
            width = max(f.shape[1] for f in gif_frames)
            frames = [
                PilImage.fromarray(
                    np.pad(f, ((0, height - f.shape[0]), (0, width - f.shape[1]), (0, 0)))
                )
                for f in gif_frames
            ]
            path = monitor.out / f"{view.name}.gif"
            frames[0].save(
                path,
                save_all=True,
                append_images=frames[1:],
                duration=int(GIF_PERIOD_S * 1000),
                loop=0,
            )
            print(f"  wrote {path} ({len(frames)} frames) and {monitor.snapshots} snapshot(s)")
