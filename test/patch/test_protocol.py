import numpy as np
import pytest

from eit_skin.patch.protocol import Protocol, ProtocolSpec, build_protocol


def test_canonical_adjacent_16_gives_208_in_documented_order():
    p = build_protocol(ProtocolSpec(), 16)
    assert p.n_injections == 16 and p.n_measurements == 208
    np.testing.assert_array_equal(
        p.injections, np.column_stack([np.arange(16), (np.arange(16) + 1) % 16])
    )
    # injection 0: pairs (2,3) .. (14,15); injection 1: (3,4) .. (15,0)
    first = p.measurements[p.measurements[:, 0] == 0]
    np.testing.assert_array_equal(first[:, 1], np.arange(2, 15))
    np.testing.assert_array_equal(first[:, 2], np.arange(3, 16))
    second = p.measurements[p.measurements[:, 0] == 1]
    np.testing.assert_array_equal(second[:, 1], np.arange(3, 16))
    np.testing.assert_array_equal(second[:, 2], (np.arange(3, 16) + 1) % 16)
    # injection 15 (15 -> 0): m = 1..13 in increasing order
    last = p.measurements[p.measurements[:, 0] == 15]
    np.testing.assert_array_equal(last[:, 1], np.arange(1, 14))
    # measurements never touch a drive electrode and come in injection order
    assert not np.any(p.touching([]))
    assert np.all(np.diff(p.measurements[:, 0]) >= 0)
    for k, a, b in p.measurements:
        assert {a, b}.isdisjoint(p.injections[k])


@pytest.mark.parametrize("n", [4, 8, 16, 32])
def test_adjacent_count_is_n_times_n_minus_3(n):
    assert build_protocol(ProtocolSpec(), n).n_measurements == n * (n - 3)


def test_opposite_drive_counts():
    p = build_protocol(ProtocolSpec(drive="opposite"), 16)
    np.testing.assert_array_equal(p.injections[:, 1], (np.arange(16) + 8) % 16)
    # adjacent measuring pairs touching k or k+8: (k-1,k),(k,k+1),(k+7,k+8),(k+8,k+9) -> 12 left
    assert p.n_measurements == 16 * 12
    q = build_protocol(ProtocolSpec(drive="opposite", measure="opposite"), 16)
    # opposite pairs (m, m+8) touching k or k+8: only m = k and m = k+8 -> 14 per injection
    assert q.n_measurements == 16 * 14


def test_skip_k_pairs():
    p = build_protocol(ProtocolSpec(drive="skip", drive_skip=2, measure="skip", measure_skip=2), 16)
    np.testing.assert_array_equal(p.injections[3], [3, 6])
    assert np.all((p.measurements[:, 2] - p.measurements[:, 1]) % 16 == 3)
    # pairs (m, m+3) touching k or k+3: m in {k-3, k, k+3} -> 13 remain
    assert p.n_measurements == 16 * 13
    assert build_protocol(ProtocolSpec(drive="skip", drive_skip=0), 16).n_measurements == 208


def test_explicit_lists_keep_their_order():
    spec = ProtocolSpec(
        drive="explicit",
        injections=((0, 2), (5, 1)),
        measure="explicit",
        measurements=((1, 7, 3), (0, 4, 5), (0, 6, 7)),
    )
    p = build_protocol(spec, 8)
    np.testing.assert_array_equal(p.injections, [[0, 2], [5, 1]])
    np.testing.assert_array_equal(p.measurements, [[1, 7, 3], [0, 4, 5], [0, 6, 7]])
    # explicit drive with pattern measurements
    q = build_protocol(ProtocolSpec(drive="explicit", injections=((0, 4),)), 8)
    assert q.n_measurements == 8 - 4


def test_first_electrode_rotates_to_config_numbering():
    base = build_protocol(ProtocolSpec(), 16)
    rot = build_protocol(ProtocolSpec(first_electrode=5), 16)
    np.testing.assert_array_equal(rot.injections, (base.injections + 5) % 16)
    np.testing.assert_array_equal(rot.measurements[:, 0], base.measurements[:, 0])
    np.testing.assert_array_equal(rot.measurements[:, 1:], (base.measurements[:, 1:] + 5) % 16)


