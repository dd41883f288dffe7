"""Convert the multi-touch, damage and repeatability recordings of DSHardman/HydrogelEIT.

Source: https://github.com/DSHardman/HydrogelEIT (Hardman, Thuruthel, Iida, *Tactile perception
in hydrogel-based robotic skins using data-driven electrical impedance tomography*, Materials
Today Electronics 4 (2023) 100032; CC BY 4.0). Reads the MATLAB files straight from a git
directory of that repository (``git show <commit>:<path>``) and writes, next to this script:

* ``hydrogel_multitouch.npz``: the two-probe presses
  (``Extracted/MultiTouch/multitouch{A,B,C}.mat``, probe separations 108, 75,
  20 mm) and the 500 single presses of the same session
  (``Extracted/MultiTouch/superpose500.mat``: positions and depths by the robot), patch
  ``hydrogel_ohmc16.yaml``;
* ``hydrogel_damage.npz``: ``DamageTests/Damage.mat``, the same skin recorded every 8 s while
  it was damaged (``plotDamageDetect.m``), no touch; patch ``hydrogel_ohmc16.yaml``;
* ``hydrogel_rect_repeats.npz``: ``Extracted/Rectangle/repeats_r_s_16_50_5.mat``, 50 random
  points of the 130 x 60 mm rectangular skin pressed 5 times each (``Rectangle
  Tests/RectangularProbing.py``: depths 2, 4, 6 mm), patch ``hydrogel_rect16.yaml``.

Values are the board's magnitudes (multiples of 1/16), stored as float32 (exact: checked).
Run: ``.venv/bin/python data/real/convert_hydrogel_eit.py GIT_DIR [COMMIT]``.
"""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import scipy.io

OUT = Path(__file__).resolve().parent
REPO = "DSHardman/HydrogelEIT"
SEPARATIONS_M = {"A": 0.108, "B": 0.075, "C": 0.020}
DAMAGE_PERIOD_S = 8.0  # plotDamageDetect.m: time axis 0:8:8*(T-1) s


def load_mat(git_dir: str, commit: str, path: str) -> dict[str, np.ndarray]:
    """The variables of one MATLAB file of the source repository."""
    blob = subprocess.run(
        ["git", "-C", git_dir, "show", f"{commit}:{path}"], check=True, capture_output=True
    ).stdout
    return {k: v for k, v in scipy.io.loadmat(io.BytesIO(blob)).items() if not k.startswith("__")}


def exact32(values: np.ndarray, what: str) -> np.ndarray:
    """``values`` as float32, refusing any rounding."""
    out = np.asarray(values, dtype=np.float32)
    if not np.array_equal(out.astype(np.float64), values):
        raise ValueError(f"{what}: values are not exact in float32")
    return out


def protocol_arrays() -> dict[str, np.ndarray]:
    """``ex_mat`` and ``meas_mat`` of the OpenEIT opposite-drive protocol (hydrogel_ohmc16)."""
    with np.load(OUT / "hydrogel_ohmc16.npz") as d:
        return {"ex_mat": d["ex_mat"], "meas_mat": d["meas_mat"]}


