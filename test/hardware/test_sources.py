"""Frame sources without ROS: which serial frames belong to a layer, and why not."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from eit_skin.hardware.sources import REJECT_REASONS, LayerFrameFactory, drive_offset
from eit_skin.hardware.wire import DeviceFrame, PatternId
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import ProtocolSpec
from eit_skin.resources import config_path

ARM = load_patch(config_path("arm"))


def frame(m: int = 208, **fields) -> DeviceFrame:
    header = {"n_electrodes": 16, "pattern_id": PatternId.ADJACENT, "current_a": 1e-3}
    return DeviceFrame(7, 0, voltages_v=np.zeros(m), **(header | fields))


@pytest.fixture(scope="module")
def pressure() -> LayerFrameFactory:
    return LayerFrameFactory(ARM, ARM.layer("pressure"), "arm_skin_link")


@pytest.mark.parametrize(
    ("bad", "reason", "words"),
    [
        (frame(m=192), "values", ["frame 7", "192 values", "expects 208"]),
        (frame(n_electrodes=12), "electrodes", ["12 electrodes", "has 16"]),
        (frame(pattern_id=PatternId.OPPOSITE), "pattern", ["opposite", "drives adjacent"]),
        (frame(pattern_id=PatternId.SKIP, pattern_param=2), "pattern", ["skip (param 2)"]),
        (frame(pattern_id=PatternId.EXPLICIT), "pattern", ["explicit"]),
        (frame(current_a=0.0), "current", ["current 0 A", "> 0"]),
        (frame(current_a=-1e-3), "current", ["current -0.001 A"]),
        (frame(m=192, n_electrodes=12, current_a=0.0), "values", ["192 values"]),  # first wins
    ],
)
def test_a_frame_that_is_not_the_layers_is_rejected_with_a_reason(pressure, bad, reason, words):
    got, text = pressure.reject(bad)
    assert got == reason and reason in REJECT_REASONS
    assert all(word in text for word in words), text
    assert "'pressure'" in text or reason == "current"


def test_the_layers_frames_and_equivalent_patterns_pass(pressure) -> None:
    assert pressure.reject(frame()) is None
    assert pressure.reject(frame(pattern_id=PatternId.SKIP, pattern_param=0)) is None
    assert pressure.reject(frame(current_a=1e-6)) is None


def test_skip_and_opposite_layers_check_k(pressure) -> None:
    layer = ARM.layer("pressure")
    skip2 = dataclasses.replace(layer, protocol=ProtocolSpec(drive="skip", drive_skip=2))
    factory = LayerFrameFactory(ARM, skip2, "f")
    m = factory.n_measurements
    assert factory.reject(frame(m, pattern_id=PatternId.SKIP, pattern_param=2)) is None
    assert factory.reject(frame(m, pattern_id=PatternId.SKIP, pattern_param=3))[0] == "pattern"
    assert factory.reject(frame(m))[0] == "pattern"
    assert drive_offset(PatternId.OPPOSITE, 0, 16) == drive_offset(PatternId.SKIP, 7, 16) == 8
    assert drive_offset(PatternId.EXPLICIT, 0, 16) is None