def test_sign_flips_every_value():
    u = np.random.default_rng(0).normal(size=(16, 16))
    plus = build_protocol(ProtocolSpec(), 16)
    minus = build_protocol(ProtocolSpec(sign=-1), 16)
    np.testing.assert_allclose(minus.measure(u), -plus.measure(u))


def test_rotated_order_starts_after_the_sink():
    p = build_protocol(ProtocolSpec(order="rotated"), 16)
    for k in (0, 7, 14, 15):
        rows = p.measurements[p.measurements[:, 0] == k]
        assert rows[0, 1] == (k + 2) % 16
        np.testing.assert_array_equal(rows[:, 1], (k + 2 + np.arange(13)) % 16)
    inc = build_protocol(ProtocolSpec(), 16)
    assert {tuple(r) for r in p.measurements} == {tuple(r) for r in inc.measurements}


def test_measure_and_selection_matrix_agree():
    p = build_protocol(ProtocolSpec(), 8)
    u = np.random.default_rng(1).normal(size=(8, 8))
    v = p.measure(u)
    np.testing.assert_allclose(p.selection_matrix @ u.ravel(), v)
    k, a, b = p.measurements[3]
    assert v[3] == u[k, a] - u[k, b]
    np.testing.assert_allclose(p.measure(np.stack([u, 2 * u])), [v, 2 * v])
    with pytest.raises(ValueError, match="electrode_potentials"):
        p.measure(np.zeros((8, 7)))


def test_touching_marks_drive_and_measure_electrodes():
    p = build_protocol(ProtocolSpec(), 16)
    mask = p.touching([4])
    k = p.measurements[:, 0]
    expect = np.isin(p.injections[k], 4).any(axis=1) | np.isin(p.measurements[:, 1:], 4).any(axis=1)
    np.testing.assert_array_equal(mask, expect)
    # injections 3 (3->4) and 4 (4->5) are lost entirely; others lose pairs (3,4), (4,5)
    assert mask.sum() == 2 * 13 + 14 * 2 - 2  # injections 2 and 5 have only one of them
    assert not p.touching([]).any()
    with pytest.raises(ValueError, match="electrodes"):
        p.touching([16])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"drive": "neighbour"}, "drive"),
        ({"measure": "x"}, "measure"),
        ({"sign": 0}, "sign"),
        ({"order": "backwards"}, "order"),
        ({"drive_skip": -1}, "drive_skip"),
        ({"drive": "explicit"}, "injections"),
        ({"injections": ((0, 1),)}, "injections"),
        ({"measure": "explicit", "measurements": ((0, 1),)}, "measurements"),
    ],
)
def test_spec_rejects_bad_fields(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ProtocolSpec(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "n", "match"),
    [
        ({}, 2, "n_electrodes"),
        ({"first_electrode": 16}, 16, "first_electrode"),
        ({"drive": "skip", "drive_skip": 15}, 16, "drive_skip"),
        ({"drive": "explicit", "injections": ((0, 16),)}, 16, "injections"),
        ({"drive": "explicit", "injections": ((3, 3),)}, 16, "injections"),
        ({"measure": "explicit", "measurements": ((16, 0, 1),)}, 16, "measurements"),
        ({"measure": "explicit", "measurements": ((0, 2, 2),)}, 16, "measurements"),
    ],
)
def test_validate_rejects_index_errors(kwargs, n, match):
    spec = ProtocolSpec(**kwargs)
    with pytest.raises(ValueError, match=match):
        spec.validate(n)
    with pytest.raises(ValueError):
        build_protocol(spec, n)


def test_protocol_rejects_bad_arrays():
    with pytest.raises(ValueError):
        Protocol("x", 4, np.array([[0, 0]]), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError):
        Protocol("x", 4, np.array([[0, 1]]), np.array([[1, 2, 3]]))


