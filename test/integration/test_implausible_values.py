"""Issue 38, point 5: every bad value caught, and said. Each small bug of the issue,
reproduced on a simulated arm pinch (frames at 50 Hz, the pinch from 1.0 to 2.6 s)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator


@pytest.fixture(scope="module")
def pinch(tmp_path_factory):
    """``(folder, frames of the healthy pinch, frames with electrode 5 dead throughout)``."""
    out = tmp_path_factory.mktemp("pinch")
    patch = load_patch(config_path("arm"))
    healthy = SkinSimulator(patch, "pinch", rate_hz=50.0, seed=1).run()
    dead = SkinSimulator(patch, "pinch", rate_hz=50.0, seed=1, faults=("dead-electrode:5",)).run()
    healthy.save(out / "ok")
    dead.save(out / "dead")
    return out


@pytest.fixture
def cache(monkeypatch, tmp_path):
    monkeypatch.setenv("EIT_SKIN_CACHE", str(tmp_path.parent / "imager-cache"))


def edited(pinch, name: str, edit) -> str:
    """The healthy pressure frames with ``edit(data dict)`` applied, saved as ``name``."""
    with np.load(pinch / "ok" / "pressure.npz") as data:
        arrays = {k: data[k] for k in data.files}
    edit(arrays)
    path = pinch / name
    np.savez(path, **arrays)
    return str(path)


def classify(path: str, capsys) -> tuple[int, list[dict], str]:
    code = main(["classify", "--patch", "arm", "--frames", path])
    out, err = capsys.readouterr()
    return code, [json.loads(line) for line in out.splitlines()], err


def touches(lines: list[dict]) -> list[dict]:
    return [line for line in lines if line.get("kind") != "fault"]


def test_one_channel_reading_1e6_volts_is_left_out_and_named(pinch, cache, capsys, tmp_path):
    """It was imaged as a 270 kPa press (the top of the arm's range) and made the pinch a grab."""

    def spike(a):
        a["frames"][70, 17] = 1e6

    path = edited(pinch, "spike.npz", spike)
    code, lines, err = classify(path, capsys)
    assert code == 0 and [t["label"] for t in touches(lines)] == ["pinch"]
    assert touches(lines)[0]["fault"] and touches(lines)[0]["channels_left_out"] == 1
    assert "left out 1 value(s)" in err and "frame 70 channel 17" in err and "1e+06 V" in err
    out = tmp_path / "images.npz"
    assert main(["reconstruct", "--patch", "arm", "--frames", path, "--out", str(out)]) == 0
    assert "frame 70 channel 17" in capsys.readouterr().err
    with np.load(out) as images:
        peaks = np.nanmax(images["physical"][68:73], axis=(1, 2))
    assert peaks.max() < 2.0 * np.median(peaks) < 20e3  # Pa: the neighbours' few kPa


def test_classify_names_the_dead_electrode_reconstruct_names(pinch, cache, capsys):
    code, lines, err = classify(str(pinch / "dead" / "pressure.npz"), capsys)
    assert code == 0
    assert lines[0] == {"kind": "fault", "t": 0.0, "faulty_electrodes": [5]}
    assert "faulty electrodes left out: [5]" in err
    (touch,) = touches(lines)
    assert touch["label"] == "pinch" and touch["fault"] and touch["faulty_electrodes"] == [5]


def test_an_electrode_dying_during_the_pinch_marks_the_touch(pinch, cache, capsys):
    """The dead channels spoil the images until the next fault check names the electrode.
    The touch is marked, and those frames (from the electrode's first one-frame jumps to its
    naming) no longer decide its label: it was labelled a grab from them."""
    with np.load(pinch / "dead" / "pressure.npz") as dead:
        dead_frames = dead["frames"]

    def dies(a):
        a["frames"][60:] = dead_frames[60:]  # at 1.2 s, inside the pinch

    code, lines, err = classify(edited(pinch, "dies.npz", dies), capsys)
    assert code == 0
    faults = [line for line in lines if line.get("kind") == "fault"]
    assert len(faults) == 1 and faults[0]["faulty_electrodes"] == [5]
    assert 1.2 <= faults[0]["t"] <= 2.3  # the first fault check after frame 60
    (touch,) = touches(lines)
    assert touch["fault"] and touch["faulty_electrodes"] == [5]
    assert touch["t_start"] <= faults[0]["t"] <= touch["t_end"]
    assert touch["label"] == "pinch"
    assert "one-frame jumps" in err and "frame 60 channel" in err


def test_a_file_shorter_than_the_calibration_is_an_error(pinch, cache, capsys):
    def cut(a):
        a["frames"], a["t"] = a["frames"][:10], a["t"][:10]

    code, lines, err = classify(edited(pinch, "short.npz", cut), capsys)
    assert code == 1 and lines == []
    assert "10 imaged frame(s) do not cover the classifier's calibration (0.5 s" in err


def test_a_reference_in_another_unit_is_refused_with_the_reason(pinch, cache, capsys):
    def millivolts(a):
        a["reference"] = a["reference"] * 1000.0

    code, lines, err = classify(edited(pinch, "mv.npz", millivolts), capsys)
    assert code == 1 and lines == [] and err.count("\n") == 1
    assert "frames are 0.001 times the reference" in err and "another unit" in err


def test_an_inf_reference_channel_is_left_out_without_a_warning(pinch, cache):
    """The drift tracker moved an Inf reference channel towards the frame: inf - inf."""
    patch = load_patch(config_path("arm"))
    imager = LayerImager.build(patch.layers[0])
    with np.load(pinch / "ok" / "pressure.npz") as data:
        reference, frames = data["reference"].copy(), data["frames"]
    reference[17] = np.inf
    processor = LayerProcessor(imager, drift_time_constant_s=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        processor.set_reference(reference, 0.0, frames[:20])
        images = [processor.step(frame, 0.02 * k) for k, frame in enumerate(frames[:40])]
    assert all(image is not None and image.channels_used == 207 for image in images)
    assert processor.drift_updates > 0 and np.isinf(processor.reference()[17])


def test_fake_device_with_a_negative_rate_is_one_line(capsys):
    assert main(["fake-device", "--rate", "-1"]) == 2  # a usage error, as argparse's
    err = capsys.readouterr().err
    assert err == "eit-skin fake-device: --rate must be > 0\n"


def test_frames_import_of_a_yaml_file_says_it_is_no_npz(tmp_path, capsys):
    path = tmp_path / "arm.yaml"
    path.write_text("name: arm\n")
    assert main(["frames", "import", str(path), str(tmp_path / "out.mcap"), "--patch", "arm"]) == 1
    err = capsys.readouterr().err
    assert "not an .npz frames file" in err and "zip archive" in err and "pickle" not in err
    assert err.count("\n") == 1 and not (tmp_path / "out.mcap").exists()


def test_full_scale_v_is_read_refused_when_bad_and_is_the_simulated_boards():
    from eit_skin.patch.loading import patch_from_dict
    from eit_skin.patch.model import PatchError
    from test.support.patch_copies import shipped_patch_data

    data = shipped_patch_data("elbow")
    base_hash = patch_from_dict(data).content_hash
    data["layers"][0]["full_scale_v"] = 0.6
    patch = patch_from_dict(data)
    assert patch.layers[0].full_scale_v == 0.6 and patch.content_hash != base_hash
    simulator = SkinSimulator(patch, "idle", rate_hz=50.0)
    assert simulator.adc(patch.layers[0].name).full_scale_v == pytest.approx(0.6)
    data["layers"][0]["full_scale_v"] = -1
    with pytest.raises(PatchError, match=r"layers\[0\]\.full_scale_v: must be > 0"):
        patch_from_dict(data)
    assert load_patch(config_path("elbow")).content_hash == base_hash  # unstated: hash as before


@pytest.mark.ros
def test_the_node_leaves_the_1e6_volt_value_out_and_counts_it(pinch, cache, tmp_path):
    """The reconstruction node over DDS: the spiked frame's image is like its neighbours',
    and the diagnostics count one jumped value (WARN)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from eit_skin_msgs.msg import EitFrame
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from eit_skin.ros.probe import Probe, frame_msg, stamp_ns, start_node, stop_node
    from test.support.patience import EVENT_S

    layer = load_patch(config_path("arm")).layers[0]
    with np.load(pinch / "ok" / "pressure.npz") as data:
        frames = data["frames"][:45].copy()
    frames[30, 17] = 1e6
    probe = Probe("spike_probe")
    probe.subscribe(DiagnosticArray, "/diagnostics", 50)
    image_sub = probe.subscribe(Image, "/spike/pressure/image")
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    publisher = probe.node.create_publisher(EitFrame, "/spike/pressure/frames", reliable)
    log = tmp_path / "recon.log"
    params = {"patch_config": "arm", "diagnostics_period_s": 0.1, "frame_timeout_s": 0.0}
    node = start_node("eit_reconstruction", "/spike", params, log)

    def jumped() -> int | None:
        """The node's count of jumped values; None before its first diagnostics (not ready)."""
        for _, msg in reversed(probe.messages["/diagnostics"]):
            for status in msg.status:
                if status.name.endswith("eit_reconstruction: pressure"):
                    return int({kv.key: kv.value for kv in status.values}["values_jumped"])
        return None

    try:
        assert probe.spin_until(  # both ways matched: the images are best effort
            lambda: (
                (
                    publisher.get_subscription_count() > 0
                    and image_sub.get_publisher_count() > 0
                    and jumped() is not None  # matrices loaded: frames are not queued behind
                )
                or node.poll() is not None
            ),
            EVENT_S,
        ), log.read_text()
        for k, frame in enumerate(frames):
            publisher.publish(frame_msg(layer, k, frame, patch="arm", frame_id="arm_skin_link"))
            probe.spin_for(0.02)  # the sensor's 50 Hz
        last = stamp_ns(frame_msg(layer, len(frames) - 1, frames[-1]))
        images = probe.messages["/spike/pressure/image"]
        assert probe.spin_until(
            lambda: images and stamp_ns(images[-1][1]) >= last and (jumped() or 0) >= 1, EVENT_S
        ), log.read_text()
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()
    assert jumped() == 1
    peaks = {stamp_ns(m): np.nanmax(np.frombuffer(bytes(m.data), np.float32)) for _, m in images}
    spiked = stamp_ns(frame_msg(layer, 30, frames[30]))
    neighbours = [peaks[stamp_ns(frame_msg(layer, k, frames[k]))] for k in (28, 29, 31, 32)]
    assert peaks[spiked] < 2.0 * max(neighbours) < 20e3  # Pa; it was 270 kPa
