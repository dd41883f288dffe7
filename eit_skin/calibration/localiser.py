"""A model-free press localiser: labelled presses -> where (and how deep) a new press is.

Features (no physical model of the sheet is used):

1. relative change per channel ``d = (v - v_ref) / |v_ref|``, ``[T, M]`` (dimensionless;
   the per-press baseline when the session has one, so slow drift cancels);
2. divided by each channel's spread over the training presses (std of ``d``), so no channel
   dominates by its small reference;
3. split into the **pattern** ``u = q / |q|`` (unit vector: where) and the **magnitude**
   ``log |q|`` (how hard). Position is read from the pattern only, so it does not depend on
   depth or force; depth is read from pattern and magnitude.

Model: kernel ridge regression with a Gaussian (RBF) kernel, i.e. the posterior mean of a
Gaussian process. Hyperparameters are chosen inside every fit by a scale-free rule: the length
scale is a factor of the median pairwise distance of the training features, the ridge is
relative to the kernel's unit diagonal, and the pair with the least closed-form leave-one-out
error wins (grids :data:`LENGTH_SCALE_FACTORS` x :data:`RIDGE_GRID`). Nothing is tuned to one
data set.

Confidence of a located press, in [0, 1]: the share of calibration presses whose nearest
other calibration press (in pattern space) is at least as far as this frame's nearest
calibration press. A new press like the calibration presses scores uniformly in [0, 1]
(median ~0.5; 1 on a calibration press itself); a frame unlike any of them (no press, several
presses, an electrode fault, a sheet that changed) scores near 0. Scale-free: it compares
distances only with the calibration set's own spacing.
"""

from __future__ import annotations

import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from eit_skin.calibration.multi_touch import MultiTouchModel, electrode_pitch
from eit_skin.calibration.session import PressSession
from eit_skin.io.npz import write_npz_atomic
from eit_skin.patch.model import Layer

FORMAT_VERSION = 1
"""Version of the calibration file layout; files of another version are refused."""

LENGTH_SCALE_FACTORS = (0.25, 0.5, 1.0, 2.0, 4.0)
"""Kernel length scales tried, as factors of the median pairwise feature distance."""

RIDGE_GRID = tuple(10.0 ** np.arange(-6, 1))
"""Ridge values tried, relative to the kernel's unit diagonal (dimensionless)."""


