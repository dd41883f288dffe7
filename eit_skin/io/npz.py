"""The offline frames format (``.npz``) and atomic npz writes.

A frames file (the stable input of ``eit-skin reconstruct`` and ``eit-skin classify``) holds
``reference`` float [M] volts (NaN/Inf: a missing channel, left out by the pipeline's
reference check), ``frames`` float [T, M] volts (T >= 1, NaN marks a
missing value) and optionally ``t`` float [T] seconds and ``references`` float [T, M] volts
(a no-load frame per frame: each frame is imaged against its own, e.g. a press and the frame
just before it). A device's own frames (the full layout, complex values:
:meth:`eit_skin.patch.protocol.Protocol.select`) are read through a ``convert`` function
(:class:`FramesNpzReader`). ``write_npz_atomic`` writes any npz complete or not at all
(temporary file + rename).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Iterator
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


_ZIP_SIGNATURES = (b"PK\x03\x04", b"PK\x05\x06")
"""The first bytes of an ``.npz``: a zip archive (an empty one starts ``PK\x05\x06``)."""


def _require_zip(path: str | Path) -> None:
    """ValueError naming ``path`` unless it starts like a zip archive (an ``.npz``).

    Without it numpy takes any other file for a pickle and talks about pickled data.
    """
    with open(path, "rb") as stream:
        head = stream.read(4)
    if head not in _ZIP_SIGNATURES:
        raise ValueError(
            f"{path}: not an .npz frames file: an .npz is a zip archive (starting 'PK'), this "
            f"file starts with {head!r}"
        )


def load_frames_npz(
    path: str | Path, n_measurements: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read and validate an offline frames file: returns (reference [M], frames [T, M], t|None).

    Raises ValueError naming the file and key for a missing key, a wrong shape or dtype or an M
    different from ``n_measurements``. A NaN/Inf in the reference is a missing channel, left to
    the pipeline's reference check (:func:`eit_skin.inverse.channel_noise.check_reference`).
    """
    _require_zip(path)
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


#: Frames per block of the streaming reader (208 channels x 4096 x 8 B = 6.8 MB).
DEFAULT_BLOCK_FRAMES = 4096


def _member_header(
    path: str, key: str, stream: Any, complex_ok: bool = False
) -> tuple[tuple[int, ...], bool, np.dtype]:
    """Shape, Fortran order and dtype of a ``.npy`` member opened at its start."""
    try:
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(stream)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(stream)
    except ValueError as error:
        raise ValueError(f"{path}: '{key}' is not a .npy array ({error})") from error
    if dtype.kind not in ("fiuc" if complex_ok else "fiu") or dtype.hasobject:
        what = "real or complex numbers" if complex_ok else "real numbers"
        raise ValueError(f"{path}: '{key}' must be {what}, got dtype {dtype}")
    return tuple(shape), bool(fortran), dtype


