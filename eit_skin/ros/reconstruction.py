"""``eit_reconstruction``: pressure and stretch images of one skin patch.

Subscribes to every layer's ``<layer>/frames`` (``eit_skin_msgs/EitFrame``), checks that a
frame fits the layer and hands it to the layer's ``LayerProcessor``
(:mod:`eit_skin.pipeline.processor`: reference capture, ``~/rezero``, drift tracking, posture
compensation, flags, fault checks on frame time; the same code ``eit-skin reconstruct`` runs
offline), then publishes, per layer with quantity Q (``pressure`` or ``stretch``):

* ``Q/image``: ``sensor_msgs/Image`` 32FC1 in the layer's physical unit (pressure: Pa,
  stretch: strain), NaN outside the sheet and in holes, stamped with the frame's
  acquisition time, row i / column j at ``(x[j], y[i])`` of the layer's image grid;
* ``Q/image_color``: the same as rgb8 with a fixed colour scale (parameters), for rviz;
* ``Q/skin_marker``: a coloured TRIANGLE_LIST of the layer on the patch's 3-D surface (one
  topic per layer: stacked layers would hide each other in one display);
* ``calibrated_contacts`` (only with the ``calibration`` parameter): per imaged frame of the
  calibrated layer an ``eit_skin_msgs/ContactArray`` stamped like the frame, with the presses
  (at most ``calibration_max_touches``, one confidence each) located by the press calibration
  when the processor calls the frame touched, else empty (also while the sheet has changed:
  a warning says so)
  (:mod:`eit_skin.calibration.online`, docs/press-calibration.md);
* ``/diagnostics``: rate, latency, dropped and rejected frames, reference age, faults,
  values left out (beyond the full scale, one-frame jumps), a changed sheet of the
  calibrated layer (WARN, :mod:`eit_skin.calibration.online`).
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import ColorRGBA, Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker

from eit_skin.calibration.online import OnlineLocaliser
from eit_skin.hardware.source_status import RateMeter
from eit_skin.hardware.sources import pattern_name
from eit_skin.io.cdr import EitFrameFields, Float32ImageCdr, read_eit_frame
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import Layer
from eit_skin.pipeline.builder import LayerImager, default_cache_dir
from eit_skin.pipeline.colour_scale import ColourScale
from eit_skin.pipeline.frame_kernel import compiled_step_status
from eit_skin.pipeline.processor import (
    LayerProcessor,
    fault_check_phase,
    stamp_to_s,
)
from eit_skin.pipeline.reference import JointAngleHistory, PostureReferences, PostureSync
from eit_skin.resources import config_path
from eit_skin.ros.node_runner import (
    REJECT_LOG_PERIOD_S,
    LiveParameters,
    ThrottledLog,
    declare_parameters,
    diagnostic_status,
    run_node,
)
from eit_skin.ros.parameters import RECONSTRUCTION, WRITABLE
from eit_skin.ros.qos import OVERRIDABLE, SENSOR_READER
from eit_skin.ros.surface_fields import place_on_surface
from eit_skin.ros.topics import LayerTopics, patch_topics

#: Seconds between looks at whether a viewer subscribes to a layer's colour image (a look
#: is an rmw call; once per frame it cost 1.5 % of a frame's CPU at 50 patches).
VIEWER_CHECK_PERIOD_S = 0.5

#: Cells along the long side of a layer's rviz marker (each costs Python objects per update).
MARKER_PIXELS = 24


@dataclass
class LayerState:
    """Everything the node keeps for one layer."""

    layer: Layer
    imager: LayerImager
    processor: LayerProcessor
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
    last_image: np.ndarray | None = None
    last_reject: str = ""
    last_arrival: float | None = None  # time.monotonic() of the last frame, good or bad
    frames_topic: str = ""
    marker_topic: str = ""
    image_cdr: Float32ImageCdr | None = None  # refilled per frame (:meth:`_publish_images`)
    colour_wanted: bool = False  # a viewer subscribes to the colour image
    colour_checked_s: float = -math.inf  # time.monotonic() of that look


class ReconstructionNode(Node):
    """Thin adapter: EitFrame -> LayerProcessor -> images, markers and diagnostics."""

    def __init__(self, **kwargs) -> None:
        super().__init__("eit_reconstruction", **kwargs)
        p = declare_parameters(self, RECONSTRUCTION, "eit_reconstruction")
        path = config_path(str(p["patch_config"]))
        self.patch = load_patch(path)
        # refused (CalibrationError, a ValueError) before any matrix is built
        self.calibration = (
            OnlineLocaliser.load(
                str(p["calibration"]), self.patch, int(p["calibration_max_touches"])
            )
            if p["calibration"]
            else None
        )
        cache = str(p["cache_dir"]) or default_cache_dir()
        joint = str(p["joint_name"])
        self.joint = joint
        self.layers: dict[str, LayerState] = {}
        self._log_reject = ThrottledLog(self.get_logger().error, REJECT_LOG_PERIOD_S)
        topics = patch_topics(self.patch)
        for layer in self.patch.layers:
            posture = None
            if p["posture_references"]:
                posture = PostureReferences.load(str(p["posture_references"]), layer.name)
                joint = joint or posture.joint
            topic = topics.layers[layer.name]
            self.layers[layer.name] = self._layer_state(layer, p, cache, topic, posture)
            self.create_subscription(  # CDR bytes: read_eit_frame beats rclpy's message
                _frame_type(),
                topic.frames,
                lambda data, name=layer.name: self._on_frame(name, data),
                SENSOR_READER,
                raw=True,
                qos_overriding_options=OVERRIDABLE,
            )
        self.joint = joint
        self.calibrated_pub = self._calibrated_publisher(topics.calibrated_contacts)
        self.frame_timeout_s = float(p["frame_timeout_s"])
        self.started = time.monotonic()
        self.joint_history = JointAngleHistory()
        self.posture_sync = PostureSync(self.joint_history, float(p["posture_wait_s"]))
        if joint:
            self.create_subscription(
                JointState,
                topics.joint_states,
                self._on_joint_state,
                10,
                qos_overriding_options=OVERRIDABLE,
            )
            self.create_timer(0.05, self._release_late_frames)
        self.create_service(Trigger, topics.rezero, self._on_rezero)
        self._implausible_reported: dict[str, int] = {}  # values left out, last diagnostics
        self.diagnostics = self.create_publisher(
            DiagnosticArray, topics.diagnostics, 10, qos_overriding_options=OVERRIDABLE
        )
        self.diagnostics_timer = self.create_timer(
            float(p["diagnostics_period_s"]), self._publish_diagnostics
        )
        self.live = LiveParameters(self, WRITABLE["eit_reconstruction"], self._apply_parameters)
        if float(p["marker_period_s"]) > 0:
            self.marker_pubs = {
                name: self.create_publisher(
                    Marker, state.marker_topic, 1, qos_overriding_options=OVERRIDABLE
                )
                for name, state in self.layers.items()
            }
            self._marker_geometry = {
                name: self._marker_mesh(state) for name, state in self.layers.items()
            }
            self.create_timer(float(p["marker_period_s"]), self._publish_markers)
        self.get_logger().info(
            f"patch {self.patch.name!r} ({path}): layers {list(self.layers)}; "
            f"posture compensation {'on joint ' + repr(joint) if joint else 'off'}; "
            f"per-frame step {compiled_step_status()}"
        )

    def _calibrated_publisher(self, topic: str) -> Publisher | None:
        """The publisher of the calibrated contacts on ``topic`` (None: no calibration)."""
        if self.calibration is None:
            return None
        name = self.calibration.layer_name
        self.calibration.check_measurements(self.layers[name].imager.n_measurements)
        publisher = self.create_publisher(
            _contact_types()[1], topic, 10, qos_overriding_options=OVERRIDABLE
        )
        self.get_logger().info(
            f"layer {name}: calibrated contacts on {topic} from {self.calibration.source}"
        )
        return publisher

    def _layer_state(
        self,
        layer: Layer,
        p: dict,
        cache: str,
        topic: LayerTopics,
        posture: PostureReferences | None,
    ) -> LayerState:
        """Build one layer's imager and processor (logging the time) and its publishers.

        ``p`` holds the node's parameters, ``cache`` the matrix cache directory.
        """
        started = time.perf_counter()
        imager = LayerImager.build(layer, cache_dir=cache)
        self.get_logger().info(
            f"layer {layer.name}: {imager.mesh.n_triangles} elements, "
            f"{imager.n_measurements} measurements, grid {imager.grid.shape}, "
            f"matrix {'from cache' if imager.from_cache else 'built'} in "
            f"{time.perf_counter() - started:.2f} s"
        )
        quantity = layer.material.quantity
        top = p[_range_parameter(quantity)]
        return LayerState(
            layer=layer,
            imager=imager,
            processor=LayerProcessor(
                imager,
                int(p["reference_frames"]) or None,
                float(p["drift_time_constant_s"]),
                float(p["contact_k"]),
                posture,
                float(p["fault_check_period_s"]),
                fault_check_phase(self.patch.name, layer.name),
                jump_k=float(p["jump_k"]),
            ),
            quantity=quantity,
            image_pub=self.create_publisher(
                Image, topic.image, qos_profile_sensor_data, qos_overriding_options=OVERRIDABLE
            ),
            colour_pub=self.create_publisher(
                Image,
                topic.image_color,
                qos_profile_sensor_data,
                qos_overriding_options=OVERRIDABLE,
            ),
            scale=ColourScale.named(0.0, float(top)),
            pattern=pattern_name(layer),
            frames_topic=topic.frames,
            marker_topic=topic.marker,
        )

    # ------------------------------------------------------------------ live tuning
    def _apply_parameters(self, values: dict[str, object]) -> None:
        """Writable parameters set while running: in effect from the next frame."""
        for state in self.layers.values():
            top = values.get(_range_parameter(state.quantity))
            if top is not None:
                state.scale = ColourScale.named(0.0, float(top))
            tracker = state.processor.tracker  # read on every frame
            if "drift_time_constant_s" in values:
                tracker.drift_time_constant_s = float(values["drift_time_constant_s"])
            if "contact_k" in values:
                tracker.contact_k = float(values["contact_k"])
        if "frame_timeout_s" in values:
            self.frame_timeout_s = float(values["frame_timeout_s"])
        if "diagnostics_period_s" in values:
            self.diagnostics_timer.timer_period_ns = round(
                float(values["diagnostics_period_s"]) * 1e9
            )

    # ------------------------------------------------------------------ frames
    def _reject(self, state: LayerState, reason: str) -> None:
        state.rejected += 1
        state.last_reject = reason
        self._log_reject(f"rejected frame on layer {state.layer.name}: {reason}")

    def _on_frame(self, name: str, data: bytes) -> None:
        state = self.layers[name]
        state.last_arrival = time.monotonic()
        try:
            msg = read_eit_frame(data)
        except ValueError as error:
            self._reject(state, f"undecodable frame: {error}")
            return
        m = state.imager.n_measurements
        if msg.voltages.size != m or msg.n_electrodes != state.layer.n_electrodes:
            self._reject(
                state,
                f"frame has {msg.voltages.size} values / {msg.n_electrodes} electrodes, "
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
        frame = msg.voltages.astype(np.float64)
        flags = msg.channel_flags if msg.channel_flags.size else None
        if flags is not None and flags.size != m:
            self._reject(state, f"frame has {flags.size} channel flags for {m} values")
            return
        if self.joint:  # image it once the joint angle at its acquisition time is known
            self._release(
                self.posture_sync.push(
                    msg.stamp_ns, time.monotonic_ns(), (state, msg, frame, flags)
                )
            )
            return
        self._image(state, msg, frame, flags, None)

    def _image(self, state: LayerState, msg: EitFrameFields, frame: np.ndarray, flags, angle):
        """Step the layer's processor with a decoded frame and publish what it gives."""
        name = state.layer.name
        stamp_ns = msg.stamp_ns
        started = time.perf_counter()
        processor = state.processor
        was_ready = processor.reference_ready
        out = processor.step(frame, stamp_to_s(stamp_ns), flags, angle)
        if not was_ready and processor.reference_ready:
            self.get_logger().info(
                f"layer {name}: reference captured from {processor.reference_frames} frames"
            )
        if out is None:
            return
        if self.calibrated_pub is not None and name == self.calibration.layer_name:
            self._publish_calibrated(_stamped(Header(), msg), frame, flags, out, processor)
        self._publish_images(state, msg, out.image)
        state.last_image = out.image
        state.imaged += 1
        state.rate.tick()
        state.latencies_ms.append((time.time_ns() - stamp_ns) * 1e-6)
        state.processing_ms.append((time.perf_counter() - started) * 1e3)

    def _publish_images(self, state: LayerState, msg: EitFrameFields, physical: np.ndarray):
        """Publish the float image (and the colour one to a viewer) of one frame.

        Stamped and framed like the frame ``msg``. The float image goes out as CDR bytes
        kept per layer and refilled (:class:`~eit_skin.io.cdr.Float32ImageCdr`): rclpy then
        neither converts a Python message nor serialises it (publishing went from 0.027 to
        0.015 ms of a frame at 50 patches, bench/standing/frame_cost.md); subscribers get an
        ordinary ``sensor_msgs/Image``.
        """
        height, width = physical.shape
        image = state.image_cdr
        if image is None or not image.fits(height, width, msg.frame_id):
            image = state.image_cdr = Float32ImageCdr(height, width, msg.frame_id)
        state.image_pub.publish(image.fill(msg.stamp_sec, msg.stamp_nanosec, physical))
        now = time.monotonic()
        if now >= state.colour_checked_s + VIEWER_CHECK_PERIOD_S:
            state.colour_wanted = state.colour_pub.get_subscription_count() > 0
            state.colour_checked_s = now
        if state.colour_wanted:  # rendered only for a viewer
            colour = Image(
                header=_stamped(Header(), msg), height=height, width=width, encoding="rgb8"
            )
            colour.step = width * 3
            colour.data = state.scale.to_rgb(physical).tobytes()
            state.colour_pub.publish(colour)

    def _publish_calibrated(self, header, frame, flags, out, processor: LayerProcessor) -> None:
        """The frame's calibrated contacts (none if untouched), before its images."""
        Contact, ContactArray = _contact_types()
        array = ContactArray(header=header, patch=self.patch.name)
        changed = self.calibration.sheet_changed
        contacts = self.calibration.contacts(frame, flags, out, processor)
        if self.calibration.sheet_changed is not None and changed is None:
            self.get_logger().warning(self.calibration.sheet_changed)
        peak = float(np.nanmax(out.image, initial=-np.inf))
        for contact in contacts:
            item = Contact(layer=self.calibration.layer_name, area_m2=0.0, mean=float("nan"))
            item.centroid.x, item.centroid.y = (float(v) for v in contact.xy_m)
            item.peak = peak
            item.depth_m = contact.depth_m
            item.confidence = contact.confidence
            place_on_surface([item], self.patch.placement, [contact.xy_m])
            array.contacts.append(item)
        self.calibrated_pub.publish(array)

    # --------------------------------------------------------------- services
    def _on_rezero(self, request, response):
        for state in self.layers.values():
            state.processor.rezero()
        response.success = True
        frames = {name: s.processor.reference_frames for name, s in self.layers.items()}
        response.message = f"re-taking the reference from the next frames: {frames}"
        self.get_logger().info(response.message)
        return response

    def _on_joint_state(self, msg: JointState) -> None:
        if self.joint in msg.name:
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            angle = float(msg.position[list(msg.name).index(self.joint)])
            self.joint_history.add(stamp or self.get_clock().now().nanoseconds, angle)
            self._release(self.posture_sync.ready(time.monotonic_ns()))

    def _release_late_frames(self) -> None:
        """Frames whose joint state is overdue go on with the held angle (counted late)."""
        self._release(self.posture_sync.ready(time.monotonic_ns()))

    def _release(self, ready: list) -> None:
        for (state, msg, frame, flags), angle in ready:
            self._image(state, msg, frame, flags, angle)

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
        for name, state in self.layers.items():
            if state.last_image is None:
                continue
            points, pixels = self._marker_geometry[name]
            rgb = state.scale.to_rgb(state.last_image.reshape(1, -1)[:, pixels])[0] / 255.0
            colours = [ColorRGBA(r=float(r), g=float(g), b=float(b), a=1.0) for r, g, b in rgb]
            marker = Marker(ns=name, id=0, type=Marker.TRIANGLE_LIST, action=Marker.ADD)
            marker.header.frame_id = self.patch.frame_id
            marker.header.stamp = self.get_clock().now().to_msg()
            marker.pose.orientation.w = 1.0
            marker.scale.x = marker.scale.y = marker.scale.z = 1.0
            marker.points = points
            marker.colors = [c for c in colours for _ in range(6)]  # two triangles per cell
            self.marker_pubs[name].publish(marker)

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        now = time.time_ns()
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        for name, state in self.layers.items():
            processor = state.processor
            faulty = processor.faulty_electrodes
            latency = np.asarray(state.latencies_ms or [np.nan])
            values = {
                "reconstruction_rate_hz": f"{state.rate.rate_hz():.1f}",
                "latency_median_ms": f"{np.median(latency):.2f}",
                "latency_p99_ms": f"{np.percentile(latency, 99):.2f}",
                "processing_median_ms": f"{np.median(state.processing_ms or [np.nan]):.3f}",
                "frames_imaged": str(state.imaged),
                "frames_dropped": str(state.dropped),
                "frames_rejected": str(state.rejected),
                "frames_unusable": str(processor.frames_unusable),
                "frames_compiled": str(processor.frames_compiled),
                "reference_ready": str(processor.reference_ready).lower(),
                "reference_age_s": f"{processor.reference_age_s(now * 1e-9):.1f}",
                "drift_updates": str(processor.drift_updates),
                "faulty_electrodes": ",".join(str(e) for e in faulty),
                "values_out_of_range": str(processor.values_out_of_range),
                "values_jumped": str(processor.values_jumped),
                "joint_angle_rad": f"{processor.angle_rad:.3f}",
                "frames_waiting_for_joint": str(self.posture_sync.waiting),
                "frames_joint_late": str(self.posture_sync.late),
            }
            report = processor.reference_report
            excluded = report.check.excluded.sum() if report is not None else 0
            implausible = processor.values_out_of_range + processor.values_jumped
            silent_s = time.monotonic() - (state.last_arrival or self.started)
            values["last_frame_age_s"] = f"{silent_s:.1f}" if state.last_arrival else "never"
            if self.frame_timeout_s and silent_s > self.frame_timeout_s:
                topic = self.resolve_topic_name(state.frames_topic)
                level, text = 2, f"no frame on {topic} for {silent_s:.0f} s"
            elif processor.reference_error is not None:
                level, text = 2, f"not imaging: {processor.reference_error}"
            elif state.rejected and state.last_reject:
                level, text = 1, f"rejected frames: {state.last_reject}"
            elif excluded:
                level, text = 1, report.check.summary
            elif faulty.size:
                level, text = 1, f"imaging without faulty electrodes {values['faulty_electrodes']}"
            elif (
                self.calibration is not None
                and self.calibration.layer_name == name
                and (self.calibration.sheet_changed is not None)
            ):
                level, text = 1, self.calibration.sheet_changed
            elif implausible > self._implausible_reported.get(name, 0):
                level, text = (
                    1,
                    (
                        f"values left out as no measurement of the sheet: "
                        f"{processor.values_out_of_range} beyond the full scale, "
                        f"{processor.values_jumped} one-frame jumps"
                    ),
                )
            elif not processor.reference_ready:
                level, text = 0, "capturing the no-load reference (do not touch)"
            else:
                level, text = 0, f"{values['reconstruction_rate_hz']} images/s"
            self._implausible_reported[name] = implausible  # WARN while the count grows
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


def _range_parameter(quantity: str) -> str:
    """The parameter with the top of a layer's colour scale, by its quantity."""
    return "pressure_range_pa" if quantity == "pressure" else "stretch_range"


def _stamped(header: Header, msg: EitFrameFields) -> Header:
    """``header``, given the frame ``msg``'s stamp and frame_id, returned.

    The frame_id is set only when it differs (the image message is reused per frame).
    """
    header.stamp.sec, header.stamp.nanosec = msg.stamp_sec, msg.stamp_nanosec
    if header.frame_id != msg.frame_id:
        header.frame_id = msg.frame_id
    return header


def _frame_type():
    from eit_skin_msgs.msg import EitFrame

    return EitFrame


def _contact_types():
    from eit_skin_msgs.msg import Contact, ContactArray

    return Contact, ContactArray


def main(args: list[str] | None = None) -> int:
    """Console script ``eit_reconstruction``; exit 2 on a bad configuration."""
    return run_node(ReconstructionNode, "eit_reconstruction", args)


if __name__ == "__main__":
    sys.exit(main())