class CalibrationError(ValueError):
    """A calibration file is invalid or does not belong to the patch: names the file."""


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[A, B]`` squared Euclidean distances between the rows of ``a`` [A, D] and ``b`` [B, D]."""
    d = (a * a).sum(axis=1)[:, None] + (b * b).sum(axis=1)[None, :] - 2.0 * a @ b.T
    return np.maximum(d, 0.0)


@dataclass(frozen=True, eq=False)
class KernelRidge:
    """RBF kernel ridge regression (GP posterior mean) with leave-one-out hyperparameters.

    Attributes:
        inputs: ``[N, D]`` training features.
        gamma: kernel ``exp(-gamma |x - x'|^2)``, 1 / feature unit^2.
        ridge: ridge relative to the unit kernel diagonal.
        weights: ``[N, K]`` dual weights.
        offset: ``[K]`` mean of the training targets (the prediction far from all data).
        spacing: ``[N]`` sorted distances of each training input to its nearest other one.
        loo_error: mean Euclidean leave-one-out error of the chosen pair, target units.
    """

    inputs: np.ndarray
    gamma: float
    ridge: float
    weights: np.ndarray
    offset: np.ndarray
    spacing: np.ndarray
    loo_error: float

    @classmethod
    def fit(
        cls,
        inputs: np.ndarray,
        targets: np.ndarray,
        factors: tuple[float, ...] = LENGTH_SCALE_FACTORS,
        ridges: tuple[float, ...] = RIDGE_GRID,
    ) -> KernelRidge:
        """Fit ``targets`` [N, K] on ``inputs`` [N, D]; the (factor, ridge) pair by LOO error.

        One eigendecomposition per length scale gives the exact leave-one-out residuals
        ``(y - H y) / (1 - diag H)`` of every ridge at once.
        """
        x = np.asarray(inputs, float)
        y = np.asarray(targets, float).reshape(len(x), -1)
        offset = y.mean(axis=0)
        yc = y - offset
        d2 = squared_distances(x, x)
        median = float(np.median(d2[np.triu_indices(len(x), 1)]))
        if not median > 0:
            raise ValueError("all training features are identical: nothing to learn from")
        best = (np.inf, 1.0, 1.0)
        for factor in factors:
            gamma = 1.0 / (2.0 * factor * factor * median)
            s, U = np.linalg.eigh(np.exp(-gamma * d2))
            s = np.maximum(s, 0.0)
            Uy = U.T @ yc
            U2 = U * U
            for ridge in ridges:
                g = s / (s + ridge)
                residual = (yc - U @ (g[:, None] * Uy)) / (1.0 - U2 @ g)[:, None]
                error = float(np.mean(np.linalg.norm(residual, axis=1)))
                if error < best[0]:
                    best = (error, gamma, ridge)
        error, gamma, ridge = best
        weights = np.linalg.solve(np.exp(-gamma * d2) + ridge * np.eye(len(x)), yc)
        np.fill_diagonal(d2, np.inf)
        spacing = np.sort(np.sqrt(d2.min(axis=1)))
        return cls(x, gamma, ridge, weights, offset, spacing, error)

    def predict(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``[T, K]`` prediction, ``[T]`` confidence in [0, 1]) for ``queries`` [T, D]."""
        d2 = squared_distances(queries, self.inputs)
        nearest = np.sqrt(d2.min(axis=1))
        farther = self.spacing.size - np.searchsorted(self.spacing, nearest, side="left")
        return np.exp(-self.gamma * d2) @ self.weights + self.offset, farther / self.spacing.size

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {
            f"{prefix}_inputs": self.inputs,
            f"{prefix}_gamma": np.float64(self.gamma),
            f"{prefix}_ridge": np.float64(self.ridge),
            f"{prefix}_weights": self.weights,
            f"{prefix}_offset": self.offset,
            f"{prefix}_spacing": self.spacing,
            f"{prefix}_loo_error": np.float64(self.loo_error),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> KernelRidge:
        return cls(
            arrays[f"{prefix}_inputs"],
            float(arrays[f"{prefix}_gamma"]),
            float(arrays[f"{prefix}_ridge"]),
            arrays[f"{prefix}_weights"],
            arrays[f"{prefix}_offset"],
            arrays[f"{prefix}_spacing"],
            float(arrays[f"{prefix}_loo_error"]),
        )


def relative_change(frames: np.ndarray, baselines: np.ndarray) -> np.ndarray:
    """``[T, M]`` ``(v - v_ref) / |v_ref|`` of ``frames`` [T, M]; ``baselines`` [M] or [T, M]."""
    frames = np.asarray(frames, float)
    baselines = np.asarray(baselines, float)
    return (frames - baselines) / np.abs(baselines)


@dataclass(frozen=True)
class LocatedPresses:
    """Where the localiser puts each frame's press.

    Attributes:
        xy: ``[T, 2]`` press centres in the sheet frame, m.
        confidence: ``[T]`` in [0, 1] (see the module docstring).
        depth: ``[T]`` press depth, m, or ``None`` if the calibration had no depths.
    """

    xy: np.ndarray
    confidence: np.ndarray
    depth: np.ndarray | None


@dataclass(frozen=True, eq=False)
class PressLocaliser:
    """A fitted press localiser of one layer (see the module docstring for the method).

    Attributes:
        layer_name: the layer it was calibrated on.
        layer_hash: ``Layer.content_hash`` of that layer.
        scale: ``[M]`` per-channel spread of the relative change over the training presses.
        position: position model (pattern -> ``[x, y]`` m).
        depth_model: depth model (pattern, standardised log-magnitude -> depth m), or ``None``.
        magnitude_stats: ``[2]`` mean and std of the training log-magnitudes.
        n_presses: training presses.
        multi_touch: the several-touches model (:mod:`eit_skin.calibration.multi_touch`), or
            ``None`` when calibrated for one touch at a time.
    """

    layer_name: str
    layer_hash: str
    scale: np.ndarray
    position: KernelRidge
    depth_model: KernelRidge | None
    magnitude_stats: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0]))
    n_presses: int = 0
    multi_touch: MultiTouchModel | None = None

    @property
    def n_measurements(self) -> int:
        return int(self.scale.size)

    @classmethod
    def fit(cls, session: PressSession, layer: Layer, max_touches: int = 1) -> PressLocaliser:
        """Fit on ``session`` (checked against ``layer``: channel count, positions on the sheet).

        ``max_touches`` > 1 also fits the several-touches model from the same single presses.
        """
        session.check_layer(layer)
        d = relative_change(session.frames, session.baselines())
        scale = d.std(axis=0)
        scale = np.where(scale > 0, scale, 1.0)  # a channel no press moves carries no pattern
        pattern, magnitude = split_features(d / scale)
        stats = np.array([magnitude.mean(), max(float(magnitude.std()), 1e-12)])
        position = KernelRidge.fit(pattern, session.press_xy)
        depth_model = None
        if session.depth is not None:
            depth_inputs = np.hstack([pattern, ((magnitude - stats[0]) / stats[1])[:, None]])
            depth_model = KernelRidge.fit(depth_inputs, session.depth)
        multi = None
        if max_touches > 1:
            multi = MultiTouchModel.fit(d / scale, session.press_xy, electrode_pitch(layer))
        return cls(
            layer.name,
            layer.content_hash,
            scale,
            position,
            depth_model,
            stats,
            session.n_presses,
            multi,
        )

    def locate(
        self, frames: np.ndarray, reference: np.ndarray, references: np.ndarray | None = None
    ) -> LocatedPresses:
        """Press position, confidence and depth of ``frames`` [T, M].

        Args:
            frames: ``[T, M]`` frames at full press, the unit of the calibration.
            reference: ``[M]`` unloaded frame.
            references: ``[T, M]`` per-frame unloaded frames (used instead of ``reference``).
        """
        baselines = reference if references is None else references
        return self.locate_responses(self.responses(np.asarray(frames, float), baselines))

    def locate_touches(
        self, frame: np.ndarray, baseline: np.ndarray, max_touches: int
    ) -> LocatedPresses:
        """Up to ``max_touches`` presses of one ``frame`` [M] against ``baseline`` [M].

        Rows of the result are touches (count = rows). One touch unless the calibration has a
        several-touches model (``fit(..., max_touches > 1)``) and it counts more (its module).

        Raises:
            CalibrationError: ``max_touches`` > 1 but the calibration was made for one touch.
        """
        x = self.responses(np.asarray(frame, float), baseline)[0]
        if max_touches > 1 and self.multi_touch is None:
            raise CalibrationError(
                f"max_touches {max_touches}: this calibration locates one touch at a time "
                f"(calibrate again with --max-touches {max_touches})"
            )
        split = None if max_touches == 1 else self.multi_touch.decompose(x, max_touches)
        if split is None:
            return self.locate_responses(x[None, :])
        depth = self.locate_responses(split.responses).depth
        return LocatedPresses(split.xy, split.confidence, depth)

    def responses(self, frames: np.ndarray, baselines: np.ndarray) -> np.ndarray:
        """``[T, M]`` channel-scaled relative changes of ``frames`` [T, M] (the model's input)."""
        return relative_change(np.atleast_2d(frames), baselines) / self.scale

    def locate_responses(self, responses: np.ndarray) -> LocatedPresses:
        """Press position, confidence and depth of channel-scaled ``responses`` [T, M]."""
        pattern, magnitude = split_features(np.atleast_2d(responses))
        xy, confidence = self.position.predict(pattern)
        depth = None
        if self.depth_model is not None:
            z = (magnitude - self.magnitude_stats[0]) / self.magnitude_stats[1]
            depth = self.depth_model.predict(np.hstack([pattern, z[:, None]]))[0][:, 0]
        return LocatedPresses(xy, confidence, depth)

    def check_layer(self, layer: Layer, source: str = "calibration") -> None:
        """Raise :class:`CalibrationError` unless this calibration was made on ``layer``."""
        if layer.content_hash != self.layer_hash:
            raise CalibrationError(
                f"{source}: key 'layer_hash': calibrated on layer {self.layer_name!r} with "
                f"content hash {self.layer_hash[:12]}..., but layer {layer.name!r} of this patch "
                f"hashes to {layer.content_hash[:12]}... (another patch, or the patch file "
                "changed since calibration: calibrate again)"
            )

    def check_frames(self, m: int, source: str, key: str = "frames") -> None:
        """Raise :class:`CalibrationError` if frames of ``m`` channels do not fit this model."""
        if m != self.n_measurements:
            raise CalibrationError(
                f"{source}: key '{key}': {m} measurements per frame, the calibration has "
                f"{self.n_measurements}"
            )

    def save(self, path: str | Path) -> None:
        """Write the calibration file atomically (npz, no pickles)."""
        arrays = {
            "format_version": np.int64(FORMAT_VERSION),
            "kind": np.str_("press_localiser"),
            "layer_name": np.str_(self.layer_name),
            "layer_hash": np.str_(self.layer_hash),
            "n_measurements": np.int64(self.n_measurements),
            "n_presses": np.int64(self.n_presses),
            "scale": self.scale,
            "magnitude_stats": self.magnitude_stats,
            **self.position.arrays("position"),
        }
        if self.depth_model is not None:
            arrays.update(self.depth_model.arrays("depth"))
        if self.multi_touch is not None:
            arrays.update(self.multi_touch.arrays("multi"))
        write_npz_atomic(path, **arrays)

    @classmethod
    def load(cls, path: str | Path, layer: Layer | None = None) -> PressLocaliser:
        """Read a calibration file; with ``layer``, refuse one made on another layer."""
        source = str(path)
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except FileNotFoundError as error:
            raise CalibrationError(f"{source}: no such file") from error
        except (zipfile.BadZipFile, OSError, EOFError, ValueError, AttributeError) as error:
            raise CalibrationError(f"{source}: not a readable calibration npz ({error})") from error
        version = arrays.get("format_version")
        if version is None or arrays.get("kind", np.str_("")).item() != "press_localiser":
            raise CalibrationError(
                f"{source}: key 'format_version'/'kind': not a press calibration file "
                "(write one with `eit-skin calibrate`)"
            )
        if int(version) != FORMAT_VERSION:
            raise CalibrationError(
                f"{source}: key 'format_version': version {int(version)}, this eit_skin reads "
                f"version {FORMAT_VERSION} (calibrate again)"
            )
        try:
            model = cls(
                str(arrays["layer_name"]),
                str(arrays["layer_hash"]),
                arrays["scale"],
                KernelRidge.from_arrays(arrays, "position"),
                KernelRidge.from_arrays(arrays, "depth") if "depth_weights" in arrays else None,
                arrays["magnitude_stats"],
                int(arrays["n_presses"]),
                MultiTouchModel.from_arrays(arrays, "multi")
                if "multi_responses" in arrays
                else None,
            )
        except KeyError as error:
            raise CalibrationError(f"{source}: missing key {error}") from error
        if int(arrays["n_measurements"]) != model.scale.size:
            raise CalibrationError(f"{source}: key 'scale': size differs from 'n_measurements'")
        if layer is not None:
            model.check_layer(layer, source)
        return model


