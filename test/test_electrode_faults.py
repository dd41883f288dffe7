from __future__ import annotations

import numpy as np
import pytest

from eit_skin.inverse.electrode_faults import bad_channels, excluded_channels, faulty_electrodes
from eit_skin.patch.protocol import ProtocolSpec, build_protocol

pytestmark = pytest.mark.filterwarnings("error")
PROTOCOL = build_protocol(ProtocolSpec(), 16)


def frames_with(seed: int = 0, t: int = 20):
    rng = np.random.default_rng(seed)
    ref = rng.uniform(0.5, 2.0, PROTOCOL.n_measurements) * rng.choice([-1, 1], 208)
    frames = ref * (1 + 1e-3 * rng.normal(size=(t, 208)))
    frames[:, :30] *= 1.03  # a "touch": a few per cent on some channels
    return ref, frames


def test_healthy_frames_have_no_fault():
    ref, frames = frames_with()
    assert faulty_electrodes(frames, ref, PROTOCOL).size == 0
    assert not bad_channels(frames, ref).any()


@pytest.mark.parametrize("electrode", [0, 7, 15])
def test_dead_electrode_found_alone(electrode):
    ref, frames = frames_with(electrode)
    touch = PROTOCOL.touching([electrode])
    frames[:, touch] = 1e-4 * np.random.default_rng(1).normal(size=(20, touch.sum()))
    el, mask = excluded_channels(frames, ref, PROTOCOL)
    assert el.tolist() == [electrode]
    np.testing.assert_array_equal(mask, touch)


def test_noisy_electrode_found_from_variance():
    ref, frames = frames_with(3)
    touch = PROTOCOL.touching([5])
    frames[:, touch] += 0.05 * np.random.default_rng(2).normal(size=(20, touch.sum()))
    assert faulty_electrodes(frames, ref, PROTOCOL).tolist() == [5]


def test_nan_and_saturated_channels():
    ref, frames = frames_with(4)
    frames[3, 17] = np.nan
    frames[:, 40] = 2.5
    ref2 = ref.copy()
    ref2[99] = np.inf
    bad = bad_channels(frames, ref2, saturation_v=2.5)
    assert np.flatnonzero(bad).tolist() == [17, 40, 99]
    assert faulty_electrodes(frames, ref2, PROTOCOL, saturation_v=2.5).size == 0
