"""Press sessions: frames of known presses, the training data of a press localiser.

A press session file is an npz (no pickles):

=============== ======= ==========================================================
key             shape   meaning
=============== ======= ==========================================================
``reference``   [M]     unloaded frame, any unit (volts or device counts)
``frames``      [T, M]  frame at full press, same unit and protocol order
``press_xy``    [T, 2]  press centre in the patch (sheet) frame, m
``depth``       [T]     optional: press depth, m
``references``  [T, M]  optional: each press's own unloaded frame just before it
=============== ======= ==========================================================

:func:`pair_probe_csv` builds one from a frame recording and a probe log (a robot's CSV of
``time, x, y[, depth]``); ``eit_skin.sim.press_session`` simulates one for any patch.
"""

from __future__ import annotations

import csv
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eit_skin.io.npz import write_npz_atomic
from eit_skin.patch.geometry import points_in_polygon
from eit_skin.patch.model import Layer
from eit_skin.patch.protocol import build_protocol

MIN_PRESSES = 10
"""Fewest presses a session may hold: two per fold of a 5-fold cross-validation."""

REQUIRED_KEYS = ("reference", "frames", "press_xy")
OPTIONAL_KEYS = ("depth", "references")


class PressSessionError(ValueError):
    """A press session is invalid: ``"<file>: key '<key>' [row <r>]: <reason>"``."""


