"""A physics prior for the press localiser: presses simulated on the device's model.

A few real presses leave a kernel localiser guessing between them. The patch's model (its
outline, electrodes and protocol, with the sheet conductance and contact impedance
``eit-skin fit-device`` calibrated to the device) predicts how a press anywhere changes the
frame. Presses simulated on it (``eit_skin.sim.press_session``) train a **prior localiser**
(:class:`PhysicsPrior`: the localiser's own features, each channel divided by its spread over
the *simulated* presses, and the same leave-one-out kernel ridge). Its prediction ``m(u)`` for
a real press's pattern ``u`` enters the real localiser's position model
(:class:`PriorPosition`) in one of two ways (:data:`PRIOR_MODES`):

* ``mean``: a prior mean function: the kernel ridge learns the residual ``xy - a m(u)``, so
  far from the real presses the prediction falls back to the (scaled) prior's, not to the
  mean press position;
* ``features``: the prior's position as extra input: the kernel sees ``[u, w g m(u)]``, where
  ``g`` is the ratio of the median pairwise distances of the training patterns ``u`` and of
  the training press centres (scale-free: a metre of prior position weighs as much as the
  patterns of presses a metre apart): presses the model puts close together count as similar.

The weight (``a`` in :data:`MEAN_WEIGHTS` or ``w`` in :data:`FEATURE_WEIGHTS`) is chosen with
the kernel's own hyperparameters by the closed-form leave-one-out error on the real presses,
and so is the mode when several are allowed; the prior is kept only if it beats the plain
model (weight 0, exactly the localiser without prior) by more than one standard error of the
paired leave-one-out differences. So a prior that does not predict the real presses is
switched off by the data, and with many presses, when the kernel needs no prior, its gain
shrinks below the noise of the choice and the plain model is kept.
No constant is fitted to a data set: the grids are fixed, dimensionless and scale-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eit_skin.calibration.features import relative_change, split_features
from eit_skin.calibration.kernel_ridge import (
    KernelRidge,
    clearly_better,
    squared_distances,
)
from eit_skin.calibration.response_map import ResponseMap, fit_position
from eit_skin.calibration.session import PressSession
from eit_skin.calibration.stored_fields import StoredFields, stored_fields

PRIOR_MODES = ("mean", "features")
"""Ways the prior enters the position model (see the module docstring)."""

MEAN_WEIGHTS = (0.0, 0.5, 1.0)
"""Prior mean weights ``a`` tried (dimensionless; 0: no prior)."""

FEATURE_WEIGHTS = (0.0, 0.5, 1.0, 2.0)
"""Prior feature weights ``w`` tried, relative to the patterns' spread (0: no prior)."""


def channel_scale(relative: np.ndarray) -> np.ndarray:
    """``[M]`` per-channel spread (std) of relative changes ``[T, M]``; 1 where none moves."""
    scale = relative.std(axis=0)
    return np.where(scale > 0, scale, 1.0)


@dataclass(frozen=True, eq=False)
class PhysicsPrior:
    """A press localiser trained on simulated presses: pattern ``[T, M]`` -> ``[T, 2]`` m.

    Attributes:
        scale: ``[M]`` per-channel spread of the simulated presses' relative change.
        model: kernel ridge from the simulated patterns to their press centres, m.
        n_presses: simulated presses it was trained on.
    """

    scale: np.ndarray
    model: KernelRidge
    n_presses: int

    @classmethod
    def fit(cls, simulated: PressSession) -> PhysicsPrior:
        """Train on a simulated press session of the layer (its own channel spread)."""
        d = relative_change(simulated.frames, simulated.baselines())
        scale = channel_scale(d)
        pattern, _ = split_features(d / scale)
        return cls(scale, KernelRidge.fit(pattern, simulated.press_xy), simulated.n_presses)

    def predict(self, pattern: np.ndarray) -> np.ndarray:
        """``[T, 2]`` prior press centres, m, of real unit patterns ``[T, M]``."""
        return self.model.predict(pattern)[0]

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        fields = stored_fields(prefix, scale=self.scale, n_presses=np.int64(self.n_presses))
        return fields | self.model.arrays(f"{prefix}_model")

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> PhysicsPrior:
        fields = StoredFields(arrays, prefix)
        model = KernelRidge.from_arrays(arrays, fields.key("model"))
        return cls(fields["scale"], model, int(fields["n_presses"]))


def median_distance(x: np.ndarray) -> float:
    """Median pairwise Euclidean distance of the rows of ``x`` [N, D] (0 if N < 2)."""
    d2 = squared_distances(x, x)[np.triu_indices(len(x), 1)]
    return float(np.sqrt(np.median(d2))) if d2.size else 0.0