class FramesNpzReader:
    """An offline frames file read block by block: memory bounded by ``block_frames``.

    ``reference`` is read and checked at once; ``frames`` and ``t`` are streamed from their
    ``.npy`` members (stored or deflated: read through :mod:`zipfile`, never loaded whole,
    except a Fortran-ordered ``frames``, which is read in one go). Every problem raises
    ValueError naming the file, the key and, for values, the frame index.

    Args:
        path: the ``.npz`` frames file (format: module docstring).
        n_measurements: the M the protocol expects, or None.
        block_frames: frames per block of :meth:`blocks` (>= 1).
        convert: device frames ``[..., W]`` (real or complex) and a ``"<file>: '<key>'"``
            label -> float ``[..., M]`` (e.g. :meth:`~eit_skin.patch.protocol.Protocol.select`,
            which raises naming the label when ``W`` is wrong); None: the file holds the
            ``M`` real values themselves.

    Attributes:
        reference: float64 ``[M]`` V. n_frames: T. has_t: whether the file has ``t``.
        has_references: whether the file has per-frame ``references`` [T, M].
    """

    def __init__(
        self,
        path: str | Path,
        n_measurements: int | None = None,
        block_frames: int = DEFAULT_BLOCK_FRAMES,
        convert: Callable[[np.ndarray, str], np.ndarray] | None = None,
    ) -> None:
        if block_frames < 1:
            raise ValueError(f"block_frames must be >= 1, got {block_frames}")
        self.path = Path(path)
        self.block_frames = int(block_frames)
        where = str(self.path)
        members, reference, headers = _read_headers(self.path, convert is not None)
        self._members = members
        self._convert = convert
        shape, self._fortran, self._dtype = headers["frames"]
        t_shape = headers["t"][0] if "t" in headers else None
        if convert is not None:
            reference = _converted_reference(where, reference, shape, convert)
            n_measurements = None  # convert checked the device frame's width
        # the in-memory checks (same messages as load_frames_npz), frames' shape checked apart
        stand_in = np.zeros((1, max(np.size(reference), 1)))
        self.reference, _, _ = _check_frames(where, reference, stand_in, None, n_measurements)
        m = self.reference.size
        self._width = int(shape[1]) if len(shape) == 2 else m
        if convert is not None:
            shape = (shape[0], m)
        if len(shape) != 2 or shape[0] == 0 or shape[1] != m:
            raise ValueError(
                f"{where}: 'frames' must have shape [T>=1, M={m}] like 'reference', got {shape}"
            )
        self.n_frames = int(shape[0])
        self.n_measurements = int(shape[1])
        if t_shape is not None and t_shape != (self.n_frames,):
            raise ValueError(
                f"{where}: 't' must be finite with shape [T={self.n_frames}], got {t_shape}"
            )
        self.has_t = t_shape is not None
        self._t_dtype = headers["t"][2] if self.has_t else None
        self.has_references = "references" in headers
        if self.has_references:
            r_shape, r_fortran, self._r_dtype = headers["references"]
            if r_shape != (self.n_frames, self._width):
                raise ValueError(
                    f"{where}: 'references' must have the shape of 'frames' "
                    f"[{self.n_frames}, {self._width}], got {r_shape}"
                )
            if r_fortran:
                raise ValueError(f"{where}: 'references' must be C-ordered (np.ascontiguousarray)")

    def head(self, n: int) -> np.ndarray:
        """The first ``min(n, T)`` frames, float64 ``[n, M]`` V."""
        n = min(max(int(n), 0), self.n_frames)
        rows: list[np.ndarray] = []
        for _, frames, _ in self.blocks():
            rows.append(frames[: n - sum(len(r) for r in rows)])
            if sum(len(r) for r in rows) >= n:
                break
        return np.concatenate(rows) if rows else np.zeros((0, self.n_measurements))

    def blocks(self) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
        """``(start, frames float64 [B, M] V, t float64 [B] s or None)`` over the file."""
        for start, frames, t, _ in self.blocks_with_references():
            yield start, frames, t

    def blocks_with_references(
        self,
    ) -> Iterator[tuple[int, np.ndarray, np.ndarray | None, np.ndarray | None]]:
        """As :meth:`blocks`, plus the block's ``references`` float64 ``[B, M]`` V (or None)."""
        where = str(self.path)
        try:
            with zipfile.ZipFile(self.path) as archive:
                frames_stream = archive.open(self._members["frames"])
                t_stream = archive.open(self._members["t"]) if self.has_t else None
                r_stream = (
                    archive.open(self._members["references"]) if self.has_references else None
                )
                with (
                    frames_stream,
                    t_stream or contextlib.nullcontext(),
                    r_stream or contextlib.nullcontext(),
                ):
                    _member_header(where, "frames", frames_stream, self._convert is not None)
                    if t_stream is not None:
                        _member_header(where, "t", t_stream)
                    if r_stream is not None:
                        _member_header(where, "references", r_stream, self._convert is not None)
                    whole = None
                    if self._fortran:
                        shape = (self.n_frames, self._width)
                        whole = self._rows(frames_stream, "frames", 0, shape, self._dtype)
                    for start in range(0, self.n_frames, self.block_frames):
                        n = min(self.block_frames, self.n_frames - start)
                        if whole is not None:
                            frames = whole[start : start + n]
                        else:
                            shape = (n, self._width)
                            frames = self._rows(frames_stream, "frames", start, shape, self._dtype)
                        frames = self._converted(frames, "frames")
                        t = None
                        if t_stream is not None:
                            t = self._rows(t_stream, "t", start, (n,), self._t_dtype)
                            if not np.isfinite(t).all():
                                bad = start + int(np.flatnonzero(~np.isfinite(t))[0])
                                raise ValueError(
                                    f"{where}: 't' must be finite, frame {bad} is {t[bad - start]}"
                                )
                        refs = None
                        if r_stream is not None:
                            shape = (n, self._width)
                            refs = self._rows(r_stream, "references", start, shape, self._r_dtype)
                            refs = self._converted(refs, "references")
                        yield start, frames, t, refs
        except (zipfile.BadZipFile, OSError, EOFError) as error:
            raise ValueError(f"{where}: not a readable .npz frames file ({error})") from error

    def _converted(self, rows: np.ndarray, key: str) -> np.ndarray:
        if self._convert is None:
            return rows
        return np.asarray(self._convert(rows, f"{self.path}: '{key}'"), dtype=np.float64)

    def _rows(
        self,
        stream: Any,
        key: str,
        start: int,
        shape: tuple[int, ...],
        dtype: np.dtype,
    ) -> np.ndarray:
        """The next ``shape[0]`` rows of a member as float64; ValueError if it ends early.

        A Fortran-ordered ``frames`` member is read whole (``shape`` all its rows).
        """
        fortran = key == "frames" and self._fortran
        count = int(np.prod(shape))
        data = stream.read(count * dtype.itemsize)
        if len(data) < count * dtype.itemsize:
            got = len(data) // max(dtype.itemsize * int(np.prod(shape[1:])), 1)
            raise ValueError(
                f"{self.path}: '{key}' is cut short: it ends at frame {start + got} of "
                f"{self.n_frames}"
            )
        array = np.frombuffer(data, dtype=dtype, count=count)
        array = array.reshape(shape[::-1]).T if fortran else array.reshape(shape)
        return array.astype(np.complex128 if dtype.kind == "c" else np.float64)


