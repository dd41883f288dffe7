"""A tiny learned alternative to the touch rules: softmax regression on the rules' features.

Used by ``bench/standing/bench_hard_scenes.py`` to compare, on held-out (report) seeds, the rules of
:func:`~eit_skin.touch.events.decide` with a model trained on the tuning seeds' scenes.
Both label the same segmented touches (the classifier's END events matched to the truth),
so only the decision differs. numpy only; the model is a ``[F + 1, 4]`` weight matrix.

Inputs per touch (:data:`FEATURES`, all scale-free): ``spread``, ``major``, ``travel``,
``closing``, ``trend`` (signed, clipped to +-20), ``narrowing`` and ``shape_z`` (as
``arcsinh(z)``: it spans 0 to thousands; 0 where it is NaN) of
:class:`~eit_skin.touch.events.TouchFeatures`, standardised with the training set's
mean and standard deviation. Balanced classes (each touch weighted by 1 / its class count),
L2 penalty ``L2``, full-batch gradient descent.
"""

from __future__ import annotations

import numpy as np

from eit_skin.touch.events import LABELS

FEATURES = ("spread", "major", "travel", "closing", "trend", "narrowing", "shape_z")
L2 = 1e-2
STEPS = 3000
RATE = 0.5


def feature_matrix(features: list) -> np.ndarray:
    """``[N, F]`` from :class:`TouchFeatures` records."""
    x = np.array([[getattr(f, name) for name in FEATURES] for f in features], dtype=float)
    x[:, FEATURES.index("trend")] = np.clip(x[:, FEATURES.index("trend")], -20, 20)
    z = x[:, FEATURES.index("shape_z")]
    x[:, FEATURES.index("shape_z")] = np.where(np.isfinite(z), np.arcsinh(z), 0.0)
    return x.reshape(-1, len(FEATURES))


def train(x: np.ndarray, labels: list[str]) -> dict:
    """Softmax regression on ``x`` ``[N, F]``; returns the model (mean, scale, weights)."""
    y = np.array([LABELS.index(lab) for lab in labels])
    mean, scale = x.mean(axis=0), x.std(axis=0) + 1e-9
    z = np.column_stack([(x - mean) / scale, np.ones(len(x))])
    onehot = np.eye(len(LABELS))[y]
    counts = np.maximum(onehot.sum(axis=0), 1.0)
    weight = (onehot / counts).sum(axis=1)  # balanced classes
    weight /= weight.sum()
    w = np.zeros((z.shape[1], len(LABELS)))
    for _ in range(STEPS):
        logits = z @ w
        p = np.exp(logits - logits.max(axis=1, keepdims=True))
        p /= p.sum(axis=1, keepdims=True)
        grad = z.T @ ((p - onehot) * weight[:, None]) + L2 * w
        w -= RATE * grad
    return {"mean": mean, "scale": scale, "weights": w}


def predict(model: dict, x: np.ndarray) -> list[str]:
    """Labels of ``x`` ``[N, F]``."""
    z = np.column_stack([(x - model["mean"]) / model["scale"], np.ones(len(x))])
    return [LABELS[k] for k in np.argmax(z @ model["weights"], axis=1)]
