"""eit_reconstruction as a real process: simulator -> driver -> reconstruction over DDS."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import EitFrame
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.reference import PostureReferences, ReferenceTracker
from eit_skin.resources import config_path
from eit_skin.ros.bringup import find_executable
from eit_skin.ros.node_runner import REJECT_LOG_PERIOD_S
from eit_skin.ros.probe import Probe, stamp_ns, start_node, stop_node
from eit_skin.ros.topics import patch_topics
from eit_skin.sim.scripts import resolve_scenario
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

RATE_HZ = 50.0


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    """Reconstruction matrices built once for the module (the nodes load them)."""
    path = tmp_path_factory.mktemp("matrix_cache")
    for name in ("arm", "elbow"):
        for layer in load_patch(config_path(name)).layers:
            LayerImager.build(layer, cache_dir=path)
    return path


def as_array(msg: Image) -> np.ndarray:
    assert msg.encoding == "32FC1" and msg.step == 4 * msg.width
    return np.frombuffer(bytes(msg.data), np.float32).reshape(msg.height, msg.width)


def wait_ready(probe: Probe, namespace: str, node, log) -> None:
    client = probe.node.create_client(Trigger, f"{namespace}/eit_reconstruction/rezero")
    ok = probe.spin_until(lambda: client.service_is_ready() or node.poll() is not None, EVENT_S)
    assert ok and node.poll() is None, log.read_text()


def _latest_status(probe: Probe, layer: str):
    """``(message, status)`` of the newest diagnostics about ``layer``; ``(None, None)``."""
    for _, msg in reversed(probe.messages["/diagnostics"]):
        for status in msg.status:
            if status.name.endswith(f"eit_reconstruction: {layer}"):
                return msg, status
    return None, None


def diagnostics_of(probe: Probe, layer: str) -> dict[str, str]:
    _, status = _latest_status(probe, layer)
    if status is None:
        return {}
    return {"message": status.message, "level": status.level[0]} | {
        kv.key: kv.value for kv in status.values
    }


def reference_taken_s(probe: Probe, layer: str) -> float:
    """When the layer's current reference was acquired (frame time, s), by its latest
    diagnostics (stamp minus ``reference_age_s``); NaN before any. Unlike the age itself,
    it does not grow while a loaded node lags behind the driver."""
    msg, status = _latest_status(probe, layer)
    if status is None:
        return float("nan")
    age = {kv.key: kv.value for kv in status.values}.get("reference_age_s", "nan")
    return stamp_ns(msg) * 1e-9 - float(age)


def wait_for_image_of(probe: Probe, namespace: str, sequence: int) -> bool:
    """Until an image of a frame numbered ``sequence`` or later arrived on the pressure layer.

    On a loaded machine the images lag the frames by seconds: the tests wait for the image
    they need, not for a fixed time after the frames.
    """

    def caught_up() -> bool:
        frames = probe.messages[f"{namespace}/pressure/frames"]
        numbered = {stamp_ns(m): m.sequence for _, m in frames}
        images = probe.messages[f"{namespace}/pressure/image"]
        return any(numbered.get(stamp_ns(m), -1) >= sequence for _, m in images)

    return probe.spin_until(caught_up, EVENT_S)


def test_push_image_peaks_where_the_finger_was(tmp_path, cache_dir) -> None:
    """A scripted push appears as a positive pressure peak at the push position.

    Tolerance 8 mm = 10 % of the arm sheet's 80 mm diameter: the seed measures a minimum
    detectable target of 8-10 % of the diameter, and the offline chain (same simulator,
    same matrices) finds this push within 3 mm, so 8 mm catches a wrong frame, flipped axes
    or a wrong measurement order while leaving room for noise.
    """
    patch = load_patch(config_path("arm"))
    # the built-in push (5 N), 1 s later: the driver streams once its writer has matched both
    # readers, but a reader can match it later and miss the first frames (a 3-copy run kept
    # 4 quiet images of ~20); the extra second of quiet leaves room for that
    push = resolve_scenario("push", patch, 0, None).truth(RATE_HZ)[0]
    script = tmp_path / "push.yaml"
    x, y = push.contacts[0]
    script.write_text(
        f"touches:\n  - touch: push\n    at: {push.t_start_s + 1.0!r}\n"
        f"    duration: {push.t_end_s - push.t_start_s!r}\n    force_n: 5.0\n"
        f"    position: [{float(x)!r}, {float(y)!r}]\n"
    )
    truth = resolve_scenario(str(script), patch).truth(RATE_HZ)[0]
    probe = Probe()
    probe.subscribe(Image, "/arm/pressure/image")
    probe.subscribe(Image, "/arm/stretch/image")
    probe.subscribe(Image, "/arm/pressure/image_color")
    probe.subscribe(EitFrame, "/arm/pressure/frames")
    probe.subscribe(DiagnosticArray, "/diagnostics", 10)
    markers_of = {name: t.marker for name, t in patch_topics(patch, "/arm").layers.items()}
    for topic in markers_of.values():
        probe.subscribe(Marker, topic, 5)
    recon_log, driver_log = tmp_path / "recon.log", tmp_path / "driver.log"
    recon = start_node(
        "eit_reconstruction",
        "/arm",
        {"patch_config": "arm", "cache_dir": str(cache_dir), "diagnostics_period_s": 0.3},
        recon_log,
    )
    driver = None
    try:
        wait_ready(probe, "/arm", recon, recon_log)
        driver = start_node(
            "eit_driver",
            "/arm",
            # start once both the reconstruction node and this probe listen
            {
                "patch_config": "arm",
                "scenario": str(script),
                "loop": False,
                "rate_hz": RATE_HZ,
                "wait_for_subscribers": 2,
            },
            driver_log,
        )
        # 1 s of quiet after the release too (the script runs 1.5 s past it): a loaded
        # reconstruction node drops the first frames it is sent while it captures its
        # reference (a 3-copy run imaged only the last 3 quiet frames before the push)
        end_frame = int((truth.t_end_s + truth.settle_s + 1.0) * RATE_HZ)
        done = probe.spin_until(
            lambda: any(m.sequence >= end_frame for _, m in probe.messages["/arm/pressure/frames"]),
            EVENT_S,
        )
        assert done, driver_log.read_text() + recon_log.read_text()
        imaged = wait_for_image_of(probe, "/arm", end_frame)
        assert imaged, recon_log.read_text()[-2000:]
        images = probe.messages["/arm/pressure/image"]
        frames = {stamp_ns(m): m.sequence for _, m in probe.messages["/arm/pressure/frames"]}
        stamps = [stamp_ns(m) for _, m in images]
        # image stamps are the frames' acquisition times (the probe may miss the first frames)
        assert len(set(stamps) & set(frames)) > 0.9 * len(stamps)
        stamps = [s for s in stamps if s in frames]
        images = [(t, m) for t, m in images if stamp_ns(m) in frames]
        assert all(m.header.frame_id == patch.frame_id for _, m in images)

        arrays = [as_array(m) for _, m in images]
        t_script = np.array([frames[s] / RATE_HZ for s in stamps])
        peaks = np.array([np.nanmax(a) for a in arrays])
        touching = (t_script > truth.t_start_s + 0.3) & (t_script < truth.t_end_s - 0.3)
        quiet = (t_script < truth.t_start_s - 0.1) | (
            t_script > truth.t_end_s + truth.settle_s + 0.2
        )
        assert touching.sum() > 10 and quiet.sum() > 5
        assert peaks[touching].min() > 5 * np.abs(peaks[quiet]).max()

        imager = LayerImager.build(patch.layer("pressure"), cache_dir=cache_dir)
        best = arrays[int(np.argmax(peaks))]
        row, col = np.unravel_index(np.nanargmax(best), best.shape)
        found = np.array([imager.grid.x[col], imager.grid.y[row]])
        assert np.linalg.norm(found - np.array(truth.contacts[0])) < 0.008
        assert np.isnan(best[~imager.grid.inside]).all()
        assert np.isfinite(best[imager.grid.inside]).all()
        # rviz marker: coloured triangles lying on the arm's cylinder, in the patch frame
        # one topic per layer, each with that layer only: stacked layers never share a display
        assert len(set(markers_of.values())) == 2
        for name, topic in markers_of.items():
            assert probe.messages[topic], topic
            assert {m.ns for _, m in probe.messages[topic]} == {name}, topic
        marker = probe.messages[markers_of["pressure"]][-1][1]
        assert marker.type == Marker.TRIANGLE_LIST and marker.header.frame_id == patch.frame_id
        xyz = np.array([(q.x, q.y, q.z) for q in marker.points])
        assert len(xyz) % 3 == 0 and len(marker.colors) == len(xyz) > 300
        cylinder = patch.placement
        radial = xyz - cylinder.origin
        radial -= np.outer(radial @ cylinder.axis, cylinder.axis)
        np.testing.assert_allclose(np.linalg.norm(radial, axis=1), cylinder.radius, rtol=1e-9)
        colour = probe.messages["/arm/pressure/image_color"][-1][1]
        assert colour.encoding == "rgb8" and colour.step == 3 * colour.width
        assert probe.messages["/arm/stretch/image"]

        # ~/rezero re-takes the reference from the next frames: no image meanwhile.
        assert probe.spin_until(lambda: reference_taken_s(probe, "pressure") > 0, EVENT_S)
        taken_before = reference_taken_s(probe, "pressure")
        client = probe.node.create_client(Trigger, "/arm/eit_reconstruction/rezero")
        asked_ns = time.time_ns()
        future = client.call_async(Trigger.Request())
        assert probe.spin_until(future.done, EVENT_S)  # safety net; it returns on the answer
        assert future.result().success
        answered_ns = time.time_ns()
        assert probe.spin_until(  # images of frames acquired 1 s after the answer
            lambda: stamp_ns(probe.messages["/arm/pressure/image"][-1][1]) > answered_ns + 10**9,
            EVENT_S,
        )
        seq = {stamp_ns(m): m.sequence for _, m in probe.messages["/arm/pressure/frames"]}
        around = sorted(seq[stamp_ns(m)] for _, m in probe.messages["/arm/pressure/image"]
                        if stamp_ns(m) > asked_ns - 3 * 10**9 and stamp_ns(m) in seq)  # fmt: skip
        # frames queued before the request are still imaged (a loaded node lags behind the
        # driver), then the capture leaves a gap of reference_frames frames
        assert max(np.diff(around)) > patch.layer("pressure").solver.reference_frames, (
            around,
            asked_ns,
            [(stamp_ns(m), m.sequence) for _, m in probe.messages["/arm/pressure/frames"][-80:]],
            recon_log.read_text()[-1500:],
        )
        assert probe.spin_until(  # the new reference's frames, however far the node lags
            lambda: reference_taken_s(probe, "pressure") > taken_before + 0.5, EVENT_S
        )
        assert diagnostics_of(probe, "pressure")["frames_rejected"] == "0"
    finally:
        if driver is not None:
            assert stop_node(driver) == 0
        assert stop_node(recon) == 0
        probe.close()


def test_mismatched_frames_are_rejected_and_node_survives_restart(tmp_path, cache_dir) -> None:
    probe = Probe()
    probe.subscribe(DiagnosticArray, "/diagnostics", 10)
    probe.subscribe(Image, "/arm/pressure/image")
    publisher = probe.node.create_publisher(EitFrame, "/arm/pressure/frames", 10)
    log = tmp_path / "recon.log"
    params = {"patch_config": "arm", "cache_dir": str(cache_dir), "diagnostics_period_s": 0.2}
    recon = start_node("eit_reconstruction", "/arm", params, log)
    try:
        wait_ready(probe, "/arm", recon, log)
        bad = EitFrame(n_electrodes=16, drive_pattern="adjacent", voltages=[0.1] * 100)
        wrong_pattern = EitFrame(n_electrodes=16, drive_pattern="opposite", voltages=[0.1] * 208)
        started = time.monotonic()
        for _ in range(5):
            publisher.publish(bad)
            publisher.publish(wrong_pattern)
            probe.spin_for(0.1)
        assert probe.spin_until(
            lambda: int(diagnostics_of(probe, "pressure").get("frames_rejected", 0)) >= 6, EVENT_S
        )
        status = diagnostics_of(probe, "pressure")
        assert status["level"] == 1 and "expects" in status["message"]
        assert recon.poll() is None
        text = log.read_text()
        assert "100 values" in text or "opposite" in text
        # every rejected frame is counted, but a bad stream logs one line per 5 s
        lines = text.count("rejected frame on layer")
        assert 1 <= lines <= 1 + (time.monotonic() - started) / REJECT_LOG_PERIOD_S, text
        # bytes that are not a whole EitFrame (the node reads the CDR itself) are counted too
        rejected = int(status["frames_rejected"])
        damaged = serialize_message(wrong_pattern)[:60]
        for _ in range(5):
            publisher.publish(damaged)
            probe.spin_for(0.1)
        assert probe.spin_until(
            lambda: (
                int(diagnostics_of(probe, "pressure")["frames_rejected"]) >= rejected + 3
                and "undecodable frame: byte" in diagnostics_of(probe, "pressure")["message"]
            ),
            EVENT_S,
        )
        assert recon.poll() is None
        assert probe.messages["/arm/pressure/image"] == []
    finally:
        assert stop_node(recon) == 0
    # A restarted node loads its matrices from the cache and works again.
    recon = start_node("eit_reconstruction", "/arm", params, log)
    try:
        wait_ready(probe, "/arm", recon, log)
        assert "from cache" in log.read_text()
        # the arm's model reads negative on every channel: a positive reference would be a
        # sign flip on all of them, an unusable reference (test_channel_noise.py)
        good = EitFrame(n_electrodes=16, drive_pattern="adjacent", voltages=[-0.01] * 208)
        for i in range(40):
            good.sequence = i
            publisher.publish(good)
            probe.spin_for(0.02)
        assert probe.spin_until(lambda: len(probe.messages["/arm/pressure/image"]) >= 5, EVENT_S)
        image = as_array(probe.messages["/arm/pressure/image"][-1][1])
        assert np.nanmax(np.abs(image)) == 0.0  # frames equal to the reference image as zero
    finally:
        assert stop_node(recon) == 0
        probe.close()


# a posture sweep, then a touch, through real nodes: ~30 s idle (121 s at load 15 on 2 cores)
@pytest.mark.timeout(120)
def test_bent_elbow_reads_no_touch_and_touch_is_still_found(tmp_path, cache_dir) -> None:
    """Posture compensation: references recorded over a joint sweep, then elbow_bend."""
    patch = load_patch(config_path("elbow"))
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        "name: sweep\nduration: 12.0\ntouches: []\nposture:\n"
        "  - {at: 0.0, angle: 0.0}\n  - {at: 1.0, angle: 0.0}\n"
        "  - {at: 11.0, angle: 2.2}\n"
    )
    out = tmp_path / "posture.npz"
    # The sweep is recorded whole however slowly a loaded machine plays it: the driver holds
    # its script until the probe and the calibration listen, and the calibration is stopped
    # (Ctrl-C keeps what it recorded) once the probe has seen the script's last frame.
    sweep_probe = Probe()
    sweep_probe.subscribe(EitFrame, "/elbow/pressure/frames")
    driver = start_node(
        "eit_driver",
        "/elbow",
        {
            "patch_config": "elbow",
            "scenario": str(sweep),
            "loop": False,
            "wait_for_subscribers": 2,
        },
        tmp_path / "sweep_driver.log",
    )
    calibration = subprocess.Popen(
        [
            str(find_executable("eit-skin")),
            "record-postures",
            "--patch",
            "elbow",
            "--joint",
            "elbow",
            "--duration",
            "600",  # safety net: stopped by SIGINT once the sweep is over
            "--bin-deg",
            "8",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        end = int(12.0 * RATE_HZ)  # the sweep's last frame
        assert sweep_probe.spin_until(
            lambda: any(
                m.sequence >= end + 5 for _, m in sweep_probe.messages["/elbow/pressure/frames"]
            ),
            300,
        ), (tmp_path / "sweep_driver.log").read_text()
        calibration.send_signal(signal.SIGINT)
        stdout, _ = calibration.communicate(timeout=EVENT_S)
    finally:
        if calibration.poll() is None:
            calibration.kill()
        assert stop_node(driver) == 0
        sweep_probe.close()
    assert calibration.returncode == 0, stdout
    assert "references at" in stdout
    table = PostureReferences.load(str(out), "pressure")
    assert table.angles_rad.max() > 2.2 - np.radians(16), stdout  # the whole sweep, 0..2.2 rad

    scenario = resolve_scenario("elbow_bend", patch, 0, None)
    push = scenario.truth(RATE_HZ)[0]
    probe = Probe()
    probe.subscribe(Image, "/elbow/pressure/image")
    probe.subscribe(EitFrame, "/elbow/pressure/frames")
    log = tmp_path / "recon.log"
    recon = start_node(
        "eit_reconstruction",
        "/elbow",
        {
            "patch_config": "elbow",
            "cache_dir": str(cache_dir),
            "joint_name": "elbow",
            "posture_references": str(out),
        },
        log,
    )
    driver = None
    try:
        wait_ready(probe, "/elbow", recon, log)
        driver = start_node(
            "eit_driver",
            "/elbow",
            {
                "patch_config": "elbow",
                "scenario": "elbow_bend",
                "loop": False,
                "wait_for_subscribers": 2,
            },
            tmp_path / "driver.log",
        )
        last = int(8.5 * RATE_HZ)
        assert probe.spin_until(
            lambda: any(m.sequence >= last for _, m in probe.messages["/elbow/pressure/frames"]),
            EVENT_S,
        ), log.read_text()
        pressed = int((push.t_end_s - 0.4) * RATE_HZ)  # the last frame the checks below use
        assert wait_for_image_of(probe, "/elbow", pressed), log.read_text()[-2000:]
    finally:
        if driver is not None:
            assert stop_node(driver) == 0
        assert stop_node(recon) == 0
        probe.close()

    seq = {stamp_ns(m): m.sequence for _, m in probe.messages["/elbow/pressure/frames"]}
    stamped = [
        (seq.get(stamp_ns(m)), m) for _, m in probe.messages["/elbow/pressure/image"]
    ]  # the probe may miss the first frames while it discovers the driver
    images = [(k / RATE_HZ, as_array(m)) for k, m in stamped if k is not None]
    bent_quiet = [a for t, a in images if 4.3 < t < push.t_start_s - 0.1]
    pressing = [a for t, a in images if push.t_start_s + 0.4 < t < push.t_end_s - 0.4]
    assert len(bent_quiet) > 20 and len(pressing) > 10
    quiet_peak = max(np.nanmax(a) for a in bent_quiet)
    press_peak = min(np.nanmax(a) for a in pressing)
    assert quiet_peak < 0.25 * press_peak, (quiet_peak, press_peak)
    imager = LayerImager.build(patch.layer("pressure"), cache_dir=cache_dir)
    best = pressing[len(pressing) // 2]
    row, col = np.unravel_index(np.nanargmax(best), best.shape)
    found = np.array([imager.grid.x[col], imager.grid.y[row]])
    assert np.linalg.norm(found - np.array(push.contacts[0])) < 0.016  # 10 % of 160 mm

    # Without posture compensation the same bent, untouched frames look like a touch.
    frames = {
        m.sequence: np.asarray(m.voltages, float)
        for _, m in probe.messages["/elbow/pressure/frames"]
    }
    tracker = ReferenceTracker(imager.n_measurements, 20, drift_time_constant_s=0.0)
    for k in sorted(frames)[:20]:
        tracker.capture(frames[k], k / RATE_HZ)
    bent = [frames[k] for k in sorted(frames) if 4.3 < k / RATE_HZ < push.t_start_s - 0.1]
    plain = imager.physical(
        imager.images(imager.relative_change(np.stack(bent), tracker.reference()))
    )
    assert np.nanmax(np.abs(plain)) > 2 * press_peak


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-v"]))
