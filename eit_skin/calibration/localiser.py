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

from eit_skin.calibration.features import relative_change, split_features
from eit_skin.calibration.kernel_ridge import KernelRidge
from eit_skin.calibration.multi_touch import MultiTouchModel, electrode_pitch
from eit_skin.calibration.physics_prior import (
    PRIOR_MODES,
    PhysicsPrior,
    PriorPosition,
    fit_prior_position,
)
from eit_skin.calibration.response_map import ResponseMap, fit_position
from eit_skin.calibration.session import PressSession
from eit_skin.io.npz import write_npz_atomic
from eit_skin.patch.model import Layer

FORMAT_VERSION = 1
"""Version of the calibration file layout; files of another version are refused."""

PRIOR_FORMAT_VERSION = 2
"""Version of a file whose position model has a physics prior (readers of version 1 refuse it)."""

RESPONSE_MAP_FORMAT_VERSION = 3
"""Version of a file whose position model is a response map (older readers refuse it)."""

POSITION_MODELS = {
    FORMAT_VERSION: KernelRidge,
    PRIOR_FORMAT_VERSION: PriorPosition,
    RESPONSE_MAP_FORMAT_VERSION: ResponseMap,
}
"""The position model class a file of each format version stores."""


class CalibrationError(ValueError):
    """A calibration file is invalid or does not belong to the patch: names the file."""


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
        position: position model (pattern -> ``[x, y]`` m): inverse kernel ridge, with a
            physics prior or without, or a response map (:mod:`~eit_skin.calibration.response_map`).
        depth_model: depth model (pattern, standardised log-magnitude -> depth m), or ``None``.
        magnitude_stats: ``[2]`` mean and std of the training log-magnitudes.
        n_presses: training presses.
        multi_touch: the several-touches model (:mod:`eit_skin.calibration.multi_touch`), or
            ``None`` when calibrated for one touch at a time.
    """

    layer_name: str
    layer_hash: str
    scale: np.ndarray
    position: KernelRidge | PriorPosition | ResponseMap
    depth_model: KernelRidge | None
    magnitude_stats: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0]))
    n_presses: int = 0
    multi_touch: MultiTouchModel | None = None

    @property
    def n_measurements(self) -> int:
        return int(self.scale.size)

    @classmethod
    def fit(
        cls,
        session: PressSession,
        layer: Layer,
        max_touches: int = 1,
        *,
        prior: PhysicsPrior | None = None,
        prior_modes: tuple[str, ...] = PRIOR_MODES,
    ) -> PressLocaliser:
        """Fit on ``session`` (checked against ``layer``: channel count, positions on the sheet).

        ``max_touches`` > 1 also fits the several-touches model from the same single presses.

        With ``prior`` (presses simulated on the layer's model), position is fitted with it
        (:func:`~eit_skin.calibration.physics_prior.fit_prior_position`: mode among
        ``prior_modes`` and weight by leave-one-out; the plain model unless the prior wins).
        """
        session.check_layer(layer)
        d = relative_change(session.frames, session.baselines())
        scale = d.std(axis=0)
        scale = np.where(scale > 0, scale, 1.0)  # a channel no press moves carries no pattern
        pattern, magnitude = split_features(d / scale)
        stats = np.array([magnitude.mean(), max(float(magnitude.std()), 1e-12)])
        position = (
            fit_position(pattern, session.press_xy)
            if prior is None
            else fit_prior_position(pattern, session.press_xy, prior, prior_modes)
        )
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
        version = next(v for v, kind in POSITION_MODELS.items() if type(self.position) is kind)
        arrays = {
            "format_version": np.int64(version),
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
        if int(version) not in POSITION_MODELS:
            raise CalibrationError(
                f"{source}: key 'format_version': version {int(version)}, this eit_skin reads "
                f"versions {sorted(POSITION_MODELS)} (calibrate again)"
            )
        try:
            model = cls(
                str(arrays["layer_name"]),
                str(arrays["layer_hash"]),
                arrays["scale"],
                POSITION_MODELS[int(version)].from_arrays(arrays, "position"),
                KernelRidge.from_arrays(arrays, "depth") if "depth_weights" in arrays else None,
                arrays["magnitude_stats"],
                int(arrays["n_presses"]),
                MultiTouchModel.from_arrays(arrays, "multi")
                if "multi_responses" in arrays
                else None,
            )
        except KeyError as error:
            raise CalibrationError(f"{source}: missing key {error}") from error
        except ValueError as error:
            raise CalibrationError(f"{source}: {error}") from error
        if int(arrays["n_measurements"]) != model.scale.size:
            raise CalibrationError(f"{source}: key 'scale': size differs from 'n_measurements'")
        if layer is not None:
            model.check_layer(layer, source)
        return model


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
    prior: PhysicsPrior | None = None,
    prior_modes: tuple[str, ...] = PRIOR_MODES,
) -> CrossValidation:
    """k-fold cross-validation of :meth:`PressLocaliser.fit` on ``session``.

    The presses are shuffled (``seed``) into ``folds`` folds; each fold is located by a model
    fitted on the others (only their first ``n_train`` presses if given), with ``prior`` if
    given (see :meth:`PressLocaliser.fit`).
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
        model = PressLocaliser.fit(
            session.subset(train), layer, prior=prior, prior_modes=prior_modes
        )
        seconds.append(time.perf_counter() - start)
        refs = None if session.references is None else session.references[test]
        located = model.locate(session.frames[test], session.reference, refs)
        xy[test] = located.xy
        if depth is not None:
            depth[test] = located.depth
    xy_error = np.linalg.norm(xy - session.press_xy, axis=1)
    depth_error = None if depth is None else np.abs(depth - session.depth)
    return CrossValidation(xy, depth, xy_error, depth_error, float(np.mean(seconds)))