def split_features(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(``[T, M]`` unit pattern ``q / |q|``, ``[T]`` log-magnitude ``log |q|``) of ``q`` [T, M]."""
    norm = np.linalg.norm(q, axis=1)
    norm = np.where(norm > 0, norm, np.finfo(float).tiny)
    return q / norm[:, None], np.log(norm)


@dataclass(frozen=True)
class CrossValidation:
    """Out-of-fold predictions of a k-fold cross-validation.

    Attributes:
        xy: ``[T, 2]`` predicted positions, m (each press by a model that never saw it).
        depth: ``[T]`` predicted depths, m, or ``None``.
        xy_error: ``[T]`` position errors, m.
        depth_error: ``[T]`` absolute depth errors, m, or ``None``.
        fit_seconds: mean time of one fit, s.
    """

    xy: np.ndarray
    depth: np.ndarray | None
    xy_error: np.ndarray
    depth_error: np.ndarray | None
    fit_seconds: float


def cross_validate(
    session: PressSession,
    layer: Layer,
    folds: int = 5,
    n_train: int | None = None,
    seed: int = 0,
) -> CrossValidation:
    """k-fold cross-validation of :meth:`PressLocaliser.fit` on ``session``.

    The presses are shuffled (``seed``) into ``folds`` folds; each fold is located by a model
    fitted on the others (only their first ``n_train`` presses if given).
    """
    t = session.n_presses
    if not 2 <= folds <= t:
        raise ValueError(f"folds: need 2 <= folds <= {t} presses, got {folds}")
    order = np.random.default_rng(seed).permutation(t)
    parts = np.array_split(order, folds)
    xy = np.zeros((t, 2))
    depth = None if session.depth is None else np.zeros(t)
    seconds = []
    for i, test in enumerate(parts):
        train = np.concatenate([p for j, p in enumerate(parts) if j != i])[:n_train]
        start = time.perf_counter()
        model = PressLocaliser.fit(session.subset(train), layer)
        seconds.append(time.perf_counter() - start)
        refs = None if session.references is None else session.references[test]
        located = model.locate(session.frames[test], session.reference, refs)
        xy[test] = located.xy
        if depth is not None:
            depth[test] = located.depth
    xy_error = np.linalg.norm(xy - session.press_xy, axis=1)
    depth_error = None if depth is None else np.abs(depth - session.depth)
    return CrossValidation(xy, depth, xy_error, depth_error, float(np.mean(seconds)))
