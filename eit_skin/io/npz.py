"""The offline frames format (``.npz``) and atomic npz writes.

A frames file (the stable input of ``eit-skin reconstruct`` and ``eit-skin classify``) holds
``reference`` float [M] volts (finite), ``frames`` float [T, M] volts (T >= 1, NaN marks a
missing value) and optionally ``t`` float [T] seconds. ``write_npz_atomic`` writes any npz
complete or not at all (temporary file + rename).
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np


def _check_frames(
    where: str,
    reference: Any,
    frames: Any,
    t: Any | None,
    n_measurements: int | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    def real_array(key: str, value: Any) -> np.ndarray:
        array = np.asarray(value)
        if array.dtype.kind not in "fiu":
            raise ValueError(f"{where}: '{key}' must be real numbers, got dtype {array.dtype}")
        return array.astype(np.float64)

    reference = real_array("reference", reference)
    frames = real_array("frames", frames)
    if reference.ndim != 1 or reference.size == 0:
        raise ValueError(f"{where}: 'reference' must have shape [M], got {reference.shape}")
    m = reference.size
    if frames.ndim != 2 or frames.shape[0] == 0 or frames.shape[1] != m:
        raise ValueError(
            f"{where}: 'frames' must have shape [T>=1, M={m}] like 'reference', got {frames.shape}"
        )
    if n_measurements is not None and m != n_measurements:
        raise ValueError(
            f"{where}: 'reference' has M={m} measurements, the protocol expects {n_measurements}"
        )
    if t is not None:
        t = real_array("t", t)
        if t.shape != (frames.shape[0],) or not np.isfinite(t).all():
            raise ValueError(
                f"{where}: 't' must be finite with shape [T={frames.shape[0]}], got {t.shape}"
            )
    return reference, frames, t


def save_frames_npz(
    path: str | Path, reference: np.ndarray, frames: np.ndarray, t: np.ndarray | None = None
) -> None:
    """Write the offline frames file atomically (temporary file + rename).

    Args:
        path: destination (the name is used as given; no ``.npz`` is appended).
        reference: float [M] volts, finite.
        frames: float [T, M] volts.
        t: optional float [T] seconds.
    """
    path = Path(path)
    reference, frames, t = _check_frames(str(path), reference, frames, t, None)
    arrays = {"reference": reference, "frames": frames}
    if t is not None:
        arrays["t"] = t
    write_npz_atomic(path, **arrays)


def write_npz_atomic(path: str | Path, **arrays: np.ndarray | float) -> None:
    """Write an npz next to ``path`` and rename it into place: complete or absent, never half.

    The name is used as given (no ``.npz`` appended); a failure removes the temporary file
    and re-raises.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "wb") as stream:
            np.savez(stream, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_frames_npz(
    path: str | Path, n_measurements: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read and validate an offline frames file: returns (reference [M], frames [T, M], t|None).

    Raises ValueError naming the file and key for a missing key, a wrong shape or dtype or an M
    different from ``n_measurements``. A NaN/Inf in the reference is a missing channel, left to
    the pipeline's reference check (:func:`eit_skin.inverse.channel_noise.check_reference`).
    """
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise ValueError("a single .npy array, not an .npz archive")
        with data:
            arrays = {key: data[key] for key in data.files}
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as error:
        raise ValueError(f"{path}: not a readable .npz frames file ({error})") from error
    for key in ("reference", "frames"):
        if key not in arrays:
            raise ValueError(f"{path}: missing key '{key}' (found {sorted(arrays)})")
    return _check_frames(
        str(path), arrays["reference"], arrays["frames"], arrays.get("t"), n_measurements
    )
