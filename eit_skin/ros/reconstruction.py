"""``eit_reconstruction``: pressure and stretch images of one skin patch.

Subscribes to every layer's ``<layer>/frames`` (``eit_skin_msgs/EitFrame``), images each
frame against the layer's no-load reference (see :mod:`eit_skin.pipeline.reference` for capture,
``~/rezero``, drift tracking and posture compensation) and publishes, per layer with
quantity Q (``pressure`` or ``stretch``):

* ``Q/image``: ``sensor_msgs/Image`` 32FC1 in the layer's physical unit (pressure: Pa,
  stretch: strain), NaN outside the sheet and in holes, stamped with the frame's
  acquisition time, row i / column j at ``(x[j], y[i])`` of the layer's image grid;
* ``Q/image_color``: the same as rgb8 with a fixed colour scale (parameters), for rviz;
* ``skin_marker``: a coloured TRIANGLE_LIST of the mesh on the patch's 3-D surface;
* ``/diagnostics``: rate, latency, dropped and rejected frames, reference age, faults.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import ColorRGBA
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker

from eit_skin.hardware.sources import RateMeter, pattern_name
from eit_skin.inverse.electrode_faults import faulty_electrodes
from eit_skin.patch.model import Layer, load_patch
from eit_skin.pipeline.builder import LayerImager, default_cache_dir
from eit_skin.pipeline.colour_scale import ColourScale
from eit_skin.pipeline.reference import JointAngleHistory, PostureReferences, ReferenceTracker
from eit_skin.resources import config_path
from eit_skin.ros.node_runner import (
    ParameterTable,
    declare_read_only,
    diagnostic_status,
    run_node,
)
from eit_skin.ros.topics import patch_topics

#: Raw frames: sensor-data QoS (best effort, volatile) with room for a short burst.
FRAME_QOS = QoSProfile(
    depth=20,
    reliability=qos_profile_sensor_data.reliability,
    durability=qos_profile_sensor_data.durability,
)

#: Cells along the long side of a layer's rviz marker (each costs Python objects per update).
MARKER_PIXELS = 24

_PARAMETERS: ParameterTable = [
    ("patch_config", "arm", "patch YAML path, or a shipped patch name (arm, face, elbow)"),
    ("cache_dir", "", "reconstruction matrix cache; empty: $EIT_SKIN_CACHE or ~/.cache/eit_skin"),
    ("reference_frames", 0, "frames averaged into the reference; 0: the layer's solver setting"),
    ("drift_time_constant_s", 60.0, "drift tracking time constant while untouched, s; 0: off"),
    ("contact_k", 5.0, "a change above contact_k x noise counts as contact (freezes drift)"),
    ("joint_name", "", "joint whose angle selects the reference (posture compensation)"),
    ("posture_references", "", "npz from `eit-skin calibrate-posture`; empty: no posture"),
    ("pressure_range_pa", 10000.0, "top of the pressure colour scale, Pa"),
    ("stretch_range", 0.05, "top of the stretch colour scale, strain"),
    ("marker_period_s", 0.5, "period of skin_marker updates, s; 0: no marker"),
    ("fault_check_period_s", 1.0, "how often recent frames are checked for faulty electrodes"),
    ("diagnostics_period_s", 1.0, "period of /diagnostics messages, s"),
]


@dataclass
class LayerState:
    """Everything the node keeps for one layer."""

    layer: Layer
    imager: LayerImager
    tracker: ReferenceTracker
    quantity: str
    image_pub: object
    colour_pub: object
    scale: ColourScale
    pattern: str
    rate: RateMeter = field(default_factory=RateMeter)
    imaged: int = 0
    rejected: int = 0
    dropped: int = 0
    last_sequence: int | None = None
    latencies_ms: deque[float] = field(default_factory=lambda: deque(maxlen=500))
    processing_ms: deque[float] = field(default_factory=lambda: deque(maxlen=500))
    last_values: np.ndarray | None = None
    last_image: np.ndarray | None = None
    recent: deque[np.ndarray] = field(default_factory=lambda: deque(maxlen=50))
    faulty: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    excluded: np.ndarray | None = None
    last_reject: str = ""


class ReconstructionNode(Node):
    """Thin adapter: EitFrame -> LayerImager -> images, markers and diagnostics."""

    def __init__(self, **kwargs) -> None:
        super().__init__("eit_reconstruction", **kwargs)
        p = declare_read_only(self, _PARAMETERS)
        path = config_path(str(p["patch_config"]))
        self.patch = load_patch(path)
        cache = str(p["cache_dir"]) or default_cache_dir()
        joint = str(p["joint_name"])
        self.joint = joint
        self.layers: dict[str, LayerState] = {}
        topics = patch_topics(self.patch)
        for layer in self.patch.layers:
            started = time.perf_counter()
            imager = LayerImager.build(layer, cache_dir=cache)
            self.get_logger().info(
                f"layer {layer.name}: {imager.mesh.n_triangles} elements, "
                f"{imager.n_measurements} measurements, grid {imager.grid.shape}, "
                f"matrix {'from cache' if imager.from_cache else 'built'} in "
                f"{time.perf_counter() - started:.2f} s"
            )
            posture = None
            if p["posture_references"]:
                posture = PostureReferences.load(str(p["posture_references"]), layer.name)
                joint = joint or posture.joint
            quantity = layer.material.quantity
            topic = topics.layers[layer.name]
            top = p["pressure_range_pa"] if quantity == "pressure" else p["stretch_range"]
            self.layers[layer.name] = LayerState(
                layer=layer,
                imager=imager,
                tracker=ReferenceTracker(
                    imager.n_measurements,
                    int(p["reference_frames"]) or layer.solver.reference_frames,
                    float(p["drift_time_constant_s"]),
                    float(p["contact_k"]),
                    posture,
                ),
                quantity=quantity,
                image_pub=self.create_publisher(Image, topic.image, qos_profile_sensor_data),
                colour_pub=self.create_publisher(Image, topic.image_color, qos_profile_sensor_data),
                scale=ColourScale.named(0.0, float(top)),
                pattern=pattern_name(layer),
            )
            self.create_subscription(
                _frame_type(),
                topic.frames,
                lambda msg, name=layer.name: self._on_frame(name, msg),
                FRAME_QOS,
            )
        self.joint = joint
        self.joint_history = JointAngleHistory()
        if joint:
            self.create_subscription(JointState, topics.joint_states, self._on_joint_state, 10)
        self.create_service(Trigger, topics.rezero, self._on_rezero)
        self.diagnostics = self.create_publisher(DiagnosticArray, topics.diagnostics, 10)
        self.create_timer(float(p["diagnostics_period_s"]), self._publish_diagnostics)
        self.create_timer(float(p["fault_check_period_s"]), self._check_faults)
        self.marker_pub = None
        if float(p["marker_period_s"]) > 0:
            self.marker_pub = self.create_publisher(Marker, topics.skin_marker, 1)
            self._marker_geometry = {
                name: self._marker_mesh(state) for name, state in self.layers.items()
            }
            self.create_timer(float(p["marker_period_s"]), self._publish_markers)
        self.get_logger().info(
            f"patch {self.patch.name!r} ({path}): layers {list(self.layers)}; "
            f"posture compensation {'on joint ' + repr(joint) if joint else 'off'}"
        )

    # ------------------------------------------------------------------ frames
    def _reject(self, state: LayerState, reason: str) -> None:
        state.rejected += 1
        state.last_reject = reason
        self.get_logger().error(
            f"rejected frame on layer {state.layer.name}: {reason}", throttle_duration_sec=5.0
        )

    def _on_frame(self, name: str, msg) -> None:
        state = self.layers[name]
        m = state.imager.n_measurements
        if len(msg.voltages) != m or msg.n_electrodes != state.layer.n_electrodes:
            self._reject(
                state,
                f"frame has {len(msg.voltages)} values / {msg.n_electrodes} electrodes, "
                f"patch config {self.patch.name}/{name} expects {m} / {state.layer.n_electrodes}",
            )
            return
        if msg.drive_pattern and msg.drive_pattern != state.pattern:
            self._reject(
                state,
                f"frame drive pattern {msg.drive_pattern!r}, patch config "
                f"{self.patch.name}/{name} expects {state.pattern!r}",
            )
            return
        if state.last_sequence is not None:
            gap = (msg.sequence - state.last_sequence) % 2**32
            if 1 < gap < 2**31:
                state.dropped += gap - 1
        state.last_sequence = msg.sequence
        stamp_s = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        started = time.perf_counter()
        frame = np.frombuffer(msg.voltages, dtype=np.float32).astype(np.float64)
        flags = np.frombuffer(msg.channel_flags, np.uint8) if len(msg.channel_flags) else None
        tracker = state.tracker
        if self.joint:
            angle = self.joint_history.at(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
            tracker.angle_rad = angle if np.isfinite(angle) else tracker.angle_rad
        if not tracker.ready:
            if tracker.capture(frame, stamp_s):
                noise = state.imager.relative_change(
                    tracker.captured_frames, tracker.reference()
                ).std(axis=0)
                tracker.set_element_noise(noise)
                self.get_logger().info(
                    f"layer {name}: reference captured from {tracker.n_frames} frames"
                )
            return
        state.recent.append(frame)
        excluded = flags
        if state.excluded is not None and state.excluded.any():
            excluded = (flags if flags is not None else np.zeros(m, np.uint8)) | (
                state.excluded.astype(np.uint8) * 2
            )
        values = state.imager.relative_change(frame, tracker.reference(), excluded)
        tracker.track(frame, stamp_s, tracker.touching(values))
        physical = state.imager.images(state.imager.physical(values))
        self._publish_images(state, msg.header, physical)
        state.last_values = values
        state.last_image = physical
        state.imaged += 1
        now = time.time_ns()
        state.rate.tick()
        state.latencies_ms.append((now * 1e-9 - stamp_s) * 1e3)
        state.processing_ms.append((time.perf_counter() - started) * 1e3)

    def _publish_images(self, state: LayerState, header, physical: np.ndarray) -> None:
        height, width = physical.shape
        image = Image(header=header, height=height, width=width, encoding="32FC1")
        image.is_bigendian = int(sys.byteorder == "big")
        image.step = width * 4
        image.data = np.ascontiguousarray(physical, dtype=np.float32).tobytes()
        state.image_pub.publish(image)
        if state.colour_pub.get_subscription_count():  # rendered only for a viewer
            colour = Image(header=header, height=height, width=width, encoding="rgb8")
            colour.step = width * 3
            colour.data = state.scale.to_rgb(physical).tobytes()
            state.colour_pub.publish(colour)

    # --------------------------------------------------------------- services
    def _on_rezero(self, request, response):
        for state in self.layers.values():
            state.tracker.rezero()
        response.success = True
        frames = {name: s.tracker.n_frames for name, s in self.layers.items()}
        response.message = f"re-taking the reference from the next frames: {frames}"
        self.get_logger().info(response.message)
        return response

    def _on_joint_state(self, msg: JointState) -> None:
        if self.joint in msg.name:
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            angle = float(msg.position[list(msg.name).index(self.joint)])
            self.joint_history.add(stamp or self.get_clock().now().nanoseconds, angle)

    def _check_faults(self) -> None:
        for state in self.layers.values():
            if not state.tracker.ready or len(state.recent) < 10:
                continue
            faulty = faulty_electrodes(
                np.stack(state.recent), state.tracker.reference(), state.imager.protocol
            )
            state.faulty = np.asarray(faulty, dtype=np.int64)
            state.excluded = (
                state.imager.protocol.touching(state.faulty) if state.faulty.size else None
            )

    # ------------------------------------------------------------------ rviz
    def _marker_mesh(self, state: LayerState) -> tuple[list[Point], np.ndarray]:
        """Display surface of a layer: two triangles per cell of a coarse pixel grid.

        Returns the points of the triangles on the patch's 3-D surface and, per cell, the
        flat index of the image pixel it shows. Every marker vertex costs Python objects on
        each update, so the display uses about MARKER_PIXELS cells along the long side
        (cells whose centre is off the sheet or in a hole are left out).
        """
        grid = state.imager.grid
        height, width = grid.shape
        step = max(1, int(np.ceil(max(height, width) / MARKER_PIXELS)))
        rows, cols = np.meshgrid(
            np.arange(0, height, step), np.arange(0, width, step), indexing="ij"
        )
        keep = grid.inside[rows, cols]
        rows, cols = rows[keep], cols[keep]
        half_x = 0.5 * step * (grid.x[1] - grid.x[0]) if width > 1 else 0.0
        half_y = 0.5 * step * (grid.y[1] - grid.y[0]) if height > 1 else 0.0
        cx, cy = grid.x[cols], grid.y[rows]
        corners = np.array([(-1, -1), (1, -1), (1, 1), (-1, -1), (1, 1), (-1, 1)], float)
        xy = np.stack(
            [cx[:, None] + corners[:, 0] * half_x, cy[:, None] + corners[:, 1] * half_y], axis=-1
        ).reshape(-1, 2)
        xyz = self.patch.placement.to_3d(xy)
        points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in xyz]
        return points, rows * width + cols

    def _publish_markers(self) -> None:
        for index, (name, state) in enumerate(self.layers.items()):
            if state.last_image is None:
                continue
            points, pixels = self._marker_geometry[name]
            rgb = state.scale.to_rgb(state.last_image.reshape(1, -1)[:, pixels])[0] / 255.0
            colours = [ColorRGBA(r=float(r), g=float(g), b=float(b), a=1.0) for r, g, b in rgb]
            marker = Marker(ns=name, id=index, type=Marker.TRIANGLE_LIST, action=Marker.ADD)
            marker.header.frame_id = self.patch.frame_id
            marker.header.stamp = self.get_clock().now().to_msg()
            marker.pose.orientation.w = 1.0
            marker.scale.x = marker.scale.y = marker.scale.z = 1.0
            marker.points = points
            marker.colors = [c for c in colours for _ in range(6)]  # two triangles per cell
            self.marker_pub.publish(marker)

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        now = time.time_ns()
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        for name, state in self.layers.items():
            tracker = state.tracker
            latency = np.asarray(state.latencies_ms or [np.nan])
            values = {
                "reconstruction_rate_hz": f"{state.rate.rate_hz():.1f}",
                "latency_median_ms": f"{np.median(latency):.2f}",
                "latency_p99_ms": f"{np.percentile(latency, 99):.2f}",
                "processing_median_ms": f"{np.median(state.processing_ms or [np.nan]):.3f}",
                "frames_imaged": str(state.imaged),
                "frames_dropped": str(state.dropped),
                "frames_rejected": str(state.rejected),
                "reference_ready": str(tracker.ready).lower(),
                "reference_age_s": f"{tracker.age_s(now * 1e-9):.1f}",
                "drift_updates": str(tracker.drift_updates),
                "faulty_electrodes": ",".join(str(e) for e in state.faulty),
                "joint_angle_rad": f"{tracker.angle_rad:.3f}",
            }
            if state.rejected and state.last_reject:
                level, text = 1, f"rejected frames: {state.last_reject}"
            elif state.faulty.size:
                level, text = 1, f"imaging without faulty electrodes {values['faulty_electrodes']}"
            elif not tracker.ready:
                level, text = 0, "capturing the no-load reference (do not touch)"
            else:
                level, text = 0, f"{values['reconstruction_rate_hz']} images/s"
            msg.status.append(
                diagnostic_status(
                    level,
                    f"{self.get_fully_qualified_name()}: {name}",
                    text,
                    self.patch.name,
                    values,
                )
            )
        self.diagnostics.publish(msg)


def _frame_type():
    from eit_skin_msgs.msg import EitFrame

    return EitFrame


def main(args: list[str] | None = None) -> int:
    """Console script ``eit_reconstruction``; exit 2 on a bad configuration."""
    return run_node(ReconstructionNode, "eit_reconstruction", args)


if __name__ == "__main__":
    sys.exit(main())