class NpzStreamWriter:
    """An npz written row block by row block, renamed into place only when complete.

    Each array's rows are streamed raw into a temporary directory next to ``path``;
    :meth:`close` checks that every array got all its rows, packs them as ``.npy`` members
    into a zip (stored, zip64: what ``np.savez`` writes, so ``np.load`` reads it) and renames
    it into place. Memory: one block; disk: twice the output while closing. Leaving the
    context with an exception (or :meth:`discard`) removes everything: the destination is
    complete or untouched.

    Args:
        path: destination (the name is used as given; no ``.npz`` is appended).
        arrays: name -> (shape, dtype) of every array, members in this order; the first
            axis is filled by :meth:`append` (None: as many rows as are appended; None in
            another axis: that of the first block).
    """

    def __init__(
        self, path: str | Path, arrays: dict[str, tuple[tuple[int | None, ...], Any]]
    ) -> None:
        self.path = Path(path)
        self._dir = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
        self._shapes = {
            name: (tuple(shape), np.dtype(dtype)) for name, (shape, dtype) in arrays.items()
        }
        self._rows = dict.fromkeys(arrays, 0)
        self._files: dict[str, Any] = {}
        try:
            for name in self._shapes:
                self._files[name] = open(self._dir / name, "wb")  # noqa: SIM115 (see close)
        except BaseException:
            self.discard()
            raise

    def append(self, **blocks: np.ndarray) -> None:
        """Add rows ``[B, ...]`` to the named arrays (each array's rows in order)."""
        for name, block in blocks.items():
            shape, dtype = self._shapes[name]
            block = np.ascontiguousarray(block, dtype=dtype)
            if None in shape[1:]:  # set by the first block
                shape = (shape[0], *block.shape[1:])
                self._shapes[name] = (shape, dtype)
            rows = self._rows[name] + len(block)
            if block.shape[1:] != shape[1:] or (shape[0] is not None and rows > shape[0]):
                raise ValueError(
                    f"{self.path}: '{name}' rows {block.shape} do not fit {shape} after "
                    f"{self._rows[name]} rows"
                )
            self._files[name].write(block.tobytes())
            self._rows[name] = rows

    def close(self) -> None:
        """Check completeness, pack the zip and rename it into place; then clean up."""
        try:
            for name, (shape, _) in self._shapes.items():
                if shape[0] is not None and self._rows[name] != shape[0]:
                    raise ValueError(
                        f"{self.path}: '{name}' got {self._rows[name]} of {shape[0]} rows"
                    )
                self._files[name].close()
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=self.path.parent)
            try:
                with (
                    os.fdopen(fd, "wb") as raw,
                    zipfile.ZipFile(raw, "w", zipfile.ZIP_STORED, allowZip64=True) as archive,
                ):
                    for name, (shape, dtype) in self._shapes.items():
                        header = {
                            "descr": np.lib.format.dtype_to_descr(dtype),
                            "fortran_order": False,
                            "shape": (self._rows[name], *shape[1:]),
                        }
                        with (
                            open(self._dir / name, "rb") as src,
                            archive.open(f"{name}.npy", "w", force_zip64=True) as dst,
                        ):
                            np.lib.format.write_array_header_2_0(dst, header)
                            shutil.copyfileobj(src, dst, 1 << 20)
                os.replace(tmp, self.path)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        finally:
            self.discard()

    def discard(self) -> None:
        """Remove the temporary files (the destination is left as it was)."""
        for stream in self._files.values():
            stream.close()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> NpzStreamWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.discard()


