"""The hydrogel patch measures what the OpenEIT board's firmware measures, in its order.

Source: OpenEIT/EIT_Firmware ``lookup.h`` ``electrode_configuration_16_opposition[192]``
(= DSHardman/HydrogelEIT ``lookup192.mat``), rows ``{A+, A-, V+, V-}`` in 32-channel
multiplexer numbers, the 16 electrodes on the even channels; the board prints one magnitude
per row (bench/studies/hydrogel_pattern_study.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol

REPO = Path(__file__).resolve().parents[2]

# the table's first and last rows as printed in lookup.h (multiplexer channels)
FIRST_ROWS = [[0, 16, 4, 2], [0, 16, 6, 4], [0, 16, 8, 6], [0, 16, 10, 8], [0, 16, 12, 10]]
DRIVE_2_ROWS = [[4, 20, 2, 0], [4, 20, 8, 6]]
LAST_ROW = [30, 14, 28, 26]


def firmware_rows() -> np.ndarray:
    """``[192, 4]`` ``(A+, A-, V+, V-)`` multiplexer channels, by the table's rule."""
    rows = []
    for d in range(16):
        s = (d + 8) % 16
        for m in range(16):
            n = (m + 1) % 16
            if not {m, n} & {d, s}:
                rows.append((2 * d, 2 * s, 2 * n, 2 * m))
    return np.array(rows)


def test_rule_reproduces_the_printed_table() -> None:
    rows = firmware_rows()
    assert rows.shape == (192, 4)
    np.testing.assert_array_equal(rows[:5], FIRST_ROWS)
    np.testing.assert_array_equal(rows[24:26], DRIVE_2_ROWS)
    np.testing.assert_array_equal(rows[-1], LAST_ROW)


def test_patch_and_data_follow_the_firmware_order() -> None:
    layer = load_patch(REPO / "data/real/hydrogel_ohmc16.yaml").layers[0]
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    electrodes = firmware_rows() // 2
    meas = protocol.measurements
    np.testing.assert_array_equal(protocol.injections[meas[:, 0]], electrodes[:, :2])
    # (V+, V-) as the board wires them, so device.negative_input_gain is its V- input's
    np.testing.assert_array_equal(meas[:, 1:], electrodes[:, 2:])
    assert protocol.magnitude
    with np.load(REPO / "data/real/hydrogel_ohmc16.npz") as d:
        stored = d["meas_mat"]
    # the stored set orients each pair so the unloaded disc reads positive: same pairs, place
    assert protocol.same_numbers(stored)
    assert not protocol.same_numbers(stored[:, [0, 2, 1]][::-1])
