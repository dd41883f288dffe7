"""eit_classifier as a real process over DDS: synthetic 32FC1 images in, touch events out."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import Contact, ContactArray, EitFrame, TouchEvent
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Image

from eit_skin.fem.image_grid import ImageGrid
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.resources import config_path
from eit_skin.ros.node_runner import REJECT_LOG_PERIOD_S
from eit_skin.ros.probe import Probe, frame_msg, stamp_ns, start_node, stop_node
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from eit_skin.touch.pairing import StampPairer
from eit_skin.touch.shapes import layer_image_grid
from test.support.patch_copies import shipped_patch_data, write_patch
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros


@dataclass
class Case:
    """A patch file, where its pressure image is and where the synthetic touch is."""

    namespace: str
    config: str  # patch_config parameter
    pressure: str  # pressure layer name
    stretch: str | None  # stretch layer name
    centre: tuple[float, float]  # m


def elbow(tmp_path) -> Case:
    """The shipped elbow patch: one pressure layer, named ``pressure``."""
    return Case("/elbow_cls_test", "elbow", "pressure", None, (0.012, -0.03))


def renamed_arm(tmp_path) -> Case:
    """The arm with its layers renamed ``front`` (pressure) and ``back`` (stretch)."""
    data = shipped_patch_data("arm")
    names = [layer["name"] for layer in data["layers"]]
    assert names == ["pressure", "stretch"]
    data["layers"][0]["name"], data["layers"][1]["name"] = "front", "back"
    return Case("/arm_cls_test", str(write_patch(tmp_path, data)), "front", "back", (0.01, -0.005))


def image_msg(grid: ImageGrid, k: int, values: np.ndarray) -> Image:
    values = np.where(grid.inside, values, np.nan).astype("<f4")
    msg = Image()
    msg.header.stamp = Time(sec=1000 + k // 50, nanosec=(k % 50) * 20_000_000)
    msg.header.frame_id = "skin_link"
    msg.height, msg.width = values.shape
    msg.encoding = "32FC1"
    msg.is_bigendian = 0
    msg.step = 4 * msg.width
    msg.data = values.tobytes()
    return msg


def fingertip_blob(grid: ImageGrid, centre: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """``(xx [H, W] m, blob [H, W] Pa)``: the pixel x and a 6 kPa fingertip at ``centre``."""
    xx, yy = np.meshgrid(grid.x, grid.y)
    return xx, 6000.0 * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / 2e-5)


def classifier_probe(name: str, topics, pressure: str):
    """``(probe, publisher)``: a probe hearing the classifier's events, contacts and
    diagnostics, and a publisher of the ``pressure`` layer's images."""
    probe = Probe(name)
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    probe.subscribe(TouchEvent, topics.touch_events, reliable)
    probe.subscribe(ContactArray, topics.contacts, 10)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10)
    pub = probe.node.create_publisher(Image, topics.layers[pressure].image, qos_profile_sensor_data)
    return probe, pub


def preroll(probe: Probe, send: Callable[[int, bool], list], contacts: list, log: Path) -> int:
    """Quiet frames ``send(k, False)`` for k = 0, 1, ... until the classifier has calibrated
    and answers with ``contacts``; returns the next k, where the test's scene starts (its
    stamps go on without a gap), so every frame of the scene is paced by
    :func:`wait_for_contacts`.

    Until the classifier's diagnostics count an image, a frame every 20 ms (our writer
    matching the node's best-effort reader does not mean the reader has matched us). Then
    each frame waits for the count to grow (at most 1 s): a busy machine that let frames
    pile up in the reader's queue dropped a third of them, and a scene sent un-paced while
    the classifier still calibrated lost its touch onset."""
    deadline = time.monotonic() + EVENT_S
    k = 0
    while time.monotonic() < deadline:
        if contacts:
            return k
        seen = images(probe)
        send(k, False)
        k += 1
        if not seen:
            probe.spin_for(0.02)
        else:
            probe.spin_until(lambda seen=seen: contacts or images(probe) > seen, 1.0)
    raise AssertionError(f"the classifier answered no image in {EVENT_S} s\n{log.read_text()}")