@dataclass(frozen=True, eq=False)
class PressSession:
    """Frames of labelled presses on one layer.

    Attributes:
        reference: ``[M]`` unloaded frame.
        frames: ``[T, M]`` frames at full press.
        press_xy: ``[T, 2]`` press centres in the sheet frame, m.
        depth: ``[T]`` press depths, m, or ``None``.
        references: ``[T, M]`` per-press unloaded frames, or ``None`` (then ``reference``).
        source: where the session came from (file name), used in error messages.
    """

    reference: np.ndarray
    frames: np.ndarray
    press_xy: np.ndarray
    depth: np.ndarray | None = None
    references: np.ndarray | None = None
    source: str = "<memory>"

    def __post_init__(self) -> None:
        check_session_arrays(
            self.source,
            {
                "reference": self.reference,
                "frames": self.frames,
                "press_xy": self.press_xy,
                "depth": self.depth,
                "references": self.references,
            },
        )

    @property
    def n_presses(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_measurements(self) -> int:
        return int(self.frames.shape[1])

    def baselines(self) -> np.ndarray:
        """``[T, M]`` the unloaded frame each press is compared with."""
        if self.references is not None:
            return self.references
        return np.broadcast_to(self.reference, self.frames.shape)

    def subset(self, rows: np.ndarray) -> PressSession:
        """The presses ``rows`` (indices or mask) as a new session."""
        return PressSession(
            self.reference,
            self.frames[rows],
            self.press_xy[rows],
            None if self.depth is None else self.depth[rows],
            None if self.references is None else self.references[rows],
            self.source,
        )

    def check_layer(self, layer: Layer) -> None:
        """Raise :class:`PressSessionError` unless M and every press position fit ``layer``."""
        check_measurement_count(self.source, "frames", self.n_measurements, layer)
        inside = points_in_polygon(self.press_xy, layer.outline)
        for hole in layer.holes:
            inside &= ~points_in_polygon(self.press_xy, hole)
        if not inside.all():
            row = int(np.flatnonzero(~inside)[0])
            x, y = self.press_xy[row]
            raise PressSessionError(
                f"{self.source}: key 'press_xy' row {row}: ({x:.4g}, {y:.4g}) m is outside the "
                f"sheet of layer {layer.name!r} ({int((~inside).sum())} of {self.n_presses} "
                "presses outside; positions must be in the patch frame, metres)"
            )

    def save(self, path: str | Path) -> None:
        """Write the session file atomically (optional keys only when present)."""
        arrays = {"reference": self.reference, "frames": self.frames, "press_xy": self.press_xy}
        if self.depth is not None:
            arrays["depth"] = self.depth
        if self.references is not None:
            arrays["references"] = self.references
        write_npz_atomic(path, **arrays)


def check_measurement_count(source: str, key: str, m: int, layer: Layer) -> None:
    """Raise :class:`PressSessionError` if ``m`` differs from the layer's protocol length."""
    expected = build_protocol(layer.protocol, layer.n_electrodes).n_measurements
    if m != expected:
        raise PressSessionError(
            f"{source}: key '{key}': {m} measurements per frame, but layer {layer.name!r} "
            f"measures {expected} (wrong patch or layer?)"
        )


def check_session_arrays(source: str, arrays: dict[str, np.ndarray | None]) -> None:
    """Validate shapes, dtypes and finiteness; errors name the file, key and first bad row."""
    for key in REQUIRED_KEYS:
        if arrays.get(key) is None:
            raise PressSessionError(f"{source}: missing key '{key}'")
    for key, value in arrays.items():
        if value is not None and not (
            isinstance(value, np.ndarray) and np.issubdtype(value.dtype, np.number)
        ):
            raise PressSessionError(f"{source}: key '{key}': must be a numeric array")
    reference, frames = arrays["reference"], arrays["frames"]
    if reference.ndim != 1 or reference.size == 0:
        raise PressSessionError(f"{source}: key 'reference': shape {reference.shape}, want [M]")
    m = reference.size
    expected = {"frames": (None, m), "press_xy": (None, 2), "depth": (None,)}
    expected["references"] = (None, m)
    if frames.ndim != 2:
        raise PressSessionError(f"{source}: key 'frames': shape {frames.shape}, want [T, {m}]")
    t = frames.shape[0]
    for key, shape in expected.items():
        value = arrays.get(key)
        if value is None:
            continue
        want = (t, *shape[1:])
        if value.shape != want:
            raise PressSessionError(
                f"{source}: key '{key}': shape {value.shape}, want {list(want)} "
                f"(T = {t} presses from 'frames', M = {m} from 'reference')"
            )
    if t < MIN_PRESSES:
        raise PressSessionError(
            f"{source}: key 'frames': {t} presses, need at least {MIN_PRESSES} to calibrate"
        )
    for key, value in arrays.items():
        if value is None:
            continue
        bad = ~np.isfinite(value.reshape(value.shape[0], -1) if value.ndim > 1 else value)
        bad = bad.any(axis=1) if bad.ndim > 1 else bad
        if key == "reference" and bad.any():
            raise PressSessionError(
                f"{source}: key 'reference' channel {int(np.flatnonzero(bad)[0])}: not finite"
            )
        if bad.any():
            raise PressSessionError(
                f"{source}: key '{key}' row {int(np.flatnonzero(bad)[0])}: not finite "
                f"({int(bad.sum())} rows; drop them before calibrating)"
            )
    if np.any(reference == 0):
        raise PressSessionError(
            f"{source}: key 'reference' channel {int(np.flatnonzero(reference == 0)[0])}: zero "
            "(relative changes need a non-zero unloaded value)"
        )
    if arrays.get("references") is not None and np.any(arrays["references"] == 0):
        row = int(np.flatnonzero((arrays["references"] == 0).any(axis=1))[0])
        raise PressSessionError(f"{source}: key 'references' row {row}: a zero channel")
    depth = arrays.get("depth")
    if depth is not None and np.any(depth < 0):
        raise PressSessionError(
            f"{source}: key 'depth' row {int(np.flatnonzero(depth < 0)[0])}: negative depth"
        )


def load_press_session(path: str | Path) -> PressSession:
    """Read and validate a press session file (see the module docstring for its keys)."""
    source = str(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                raise PressSessionError(f"{source}: a single .npy array, not an .npz archive")
            arrays = {
                k: np.asarray(data[k]) for k in data.files if k in REQUIRED_KEYS + OPTIONAL_KEYS
            }
    except FileNotFoundError as error:
        raise PressSessionError(f"{source}: no such file") from error
    except (zipfile.BadZipFile, OSError, EOFError) as error:
        raise PressSessionError(f"{source}: not a readable .npz file ({error})") from error
    except ValueError as error:
        if isinstance(error, PressSessionError):
            raise
        raise PressSessionError(f"{source}: not a readable .npz file ({error})") from error
    floats = {k: (v.astype(np.float64) if v.dtype.kind in "iuf" else v) for k, v in arrays.items()}
    return PressSession(
        floats.get("reference"),
        floats.get("frames"),
        floats.get("press_xy"),
        floats.get("depth"),
        floats.get("references"),
        source,
    )


def read_probe_csv(path: str | Path) -> np.ndarray:
    """``[P, 3 or 4]`` rows ``time_s, x_m, y_m[, depth_m]`` of a probe log (header optional).

    A gap (an empty cell before the row's last value), a row of another width than the rows
    above, or a time not after the row above is refused naming the row (and column).
    """
    rows: list[list[float]] = []
    width = None
    with open(path, newline="") as stream:
        for line_no, row in enumerate(csv.reader(stream), start=1):
            cells = [c.strip() for c in row]
            while cells and not cells[-1]:
                cells.pop()  # trailing separators
            if not cells or cells[0].startswith("#"):
                continue
            if "" in cells:
                raise PressSessionError(
                    f"{path}: row {line_no} column {cells.index('') + 1}: empty (a gap in the "
                    "probe log: every row needs time, x, y[, depth])"
                )
            try:
                values = [float(c) for c in cells]
            except ValueError:
                if not rows and line_no == 1:
                    continue  # header line
                raise PressSessionError(
                    f"{path}: row {line_no}: {row!r} is not numbers (time, x, y[, depth])"
                ) from None
            if len(values) not in (3, 4) or (width is not None and len(values) != width):
                above = "" if width is None else f", like the rows above ({width})"
                raise PressSessionError(
                    f"{path}: row {line_no}: {len(values)} columns, want 3 (time, x, y) or 4 "
                    f"(time, x, y, depth){above}"
                )
            if not np.all(np.isfinite(values)):
                raise PressSessionError(f"{path}: row {line_no}: not finite")
            if rows and values[0] <= rows[-1][0]:
                raise PressSessionError(
                    f"{path}: row {line_no}: time {values[0]:.6g} s is not after the row above "
                    f"({rows[-1][0]:.6g} s)"
                )
            width = len(values)
            rows.append(values)
    if not rows:
        raise PressSessionError(f"{path}: no probe rows (time, x, y[, depth])")
    return np.array(rows)


def pair_probe_csv(
    reference: np.ndarray,
    frames: np.ndarray,
    t: np.ndarray,
    probe_csv: str | Path,
    baseline_offset_s: float | None = None,
    source: str = "<frames>",
) -> PressSession:
    """Pair every probe row (time at full press, x, y[, depth]) with the nearest frame in time.

    Args:
        reference: ``[M]`` unloaded frame.
        frames: ``[F, M]`` recorded frames.
        t: ``[F]`` frame times, s, on the probe log's clock.
        probe_csv: the robot's log: one row per press at full depth, ``time_s, x_m, y_m`` and
            optionally ``depth_m``; an optional header line.
        baseline_offset_s: if given, each press's own baseline is the frame nearest to
            ``time - baseline_offset_s`` (the probe lifted before the press).
        source: the frames file, for messages.

    A probe row farther than one median frame interval from every frame is an error naming
    its row (the clocks or the files do not match).
    """
    probe = read_probe_csv(probe_csv)
    t = np.asarray(t, float)
    order = np.argsort(t)
    t_sorted = t[order]
    period = float(np.median(np.diff(t_sorted))) if t.size > 1 else np.inf

    def nearest(times: np.ndarray, what: str) -> np.ndarray:
        j = np.clip(np.searchsorted(t_sorted, times), 1, t_sorted.size - 1)
        left = np.abs(times - t_sorted[j - 1]) <= np.abs(t_sorted[j] - times)
        j = np.where(left, j - 1, j)
        gap = np.abs(t_sorted[j] - times)
        if np.any(gap > period):
            row = int(np.flatnonzero(gap > period)[0])
            raise PressSessionError(
                f"{probe_csv}: row {row + 1} (data row): no frame of {source} within one frame "
                f"interval ({period:.3g} s) of its {what} time {times[row]:.6g} s (nearest "
                f"{gap[row]:.3g} s away: clocks or files do not match)"
            )
        return order[j]

    pressed = nearest(probe[:, 0], "press")
    references = None
    if baseline_offset_s is not None:
        references = frames[nearest(probe[:, 0] - baseline_offset_s, "baseline")]
    return PressSession(
        np.asarray(reference, float),
        np.asarray(frames, float)[pressed],
        probe[:, 1:3],
        probe[:, 3] if probe.shape[1] == 4 else None,
        references,
        str(probe_csv),
    )
