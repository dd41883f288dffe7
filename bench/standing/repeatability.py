"""Repeatability floor of the press localiser on each real hydrogel skin (issue 37, item 4).

Shared by ``bench_press_calibration`` (error / floor per skin) and ``bench_multitouch`` (the
floor section). Definition, the same on both skins: the **floor** is the median error an
unbiased localiser would have given the scatter of its own estimate over repeats of one press:

* ``hydrogel_rect_repeats`` (130 x 60 mm skin): 50 points pressed 5 times each. Folds by point
  (a point is never in its own training set: 200 training presses, 40 points); each repeat's
  distance from the mean of its point's 5 estimates, times ``sqrt(5 / 4)`` (a deviation from
  the mean of n spreads ``sqrt(1 - 1 / n)`` times one from the true mean);
* ``hydrogel_ohmc16`` (170 mm disc): no repeats were recorded; pairs of presses within
  ``NEAR_M`` of each other at the same depth stand in for them, located at N = 400 (5-fold):
  the distance between their error vectors over ``sqrt(2)`` (the truth subtracted, so the
  pair's own offset drops out).

For a Gaussian scatter both give its Rayleigh median, the median error of an unbiased
localiser with that scatter; the localiser's **error** is measured on the same skin, the same
folds. The floor is the localiser's own scatter: a localiser that shrinks everything to the
centre would have a low one, so it is reported beside the error, never alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.standing.real_sessions import REAL, hydrogel_ohmc16_session, load_real
from eit_skin.calibration.localiser import PressLocaliser, cross_validate
from eit_skin.calibration.session import PressSession
from eit_skin.patch.loading import load_patch

NEAR_M = 0.002
"""Presses of hydrogel_ohmc16 this close (at the same depth) count as repeats of each other."""


@dataclass(frozen=True)
class Floor:
    """A skin's repeatability floor beside its localiser's error (m; median / p90).

    Attributes:
        skin: which recording.
        repeats: how the repeats were found, for the report.
        n_train: training presses per fold.
        floor: ``[2]`` median, p90 of the scaled scatter, m.
        error: ``[2]`` median, p90 of the localiser's out-of-fold error, m.
        centre: ``[2]`` median, p90 of "always the centre of the presses", m.
    """

    skin: str
    repeats: str
    n_train: int
    floor: np.ndarray
    error: np.ndarray
    centre: np.ndarray

    @property
    def ratio(self) -> float:
        """Median error over median floor."""
        return float(self.error[0] / self.floor[0])


def _stats(x: np.ndarray) -> np.ndarray:
    return np.array([np.median(x), np.percentile(x, 90)])


def rect_repeats_session() -> tuple[PressSession, np.ndarray]:
    """(session, ``[250]`` point index) of ``hydrogel_rect_repeats``.

    No unloaded frame was recorded: each round of 50 presses is compared with its own median
    frame (slow drift between rounds cancels).
    """
    d = load_real("hydrogel_rect_repeats")
    frames = d["frames"].astype(float)
    rounds = np.array([np.median(frames[d["repeat"] == r], axis=0) for r in range(5)])
    session = PressSession(
        d["reference"], frames, d["truth_xy"][:, 0], d["depth"], rounds[d["repeat"]]
    )
    return session, d["point"]


def rectangle_floor() -> Floor:
    """The rectangle's floor and its localiser's error (folds by point)."""
    session, point = rect_repeats_session()
    layer = load_patch(REAL / "hydrogel_rect16.yaml").layers[0]
    n_points = int(point.max()) + 1
    folds = np.array_split(np.random.default_rng(0).permutation(n_points), 5)
    xy = np.zeros((session.n_presses, 2))
    for fold in folds:
        test = np.isin(point, fold)
        model = PressLocaliser.fit(session.subset(np.flatnonzero(~test)), layer)
        xy[test] = model.locate(
            session.frames[test], session.reference, session.baselines()[test]
        ).xy
    n = np.bincount(point)[point]
    mean = np.array([xy[point == p].mean(axis=0) for p in range(n_points)])[point]
    scatter = np.linalg.norm(xy - mean, axis=1) * np.sqrt(n / (n - 1.0))
    error = np.linalg.norm(xy - session.press_xy, axis=1)
    centre = np.linalg.norm(session.press_xy - session.press_xy.mean(axis=0), axis=1)
    return Floor(
        "hydrogel_rect_repeats (130 x 60 mm)",
        f"{n_points} points x 5 repeats",
        session.n_presses - session.n_presses // 5,
        _stats(scatter),
        _stats(error),
        _stats(centre),
    )


def disc_floor(n_train: int = 400, near_m: float = NEAR_M) -> Floor:
    """hydrogel_ohmc16's floor (presses within ``near_m`` as repeats) and error (5-fold)."""
    session = hydrogel_ohmc16_session()
    layer = load_patch(REAL / "hydrogel_ohmc16.yaml").layers[0]
    cv = cross_validate(session, layer, n_train=n_train)
    gap = np.linalg.norm(session.press_xy[:, None] - session.press_xy[None], axis=2)
    same_depth = np.isclose(session.depth[:, None], session.depth[None])
    i, j = np.nonzero(np.triu((gap < near_m) & same_depth, 1))
    residual = cv.xy - session.press_xy
    scatter = np.linalg.norm(residual[i] - residual[j], axis=1) / np.sqrt(2.0)
    centre = np.linalg.norm(session.press_xy - session.press_xy.mean(axis=0), axis=1)
    return Floor(
        "hydrogel_ohmc16 (170 mm disc)",
        f"{len(i)} pairs within {near_m * 1e3:g} mm at the same depth",
        n_train,
        _stats(scatter),
        _stats(cv.xy_error),
        _stats(centre),
    )


def floor_table(floors: list[Floor]) -> list[str]:
    """Markdown rows: skin, repeats, training presses, floor, error, centre, error / floor."""

    def mm(x: np.ndarray) -> str:
        return f"{x[0] * 1e3:.1f} / {x[1] * 1e3:.1f}"

    lines = [
        "| skin | repeats | training presses | floor (mm) | localiser error (mm) |"
        " always the centre (mm) | error / floor (median) |",
        "|---|---|---|---|---|---|---|",
    ]
    for f in floors:
        lines.append(
            f"| {f.skin} | {f.repeats} | {f.n_train} | {mm(f.floor)} | {mm(f.error)} |"
            f" {mm(f.centre)} | {f.ratio:.2f}x |"
        )
    return lines