@dataclass(frozen=True, eq=False)
class PriorPosition:
    """Position model of a localiser with a physics prior (see the module docstring).

    Attributes:
        prior: the prior localiser.
        mode: ``"mean"`` or ``"features"``.
        weight: the chosen prior weight (0: the plain localiser).
        prior_offset: ``[2]`` mean prior position of the training presses, m (``features``).
        prior_gain: factor from prior positions (m) to feature units (``features``), 1/m.
        residual: the kernel ridge on the real presses (targets ``xy - a m`` for ``mean``,
            inputs ``[u, w m']`` for ``features``).
    """

    prior: PhysicsPrior
    mode: str
    weight: float
    prior_offset: np.ndarray
    prior_gain: float
    residual: KernelRidge

    @property
    def loo_error(self) -> float:
        """Mean leave-one-out position error of the chosen model on the real presses, m."""
        return self.residual.loo_error

    def predict(self, pattern: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``[T, 2]`` press centres m, ``[T]`` confidence in [0, 1]) of patterns ``[T, M]``."""
        m = self.prior.predict(pattern)
        inputs = prior_inputs(
            pattern, m, self.mode, self.weight * self.prior_gain, self.prior_offset
        )
        xy, confidence = self.residual.predict(inputs)
        return xy + prior_mean(m, self.mode, self.weight), confidence

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        own = stored_fields(
            f"{prefix}_prior",
            mode=np.str_(self.mode),
            weight=np.float64(self.weight),
            offset=self.prior_offset,
            gain=np.float64(self.prior_gain),
        )
        return self.residual.arrays(prefix) | own | self.prior.arrays(f"{prefix}_prior")

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> PriorPosition:
        fields = StoredFields(arrays, f"{prefix}_prior")
        mode = str(fields["mode"])
        if mode not in PRIOR_MODES:
            raise ValueError(f"key '{fields.key('mode')}': {mode!r}, want one of {PRIOR_MODES}")
        return cls(
            PhysicsPrior.from_arrays(arrays, fields.prefix),
            mode,
            fields.value("weight"),
            fields["offset"],
            fields.value("gain"),
            KernelRidge.from_arrays(arrays, prefix),
        )


def prior_mean(m: np.ndarray, mode: str, weight: float) -> np.ndarray:
    """``[T, 2]`` the prior mean function at prior positions ``m`` [T, 2], m."""
    return weight * m if mode == "mean" else np.zeros_like(m)


def prior_inputs(
    pattern: np.ndarray, m: np.ndarray, mode: str, gain: float, offset: np.ndarray
) -> np.ndarray:
    """``[T, D]`` kernel inputs: patterns ``[T, M]``, with ``gain (m - offset)`` for features."""
    if mode == "mean" or gain == 0.0:
        return pattern
    return np.hstack([pattern, gain * (m - offset)])


def fit_prior_position(
    pattern: np.ndarray,
    xy: np.ndarray,
    prior: PhysicsPrior,
    modes: tuple[str, ...] = PRIOR_MODES,
) -> KernelRidge | ResponseMap | PriorPosition:
    """Position model of real patterns ``[N, M]`` and press centres ``[N, 2]`` m, with ``prior``.

    Tries every mode of ``modes`` and weight of its grid by leave-one-out error; returns the
    plain model (:func:`~eit_skin.calibration.response_map.fit_position`) unless the best
    prior beats it by more than one standard error of the paired leave-one-out differences
    (else selection noise would decide).
    """
    unknown = set(modes) - set(PRIOR_MODES)
    if not modes or unknown:
        raise ValueError(f"prior modes: {sorted(unknown) or '[]'}, want some of {PRIOR_MODES}")
    m = prior.predict(pattern)
    offset = m.mean(axis=0)
    spread = median_distance(xy)  # metres on the sheet, not the prior's own spread: a prior
    gain = median_distance(pattern) / spread if spread > 0 else 0.0  # that collapses stays so
    plain = fit_position(pattern, xy)  # as without a prior
    best: KernelRidge | ResponseMap | PriorPosition = plain
    for mode in modes:
        for weight in MEAN_WEIGHTS if mode == "mean" else FEATURE_WEIGHTS:
            if weight == 0.0 or (mode == "features" and gain == 0.0):
                continue  # the plain model, or a prior that puts every press at one place
            inputs = prior_inputs(pattern, m, mode, weight * gain, offset)
            model = KernelRidge.fit(inputs, xy - prior_mean(m, mode, weight))
            if model.loo_error < best.loo_error:
                best = PriorPosition(prior, mode, weight, offset, gain, model)
    if best is plain:
        return plain
    return best if clearly_better(plain.loo_errors, best.residual.loo_errors) else plain