def _read_headers(
    path: Path, converted: bool
) -> tuple[dict[str, str], np.ndarray, dict[str, tuple[tuple[int, ...], bool, np.dtype]]]:
    """``(members by key, reference, header of frames/t/references)`` of an npz frames file.

    ``converted``: frames and references hold device frames to be converted.
    """
    where = str(path)
    try:
        with zipfile.ZipFile(path) as archive:
            members = {
                name.removesuffix(".npy"): name
                for name in archive.namelist()
                if name.endswith(".npy")
            }
            for key in ("reference", "frames"):
                if key not in members:
                    raise ValueError(f"{where}: missing key '{key}' (found {sorted(members)})")
            with archive.open(members["reference"]) as stream:
                reference = np.lib.format.read_array(stream, allow_pickle=False)
            headers = {}
            for key in ("frames", "t", "references"):
                if key in members:
                    with archive.open(members[key]) as stream:
                        headers[key] = _member_header(where, key, stream, converted and key != "t")
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError) as error:
        raise ValueError(f"{where}: not a readable .npz frames file ({error})") from error
    return members, reference, headers


def _converted_reference(
    where: str,
    reference: np.ndarray,
    shape: tuple[int, ...],
    convert: Callable[[np.ndarray, str], np.ndarray],
) -> np.ndarray:
    """The device-frame ``reference`` ``[W]`` checked against the frames' ``shape``, converted."""
    if np.ndim(reference) != 1 or np.size(reference) == 0:
        raise ValueError(
            f"{where}: 'reference' must have shape [W] (one device frame), got "
            f"{np.shape(reference)}"
        )
    if np.asarray(reference).dtype.kind not in "fiuc":
        raise ValueError(
            f"{where}: 'reference' must be real or complex numbers, got dtype "
            f"{np.asarray(reference).dtype}"
        )
    width = np.size(reference)
    if len(shape) != 2 or shape[0] == 0 or shape[1] != width:
        raise ValueError(
            f"{where}: 'frames' must have shape [T>=1, W={width}] like 'reference', got {shape}"
        )
    return convert(reference, f"{where}: 'reference'")