def wait_for_contacts(probe: Probe, contacts: list, sent: list[tuple]) -> None:
    """Pace images by the classifier: once calibrated, it answers every image with its
    ``contacts`` (same stamp), so the next image waits for them and a busy machine drops
    none (touch latencies are asserted in image time). ``sent``: the ``(publisher,
    message)`` pairs of this frame, the image last; published again when no answer came in
    1 s (best effort: a busy machine lost images at the onset under pytest -n 2), at most 5
    times."""
    image = sent[-1][1]
    for _ in range(5):
        if probe.spin_until(lambda: stamp_ns(contacts[-1][1]) >= stamp_ns(image), 1.0):
            return
        for publisher, message in sent:
            publisher.publish(message)


def images(probe: Probe) -> int:
    """The classifier's latest count of images processed (0 before its first status)."""
    return int(classifier_values(probe).get("images", "0"))


def classifier_values(probe: Probe) -> dict[str, str]:
    """The values of the classifier's latest diagnostics status ({} before the first)."""
    for _, msg in reversed(probe.messages[DIAGNOSTICS]):
        for status in msg.status:
            if "touch classifier" in status.name:
                return {kv.key: kv.value for kv in status.values}
    return {}


@pytest.mark.parametrize("make_case", [elbow, renamed_arm], ids=["elbow", "renamed_arm"])
def test_blob_appears_stays_disappears(tmp_path, make_case) -> None:
    case = make_case(tmp_path)
    patch = load_patch(config_path(case.config))
    topics = patch_topics(patch, case.namespace)
    grid = layer_image_grid(patch.layer(case.pressure))
    probe, pub = classifier_probe("classifier_probe", topics, case.pressure)
    pubs = [pub]
    if case.stretch is not None:
        stretch_grid = layer_image_grid(patch.layer(case.stretch))
        stretch_pub = probe.node.create_publisher(
            Image, topics.layers[case.stretch].image, qos_profile_sensor_data
        )
        pubs.append(stretch_pub)
    log = tmp_path / "classifier.log"
    params = {"patch_config": case.config, "diagnostics_period_s": 0.02}
    node = start_node("eit_classifier", case.namespace, params, log)
    try:
        assert probe.spin_until(lambda: all(p.get_subscription_count() for p in pubs), EVENT_S), (
            log.read_text()
        )
        assert probe.spin_until(
            lambda: probe.node.count_publishers(topics.touch_events) > 0, EVENT_S
        )
        rng = np.random.default_rng(0)
        xx, blob = fingertip_blob(grid, case.centre)

        def send(k: int, touch: bool) -> list[tuple]:
            sent = []
            if case.stretch is not None:  # first, stamped 7 ms later as by a second board
                strain = 1e-4 * rng.standard_normal(stretch_grid.shape)
                stretch = image_msg(stretch_grid, k, strain)
                stretch.header.stamp.nanosec += 7_000_000
                sent.append((stretch_pub, stretch))
            msg = image_msg(grid, k, 10.0 * rng.standard_normal(xx.shape) + touch * blob)
            for publisher, message in [*sent, (pub, msg)]:
                publisher.publish(message)
            return [*sent, (pub, msg)]

        contacts = probe.messages[topics.contacts]  # the list the probe appends to
        first = preroll(probe, send, contacts, log)
        for j in range(110):  # 0.6 s quiet, 1.0 s touch, 0.6 s quiet at 50 Hz
            wait_for_contacts(probe, contacts, send(first + j, 30 <= j < 80))
        topic = topics.touch_events
        probe.spin_until(
            lambda: any(m.state == TouchEvent.END for _, m in probe.messages[topic]), EVENT_S
        )
        events = [m for _, m in probe.messages[topic]]
        assert events, log.read_text()
        states = [e.state for e in events]
        assert states[0] == TouchEvent.START and states[-1] == TouchEvent.END
        assert TouchEvent.UPDATE in states and states.count(TouchEvent.START) == 1
        assert {e.id for e in events} == {events[0].id}
        start, end = events[0], events[-1]
        assert (
            start.header.stamp.sec * 1e9
            + start.header.stamp.nanosec
            - (1000e9 + (first + 30) * 20e6)
            <= 150e6
        ), (first, classifier_values(probe), states)
        assert end.label == TouchEvent.PUSH and end.patch == patch.name
        assert end.header.frame_id == "skin_link"
        pixel = grid.x[1] - grid.x[0]
        mid = events[len(events) // 2]
        assert (mid.centroid.x, mid.centroid.y) == pytest.approx(case.centre, abs=pixel)
        assert end.duration.sec + 1e-9 * end.duration.nanosec == pytest.approx(1.0, abs=0.1)
        arrays = [m for _, m in probe.messages[topics.contacts] if m.contacts]
        assert arrays and arrays[len(arrays) // 2].contacts[0].peak > 3000.0
        assert arrays[-1].contacts[0].layer == case.pressure
        if case.stretch is not None:  # the stretch layer is heard: images were paired
            assert probe.spin_until(
                lambda: (
                    int(classifier_values(probe).get("images", 0))
                    - int(classifier_values(probe).get("unpaired", 0))
                    >= 50
                ),
                EVENT_S,
            ), classifier_values(probe)
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()


def test_raw_frames_of_the_same_stamp_tell_a_close_pinch_from_a_push(tmp_path) -> None:
    """A still blob in the images whose raw frames close like a pinch (a pattern growing to
    60 noise units over the hold, beyond what the blob's amplitude explains) is a pinch: the
    node pairs each image with the frame of its stamp. A frame of the wrong size is counted
    and left out."""
    case = elbow(tmp_path)
    patch = load_patch(config_path(case.config))
    layer = patch.layer(case.pressure)
    topics = patch_topics(patch, "/elbow_frames_test")
    grid = layer_image_grid(layer)
    m = build_protocol(layer.protocol, layer.n_electrodes).n_measurements
    probe, pub = classifier_probe("classifier_frames_probe", topics, case.pressure)
    frames_pub = probe.node.create_publisher(
        EitFrame,
        topics.layers[case.pressure].frames,
        qos_profile_sensor_data,
    )
    log = tmp_path / "classifier.log"
    params = {"patch_config": case.config, "diagnostics_period_s": 0.02}
    node = start_node("eit_classifier", "/elbow_frames_test", params, log)
    try:
        assert probe.spin_until(
            lambda: pub.get_subscription_count() and frames_pub.get_subscription_count(), EVENT_S
        ), log.read_text()
        rng = np.random.default_rng(1)
        xx, blob = fingertip_blob(grid, case.centre)
        sigma = 1e-5 * (1 + rng.random(m))
        reference = 0.01 + 0.05 * rng.random(m)
        push = rng.normal(size=m)
        push *= 400.0 / np.linalg.norm(push)
        closing = rng.normal(size=m)
        closing /= np.linalg.norm(closing)
        first = 0

        def send(k: int, touch: bool) -> list[tuple]:
            j = k - first
            grow = 60.0 * np.clip((j - 32) / 46.0, 0.0, 1.0) if touch else 0.0
            x = touch * push + grow * closing + rng.normal(size=m)
            frame = frame_msg(layer, k, reference + sigma * x)
            image = image_msg(grid, k, 10.0 * rng.standard_normal(xx.shape) + touch * blob)
            sent = [(frames_pub, frame), (pub, image)]
            for publisher, message in sent:
                publisher.publish(message)
            return sent

        contacts = probe.messages[topics.contacts]
        first = preroll(probe, send, contacts, log)
        for j in range(110):  # 0.6 s quiet, 1.0 s touch, 0.6 s quiet at 50 Hz
            wait_for_contacts(probe, contacts, send(first + j, 30 <= j < 80))
        topic = topics.touch_events
        assert probe.spin_until(
            lambda: any(m.state == TouchEvent.END for _, m in probe.messages[topic]), EVENT_S
        ), log.read_text()
        end = [msg for _, msg in probe.messages[topic] if msg.state == TouchEvent.END]
        assert [e.label for e in end] == [TouchEvent.PINCH], classifier_values(probe)
        assert probe.spin_until(
            lambda: int(classifier_values(probe).get("frames_paired", 0)) >= 100, EVENT_S
        ), classifier_values(probe)
        # now that the node has heard this writer: a frame of the wrong size is counted
        assert classifier_values(probe)["frames_rejected"] == "0"
        frames_pub.publish(frame_msg(layer, first + 110, np.zeros(m + 1)))
        assert probe.spin_until(
            lambda: classifier_values(probe).get("frames_rejected") == "1", EVENT_S
        ), classifier_values(probe)
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()


def test_patch_without_a_pressure_layer_is_refused(tmp_path) -> None:
    data = shipped_patch_data("arm")
    data["layers"] = [layer for layer in data["layers"] if layer["name"] == "stretch"]
    data["layers"][0]["name"] = "sleeve"
    path = write_patch(tmp_path, data)
    log = tmp_path / "stretch_only.log"
    node = start_node("eit_classifier", "/stretch_only", {"patch_config": str(path)}, log)
    assert node.wait(EVENT_S) == 2
    text = log.read_text()
    assert "refusing to start" in text
    assert f"{path}: layers: no layer measures pressure (sleeve: stretch)" in text


def test_bad_patch_refuses_to_start(tmp_path) -> None:
    log = tmp_path / "bad.log"
    node = start_node(
        "eit_classifier", "/bad_cls_test", {"patch_config": str(tmp_path / "none.yaml")}, log
    )
    assert node.wait(EVENT_S) == 2
    assert "refusing to start" in log.read_text()


def test_events_take_the_calibrated_position_of_the_same_stamp(tmp_path) -> None:
    """With calibrated_contacts for a frame, the event centroid is the calibrated press.

    The calibrated press is put ~60 mm from the image blob, so the image centroid cannot
    pass; a low-confidence calibrated press (not a single known press) is ignored.
    """
    case = elbow(tmp_path)
    patch = load_patch(config_path(case.config))
    topics = patch_topics(patch, "/elbow_calibrated_cls_test")
    grid = layer_image_grid(patch.layer(case.pressure))
    probe = Probe("calibrated_classifier_probe")
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    probe.subscribe(TouchEvent, topics.touch_events, reliable)
    probe.subscribe(ContactArray, topics.contacts, 10)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10)
    pub = probe.node.create_publisher(
        Image, topics.layers[case.pressure].image, qos_profile_sensor_data
    )
    calibrated_pub = probe.node.create_publisher(ContactArray, topics.calibrated_contacts, 10)
    log = tmp_path / "classifier.log"
    namespace = topics.namespace
    params = {"patch_config": case.config, "diagnostics_period_s": 0.02}
    node = start_node("eit_classifier", namespace, params, log)
    calibrated_xy = (case.centre[0] - 0.02, case.centre[1] + 0.055)
    try:
        linked = probe.spin_until(
            lambda: pub.get_subscription_count() and calibrated_pub.get_subscription_count(),
            EVENT_S,
        )
        assert linked, log.read_text()
        assert probe.spin_until(
            lambda: probe.node.count_publishers(topics.touch_events) > 0, EVENT_S
        )
        rng = np.random.default_rng(0)
        xx, blob = fingertip_blob(grid, case.centre)

        def send(k: int, touch: bool) -> list[tuple]:
            image = image_msg(grid, k, 10.0 * rng.standard_normal(xx.shape) + touch * blob)
            array = ContactArray(header=image.header, patch=patch.name)
            if touch:  # the reconstruction publishes the calibrated press before the image
                confidence = 0.01 if k == first + 55 else 0.5
                item = Contact(layer=case.pressure, confidence=confidence, depth_m=0.004)
                item.centroid.x, item.centroid.y = calibrated_xy
                array.contacts.append(item)
            calibrated_pub.publish(array)
            probe.spin_for(0.005)
            pub.publish(image)
            return [(calibrated_pub, array), (pub, image)]

        contacts = probe.messages[topics.contacts]  # the list the probe appends to
        first = preroll(probe, send, contacts, log)
        for j in range(110):  # 0.6 s quiet, 1.0 s touch, 0.6 s quiet at 50 Hz
            wait_for_contacts(probe, contacts, send(first + j, 30 <= j < 80))
        topic = topics.touch_events
        probe.spin_until(
            lambda: any(m.state == TouchEvent.END for _, m in probe.messages[topic]), EVENT_S
        )
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()
    events = [m for _, m in probe.messages[topic] if m.state != TouchEvent.END]
    assert events, log.read_text()
    for e in events:
        k = round((e.header.stamp.sec - 1000) * 50 + e.header.stamp.nanosec / 20e6) - first
        xy = (e.centroid.x, e.centroid.y)
        if 30 <= k < 80 and k != 55:
            assert xy == pytest.approx(calibrated_xy, abs=1e-6), k
        else:  # no calibrated press of that stamp, or one of too low confidence
            assert xy == pytest.approx(case.centre, abs=grid.x[1] - grid.x[0]), k
    segmented = [c for _, m in probe.messages[topics.contacts] for c in m.contacts]
    assert segmented and all(np.isnan(c.confidence) and np.isnan(c.depth_m) for c in segmented)


def test_images_that_stop_turn_the_diagnostics_error(tmp_path) -> None:
    """The renamed arm's pressure images flow, its stretch images never come: after
    image_timeout_s the classifier says ERROR naming the silent topic (not the flowing
    one); once stretch images come too, the error clears."""
    case = renamed_arm(tmp_path)
    patch = load_patch(config_path(case.config))
    topics = patch_topics(patch, "/arm_timeout_test")
    pressure_topic, stretch_topic = (topics.layers[n].image for n in (case.pressure, case.stretch))
    grids = {n: layer_image_grid(patch.layer(n)) for n in (case.pressure, case.stretch)}
    probe = Probe("classifier_timeout_probe")
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    pubs = {
        name: probe.node.create_publisher(Image, topic, qos_profile_sensor_data)
        for name, topic in ((case.pressure, pressure_topic), (case.stretch, stretch_topic))
    }
    params = {"patch_config": case.config, "image_timeout_s": 1.0, "diagnostics_period_s": 0.2}
    log = tmp_path / "classifier.log"
    node = start_node("eit_classifier", topics.namespace, params, log)
    rng = np.random.default_rng(1)
    sent = [0]

    def publish(layers) -> None:
        k = sent[0]
        sent[0] += 1
        for name in layers:
            values = 10.0 * rng.standard_normal(grids[name].shape)
            pubs[name].publish(image_msg(grids[name], k, values))

    def status():
        for _, msg in reversed(probe.messages[DIAGNOSTICS]):
            for s in msg.status:
                if s.name == f"{topics.namespace}/eit_classifier: touch classifier":
                    return s
        return None

    def after(count: int, condition):
        """Publish images and spin until a status after the first ``count`` meets it."""

        def check() -> bool:
            mine = [
                s
                for _, m in probe.messages[DIAGNOSTICS]
                for s in m.status
                if s.name.startswith(f"{topics.namespace}/eit_classifier")
            ]
            publish(layers)
            return any(condition(s) for s in mine[count:]) or node.poll() is not None

        return check

    try:
        assert probe.spin_until(
            lambda: all(p.get_subscription_count() for p in pubs.values()), EVENT_S
        )
        layers = [case.pressure]
        error = f"no image on {stretch_topic}"
        assert probe.spin_until(
            after(0, lambda s: s.level[0] == 2 and s.message.startswith(error)), EVENT_S
        ), (status(), log.read_text())
        assert pressure_topic not in status().message
        ages = {kv.key: kv.value for kv in status().values}
        assert ages[f"last_image_age_s {patch_topics(patch).layers[case.stretch].image}"] == "never"
        seen = len(probe.messages[DIAGNOSTICS])
        layers = [case.pressure, case.stretch]
        assert probe.spin_until(after(seen, lambda s: s.level[0] < 2), EVENT_S), status()
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()


def test_stamp_pairer_pairs_the_nearest_stamp_within_the_slop() -> None:
    pairer = StampPairer(slop_ns=10_000_000, timeout_ns=100_000_000)
    assert pairer.push_stretch(1_007_000_000, "s0") == []
    assert pairer.push_pressure(1_000_000_000, "p0") == [("p0", "s0")]  # 7 ms apart
    assert pairer.push_pressure(1_020_000_000, "p1") == []  # its partner is late
    assert pairer.push_stretch(1_045_000_000, "far") == []  # 25 ms: not its partner
    assert pairer.push_stretch(1_026_000_000, "s1") == [("p1", "s1")]
    assert pairer.push_pressure(1_040_000_000, "p2") == [("p2", "far")]  # nearest, 5 ms
    assert pairer.push_pressure(1_100_000_000, "p3") == []
    assert pairer.flush() == []  # p3 waited for nothing yet
    assert pairer.push_pressure(1_200_000_000, "p4") == []
    assert pairer.flush() == [("p3", None)] and pairer.unpaired == 1


def test_images_that_do_not_fit_are_counted_dropped_and_logged_once(tmp_path) -> None:
    """Wrong-size and truncated pressure images at 50 Hz: every one is counted as
    ``rejected``, none is classified, the node stays up, and its log gets one line per
    5 s however many come."""
    case = elbow(tmp_path)
    patch = load_patch(config_path(case.config))
    topics = patch_topics(patch, case.namespace + "_bad")
    grid = layer_image_grid(patch.layer(case.pressure))
    probe, pub = classifier_probe("classifier_bad_probe", topics, case.pressure)
    log = tmp_path / "classifier.log"
    params = {"patch_config": case.config, "diagnostics_period_s": 0.05}
    node = start_node("eit_classifier", case.namespace + "_bad", params, log)
    try:
        assert probe.spin_until(lambda: pub.get_subscription_count() > 0, EVENT_S), log.read_text()
        assert probe.spin_until(lambda: classifier_values(probe), EVENT_S), log.read_text()
        started = time.monotonic()
        sent = 0
        # best effort: keep sending until 20 were counted (a busy reader may drop some)
        while int(classifier_values(probe).get("rejected", 0)) < 20:
            assert time.monotonic() - started < EVENT_S, classifier_values(probe)
            wrong = image_msg(grid, sent, np.zeros(grid.shape))
            wrong.width -= 1  # the patch grid's height x (width - 1): another grid
            short = image_msg(grid, sent, np.zeros(grid.shape))
            short.data = bytes(short.data)[: len(short.data) // 2]
            pub.publish(wrong if sent % 2 else short)
            sent += 1
            probe.spin_for(0.02)
        values = classifier_values(probe)
        assert values["images"] == "0" and node.poll() is None, values
        text = log.read_text()
        lines = text.count("does not match the patch grid") + text.count("is shorter than")
        assert 1 <= lines <= 1 + (time.monotonic() - started) / REJECT_LOG_PERIOD_S, text
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()


def test_a_touch_that_never_ends_is_withdrawn_as_a_changed_sheet(tmp_path) -> None:
    """baseline_tau_s 0.1 s x sheet_change_taus 5: a blob that stays on for longer than 0.5 s
    of image time is the sheet changing (docs/classifier.md, "Changed sheet"): its END has
    confidence 0, the node logs the reason, and /diagnostics turns WARN naming it
    (``sheet_changed``) and counts it (``sheet_changes``)."""
    case = elbow(tmp_path)
    patch = load_patch(config_path(case.config))
    topics = patch_topics(patch, "/elbow_changed_test")
    grid = layer_image_grid(patch.layer(case.pressure))
    probe, pub = classifier_probe("changed_sheet_probe", topics, case.pressure)
    log = tmp_path / "classifier.log"
    params = {
        "patch_config": case.config,
        "diagnostics_period_s": 0.02,
        "baseline_tau_s": 0.1,
        "sheet_change_taus": 5.0,
    }
    node = start_node("eit_classifier", topics.namespace, params, log)
    try:
        assert probe.spin_until(lambda: pub.get_subscription_count() > 0, EVENT_S), log.read_text()
        rng = np.random.default_rng(2)
        xx, blob = fingertip_blob(grid, case.centre)

        def send(k: int, touch: bool) -> list[tuple]:
            msg = image_msg(grid, k, 10.0 * rng.standard_normal(xx.shape) + touch * blob)
            pub.publish(msg)
            return [(pub, msg)]

        contacts = probe.messages[topics.contacts]
        k = preroll(probe, send, contacts, log)
        for _ in range(30):  # 0.6 s quiet
            wait_for_contacts(probe, contacts, send(k, False))
            k += 1
        events = probe.messages[topics.touch_events]

        def withdrawn() -> bool:
            return any(m.state == TouchEvent.END for _, m in events)

        deadline = time.monotonic() + EVENT_S
        while not withdrawn() and time.monotonic() < deadline:  # the blob stays on
            seen = images(probe)
            send(k, True)
            k += 1
            probe.spin_until(lambda seen=seen: withdrawn() or images(probe) > seen, 1.0)
        assert withdrawn(), (classifier_values(probe), log.read_text())
        touch = [m for _, m in events]
        assert touch[0].state == TouchEvent.START and {m.id for m in touch} == {touch[0].id}
        end = touch[-1]
        assert end.state == TouchEvent.END and end.confidence == 0.0
        assert end.duration.sec + 1e-9 * end.duration.nanosec > 0.5

        def warned() -> bool:
            return any(
                s.level[0] == 1 and s.message.startswith("sheet changed")
                for _, m in probe.messages[DIAGNOSTICS]
                for s in m.status
                if "touch classifier" in s.name
            )

        assert probe.spin_until(warned, EVENT_S), classifier_values(probe)
        values = classifier_values(probe)
        assert values["sheet_changes"] == "1"
        assert probe.spin_until(lambda: "sheet changed" in log.read_text(), EVENT_S)
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()