def multitouch(git_dir: str, commit: str) -> dict[str, np.ndarray]:
    single = load_mat(git_dir, commit, "Extracted/MultiTouch/superpose500.mat")
    ups, downs, sets, duplicate, sources = [], [], [], [], []
    for name in SEPARATIONS_M:
        path = f"Extracted/MultiTouch/multitouch{name}.mat"
        m = load_mat(git_dir, commit, path)
        for k in range(len(m["responsedowns"])):
            same = [
                j
                for j in range(k)
                if np.array_equal(m["responsedowns"][j], m["responsedowns"][k])
                and np.array_equal(m["responseups"][j], m["responseups"][k])
            ]
            duplicate.append(len(ups) - k + same[0] if same else -1)
            ups.append(m["responseups"][k])
            downs.append(m["responsedowns"][k])
            sets.append(name)
        sources.append(path)
    ups_a, downs_a = np.array(ups), np.array(downs)
    reference = single["responseups"].mean(axis=0)
    t = len(ups_a)
    labels = [
        f"two probes {SEPARATIONS_M[s] * 1000:.0f} mm apart, set {s}"
        + (f" (copy of row {d})" if d >= 0 else "")
        for s, d in zip(sets, duplicate, strict=True)
    ]
    return {
        "reference": reference,
        "frames": reference * downs_a / ups_a,
        "ups": exact32(ups_a, "multitouch ups"),
        "downs": exact32(downs_a, "multitouch downs"),
        "truth_xy": np.full((t, 2, 2), np.nan),
        "truth_r": np.full(2, np.nan),
        "expected_sign": np.int64(-1),
        "labels": np.array(labels),
        "set": np.array(sets),
        "separation_m": np.array([SEPARATIONS_M[s] for s in sets]),
        "duplicate_of": np.array(duplicate, dtype=np.int64),
        "single_ups": exact32(single["responseups"], "superpose500 ups"),
        "single_downs": exact32(single["responsedowns"], "superpose500 downs"),
        "single_xy": single["positions"][:, :2],
        "single_depth": single["positions"][:, 2],
        "source": np.str_(
            f"{REPO}@{commit}:" + " + ".join([*sources, "Extracted/MultiTouch/superpose500.mat"])
        ),
        **protocol_arrays(),
    }


def damage(git_dir: str, commit: str) -> dict[str, np.ndarray]:
    frames = load_mat(git_dir, commit, "DamageTests/Damage.mat")["damage"]
    t = np.arange(len(frames)) * DAMAGE_PERIOD_S
    return {
        "reference": frames[0].astype(np.float64),
        "frames": exact32(frames, "damage"),
        "t": t,
        "truth_xy": np.full((len(frames), 1, 2), np.nan),
        "truth_r": np.full(1, np.nan),
        "expected_sign": np.int64(-1),
        "labels": np.array([f"damage test, no touch, t = {s:.0f} s" for s in t]),
        "source": np.str_(f"{REPO}@{commit}:DamageTests/Damage.mat"),
        **protocol_arrays(),
    }


def rect_repeats(git_dir: str, commit: str) -> dict[str, np.ndarray]:
    m = load_mat(git_dir, commit, "Extracted/Rectangle/repeats_r_s_16_50_5.mat")
    responses, positions = m["responses"], m["positions"]  # [50, 5, 192], [50, 3]
    n_points, n_repeats, n_channels = responses.shape
    frames = responses.reshape(-1, n_channels)
    point = np.repeat(np.arange(n_points), n_repeats)
    # the rectangle's frame: the probing script's x in [0, 130] mm, y in [0, 60] mm from
    # one corner; the patch is centred on the sheet
    xy = positions[point, :2] - np.array([0.065, 0.030])
    return {
        # no unloaded frame was recorded: the median press frame stands in for it
        "reference": np.median(frames, axis=0),
        "frames": exact32(frames, "repeats"),
        "truth_xy": xy[:, None, :],
        "truth_r": np.array([0.0025]),
        "expected_sign": np.int64(-1),
        "labels": np.array([f"point {p}, repeat {r}" for p in range(n_points) for r in range(5)]),
        "point": point,
        "repeat": np.tile(np.arange(n_repeats), n_points),
        "depth": positions[point, 2],
        "source": np.str_(f"{REPO}@{commit}:Extracted/Rectangle/repeats_r_s_16_50_5.mat"),
        **protocol_arrays(),
    }


def main(argv: list[str]) -> int:
    if len(argv) not in (1, 2):
        print(__doc__, file=sys.stderr)
        return 2
    git_dir = argv[0]
    commit = argv[1] if len(argv) == 2 else "HEAD"
    commit = subprocess.run(
        ["git", "-C", git_dir, "rev-parse", commit], check=True, capture_output=True, text=True
    ).stdout.strip()
    for name, make in (
        ("hydrogel_multitouch", multitouch),
        ("hydrogel_damage", damage),
        ("hydrogel_rect_repeats", rect_repeats),
    ):
        path = OUT / f"{name}.npz"
        np.savez_compressed(path, **make(git_dir, commit))
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