def test_clockwise_electrode_order_maps_board_to_config_numbering():
    n = 16
    clockwise = [0, *range(n - 1, 0, -1)]  # board b sits at config electrode -b mod n
    p = build_protocol(ProtocolSpec(electrode_order=tuple(clockwise)), n)
    canon = build_protocol(ProtocolSpec(), n)
    # board injection k drives board k -> k+1, i.e. config -k -> -k-1
    np.testing.assert_array_equal(p.injections[:, 0], (-np.arange(n)) % n)
    np.testing.assert_array_equal(p.injections[:, 1], (-np.arange(n) - 1) % n)
    np.testing.assert_array_equal(p.measurements[:, 1:], (-canon.measurements[:, 1:]) % n)
    shuffled = tuple(np.random.default_rng(0).permutation(n).tolist())
    q = build_protocol(ProtocolSpec(electrode_order=shuffled), n)
    np.testing.assert_array_equal(q.injections, np.array(shuffled)[canon.injections])
    with pytest.raises(ValueError, match="electrode_order: must list every electrode"):
        build_protocol(ProtocolSpec(electrode_order=(0, 1, 2, 2)), 4)
    with pytest.raises(ValueError, match="electrode_order: give electrode_order or first"):
        ProtocolSpec(electrode_order=(0, 1, 2, 3), first_electrode=1)


def test_full_layout_selects_the_pairs_off_the_driven_electrodes():
    n = 16
    p = build_protocol(ProtocolSpec(layout="full"), n)
    canon = build_protocol(ProtocolSpec(), n)
    np.testing.assert_array_equal(p.measurements, canon.measurements)
    assert p.frame_size == 256 and p.frame_index.shape == (208,)
    # device entry i * n + m is pair (m, m+1) of injection i
    i, m = np.divmod(p.frame_index, n)
    np.testing.assert_array_equal(i, canon.measurements[:, 0])
    np.testing.assert_array_equal(m, canon.measurements[:, 1])
    full = np.arange(256.0)
    np.testing.assert_array_equal(p.select(full), p.frame_index)
    np.testing.assert_array_equal(p.select(np.tile(full, (3, 1)))[2], p.frame_index)
    with pytest.raises(ValueError, match="expects 256 numbers per frame \\(full layout"):
        p.select(np.zeros(200))
    np.testing.assert_array_equal(p.select(np.arange(208.0)), np.arange(208.0))  # already M
    # rotated full frames: each injection's n numbers start after the sink
    r = build_protocol(ProtocolSpec(layout="full", order="rotated"), n)
    i, j = np.divmod(r.frame_index, n)
    np.testing.assert_array_equal((i + 2 + j) % n, r.measurements[:, 1])
    # measuring on the driven electrodes too: all 256 used
    a = build_protocol(ProtocolSpec(layout="full", measure_driven=True), n)
    np.testing.assert_array_equal(a.frame_index, np.arange(256))
    with pytest.raises(ValueError, match="layout: 'full' needs a measure pattern"):
        ProtocolSpec(layout="full", measure="explicit", measurements=((0, 2, 3),))


def test_current_vectors_are_validated_and_trigonometric_patterns_are_orthogonal():
    t = build_protocol(ProtocolSpec(drive="trigonometric"), 16)
    c = t.current_patterns
    assert c.shape == (15, 16) and np.abs(c).max() == pytest.approx(1.0)
    gram = c @ c.T
    np.testing.assert_allclose(gram - np.diag(np.diag(gram)), 0, atol=1e-12)
    assert t.n_measurements == 15 * 16  # every pair, driven ones included
    # electrode 0 (theta 0) carries current in the 8 cos rows, none in the 7 sin rows, where
    # only its 2 pairs touch it
    assert t.touching([0]).sum() == 8 * 16 + 7 * 2
    with pytest.raises(ValueError, match=r"currents\[1\]: currents must sum to zero"):
        ProtocolSpec(drive="currents", currents=((1, -1, 0, 0), (1, 1, 0, 0)))
    with pytest.raises(ValueError, match=r"currents\[0\]: expected 4 values"):
        build_protocol(ProtocolSpec(drive="currents", currents=((1, -1, 0),)), 4)
    with pytest.raises(ValueError, match="currents: only allowed with drive='currents'"):
        ProtocolSpec(currents=((1, -1),))
    with pytest.raises(ValueError, match=r"currents\[0\]: all zero"):
        ProtocolSpec(drive="currents", currents=((0, 0, 0, 0),))
