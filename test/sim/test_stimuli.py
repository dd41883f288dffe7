"""Touch primitives: magnitudes, timing and shapes of the pressure and strain fields."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eit_skin.sim.stimuli import (
    RUB_TRAIL_TAU_S,
    Grab,
    Pinch,
    PostureTrack,
    Push,
    Rub,
    hertz_pressure,
    peak_hertz_pressure,
)


def _grid(half: float = 0.04, n: int = 401) -> tuple[np.ndarray, float]:
    x = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(x, x)
    return np.column_stack([xx.ravel(), yy.ravel()]), (x[1] - x[0]) ** 2


def test_hertz_pressure_integrates_to_the_force_and_peaks_at_3f_over_2_pi_a2() -> None:
    pts, cell = _grid()
    p = hertz_pressure(pts, np.array([0.005, -0.003]), 0.006, 5.0)
    assert p.sum() * cell == pytest.approx(5.0, rel=0.01)
    assert p.max() == pytest.approx(peak_hertz_pressure(0.006, 5.0), rel=0.01)
    assert peak_hertz_pressure(0.006, 5.0) == pytest.approx(3 * 5.0 / (2 * math.pi * 0.006**2))


def test_push_envelope_ramps_holds_and_releases() -> None:
    push = Push(1.0, 1.0, (0.0, 0.0), force_n=4.0, ramp_s=0.2)
    assert push.envelope(0.99) == 0.0
    assert push.envelope(1.1) == pytest.approx(0.5)
    assert push.envelope(1.5) == 1.0
    assert push.envelope(2.01) == 0.0
    pts, _ = _grid(n=81)
    assert not push.pressure(2.0, pts).any()
    assert push.force(1.5) == pytest.approx(4.0)


def test_push_strain_is_a_small_ring_zero_under_the_finger() -> None:
    push = Push(0.0, 1.0, (0.0, 0.0), force_n=5.0, radius_m=0.006)
    r = np.array([[0.0, 0.0], [1.4 * 0.006, 0.0], [0.03, 0.0]])
    e = push.strain(0.5, r)
    assert e[0] == 0.0 and e[2] == 0.0
    assert 0.005 < e[1] < 0.05  # "little lateral stretch": a few percent


def test_rub_slides_at_its_speed_and_its_trail_relaxes() -> None:
    rub = Rub(0.0, 1.5, (-0.02, 0.0), force_n=4.0, ramp_s=0.25, direction_rad=0.0, speed_mps=0.04)
    c1, c2 = rub.contacts(0.5)[0], rub.contacts(1.0)[0]
    assert c2 - c1 == pytest.approx([0.04 * 0.5, 0.0])
    assert rub.contacts(1.5)[0] == pytest.approx(rub.end_position())
    behind = rub.contacts(1.0) - np.array([[0.012, 0.0]])
    assert rub.strain(1.0, behind)[0] > 0.0
    # after lifting, the trail decays and is exactly gone after settle_s
    end = rub.end_position()[None, :] - np.array([[0.005, 0.0]])
    s_a = rub.strain(1.5 + RUB_TRAIL_TAU_S, end)[0]
    s_b = rub.strain(1.5 + 2 * RUB_TRAIL_TAU_S, end)[0]
    assert 0.0 < s_b < s_a
    assert rub.strain(1.5 + rub.settle_s + 1e-6, end)[0] == 0.0
    assert rub.active(1.5 + 0.5 * rub.settle_s) and not rub.active(1.5 + rub.settle_s + 0.01)


def test_pinch_contacts_close_and_strain_concentrates_between_them() -> None:
    pinch = Pinch(
        0.0, 2.0, (0.0, 0.0), force_n=3.0, axis_rad=0.0, start_gap_m=0.04, end_gap_m=0.015
    )
    g0 = np.diff(pinch.contacts(0.1)[:, 0])[0]
    g1 = np.diff(pinch.contacts(1.7)[:, 0])[0]
    assert g0 == pytest.approx(0.04) and g1 == pytest.approx(0.015)
    pts = np.array([[0.0, 0.0], [0.0, 0.02], [0.03, 0.0]])
    e = pinch.strain(1.7, pts)
    assert e[0] > 0.1  # strong stretch in the middle
    assert e[0] > 5 * e[1] and e[2] == 0.0
    assert pinch.strain(1.7, pts[:1])[0] > pinch.strain(0.5, pts[:1])[0]


def test_grab_presses_separate_contacts_at_once() -> None:
    grab = Grab(0.0, 1.0, (0.0, 0.0), offsets=((-0.02, 0), (0.02, 0), (0, 0.02), (0, -0.02)))
    pts, cell = _grid()
    p = grab.pressure(0.5, pts)
    assert p.sum() * cell == pytest.approx(4 * grab.force_n, rel=0.02)
    assert p[np.argmin(np.linalg.norm(pts, axis=1))] == 0.0  # separate: nothing between them
    assert grab.force(0.5) == pytest.approx(4 * grab.force_n)


def test_posture_strain_follows_the_angle_and_peaks_on_the_crease() -> None:
    posture = PostureTrack(((0.0, 0.0), (2.0, 2.5)), peak_strain=1.5, width_m=0.04)
    assert posture.angle(0.0) == 0.0 and posture.angle(2.0) == 2.5
    assert posture.angle(1.0) == pytest.approx(1.25)
    pts = np.array([[0.0, 0.0], [0.0, 0.04], [0.01, 0.0]])
    e = posture.strain(2.0, pts)
    assert e[0] == pytest.approx(1.5) and e[2] == pytest.approx(1.5)
    assert e[1] == pytest.approx(1.5 / math.e)
    assert posture.strain(1.0, pts)[0] == pytest.approx(0.75)


@pytest.mark.parametrize(
    ("factory", "message"),
    [
        (lambda: Push(0.0, 0.4, (0, 0), ramp_s=0.25), "duration"),
        (lambda: Push(0.0, 1.0, (0, 0), force_n=0.0), "force_n"),
        (lambda: Pinch(0.0, 1.0, (0, 0), start_gap_m=0.01, end_gap_m=0.02), "end_gap"),
        (lambda: PostureTrack(((1.0, 0.0), (0.5, 1.0))), "increase"),
    ],
)
def test_invalid_stimuli_are_rejected(factory, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        factory()
