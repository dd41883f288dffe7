"""``eit_classifier``: touch events (push, rub, pinch, grab) from a patch's reconstructed images.

Subscribes (sensor-data QoS) to the image of the patch's pressure layer and, when it has one,
of its stretch layer (chosen by material quantity, whatever their names:
:func:`~eit_skin.touch.classifier.classifier_layers`; topic names from
:mod:`eit_skin.ros.topics`; ``sensor_msgs/Image`` 32FC1, Pa / strain, NaN outside the
sheet); a pressure image is paired with the stretch image nearest in ``header.stamp``
within ``pair_slop_s`` (the two layers may come from two boards with their own clocks:
:class:`~eit_skin.touch.pairing.StampPairer`), or classified alone after ``pair_timeout_s``.
No image on a subscribed topic for ``image_timeout_s`` turns the diagnostics ERROR. A patch
without a pressure layer is refused.
Publishes ``touch_events`` (``eit_skin_msgs/TouchEvent``, reliable, depth 50), ``contacts``
(``ContactArray``) and ``/diagnostics``. Electrode faults: the reconstruction's
``/diagnostics`` status of the pressure layer names the electrodes it leaves out
(``faulty_electrodes``); they go to the classifier (no event from a fault, less confidence
near one; docs/classifier.md). A changed sheet: a touch withdrawn by the classifier (longer
than ``sheet_change_taus`` baseline time constants) ends with confidence 0, is logged as a
warning, counted (``sheet_changes``) and turns /diagnostics WARN with the reason
(``sheet_changed``) until the sheet is still again. Pixel geometry: row i, column j is centred at
(x[j], y[i]) of the pressure layer's image grid, rebuilt from ``patch_config`` (its inverse
mesh; the single-finger spread map comes from the reconstruction cache:
:func:`~eit_skin.touch.shapes.contact_geometry`). The first ``calibration_s`` of images
must be free of touch (noise and baseline). Method and parameters: docs/classifier.md.

Raw frames: the node also subscribes (sensor-data QoS) to the pressure layer's
``<layer>/frames`` and hands each image the frame of the same ``header.stamp`` (flagged
channels NaN): the classifier's ``shape_z`` tells a close pinch from a push on the raw
channels (docs/classifier.md). An image whose frame has not arrived is classified without it;
frames of another size are counted (``frames_rejected``) and left out.

Calibrated positions: when the reconstruction publishes ``calibrated_contacts`` (its
``calibration`` parameter), an event's centroid is the calibrated press of the same
``header.stamp`` if one with confidence >= ``MIN_CONFIDENCE`` has arrived by then (and it is
the frame's only calibrated press); otherwise it stays the image centroid. Segmented
``contacts`` carry NaN depth and confidence.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from eit_skin.calibration.online import MIN_CONFIDENCE
from eit_skin.frames import flagged_as_nan
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.pipeline.builder import default_cache_dir
from eit_skin.resources import config_path
from eit_skin.ros.node_runner import (
    REJECT_LOG_PERIOD_S,
    LiveParameters,
    ThrottledLog,
    declare_parameters,
    diagnostic_status,
    run_node,
)
from eit_skin.ros.parameters import CLASSIFIER, WRITABLE
from eit_skin.ros.qos import OVERRIDABLE, SENSOR_READER
from eit_skin.ros.surface_fields import place_on_surface
from eit_skin.ros.topics import RECONSTRUCTION_NODE, patch_topics
from eit_skin.touch.classifier import TouchClassifier, classifier_layers
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.events import LABELS, STATES
from eit_skin.touch.frame_evidence import channel_electrodes
from eit_skin.touch.pairing import StampPairer
from eit_skin.touch.settings import setting_values, settings_from
from eit_skin.touch.shapes import contact_geometry


class ClassifierNode(Node):
    """Thin adapter: images -> :class:`TouchClassifier` -> TouchEvent / ContactArray."""

    def __init__(self, **kwargs) -> None:
        super().__init__("eit_classifier", **kwargs)
        p = declare_parameters(self, CLASSIFIER, "eit_classifier")
        path = config_path(str(p["patch_config"]))
        self.patch = load_patch(path)  # PatchError: refuse to start (see main)
        layer, stretch = classifier_layers(self.patch)  # PatchError: no pressure layer
        # every declared setting from its parameter; out of range: ValueError, exit 2
        config = settings_from(ClassifierConfig, p)
        started = time.perf_counter()
        # the pixel grid and one fingertip's blur at every pixel (m); no reconstruction
        # matrix unless the spread map is not cached yet
        geometry = contact_geometry(
            layer,
            str(p["cache_dir"]) or default_cache_dir(),
            radius_m=config.finger_radius_m,
            fraction=config.blob_fraction,
        )
        self.grid = geometry.grid
        spread = geometry.spread_m
        geometry_s = time.perf_counter() - started
        noise = float(p["noise_pa"]) or None
        protocol = build_protocol(layer.protocol, layer.n_electrodes)
        self.n_channels = protocol.n_measurements
        self.classifier = TouchClassifier(
            self.grid.x,
            self.grid.y,
            config,
            noise,
            contact_spread_m=spread,
            electrodes_m=np.array([e.center for e in layer.electrodes], dtype=np.float64),
            channel_electrodes=channel_electrodes(protocol),
            disc_rel=geometry.disc_rel,  # the raw frames' START filter
            contact_rel=geometry.contact_rel,
        )
        self._frames: dict[int, np.ndarray] = {}  # stamp ns -> raw frame [M] V, oldest first
        self.pressure_layer = layer.name
        self.has_stretch = stretch is not None
        self.pairer: StampPairer[tuple[Image, np.ndarray], np.ndarray] = StampPairer(
            int(float(p["pair_slop_s"]) * 1e9), int(float(p["pair_timeout_s"]) * 1e9)
        )
        self._log_reject = ThrottledLog(self.get_logger().error, REJECT_LOG_PERIOD_S)
        self.counts = {
            "images": 0,
            "rejected": 0,
            "events": 0,
            "bad_fault_reports": 0,
            "sheet_changes": 0,
            "frames_paired": 0,
            "frames_rejected": 0,
        }
        self.image_timeout_s = float(p["image_timeout_s"])
        self.started = time.monotonic()
        self._busy_s = 0.0

        self._connect(layer.name, stretch.name if stretch else None)
        self.diagnostics_timer = self.create_timer(
            float(p["diagnostics_period_s"]), self._publish_diagnostics
        )
        self.live = LiveParameters(
            self, WRITABLE["eit_classifier"], self._apply_parameters, self._settings_with
        )
        self.get_logger().info(
            f"patch {self.patch.name!r} ({path}): pressure layer {layer.name!r}, image "
            f"{self.grid.shape[0]}x{self.grid.shape[1]}, stretch layer "
            f"{stretch.name if stretch else None!r}; single-finger spread from "
            f"{geometry.source} in {geometry_s:.2f} s"
        )

    def _connect(self, pressure: str, stretch: str | None) -> None:
        """Subscribe to the layers' images and frames, calibrated contacts and diagnostics.

        Also creates the event, contact and diagnostics publishers.
        """
        topics = patch_topics(self.patch)
        #: subscribed image topic -> time.monotonic() of its last image (None: none yet)
        self.last_image: dict[str, float | None] = {}
        images = [(pressure, self._on_pressure)]
        if self.has_stretch:
            images.append((stretch, self._on_stretch))
        for name, callback in images:
            self.last_image[topics.layers[name].image] = None
            self.create_subscription(
                Image,
                topics.layers[name].image,
                callback,
                SENSOR_READER,
                qos_overriding_options=OVERRIDABLE,
            )
        if self.has_stretch:
            self.create_timer(0.02, self._flush_unpaired)
        self.image_topics = list(self.last_image)
        from eit_skin_msgs.msg import EitFrame

        self.create_subscription(
            EitFrame,
            topics.layers[pressure].frames,
            self._on_frame,
            SENSOR_READER,
            qos_overriding_options=OVERRIDABLE,
        )
        from eit_skin_msgs.msg import ContactArray, TouchEvent

        self._msgs = (TouchEvent, ContactArray)
        reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.events_pub = self.create_publisher(
            TouchEvent, topics.touch_events, reliable, qos_overriding_options=OVERRIDABLE
        )
        self.contacts_pub = self.create_publisher(
            ContactArray, topics.contacts, 10, qos_overriding_options=OVERRIDABLE
        )
        self._calibrated: dict[int, tuple[float, float]] = {}  # stamp ns -> press xy, m
        self.create_subscription(
            ContactArray,
            topics.calibrated_contacts,
            self._on_calibrated,
            10,
            qos_overriding_options=OVERRIDABLE,
        )
        self.diagnostics = self.create_publisher(
            DiagnosticArray, topics.diagnostics, 10, qos_overriding_options=OVERRIDABLE
        )
        # the reconstruction's faulty electrodes come with its diagnostics (1 Hz, like its
        # fault checks): no extra topic, nothing for a controller to wire up
        self.create_subscription(
            DiagnosticArray,
            topics.diagnostics,
            self._on_diagnostics,
            10,
            qos_overriding_options=OVERRIDABLE,
        )

    # ------------------------------------------------------------------ live tuning
    def _settings_with(self, values: dict[str, object]) -> ClassifierConfig:
        """The classifier's settings with ``values`` (name -> value) changed.

        Raises:
            ValueError: a value out of its bounds, or settings that contradict each other.
        """
        return settings_from(ClassifierConfig, {**setting_values(self.classifier.config), **values})

    def _apply_parameters(self, values: dict[str, object]) -> None:
        """Writable parameters set while running: in effect from the next image."""
        self.classifier.update_settings(self._settings_with(values))
        if "image_timeout_s" in values:
            self.image_timeout_s = float(values["image_timeout_s"])
        if "diagnostics_period_s" in values:
            self.diagnostics_timer.timer_period_ns = round(
                float(values["diagnostics_period_s"]) * 1e9
            )

    # ------------------------------------------------------------------ input
    def _decode(self, msg: Image) -> np.ndarray | None:
        shape = self.grid.shape
        if msg.encoding != "32FC1" or (msg.height, msg.width) != shape:
            self.counts["rejected"] += 1
            self._log_reject(
                f"image {msg.encoding} {msg.height}x{msg.width} does not match the patch "
                f"grid 32FC1 {shape[0]}x{shape[1]}; dropped"
            )
            return None
        dtype = np.dtype(">f4" if msg.is_bigendian else "<f4")
        row = msg.step // 4 if msg.step else msg.width
        data = np.frombuffer(bytes(msg.data), dtype=dtype)
        if data.size < msg.height * row:
            self.counts["rejected"] += 1
            self._log_reject(
                f"image data of {data.size * 4} bytes is shorter than height {msg.height} x "
                f"step {row * 4}; dropped"
            )
            return None
        return data[: msg.height * row].reshape(msg.height, row)[:, : msg.width].astype(np.float32)

    @staticmethod
    def _stamp_ns(msg: Image) -> int:
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def _on_pressure(self, msg: Image) -> None:
        self.last_image[self.image_topics[0]] = time.monotonic()
        image = self._decode(msg)
        if image is None:
            return
        if not self.has_stretch:
            self._process(msg, image, None)
            return
        self._process_pairs(self.pairer.push_pressure(self._stamp_ns(msg), (msg, image)))

    def _on_stretch(self, msg: Image) -> None:
        self.last_image[self.image_topics[1]] = time.monotonic()
        # the stretch layer has its own grid; only its peak is used, so any shape is fine
        dtype = np.dtype(">f4" if msg.is_bigendian else "<f4")
        image = np.frombuffer(bytes(msg.data), dtype=dtype).astype(np.float32)
        self._process_pairs(self.pairer.push_stretch(self._stamp_ns(msg), image))

    def _flush_unpaired(self) -> None:
        self._process_pairs(self.pairer.flush())

    def _process_pairs(self, pairs: list) -> None:
        for (msg, image), stretch in pairs:
            self._process(msg, image, stretch)

    def _on_frame(self, msg) -> None:
        """Keep the pressure layer's raw frame until the image of its stamp comes."""
        m = self.n_channels
        flags = msg.channel_flags
        if len(msg.voltages) != m or len(flags) not in (0, m):
            self.counts["frames_rejected"] += 1
            return
        frame = flagged_as_nan(msg.voltages, np.frombuffer(bytes(flags), np.uint8))
        self._frames[self._stamp_ns(msg)] = frame
        while len(self._frames) > 100:  # images stopped coming: keep the latest 2 s
            self._frames.pop(next(iter(self._frames)))

    def _frame_for(self, stamp: int) -> np.ndarray | None:
        """The raw frame of ``stamp`` (and forget every older one), or None."""
        frame = self._frames.pop(stamp, None)
        while self._frames and next(iter(self._frames)) < stamp:
            self._frames.pop(next(iter(self._frames)))
        if frame is not None:
            self.counts["frames_paired"] += 1
        return frame

    def _on_calibrated(self, msg) -> None:
        # one calibrated press: the event's centroid; several (calibration_max_touches > 1):
        # the event spans them, its image centroid stands
        if len(msg.contacts) == 1 and msg.contacts[0].confidence >= MIN_CONFIDENCE:
            c = msg.contacts[0].centroid
            self._calibrated[self._stamp_ns(msg)] = (c.x, c.y)
            while len(self._calibrated) > 50:
                self._calibrated.pop(next(iter(self._calibrated)))

    # ------------------------------------------------------------------ output
    def _process(self, msg: Image, pressure: np.ndarray, stretch: np.ndarray | None) -> None:
        started = time.perf_counter()
        self.counts["images"] += 1
        stamp = self._stamp_ns(msg)
        t_s = stamp * 1e-9
        # the classifier uses only the stretch peak: a flat vector serves
        stretch_2d = None if stretch is None else stretch.reshape(1, -1)
        volts = self._frame_for(stamp)
        events = self.classifier.step(t_s, pressure, stretch_2d, volts)
        self._publish_events(msg.header, events)
        _, ContactArray = self._msgs
        if self.classifier.calibrated:
            from eit_skin_msgs.msg import Contact

            array = ContactArray()
            array.header = msg.header
            array.patch = self.patch.name
            for c in self.classifier.last_contacts:
                item = Contact()
                item.layer = self.pressure_layer
                item.centroid.x, item.centroid.y = c.centroid_m
                item.area_m2 = float(c.area_m2)
                item.peak = float(c.peak)
                item.mean = float(c.mean)
                item.depth_m = item.confidence = float("nan")
                array.contacts.append(item)
            points = [(c.centroid.x, c.centroid.y) for c in array.contacts]
            place_on_surface(array.contacts, self.patch.placement, points)
            self.contacts_pub.publish(array)
        self._busy_s += time.perf_counter() - started

    def _publish_events(self, header, events) -> None:
        """Publish touch events with ``header`` (the stamp of the image behind them)."""
        TouchEvent, _ = self._msgs
        stamp = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
        for event in events:
            out = TouchEvent()
            out.header = header
            out.header.frame_id = header.frame_id or self.patch.frame_id
            out.patch = self.patch.name
            out.id = event.touch_id
            out.label = LABELS.index(event.label)
            out.state = STATES.index(event.state)
            out.confidence = float(event.confidence)
            out.centroid.x, out.centroid.y = self._calibrated.get(stamp, event.centroid_m)
            out.area_m2 = float(event.area_m2)
            out.peak = float(event.peak_pa)
            duration_ns = max(0, round(event.duration_s * 1e9))
            out.duration.sec, out.duration.nanosec = divmod(duration_ns, 1_000_000_000)
            place_on_surface([out], self.patch.placement, [(out.centroid.x, out.centroid.y)])
            self.events_pub.publish(out)
            self.counts["events"] += 1
            if event.withdrawn:  # END with confidence 0: the sheet changed, no touch
                self.counts["sheet_changes"] += 1
                self.get_logger().warning(event.withdrawn)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        """Faulty electrodes the reconstruction of our pressure layer leaves out -> classifier.

        The reconstruction node's status of that layer (name ``<node>: <layer>``, hardware id
        the patch name) carries them as ``faulty_electrodes`` ("3,7"; empty: none); events
        near them get less confidence.
        """
        for status in msg.status:
            if status.hardware_id != self.patch.name or not status.name.endswith(
                f"{RECONSTRUCTION_NODE}: {self.pressure_layer}"
            ):
                continue
            values = {kv.key: kv.value for kv in status.values}
            if "faulty_electrodes" not in values:
                continue
            text = values["faulty_electrodes"].strip()
            try:
                self.classifier.set_faulty_electrodes(
                    [int(e) for e in text.split(",")] if text else []
                )
            except ValueError as error:
                self.counts["bad_fault_reports"] += 1
                self.get_logger().error(
                    f"faulty_electrodes {text!r}: {error}", throttle_duration_sec=5.0
                )

    def _publish_diagnostics(self) -> None:
        c = self.classifier
        level = 0 if c.calibrated else 1
        message = "ok" if c.calibrated else "calibrating (keep the skin untouched)"
        now = time.monotonic()
        ages = {}
        for topic, last in self.last_image.items():
            silent_s = now - (last or self.started)
            ages[f"last_image_age_s {topic}"] = f"{silent_s:.1f}" if last else "never"
            if self.image_timeout_s and silent_s > self.image_timeout_s and level < 2:
                level = 2
                message = f"no image on {self.resolve_topic_name(topic)} for {silent_s:.0f} s"
        if c.sheet_changed is not None and level < 2:  # no touch until the sheet is still
            level, message = 1, c.sheet_changed
        values = {
            **{k: str(v) for k, v in self.counts.items()},
            "unpaired": str(self.pairer.unpaired),
            **ages,
            "noise_pa": f"{c.pressure_noise_pa or 0.0:.3g}",
            "touch_active": str(c.active),
            "faulty_electrodes": ",".join(str(e) for e in c.faulty),
            "sheet_changed": c.sheet_changed or "",
            "busy_s": f"{self._busy_s:.3f}",
        }
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [
            diagnostic_status(
                level,
                f"{self.get_fully_qualified_name()}: touch classifier",
                message,
                self.patch.name,
                values,
            )
        ]
        self.diagnostics.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Console script ``eit_classifier``; exit 2 on a bad configuration."""
    return run_node(ClassifierNode, "eit_classifier", args)


if __name__ == "__main__":
    sys.exit(main())
