"""The CN0565 profile (pyadi-iio, optional): a clear refusal without the package, and the
board's measurement sequence mapped onto the layer's protocol.

The stand-in ``adi`` module below does what pyadi-iio's ``adi/cn0565.py`` documents: its
``all_voltages`` walks f+ = i, f- = i + force_distance, s+ = j, s- = j + sense_distance,
skipping pairs on a drive electrode, and reads V(s+) - V(s-) of electrode potentials given by
our forward model. It is written from that description, not from our protocol code.
"""

from __future__ import annotations

import sys
import threading
import types

import numpy as np
import pytest

from eit_skin.hardware.cn0565 import Cn0565Source
from eit_skin.hardware.sources import LayerFrameFactory, board_source
from eit_skin.patch.loading import patch_from_dict
from eit_skin.patch.model import PatchError
from eit_skin.patch.yaml_reader import read_yaml


def cn0565_patch(repo, protocol):
    data = read_yaml(repo / "data/real/sciospec_adjacent.yaml", PatchError)
    data["layers"][0]["device"] = {"profile": "cn0565", "excitation_hz": 5000.0}
    data["layers"][0]["protocol"] = protocol
    return patch_from_dict(data)


def stand_in_adi(potentials):
    """An ``adi`` module whose cn0565 reads the [n_el, n_el] potentials (row: drive i)."""

    class Board:
        def __init__(self, uri=""):
            self.uri = uri
            self.electrode_count, self.force_distance, self.sense_distance = 8, 1, 1
            self.excitation_frequency = 10000

        @property
        def all_voltages(self):
            n, out = self.electrode_count, []
            for i in range(n):
                f_minus = (i + self.force_distance) % n
                for j in range(n):
                    if j in (i, f_minus):
                        continue
                    s_minus = (j + self.sense_distance) % n
                    if s_minus in (i, f_minus):
                        continue
                    v = potentials[i, j] - potentials[i, s_minus]
                    out.append([v.real, v.imag])
            return np.array(out)

    module = types.ModuleType("adi")
    module.cn0565 = Board
    return module


def test_without_pyadi_iio_the_source_refuses_naming_the_package(repo, monkeypatch):
    monkeypatch.setitem(sys.modules, "adi", None)  # import adi -> ImportError
    patch = cn0565_patch(repo, {"drive": "adjacent", "measure": "adjacent"})
    factory = LayerFrameFactory(patch, patch.layers[0], "tank_link")
    with pytest.raises(RuntimeError, match=r"cn0565 needs the Python package 'pyadi-iio'"):
        board_source(factory, "/dev/ttyACM0", 0, lambda record: None)


@pytest.mark.parametrize(
    "protocol",
    [
        {"drive": "adjacent", "measure": "adjacent"},
        {"drive": "skip", "drive_skip": 2, "measure": "adjacent"},
        {"drive": "opposite", "measure": "skip", "measure_skip": 1},
    ],
)
def test_the_boards_sequence_is_the_layers_protocol(repo, monkeypatch, protocol):
    from eit_skin.patch.protocol import build_protocol

    patch = cn0565_patch(repo, protocol)
    layer = patch.layers[0]
    rng = np.random.default_rng(5)
    n = layer.n_electrodes
    potentials = rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))
    monkeypatch.setitem(sys.modules, "adi", stand_in_adi(potentials))
    got, arrived = [], threading.Event()

    def sink(record):
        got.append(record)
        arrived.set()

    source = board_source(LayerFrameFactory(patch, layer, "tank_link"), "/dev/x", 0, sink)
    assert isinstance(source, Cn0565Source)
    assert source.board.uri == "serial:/dev/x,230400,8n1"
    assert source.board.excitation_frequency == 5000.0
    source.start()
    assert arrived.wait(30)
    source.stop()
    p = build_protocol(layer.protocol, n)
    drive = p.injections[p.measurements[:, 0], 0]  # row i of the stand-in: drive from i
    want = potentials[drive, p.measurements[:, 1]] - potentials[drive, p.measurements[:, 2]]
    np.testing.assert_allclose(got[0].voltages, want.real.astype(np.float32), rtol=1e-6)
    assert source.status().level == 0


def test_a_protocol_the_board_cannot_measure_is_refused(repo):
    with pytest.raises(PatchError, match=r"layers\[0\]\.protocol: CN0565"):
        cn0565_patch(repo, {"drive": "adjacent", "measure": "adjacent", "order": "rotated"})
